"""Gaussian-process surrogates of a QoI (scikit-learn ``GaussianProcessRegressor``) and their
stated error.

* ``GPSurrogate``: inputs scaled to the unit cube, kernel C * Matern(nu = 5/2, one length per
  input) + White noise, y normalised, hyperparameters by maximum marginal likelihood. Its
  posterior standard deviation is checked by K-fold cross-validation (hyperparameters kept,
  the fold refitted): the standardised residuals z_i = (y_i - mu_-i) / sd_-i give the calibration
  factor c = max(1, rms z), and every stated error uses c * sd.
* ``AR1Surrogate``: the multi-fidelity surrogate y_exact(x) ~ b y_low(x) + delta(x) (Kennedy & O'Hagan's
  autoregressive model), b by least squares, delta a GPSurrogate; cross-validated the same way
  (b refitted per fold).
* ``propagate``: a statistic of the QoI under a parameter distribution through the surrogate:
  the estimate on a large sample of the posterior mean plus the fitted noise, the surrogate's
  own uncertainty from joint posterior draws of the latent function on a sub-sample (the spread
  of the statistic over the draws, times c) or, where larger, from the grouped jackknife over the
  cross-validation folds (the posterior alone misses how the fit's tails move with the training
  points), the sampling error of the large sample added in quadrature.
"""
import warnings

import numpy as np
from scipy import stats
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from .intervals import point_statistic, sample_statistic, z_value


class GPSurrogate:
    """A GP on inputs X [n, d] inside [lo, hi] [d] and outputs y [n]."""

    def __init__(self, X, y, lo, hi, seed=0, kernel=None, folds=10, restarts=2):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.X, self.y = np.asarray(X, float), np.asarray(y, float)
        d = self.X.shape[1]
        if kernel is None:
            kernel = (ConstantKernel(1.0, (1e-3, 1e3))
                      * Matern(np.full(d, 0.5), (1e-2, 1e2), nu=2.5)
                      + WhiteKernel(1e-4, (1e-10, 1.0)))
        self.gp = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=restarts,
                                           random_state=seed)
        with warnings.catch_warnings():
            # hyperparameters at a bound (a flat direction) are expected; the cross-validation
            # below checks the fit
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.gp.fit(self.unit(self.X), self.y)
        self.calibration, self.cv_rel_rmse, self.cv_z = self.cross_validate(folds, seed)

    def unit(self, X):
        return (np.asarray(X, float) - self.lo) / (self.hi - self.lo)

    def noise_var(self):
        """Fitted white-noise variance in the units of y."""
        return float(self.gp.kernel_.k2.noise_level * self.gp._y_train_std ** 2)

    def predict(self, X):
        """Posterior mean [n] and latent standard deviation [n] (noise excluded, not calibrated)."""
        mu, sd = self.gp.predict(self.unit(X), return_std=True)
        return mu, np.sqrt(np.maximum(sd ** 2 - self.noise_var(), 0.0))

    def predict_value(self, X):
        """Posterior mean [n] and standard deviation [n] of the model's value at X (not
        calibrated): the latent one and the fitted white noise. A deterministic model whose output
        jitters at scales far below the design's spacing (the congested crowd's t90 moves by 3%
        when l_exit moves by one rounding unit) shows that jitter as noise, and its value at a
        map point carries it."""
        mu, sd = self.predict(X)
        return mu, np.sqrt(sd ** 2 + self.noise_var())

    def latent_draws(self, X, n_draws, rng):
        """Joint posterior draws of the latent function at X [n]: [n_draws, n]."""
        mu, cov = self.gp.predict(self.unit(X), return_cov=True)
        cov = cov - self.noise_var() * np.eye(len(mu))
        try:
            L = np.linalg.cholesky(cov + 1e-10 * np.trace(cov) / len(mu) * np.eye(len(mu)))
        except np.linalg.LinAlgError:
            w, V = np.linalg.eigh(0.5 * (cov + cov.T))
            L = V * np.sqrt(np.maximum(w, 0.0))
        return mu + rng.standard_normal((n_draws, len(mu))) @ L.T

    def cross_validate(self, folds, seed):
        n = len(self.y)
        k = min(folds, n)
        idx = np.random.default_rng(seed).permutation(n)
        z, err = np.empty(n), np.empty(n)
        self.fold_models = []
        for part in np.array_split(idx, k):
            keep = np.setdiff1d(idx, part)
            g = GaussianProcessRegressor(self.gp.kernel_, normalize_y=True, optimizer=None)
            g.fit(self.unit(self.X[keep]), self.y[keep])
            self.fold_models.append(g)
            mu, sd = g.predict(self.unit(self.X[part]), return_std=True)
            err[part] = self.y[part] - mu
            z[part] = err[part] / np.maximum(sd, 1e-300)
        self.cv_rmse = float(np.sqrt(np.mean(err ** 2)))
        rel = self.cv_rmse / max(np.mean(np.abs(self.y)), 1e-300)
        return max(1.0, float(np.sqrt(np.mean(z ** 2)))), float(rel), z


class AR1Surrogate:
    """y_exact(x) ~ b y_low(x) + delta(x): b by least squares on the training pairs, delta a GP."""

    def __init__(self, X, y_exact, y_low, lo, hi, seed=0, folds=10, restarts=2):
        self.b = self.slope(y_exact, y_low)
        self.delta = GPSurrogate(X, y_exact - self.b * y_low, lo, hi, seed, folds=folds,
                                 restarts=restarts)
        self.calibration, self.cv_rel_rmse = self.cross_validate(X, y_exact, y_low, folds, seed)

    @staticmethod
    def slope(y, ylo):
        yc, lc = y - y.mean(), ylo - ylo.mean()
        return float(np.dot(yc, lc) / np.dot(lc, lc)) if np.dot(lc, lc) > 0 else 0.0

    def predict(self, X, y_low):
        """Mean [n] and latent standard deviation [n] given the low fidelity's values y_low [n]."""
        mu, sd = self.delta.predict(X)
        return self.b * np.asarray(y_low) + mu, sd

    def predict_value(self, X, y_low):
        """Mean [n] and standard deviation [n] of the exact model's value (the discrepancy's
        fitted noise included, as ``GPSurrogate.predict_value``)."""
        mu, sd = self.delta.predict_value(X)
        return self.b * np.asarray(y_low) + mu, sd

    def cross_validate(self, X, y, ylo, folds, seed):
        n = len(y)
        idx = np.random.default_rng(seed).permutation(n)
        z, err = np.empty(n), np.empty(n)
        kern = self.delta.gp.kernel_
        for part in np.array_split(idx, min(folds, n)):
            keep = np.setdiff1d(idx, part)
            b = self.slope(y[keep], ylo[keep])
            g = GaussianProcessRegressor(kern, normalize_y=True, optimizer=None)
            g.fit(self.delta.unit(X[keep]), y[keep] - b * ylo[keep])
            mu, sd = g.predict(self.delta.unit(X[part]), return_std=True)
            err[part] = y[part] - (b * ylo[part] + mu)
            z[part] = err[part] / np.maximum(sd, 1e-300)
        self.cv_rmse = float(np.sqrt(np.mean(err ** 2)))
        rel = self.cv_rmse / max(np.mean(np.abs(y)), 1e-300)
        return max(1.0, float(np.sqrt(np.mean(z ** 2)))), float(rel)


def propagate(gp, sample_params, statistic, confidence, rng, n_large=20000, n_draws=200,
              n_sub=300, scale_df=None, **stat_kw):
    """(estimate, lo, hi) of a statistic of y = f(x) + noise, x drawn by ``sample_params(rng, n)``
    [n, d], through the surrogate ``gp`` (a GPSurrogate on those inputs). Half-widths: the larger
    of the posterior one (draws, times the calibration factor) and the grouped jackknife one over
    the cross-validation folds (the statistic recomputed with each fold left out:
    se^2 = (K - 1) / K sum_k (s_k - mean s)^2, times t_{K-1}), each side combined in quadrature
    with the large sample's own sampling error. ``scale_df``: the scale of y is itself uncertain
    (the GP works in units of the training runs' sd, an estimate with a chi-square law on scale_df
    degrees of freedom that the posterior draws hold fixed): each draw's values about the
    training mean are scaled by sqrt(scale_df / chi2_scale_df)."""
    X = sample_params(rng, n_large)
    mu, _ = gp.predict(X)
    eps = rng.standard_normal(n_large) * np.sqrt(gp.noise_var())
    est, lo_mc, hi_mc = sample_statistic(mu + eps, statistic, confidence, **stat_kw)
    Xs = X[:n_sub]
    draws = gp.latent_draws(Xs, n_draws, rng)
    mu_s, _ = gp.predict(Xs)
    eps_s = eps[:n_sub]
    base = point_statistic(mu_s + eps_s, statistic, **stat_kw)
    m = float(np.mean(gp.y))
    g = (np.sqrt(scale_df / rng.chisquare(scale_df, n_draws)) if scale_df
         else np.ones(n_draws))
    delta = np.array([point_statistic(m + gj * (d + eps_s - m), statistic, **stat_kw) - base
                      for d, gj in zip(draws, g)])
    a = 1.0 - confidence
    d_lo, d_hi = np.quantile(delta, [a / 2, 1 - a / 2]) * gp.calibration
    jk, bias = _jackknife(gp, X, eps, statistic, confidence, stat_kw, est)
    lo = est - np.hypot(max(-d_lo, jk, 0.0), est - lo_mc)
    hi = est + np.hypot(max(d_hi, jk, 0.0), hi_mc - est)
    # the jackknife's bias-corrected value est - bias, +- the same half-width, stays inside
    lo, hi = min(lo, est - bias - jk), max(hi, est - bias + jk)
    return est, lo, hi


def _jackknife(gp, X, eps, statistic, confidence, stat_kw, est):
    """Grouped-jackknife half-width t_{K-1} se and bias (K - 1)(mean s_k - s) of a statistic."""
    K = len(gp.fold_models)
    if K < 2:
        return 0.0, 0.0
    u = gp.unit(X)
    s = np.array([point_statistic(g.predict(u) + eps, statistic, **stat_kw) for g in gp.fold_models])
    se = np.sqrt((K - 1) / K * np.sum((s - s.mean()) ** 2))
    return float(stats.t.ppf(0.5 + confidence / 2, K - 1) * se), float((K - 1) * (s.mean() - est))


def map_interval(mu, sd, calibration, confidence, cv_rmse=0.0, n=None):
    """Pointwise interval of the model's value at map points: mu +- the larger of z c sd (the
    calibrated posterior, sd of the value: ``predict_value``) and the cross-validation prediction
    half-width t_{n-1} cv_rmse sqrt(1 + 1/n) (n training runs). The second holds where maximum
    likelihood on a few runs of a jittery model fits an interpolant without noise: its posterior
    sd then vanishes at the training points, its held-out errors do not."""
    h = z_value(confidence) * calibration * np.asarray(sd)
    if n is not None and n > 1:
        h = np.maximum(h, stats.t.ppf(0.5 + confidence / 2, n - 1) * cv_rmse * np.sqrt(1 + 1 / n))
    return mu, mu - h, mu + h
