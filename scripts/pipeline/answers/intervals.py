"""The answer record and the statistics of one sample with their confidence intervals.

* mean: Student t interval;
* standard deviation: chi-square interval on the variance with the degrees of freedom matched to
  the sample kurtosis (df = 2 s^4 / est. Var(s^2), at most n - 1: wider for heavy tails, never
  narrower than a Gaussian sample's), square-rooted;
* quantile q_p: distribution-free order-statistic interval [y_(l), y_(u)] with l, u the binomial
  (n, p) quantiles (an end is infinite when the sample is too small to bound it);
* exceedance probability P(Y > c): Clopper-Pearson (exact binomial) interval;
* a QoI censored at a horizon (the value of a run that never reaches it): the mean and sd of the
  censored QoI with intervals that bound the censored fraction by Clopper-Pearson, seen or not
  (``bounded_moment``), or the fraction censored and the statistics of the runs below the
  horizon (``conditional_statistic``).

The stated error of an answer is relative: max(hi - value, value - lo) / |value|.
"""
import numpy as np
from scipy import stats


class Answer:
    """One answer: ``value`` with its interval [``lo``, ``hi``] at ``confidence`` (scalars, or
    arrays [n_points] for a map), the method, the cost ledger and details (sample sizes ...)."""

    def __init__(self, question, statistic, method, value, lo, hi, confidence, ledger, **details):
        self.question, self.statistic, self.method = question, statistic, method
        self.value, self.lo, self.hi = (np.asarray(v, float) for v in (value, lo, hi))
        self.confidence, self.ledger, self.details = confidence, ledger, details

    @property
    def cost(self):
        return self.ledger.total()

    @property
    def stated_error(self):
        """Relative half-width (the larger side; the largest over a map's points)."""
        return relative_error(self.value, self.lo, self.hi)

    def covers(self, truth):
        t = np.asarray(truth, float)
        return bool(np.all((self.lo <= t) & (t <= self.hi)))

    def as_dict(self):
        def py(a):
            a = np.asarray(a, float)
            return a.item() if a.ndim == 0 else a.tolist()
        return {"question": self.question, "statistic": self.statistic, "method": self.method,
                "value": py(self.value), "lo": py(self.lo), "hi": py(self.hi),
                "confidence": self.confidence, "stated_error": _finite(self.stated_error),
                "cost_cpu_seconds": self.cost, "cost_by_stage": self.ledger.by_stage(),
                "ledger": self.ledger.as_list(), "details": _plain(self.details)}


def _finite(x):
    return float(x) if np.isfinite(x) else None


def _plain(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, np.generic):
            v = v.item()
        out[k] = v
    return out


def relative_error(value, lo, hi):
    value, lo, hi = (np.asarray(v, float) for v in (value, lo, hi))
    half = np.maximum(hi - value, value - lo)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(value) > 0, half / np.abs(value), np.inf)
    return float(np.max(rel)) if rel.size else float("inf")


def z_value(confidence):
    return stats.norm.ppf(0.5 + confidence / 2.0)


def mean_ci(y, confidence):
    """Sample mean and its Student t interval."""
    y = np.asarray(y, float)
    n, m = len(y), float(np.mean(y))
    if n < 2:
        return m, -np.inf, np.inf
    h = stats.t.ppf(0.5 + confidence / 2.0, n - 1) * np.std(y, ddof=1) / np.sqrt(n)
    return m, m - h, m + h


def variance_df(y):
    """Degrees of freedom of the chi-square law matched to the sample's variance and kurtosis, at
    most a Gaussian sample's n - 1 (a short sample's kurtosis is often below its law's, and a
    lighter tail than the Gaussian's would narrow the interval: at 32 Gaussian runs the uncapped
    interval holds the sd in 91% of 4 000 samples, the capped one in 96%)."""
    y = np.asarray(y, float)
    n = len(y)
    s2 = np.var(y, ddof=1)
    m4 = np.mean((y - y.mean()) ** 4)
    var_s2 = max((m4 - s2 ** 2 * (n - 3) / (n - 1)) / n, 2 * s2 ** 2 / (n - 1) * 1e-3)
    return min(max(2.0 * s2 ** 2 / var_s2, 1.0), n - 1.0) if s2 > 0 else float(n - 1)


def std_ci(y, confidence):
    """Sample standard deviation and its interval (chi-square, kurtosis-matched df)."""
    y = np.asarray(y, float)
    if len(y) < 3:
        return float(np.std(y, ddof=1)) if len(y) > 1 else 0.0, 0.0, np.inf
    s2 = np.var(y, ddof=1)
    return std_from_variance(s2, variance_df(y), confidence)


def std_from_variance(s2, df, confidence):
    """sd and its interval from a variance estimate s2 whose sampling law is s2 chi2_df / df."""
    a = 1.0 - confidence
    lo = s2 * df / stats.chi2.ppf(1 - a / 2, df)
    hi = s2 * df / stats.chi2.ppf(a / 2, df)
    return float(np.sqrt(max(s2, 0.0))), float(np.sqrt(max(lo, 0.0))), float(np.sqrt(max(hi, 0.0)))


def quantile_ci(y, p, confidence):
    """Empirical p-quantile (order statistic ceil(n p)) and the distribution-free interval
    [y_(l), y_(u)] with P(l <= B < u) >= confidence, B ~ Bin(n, p)."""
    y = np.sort(np.asarray(y, float))
    n = len(y)
    est = y[min(max(int(np.ceil(n * p)) - 1, 0), n - 1)]
    a = 1.0 - confidence
    l = int(stats.binom.ppf(a / 2, n, p))            # P(B < l) <= a/2
    u = int(stats.binom.ppf(1 - a / 2, n, p)) + 1     # P(B >= u) <= a/2
    lo = y[l - 1] if l >= 1 else -np.inf
    hi = y[u - 1] if u <= n else np.inf
    return float(est), float(lo), float(hi)


def exceedance_ci(y, c, confidence):
    """Fraction of y above c and its Clopper-Pearson interval."""
    y = np.asarray(y, float)
    n, k = len(y), int(np.sum(y > c))
    a = 1.0 - confidence
    lo = stats.beta.ppf(a / 2, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(1 - a / 2, k + 1, n - k) if k < n else 1.0
    return k / n, float(lo), float(hi)


def point_statistic(y, statistic, percentile=95.0, threshold=None, horizon=None, censoring=None):
    """The estimate of ``sample_statistic`` alone (no interval: cheap inside a bootstrap)."""
    y = np.asarray(y, float)
    if horizon is not None and censoring == "condition":
        if statistic == "censored":
            return float(np.mean(y >= horizon))
        y = y[y < horizon]
    if statistic == "mean":
        return float(np.mean(y))
    if statistic == "std":
        return float(np.std(y, ddof=1)) if len(y) > 1 else 0.0
    if statistic == "exceedance":
        return float(np.mean(y > threshold))
    ys = np.sort(y)
    return float(ys[min(max(int(np.ceil(len(y) * percentile / 100.0)) - 1, 0), len(y) - 1)])


def censored_fraction_ci(y, horizon, confidence):
    """Fraction of runs censored (y >= horizon) and its Clopper-Pearson interval."""
    return exceedance_ci(y, np.nextafter(horizon, -np.inf), confidence)


def censored_moments(p, mu, sd, horizon):
    """Mean and sd of a QoI that is ``horizon`` with probability p and otherwise has mean mu and
    sd sd (arrays broadcast)."""
    d = horizon - mu
    return (1 - p) * mu + p * horizon, np.sqrt(np.maximum((1 - p) * sd ** 2 + p * (1 - p) * d ** 2, 0.0))


def bounded_moment(y, statistic, confidence, horizon):
    """Mean or sd of min(QoI, horizon) with an interval that bounds the censored mass, seen or
    not: Clopper-Pearson on the censored fraction p, the t interval of the mean mu and the
    chi-square interval of the sd of the runs below the horizon, each at 1 - (1 - confidence) / 3
    (Bonferroni), and the statistic's range over that box (its extremes in p over a grid that
    holds the ends and the sd's stationary point, in mu and sd at their ends: the mean rises with
    mu and sd, the sd with sd and falls with mu below the horizon). The value is the sample's."""
    y = np.asarray(y, float)
    cens = y >= horizon
    c3 = 1 - (1 - confidence) / 3
    _, plo, phi = censored_fraction_ci(y, horizon, c3)
    free = y[~cens]
    if len(free) < 3:
        return point_statistic(y, statistic), -np.inf if statistic == "mean" else 0.0, np.inf
    _, mlo, mhi = mean_ci(free, c3)
    _, slo, shi = std_ci(free, c3)
    lo, hi = censored_moment_range(statistic, horizon, (plo, phi), (mlo, mhi), (slo, shi))
    return point_statistic(y, statistic), lo, hi


def censored_moment_range(statistic, horizon, p, mu, sd):
    """Range of the mean or sd of min(QoI, horizon) over the box of the censored fraction p, the
    free runs' mean mu and sd sd (each a (lo, hi) pair): its extremes in p over a grid that holds
    the ends and the sd's stationary point, in mu and sd at their ends (the mean rises with mu and
    sd, the sd with sd and falls with mu below the horizon)."""
    (plo, phi), (mlo, mhi), (slo, shi) = p, mu, sd
    mlo, mhi = min(mlo, horizon), min(mhi, horizon)
    ps = np.linspace(plo, phi, 65)
    stat = 0 if statistic == "mean" else 1
    low = censored_moments(ps, mlo if stat == 0 else mhi, slo, horizon)[stat]
    high = censored_moments(ps, mhi if stat == 0 else mlo, shi, horizon)[stat]
    if stat == 1:     # the sd's maximum over p in (0, 1/2): where d/dp of the variance vanishes
        d = horizon - mlo
        pstar = np.clip(0.5 * (1 - shi ** 2 / d ** 2) if d > 0 else 0.0, plo, phi)
        high = np.append(high, censored_moments(pstar, mlo, shi, horizon)[1])
    return float(np.min(low)), float(np.max(high))


def censored_quantile_level(q, p):
    """The level of the free runs' quantile that is the q-quantile of min(QoI, horizon) when a
    fraction p is censored (None: the q-quantile is the horizon itself, p >= 1 - q)."""
    return q / (1.0 - p) if p < 1.0 - q else None


def conditional_statistic(y, statistic, confidence, horizon, percentile=95.0):
    """A statistic of the runs below the horizon (their own intervals); ``censored``: the
    fraction at the horizon with its Clopper-Pearson interval."""
    y = np.asarray(y, float)
    if statistic == "censored":
        return censored_fraction_ci(y, horizon, confidence)
    return sample_statistic(y[y < horizon], statistic, confidence, percentile)


def sample_statistic(y, statistic, confidence, percentile=95.0, threshold=None, horizon=None,
                     censoring=None):
    """(estimate, lo, hi) of a question's statistic from one sample of the QoI; a censored QoI
    (``horizon``): ``censoring`` 'bound' (mean and sd of min(QoI, horizon), intervals bounding
    the censored mass, ``bounded_moment``) or 'condition' (``conditional_statistic``)."""
    if horizon is not None and censoring == "condition":
        return conditional_statistic(y, statistic, confidence, horizon, percentile)
    if horizon is not None and censoring == "bound" and statistic in ("mean", "std"):
        return bounded_moment(y, statistic, confidence, horizon)
    if statistic == "mean":
        return mean_ci(y, confidence)
    if statistic == "std":
        return std_ci(y, confidence)
    if statistic == "exceedance":
        return exceedance_ci(y, threshold, confidence)
    return quantile_ci(y, percentile / 100.0, confidence)
