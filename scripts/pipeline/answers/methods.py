"""The four methods; each returns an ``Answer`` (value, interval, cost ledger).

* M0 exact model alone: plain Monte Carlo (``m0``), one run (or ``replicates`` runs) per map point
  (``m0_map``);
* M1 Gaussian-process surrogate on exact runs (``m1``, ``m1_map``);
* M2 a low fidelity alone, its bias and error from held-out exact runs (``m2``, ``m2_map``);
* M3 multi-fidelity: MFMC or ACV-MF on fresh samples (the layout of least planned variance),
  the allocation and coefficients from the pilot (``m3``), the autoregressive GP for maps
  (``m3_map``).

``ledger`` arguments are charged with every run the method makes (and the caller's entries it
holds already: builds, pilot, training).
"""
import copy

import numpy as np
from scipy import stats

from . import acv, mfmc
from .intervals import (Answer, bounded_moment, censored_fraction_ci, censored_moment_range,
                        censored_moments, censored_quantile_level, mean_ci, point_statistic,
                        sample_statistic, std_from_variance, z_value)
from .sampling import (ESTIMATION, GRID, HELD_OUT, PROPAGATION, Clock, RunCache, draw,
                       indicator_cov, per_sample, run, stream)
from .surrogate import AR1Surrogate, GPSurrogate, map_interval, propagate


def _kw(question):
    return {"percentile": question.percentile, "threshold": question.threshold,
            "horizon": getattr(question, "horizon", None), "censoring": getattr(question, "censoring", None)}


def _censored_as_exceedance(question, statistic):
    """The fraction censored asked as an exceedance of the largest double below the horizon."""
    if statistic != "censored":
        return question, statistic
    q = copy.copy(question)
    q.threshold, q.horizon, q.censoring = float(np.nextafter(question.horizon, -np.inf)), None, None
    return q, "exceedance"


def conditional(question, statistic):
    """A statistic of the runs below the horizon (M3 does not answer these)."""
    return getattr(question, "censoring", None) == "condition" and statistic != "censored"


# ------------------------------------------------------------------------------ M0

def m0(question, statistic, exact, n, seed, confidence, ledger, cache=None):
    """Plain Monte Carlo on n fresh exact runs (``cache``: a RunCache of earlier runs on the
    same seed, extended rather than rerun)."""
    params, seeds = draw(question, stream(seed, ESTIMATION), n)
    y = (cache or RunCache()).run(exact, params, seeds, ledger, "estimation")
    est, lo, hi = sample_statistic(y, statistic, confidence, **_kw(question))
    return Answer(question.id, statistic, "M0", est, lo, hi, confidence, ledger, n_exact=n)


def m0_map(question, box, exact, seed, confidence, ledger):
    """The exact model at every grid point: ``replicates`` runs per point (mean and t interval;
    a single run of a deterministic model is the answer itself)."""
    pts, shape = question.grid_points(box)
    r = question.replicates
    seeds = stream(seed, GRID).integers(0, 2 ** 31 - 1, len(pts) * r)
    y = run(exact, np.repeat(pts, r, axis=0), seeds, ledger, "estimation").reshape(len(pts), r)
    if r == 1:
        v = lo = hi = y[:, 0]
    else:
        v, lo, hi = np.array([mean_ci(row, confidence) for row in y]).T
    return Answer(question.id, "map", "M0", v, lo, hi, confidence, ledger, n_exact=len(pts) * r,
                  grid_shape=list(shape))


# ------------------------------------------------------------------------------ M1

def m1(question, statistic, training, n, seed, confidence, ledger, restarts=2, **prop):
    """GP on the first n exact training runs, the statistic by ``propagate`` (``prop``: its
    sample sizes n_large, n_draws, n_sub); a censored QoI (``horizon``) by ``_m1_censored``."""
    training.grow(n)
    if getattr(question, "horizon", None) is not None:
        return _m1_censored(question, statistic, training, n, seed, confidence, ledger, restarts, prop)
    with Clock() as c:
        reg = training.region
        gp = GPSurrogate(training.inputs(n), training.Y[:n, 0], reg.lo, reg.hi, seed,
                         restarts=restarts)
        est, lo, hi = propagate(gp, reg.sample, statistic, confidence, stream(seed, PROPAGATION),
                                **prop, **_kw(question))
    ledger.add("fitting", "gp", 0, c.seconds)
    return Answer(question.id, statistic, "M1", est, lo, hi, confidence, ledger, n_exact=n,
                  calibration=gp.calibration, cv_rel_rmse=gp.cv_rel_rmse)


def _m1_censored(question, statistic, training, n, seed, confidence, ledger, restarts, prop):
    """M1 for a QoI censored at the horizon: the GP on the training runs below it (a censored run
    is a different event, not a value of the smooth response: in the fit it bends the surface
    around one point), the censored fraction p from the k censored of the n runs (drawn from the
    question's distribution) by Clopper-Pearson, as M0. ``condition``: the free statistics from
    the free runs' GP, ``censored`` the interval of k / n. ``bound``: mean and sd over the box of
    p and the free mean and sd (each at 1 - (1 - confidence) / 3), the q-quantile as the free
    runs' quantile at level q / (1 - p) (p and the quantile at 1 - (1 - confidence) / 2 each),
    the horizon where p may reach 1 - q. The propagation's posterior draws carry the scale of
    the free runs as uncertain (``propagate``'s scale_df, their number less one): on a few runs
    the spread is what the GP knows least, and what the sd and the percentile are made of."""
    h, y = question.horizon, training.Y[:n, 0]
    free = y < h
    if statistic == "censored":
        est, lo, hi = censored_fraction_ci(y, h, confidence)
        return Answer(question.id, statistic, "M1", est, lo, hi, confidence, ledger, n_exact=n,
                      n_censored=int(n - free.sum()))
    if free.sum() < 3:
        est = point_statistic(y, statistic, question.percentile, horizon=h, censoring=question.censoring)
        return Answer(question.id, statistic, "M1", est, -np.inf if statistic == "mean" else 0.0,
                      np.inf, confidence, ledger, n_exact=n, n_censored=int(n - free.sum()))
    with Clock() as c:
        reg = training.region
        gp = GPSurrogate(training.inputs(n)[free], y[free], reg.lo, reg.hi, seed, restarts=restarts)

        def free_stat(stat, conf, percentile=question.percentile):
            return propagate(gp, reg.sample, stat, conf, stream(seed, PROPAGATION), **prop,
                             percentile=percentile, scale_df=int(free.sum()) - 1)
        if question.censoring == "condition":
            est, lo, hi = free_stat(statistic, confidence)
        elif statistic in ("mean", "std"):
            c3 = 1 - (1 - confidence) / 3
            _, plo, phi = censored_fraction_ci(y, h, c3)
            m, mlo, mhi = free_stat("mean", c3)
            s, slo, shi = free_stat("std", c3)
            est = censored_moments(1 - free.mean(), m, s, h)[0 if statistic == "mean" else 1]
            lo, hi = censored_moment_range(statistic, h, (plo, phi), (mlo, mhi), (slo, shi))
        else:
            est, lo, hi = _m1_censored_quantile(free_stat, y, h, question.percentile / 100, confidence)
    ledger.add("fitting", "gp", 0, c.seconds)
    return Answer(question.id, statistic, "M1", float(est), float(lo), float(hi), confidence, ledger,
                  n_exact=n, n_censored=int(n - free.sum()), calibration=gp.calibration,
                  cv_rel_rmse=gp.cv_rel_rmse)


def _m1_censored_quantile(free_stat, y, h, q, confidence):
    """(estimate, lo, hi) of the q-quantile of min(QoI, h): the free quantile at the level
    ``censored_quantile_level`` of k / n, of the Clopper-Pearson ends for the interval's ends."""
    c2 = 1 - (1 - confidence) / 2
    _, plo, phi = censored_fraction_ci(y, h, c2)

    def at(p, conf, end):
        level = censored_quantile_level(q, p)
        return h if level is None else min(free_stat("p", conf, 100 * level)[end], h)
    return at(np.mean(y >= h), confidence, 0), at(plo, c2, 1), at(phi, c2, 2)


def _censoring_hull(question, statistic, y, confidence, lo, hi):
    """The interval widened to hold the censoring bound from exact runs y drawn from the
    question's distribution: the bounded mean or std (``censoring: bound``). The exact runs bound
    the censored mass the multi-fidelity combination does not see."""
    if getattr(question, "censoring", None) == "bound" and statistic in ("mean", "std"):
        _, blo, bhi = bounded_moment(y, statistic, confidence, question.horizon)
        return min(lo, blo), max(hi, bhi)
    return lo, hi


def m1_map(question, box, training, n, seed, confidence, ledger, restarts=2):
    """GP on the first n exact training runs; at each grid point the posterior mean and the
    interval of the model's value there (latent uncertainty and fitted noise, calibrated)."""
    training.grow(n)
    pts, shape = question.grid_points(box)
    with Clock() as c:
        reg = training.region
        gp = GPSurrogate(training.inputs(n), training.Y[:n, 0], reg.lo, reg.hi, seed,
                         restarts=restarts)
        mu, sd = gp.predict_value(pts[:, reg.varying])
        v, lo, hi = map_interval(mu, sd, gp.calibration, confidence, gp.cv_rmse, n)
    ledger.add("fitting", "gp", 0, c.seconds)
    return Answer(question.id, "map", "M1", v, lo, hi, confidence, ledger, n_exact=n,
                  calibration=gp.calibration, cv_rel_rmse=gp.cv_rel_rmse, grid_shape=list(shape))


# ------------------------------------------------------------------------------ M2

def m2(question, statistic, low, exact, n_low, n_held, seed, confidence, ledger, n_boot=400):
    """The low fidelity's statistic on n_low runs, corrected by n_held held-out pairs (exact and
    low on the same fresh inputs): the correction's standard error from the paired bootstrap times
    sqrt(n / (n - 1)) (the plug-in variance's small-sample factor: for the mean, the pairs'
    differences' sd / sqrt(n)), combined with the low sample's own (independent samples: the
    variances add). The mean and the percentiles: the bias b = stat(exact) - stat(low), the
    interval answer + b +- t_{n-1} sqrt(se_b^2 + se_low^2), as the sd bounded at a horizon
    (``censoring: bound``: the censored mass's share of it does not scale with the free runs'
    spread). The sd otherwise (``_m2_std``): the ratio sd(exact) / sd(low) on the log scale.
    Either way the hull with the answer, t_{n-1} the Student quantile for a standard error
    estimated from n pairs."""
    params, seeds = draw(question, stream(seed, ESTIMATION), n_low)
    ylo = run(low, params, seeds, ledger, "estimation")
    s_lo, a, b = sample_statistic(ylo, statistic, confidence, **_kw(question))
    hp, hs = draw(question, stream(seed, HELD_OUT), n_held)
    yh = run(exact, hp, hs, ledger, "estimation")
    yl = run(low, hp, hs, ledger, "estimation")
    kw = _kw(question)
    rng = stream(seed, PROPAGATION)
    boot = np.array([[point_statistic(y[i], statistic, **kw) for y in (yh, yl)]
                     for i in (rng.integers(0, n_held, n_held) for _ in range(n_boot))])
    held = np.array([point_statistic(y, statistic, **kw) for y in (yh, yl)])
    t = stats.t.ppf(0.5 + confidence / 2, max(n_held - 1, 1))
    small = np.sqrt(n_held / max(n_held - 1, 1))
    z = z_value(confidence)
    scaled = statistic == "std" and getattr(question, "censoring", None) != "bound"
    if scaled and min(s_lo, a, *held, *boot.ravel()) > 0:
        lo, hi, bias, se_b = _m2_std(s_lo, a, b, held, boot, t, small, z)
    else:
        bias = float(held[0] - held[1])
        se_b = float(np.std(boot[:, 0] - boot[:, 1], ddof=1)) * small
        h = t * np.hypot(se_b, max(s_lo - a, b - s_lo) / z)
        lo, hi = s_lo + bias - h, s_lo + bias + h
    return Answer(question.id, statistic, "M2", s_lo, min(s_lo, lo), max(s_lo, hi), confidence,
                  ledger, n_low=n_low, n_exact=n_held, model=low.name, bias=bias, bias_se=se_b)


def _m2_std(s_lo, a, b, held, boot, t, small, z):
    """(lo, hi, bias, se) of M2's sd: log sd(exact) = log s_lo + log r, r = sd(exact) / sd(low)
    of the held-out pairs, interval log s_lo + log r +- t_{n-1} sqrt(se_r^2 + se_low^2) on the log
    scale (se_r from the paired bootstrap of log r times sqrt(n / (n - 1)); se_low from the low
    sample's own interval [a, b], each side its own: log(s_lo / a) / z below, log(b / s_lo) / z
    above: the kurtosis-matched chi-square interval of a heavy-tailed sample is not symmetric on
    the log scale either), exponentiated. An sd's sampling law is skewed (an sd from 31 runs
    falls far below the truth more often than above it) and its error is proportional to it: on
    the log scale the error's size no longer follows the estimate, and the interval reaches
    further above than below (an additive interval on sd(exact) - sd(low) is as narrow as a low
    estimate and misses on the high side)."""
    log_r = float(np.log(held[0] / held[1]))
    se_r = float(np.std(np.log(boot[:, 0] / boot[:, 1]), ddof=1)) * small
    c = np.log(s_lo) + log_r
    h_lo = t * np.hypot(se_r, np.log(s_lo / a) / z)
    h_hi = t * np.hypot(se_r, np.log(b / s_lo) / z) if np.isfinite(b) else np.inf
    return float(np.exp(c - h_lo)), float(np.exp(c + h_hi)), float(s_lo * np.expm1(log_r)), se_r


def m2_map(question, box, low, exact, training, n_held, seed, confidence, ledger):
    """The low fidelity at every grid point; the discrepancy exact - low at n_held training points
    of the map's region (mean d and sd s_d): interval the hull of y_low and
    y_low + d +- t s_d sqrt(1 + 1/n_held) (a prediction interval for exchangeable discrepancies)."""
    pts, shape = question.grid_points(box)
    seeds = stream(seed, GRID).integers(0, 2 ** 31 - 1, len(pts))
    ylo = run(low, pts, seeds, ledger, "estimation")
    training.grow(n_held)
    d = training.Y[:n_held, 0] - training.Y[:n_held, 1]
    h = stats.t.ppf(0.5 + confidence / 2, n_held - 1) * np.std(d, ddof=1) * np.sqrt(1 + 1 / n_held)
    lo, hi = np.minimum(ylo, ylo + d.mean() - h), np.maximum(ylo, ylo + d.mean() + h)
    return Answer(question.id, "map", "M2", ylo, lo, hi, confidence, ledger, n_exact=n_held,
                  model=low.name, bias=float(d.mean()), grid_shape=list(shape))


# ------------------------------------------------------------------------------ M3

#: the layouts M3 chooses from (ACV-IS needs per-model input blocks, which the prefix-extending
#: run cache and the top-up cannot reuse)
ENGINE_SCHEMES = ("mfmc", "acvmf")


def m3_plan(pilot, statistic, target_sd, question, m1_min=10):
    """The M3 plan (layout MFMC or ACV-MF, models, sizes m, alpha from the pilot) for a statistic
    and target sd."""
    question, statistic = _censored_as_exceedance(question, statistic)
    y0, n = pilot.Y[:, 0], len(pilot.Y)
    if statistic in ("mean", "std"):
        C = np.atleast_2d(np.cov(np.column_stack(per_sample(statistic, list(pilot.Y.T))).T, ddof=1))
    else:
        level = question.percentile / 100 if statistic != "exceedance" else np.mean(y0 <= question.threshold)
        C = indicator_cov(pilot.Y, float(np.clip(level, 0.5 / n, 1 - 0.5 / n)))
    return acv.plan(C, pilot.costs, target_sd ** 2, m1_min, ENGINE_SCHEMES)


def m3(question, statistic, models, pilot, plan, seed, confidence, ledger, cache=None):
    """MFMC / ACV-MF on fresh samples: model plan['models'][k] on the first m_k of N = max m_k
    inputs (``cache``: a RunCache of earlier runs on the same seed, extended rather than rerun)."""
    if conditional(question, statistic):
        raise ValueError(f"question '{question.id}': M3 does not answer {statistic} of the runs below the horizon")
    asked = statistic
    question, statistic = _censored_as_exceedance(question, statistic)
    order, m, alpha, scheme = plan["models"], plan["m"], plan["alpha"], plan["scheme"]
    b = acv.b_sizes(scheme, m)
    params, seeds = draw(question, stream(seed, ESTIMATION), int(np.max(m)))
    cache = cache or RunCache()
    Y = [pilot.align(j, cache.run(models[j], params[:mk], seeds[:mk], ledger, "estimation"))
         for j, mk in zip(order, m)]
    tq = stats.t.ppf(0.5 + confidence / 2, max(m[0] - 1, 1))
    if statistic == "quantile" or statistic.startswith("p"):
        est, lo, hi = _mf_quantile(Y, alpha, m, question.percentile / 100, tq, scheme)
    elif statistic == "std":
        V = acv.combine_variance(Y, alpha, b)
        var_v = acv.variance(mfmc.nested_cov(per_sample("std", Y)), m, alpha, scheme)
        df = max(2 * V ** 2 / var_v, 1.0) if var_v > 0 and V > 0 else 1.0
        est, lo, hi = std_from_variance(max(V, 0.0), df, confidence)
    else:
        G = per_sample(statistic, Y, question.threshold)
        est = acv.combine(G, alpha, b)
        if statistic == "exceedance":
            v = _indicator_variance(Y, G, 1.0 - est, m, alpha, scheme)
        else:
            v = acv.variance(mfmc.nested_cov(G), m, alpha, scheme)
        h = tq * np.sqrt(max(v, 0.0))
        lo, hi = est - h, est + h
        if statistic == "exceedance":
            est, lo, hi = min(max(est, 0.0), 1.0), max(lo, 0.0), min(hi, 1.0)
    if getattr(question, "censoring", None) == "bound" and statistic in ("mean", "std"):
        # the hull with the bound of the censored mass from the exact runs (valid by itself)
        lo, hi = _censoring_hull(question, statistic, Y[0], confidence, lo, hi)
    names = [models[j].name for j in order]
    return Answer(question.id, asked, "M3", est, lo, hi, confidence, ledger, models=names,
                  m=[int(v) for v in m], alpha=[float(a) for a in alpha], n_exact=int(m[0]),
                  layout=acv.LABELS[scheme], gammas=plan.get("gammas", {}))


def _indicator_variance(Y, G, level, m, alpha, scheme="mfmc"):
    """Variance of an MFMC mean of indicators: the larger of the plug-in value (covariances of
    the m_1 joint indicators, unreliable when they saw few tail events) and the Gaussian-copula
    value at the estimated level (correlations from the ranks of the m_1 joint values)."""
    m1 = int(m[0])
    plug = acv.variance(mfmc.nested_cov(G), m, alpha, scheme)
    n = len(Y[0])
    level = float(np.clip(level, 0.5 / n, 1 - 0.5 / n))
    joint = np.column_stack([y[:m1] for y in Y])
    return max(plug, acv.variance(indicator_cov(joint, level), m, alpha, scheme), 0.0)


def _mf_quantile(Y, alpha, m, p, tq, scheme="mfmc"):
    """Quantile from the MFMC CDF (made monotone), Woodruff interval: the CDF's inverse at
    p -+ t se(F(q))."""
    ts = np.unique(np.concatenate(Y))
    F = mfmc.monotone_cdf(acv.combine_cdf(Y, alpha, ts, acv.b_sizes(scheme, m)))

    def inverse(level):
        if level <= 0:
            return -np.inf
        i = np.searchsorted(F, level, side="left")
        return float(ts[i]) if i < len(ts) and level <= 1 else np.inf
    q = inverse(p)
    se = np.sqrt(_indicator_variance(Y, per_sample("p", Y, q), p, m, alpha, scheme))
    return q, inverse(p - tq * se), inverse(p + tq * se)


def m3_map(question, box, low, training, n, seed, confidence, ledger, restarts=2):
    """Autoregressive GP on n training pairs (exact and low at the same points) and the low
    fidelity at every grid point."""
    training.grow(n)
    pts, shape = question.grid_points(box)
    seeds = stream(seed, GRID).integers(0, 2 ** 31 - 1, len(pts))
    ylo = run(low, pts, seeds, ledger, "estimation")
    with Clock() as c:
        reg = training.region
        ar = AR1Surrogate(training.inputs(n), training.Y[:n, 0], training.Y[:n, 1], reg.lo, reg.hi, seed,
                          restarts=restarts)
        mu, sd = ar.predict_value(pts[:, reg.varying], ylo)
        v, lo, hi = map_interval(mu, sd, ar.calibration, confidence, ar.cv_rmse, n)
    ledger.add("fitting", "ar1-gp", 0, c.seconds)
    return Answer(question.id, "map", "M3", v, lo, hi, confidence, ledger, n_exact=n, model=low.name,
                  slope=ar.b, calibration=ar.calibration, cv_rel_rmse=ar.cv_rel_rmse,
                  grid_shape=list(shape))
