"""Coverage of stated intervals: an estimator repeated R times with different seeds against a known
truth.

``coverage(estimate, truth, seeds)`` calls ``estimate(seed) -> Answer`` for every seed and
reports the fraction of intervals that contain the truth with its Wilson 95% interval (the
sampling error of the coverage estimate itself: with R = 200 and a true coverage of 0.95 the
estimate's standard deviation is 0.015), the mean stated relative error, the actual relative
errors (root mean square and 95th percentile) and the mean cost. For a map the interval covers
when it holds the truth at every point; the fraction of (repetition, point) pairs covered is
reported too (``coverage_points``: each point's interval is a 95% one, not the set). With
``pool_truth`` (the statistic of the pool the repetitions draw from) the coverage of that value
is reported beside (``coverage_pool``).
"""
import numpy as np
from scipy import stats


def wilson(k, n, confidence=0.95):
    """Wilson score interval of a binomial proportion k / n."""
    z = stats.norm.ppf(0.5 + confidence / 2)
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return c - h, c + h


def repeat(estimate, seeds):
    """The answers of ``estimate(seed)`` for each seed: a list of {value, lo, hi, stated, cost}
    (lists for a map), kept so that they can be scored against another truth later."""
    out = []
    for s in seeds:
        a = estimate(int(s))
        out.append({"seed": int(s), "value": a.value.tolist(), "lo": a.lo.tolist(), "hi": a.hi.tolist(),
                    "stated": float(a.stated_error), "cost": float(a.cost)})
    return out


def score(answers, truth, pool_truth=None):
    """The coverage figures of repeated answers against a truth (and a pool's value)."""
    t = np.asarray(truth, float)
    v, lo, hi = (np.array([np.atleast_1d(a[k]) for a in answers], float) for k in ("value", "lo", "hi"))
    inside = (lo <= t) & (t <= hi)
    hits = int(np.sum(np.all(inside, axis=1)))
    stated = np.array([a["stated"] for a in answers])
    actual = np.max(np.abs(v - t) / np.abs(t), axis=1)
    R = len(answers)
    c_lo, c_hi = wilson(hits, R)
    extra = {"coverage_points": float(np.mean(inside))} if t.size > 1 else {}
    if pool_truth is not None:
        p = np.asarray(pool_truth, float)
        extra["coverage_pool"] = float(np.mean(np.all((lo <= p) & (p <= hi), axis=1)))
    fin = stated[np.isfinite(stated)]
    return {"repetitions": R, "coverage": hits / R, "coverage_lo": c_lo, "coverage_hi": c_hi, **extra,
            "stated_error_mean": float(np.mean(fin)) if fin.size else None,
            "stated_finite": int(fin.size),
            "actual_error_rms": float(np.sqrt(np.mean(actual ** 2))),
            "actual_error_p95": float(np.quantile(actual, 0.95)),
            "cost_mean": float(np.mean([a["cost"] for a in answers]))}


def coverage(estimate, truth, seeds, pool_truth=None):
    """Run ``estimate(seed)`` for each seed; a dict of the coverage figures (``score``) with the
    answers themselves under ``answers``."""
    answers = repeat(estimate, seeds)
    return {**score(answers, truth, pool_truth), "answers": answers}
