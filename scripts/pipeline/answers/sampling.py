"""Inputs for the methods: independent random streams, the region a question's surrogate lives
on, nested training designs, the joint pilot and the per-sample quantities of each statistic.

Streams: every draw comes from ``numpy.random.default_rng([seed, stream])`` with one stream per
purpose (pilot, estimation, training, held-out, grid), so the estimation samples are never the
pilot's or the training's.
"""
import time
import warnings

import numpy as np
from scipy import stats
from scipy.stats import gaussian_kde, qmc

PILOT, ESTIMATION, TRAINING, HELD_OUT, GRID, PROPAGATION = 1, 2, 3, 4, 5, 6


def stream(seed, purpose):
    return np.random.default_rng([int(seed), purpose])


def run(model, params, seeds, ledger, stage):
    """Evaluate a model, charge the ledger; values [n]."""
    ev = model.evaluate(params, seeds)
    if ev.values.shape != (len(params),) or not np.all(np.isfinite(ev.values)):
        raise ValueError(f"model '{model.name}' returned {ev.values.shape} values (finite expected) "
                         f"for {len(params)} queries")
    ledger.add(stage, model.name, len(params), ev.cpu_seconds)
    return ev.values


def draw(question, rng, n):
    """n parameter vectors [n, d] from the question's distribution and n model seeds; the first
    rows do not depend on n (params and seeds come from two streams split off ``rng``)."""
    a, b = (np.random.default_rng(int(v)) for v in rng.integers(0, 2 ** 63 - 1, 2))
    return question.distribution.sample(a, n), b.integers(0, 2 ** 31 - 1, n)


class RunCache:
    """Values already run per model on one input sequence: ``run(model, params, seeds, ledger,
    stage)`` with params [n, d] a prefix-extension of earlier calls runs (and charges) only the
    rows not yet run."""

    def __init__(self):
        self.values = {}

    def run(self, model, params, seeds, ledger, stage):
        have = self.values.get(model.name, np.empty(0))
        n = len(params)
        if n > len(have):
            new = run(model, params[len(have):], seeds[len(have):], ledger, stage)
            have = self.values[model.name] = np.concatenate([have, new])
        return have[:n]


class Region:
    """Where a question's surrogate lives: the varying parameter indices, their bounds [dv]
    (the GP's scaling) and the map from the unit cube [n, dv] to full parameter vectors [n, d]."""

    def __init__(self, question, box):
        self.question, self.box = question, box
        if question.kind == "map":
            self.varying = [box.index(n) for n in box.names
                            if n in question.grid and len(question.grid[n]) > 1]
            self.lo = np.array([min(question.grid[box.names[j]]) for j in self.varying])
            self.hi = np.array([max(question.grid[box.names[j]]) for j in self.varying])
            pts, _ = question.grid_points(box)
            self.base = pts[0].copy()
        else:
            self.varying = question.distribution.varying()
            self.lo, self.hi = box.lo[self.varying], box.hi[self.varying]

    def from_unit(self, u):
        if self.question.kind == "map":
            p = np.tile(self.base, (len(u), 1))
            p[:, self.varying] = self.lo + u * (self.hi - self.lo)
            return p
        full = np.full((len(u), self.box.dim), 0.5)
        full[:, self.varying] = u
        return self.question.distribution.from_unit(full)

    def sample(self, rng, n):
        """Parameters drawn from the question's distribution, varying components only [n, dv]."""
        return self.question.distribution.sample(rng, n)[:, self.varying]


def sobol(dim, n, seed):
    """The first n points of a scrambled Sobol sequence [n, dim] (nested in n)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return qmc.Sobol(dim, scramble=True, rng=np.random.default_rng(seed)).random(n)


class TrainingSet:
    """Exact (and optionally low-fidelity) runs on a nested Sobol design of a question's region;
    ``grow(n)`` runs only the points not yet run and charges them to ``ledger`` (stage training)."""

    def __init__(self, question, box, models, seed, ledger):
        self.region = Region(question, box)
        self.models, self.seed, self.ledger = models, seed, ledger
        self.X = np.empty((0, box.dim))
        self.Y = np.empty((0, len(models)))

    def grow(self, n):
        have = len(self.X)
        if n <= have:
            return self
        u = sobol(len(self.region.varying), n, [self.seed, TRAINING])[have:]
        X = self.region.from_unit(u)
        seeds = stream(self.seed, TRAINING).integers(0, 2 ** 31 - 1, n)[have:]
        cols = [run(m, X, seeds, self.ledger, "training") for m in self.models]
        self.X = np.vstack([self.X, X])
        self.Y = np.vstack([self.Y, np.column_stack(cols)])
        return self

    def inputs(self, n):
        return self.X[:n][:, self.region.varying]


class Pilot:
    """Joint runs of all models on n independent inputs: values Y [n, K], CPU seconds per run
    [K], and each low fidelity's affine alignment to the exact model (least squares on the
    pilot, applied to every later low-fidelity value: a fixed map, so estimators stay unbiased)."""

    def __init__(self, question, models, n, seed, ledger):
        params, seeds = draw(question, stream(seed, PILOT), n)
        self.question, self.names = question, [m.name for m in models]
        before = len(ledger.entries)
        cols = [run(m, params, seeds, ledger, "pilot") for m in models]
        self.costs = np.array([e[3] / n for e in ledger.entries[before:]])
        self.raw = np.column_stack(cols)
        self.ab = [(0.0, 1.0)] + [affine(self.raw[:, 0], self.raw[:, k]) for k in range(1, len(models))]
        self.Y = np.column_stack([self.align(k, self.raw[:, k]) for k in range(len(models))])

    def align(self, k, y):
        a, b = self.ab[k]
        return a + b * np.asarray(y, float)


def affine(y, x):
    xc = x - x.mean()
    b = float(np.dot(y - y.mean(), xc) / np.dot(xc, xc)) if np.dot(xc, xc) > 0 else 1.0
    if b == 0.0:
        b = 1.0
    return float(y.mean() - b * x.mean()), b


def per_sample(statistic, Y, t=None):
    """Per-sample quantities whose mean the statistic rests on, for each model's values Y[k]
    [m_k]: the value (mean), the squared deviation from the model's own mean (variance), the
    indicator y <= t (quantile at t) or y > t (exceedance of t)."""
    if statistic == "mean":
        return [np.asarray(y, float) for y in Y]
    if statistic == "std":
        return [(np.asarray(y) - np.mean(y)) ** 2 for y in Y]
    if statistic == "exceedance":
        return [(np.asarray(y) > t).astype(float) for y in Y]
    return [(np.asarray(y) <= t).astype(float) for y in Y]


def target_sd(statistic, y0, eps, z, t=None, percentile=95.0):
    """The standard deviation of the per-sample mean that gives a relative half-width eps, from
    the pilot's exact values y0: mean eps |m| / z; std via s = sqrt(V), sd(V) = 2 eps s^2 / z;
    quantile via the density f(q) (Gaussian kernel estimate), sd(F) = eps |q| f(q) / z;
    exceedance eps P / z (P >= 1 / (2 n) when the pilot saw no exceedance)."""
    y0 = np.asarray(y0, float)
    if statistic == "mean":
        return eps * abs(y0.mean()) / z
    if statistic == "std":
        return 2.0 * eps * np.var(y0, ddof=1) / z
    if statistic == "exceedance":
        return eps * max(np.mean(y0 > t), 0.5 / len(y0)) / z
    q = np.quantile(y0, percentile / 100.0)
    f = float(gaussian_kde(y0)(q)[0]) if np.std(y0) > 0 else 1.0
    return eps * abs(q) * f / z


class Clock:
    """CPU seconds of this process spent in a block (the surrogates' fitting and sampling)."""

    def __enter__(self):
        self.t0 = time.process_time()
        return self

    def __exit__(self, *exc):
        self.seconds = time.process_time() - self.t0
        return False


def indicator_cov(Y, p):
    """Covariance [K, K] of the indicators y_k <= q_k at level p (each model at its own
    p-quantile) under a Gaussian copula fitted to the pilot Y [n, K] (normal-score correlations
    R = 2 sin(pi r_s / 6) from Spearman's r_s): C_jk = Phi_2(z_p, z_p; R_jk) - p^2. A small
    pilot rarely sees the tail events themselves; their correlation follows from the ranks."""
    K = Y.shape[1]
    rs = np.ones((K, K))
    if K == 2:
        rs[0, 1] = rs[1, 0] = stats.spearmanr(Y[:, 0], Y[:, 1]).statistic
    elif K > 2:
        rs = stats.spearmanr(Y).statistic
    rs = np.nan_to_num(rs, nan=0.0)
    R = 2.0 * np.sin(np.pi * rs / 6.0)
    zp = stats.norm.ppf(p)
    C = np.empty((K, K))
    for j in range(K):
        for k in range(K):
            if j == k:
                C[j, k] = p * (1 - p)
            else:
                r = float(np.clip(R[j, k], -0.999999, 0.999999))
                C[j, k] = stats.multivariate_normal.cdf([zp, zp], cov=[[1, r], [r, 1]]) - p * p
    return C
