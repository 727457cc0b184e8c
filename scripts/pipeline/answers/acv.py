"""Approximate control variates (Gorodetsky, Geraci, Eldred & Jakeman, J. Comput. Phys. 408
(2020) 109257), written from the formulas, with MFMC as one of their sample layouts.

Model 0 is the exact one, models 1..K low fidelities. For a per-sample quantity g (the QoI, its
squared deviation, an indicator) and C its covariance across models, the estimator is

    s = mean_{S_0} g_0 + sum_{k>=1} alpha_k (mean_{A_k} g_k - mean_{B_k} g_k)          (unbiased)

on sample sets S_0, A_k, B_k of independent inputs. With Q_0 = mean_{S_0} g_0, D_k the bracket
and f(X, Y) = |X & Y| / (|X| |Y|):

    Cov(Q_0, D_k)  = C_0k (f(S_0, A_k) - f(S_0, B_k))                               (= c_k)
    Cov(D_j, D_k)  = C_jk (f(A_j, A_k) - f(A_j, B_k) - f(B_j, A_k) + f(B_j, B_k))    (= D_jk)
    Var s          = C_00 / |S_0| + 2 alpha . c + alpha' D alpha                     (any alpha)

minimised by alpha = -D^-1 c, for Var s = C_00 / |S_0| - c' D^-1 c. Model k runs on m_k inputs
(m_0 = |S_0|); the layouts (``SCHEMES``), all with S_0 the first m_0 inputs of one sequence:

* ``mfmc``  A_k the first m_k, B_k the first m_{k-1}, m_0 <= m_1 <= ... (Peherstorfer et al.;
  its optimal alpha and allocation are closed forms, ``mfmc``);
* ``acvmf`` A_k the first m_k, B_k the first m_0 (ACV-MF: every low fidelity's control term on
  the exact model's inputs), m_k >= m_0 in any order;
* ``acvis`` A_k the first m_0 and a block of m_k - m_0 inputs of model k's own, B_k the first m_0
  (ACV-IS: independent extra samples).

In every layout the first m_0 values of each model are on the shared inputs, and B_k is a
prefix of model k's values, so ``combine`` takes per model its m_k values and the prefix sizes
b_k. ACV-MF and ACV-IS tend, as the low fidelities become free, to (1 - R^2) times plain Monte
Carlo's variance with R^2 the squared multiple correlation of the exact model on all low
fidelities; MFMC's limit is (1 - rho_01^2). The allocation of a budget is optimised over the
ratios r_k = m_k / m_0 (``scipy.optimize.minimize``, several starts); with one low fidelity the
three layouts coincide.
"""
import itertools

import numpy as np
from scipy import optimize

from . import mfmc

SCHEMES = ("mfmc", "acvmf", "acvis")
LABELS = {"mfmc": "MFMC", "acvmf": "ACV-MF", "acvis": "ACV-IS"}


def b_sizes(scheme, m):
    """The prefix sizes b_k of the sets B_k (b_0 = m_0, unused)."""
    m = np.asarray(m)
    if scheme == "mfmc":
        return np.concatenate([m[:1], m[:-1]])
    return np.full_like(m, m[0])


def _sets(scheme, m):
    """(S_0, [A_k], [B_k]) as (prefix length, block id, block length)."""
    m = np.asarray(m, float)
    b = b_sizes(scheme, m)
    S0 = (m[0], None, 0.0)
    if scheme == "acvis":
        A = [(m[0], k, m[k] - m[0]) for k in range(1, len(m))]
    else:
        A = [(m[k], None, 0.0) for k in range(1, len(m))]
    B = [(b[k], None, 0.0) for k in range(1, len(m))]
    return S0, A, B


def _f(X, Y):
    common = min(X[0], Y[0]) + (X[2] if X[1] is not None and X[1] == Y[1] else 0.0)
    return common / ((X[0] + X[2]) * (Y[0] + Y[2]))


def moments(C, m, scheme):
    """(Var Q_0, c [K], D [K, K]) for sample sizes m [K + 1] (real or integer)."""
    S0, A, B = _sets(scheme, m)
    K = len(m) - 1
    c = np.array([C[0, k + 1] * (_f(S0, A[k]) - _f(S0, B[k])) for k in range(K)])
    D = np.empty((K, K))
    for j in range(K):
        for k in range(K):
            D[j, k] = C[j + 1, k + 1] * (_f(A[j], A[k]) - _f(A[j], B[k]) - _f(B[j], A[k]) + _f(B[j], B[k]))
    return C[0, 0] / m[0], c, D


def variance(C, m, alpha, scheme="mfmc"):
    """Var s for sample sizes m and coefficients alpha [K + 1] (alpha_0 unused)."""
    v0, c, D = moments(np.atleast_2d(C), m, scheme)
    a = np.asarray(alpha, float)[1:]
    return float(v0 + 2 * a @ c + a @ D @ a)


def optimal_alpha(C, m, scheme="mfmc"):
    """alpha = -D^-1 c [K + 1] (alpha_0 = 1; pseudo-inverse where D is singular)."""
    _, c, D = moments(np.atleast_2d(C), m, scheme)
    return np.concatenate([[1.0], -np.linalg.pinv(D) @ c])


def gamma(C, costs, r, scheme):
    """Var s times the budget at the optimal alpha for ratios r [K] = m_k / m_0 (cost w . m)."""
    m = np.concatenate([[1.0], np.asarray(r, float)])
    return variance(C, m, optimal_alpha(C, m, scheme), scheme) * float(np.dot(costs, m))


def optimal_ratios(C, costs, scheme):
    """The ratios r_k > 1 of least gamma (``scipy.optimize.minimize`` on log(r_k - 1), starts
    at MFMC's closed-form ratios where they apply and at a few common values); (r, gamma)."""
    C, w = np.atleast_2d(C), np.asarray(costs, float)
    K = len(w) - 1
    sig, rho = mfmc.correlations(C)
    starts = [np.full(K, v) for v in (2.0, 20.0)]
    guess = np.sqrt(w[0] * rho[1:] ** 2 / (w[1:] * np.maximum(1 - rho[1:] ** 2, 1e-12)))
    starts.append(np.maximum(guess, 1.01))

    def obj(x):
        return gamma(C, w, 1.0 + np.exp(np.clip(x, -20, 20)), scheme)
    best = (None, np.inf)
    for r0 in starts:
        res = optimize.minimize(obj, np.log(r0 - 1.0), method="Nelder-Mead",
                                options={"xatol": 1e-6, "fatol": 1e-12 * obj(np.log(r0 - 1.0)),
                                         "maxiter": 400 * K})
        if res.fun < best[1]:
            best = (1.0 + np.exp(np.clip(res.x, -20, 20)), float(res.fun))
    return best


def select(C, costs, schemes=("mfmc", "acvmf")):
    """The layout, model subset (model 0 first) and ratios of least gamma over every subset of
    low fidelities; plain Monte Carlo ('mc', [0]) when none beats it. Returns (scheme, order,
    ratios r [len(order) - 1], gamma, {scheme: its best gamma})."""
    C, w = np.atleast_2d(C), np.asarray(costs, float)
    best = ("mc", [0], np.empty(0), float(C[0, 0] * w[0]))
    per = {"mc": best[3]}
    for scheme in schemes:
        if scheme == "mfmc":
            order, g = mfmc.select_models(C, w)
            if len(order) > 1:
                _, rho = mfmc.correlations(C)
                m = mfmc.allocation(np.abs(rho[order]), w[order], 1.0)
                cand = ("mfmc", order, m[1:] / m[0], g)
            else:
                cand = best
        else:
            cand = best
            # one low fidelity: every layout is MFMC's (its closed form, when "mfmc" is tried)
            for size in range(2 if "mfmc" in schemes else 1, len(w)):
                for sub in itertools.combinations(range(1, len(w)), size):
                    order = [0, *sub]
                    r, g = optimal_ratios(C[np.ix_(order, order)], w[order], scheme)
                    if g < cand[3] * (1 - 1e-9):     # ties go to the layout before
                        cand = (scheme, order, r, g)
        per[scheme] = cand[3]
        if cand[3] < best[3] * (1 - 1e-9):
            best = cand
    return best + (per,)


def integer_sizes(scheme, r, m0, m1_min=10):
    """Integer sizes [m_0, m_1, ...] from a real m_0 and ratios: m_0 >= m1_min, m_k >= m_0
    (nested for MFMC)."""
    if scheme == "mfmc":
        return mfmc.integer_sizes(np.concatenate([[m0], m0 * np.asarray(r)]), m1_min)
    n0 = max(int(np.ceil(m0)), m1_min)
    return np.array([n0] + [max(int(np.round(m0 * v)), n0) for v in r], dtype=int)


def plan(C, costs, target_var, m1_min=10, schemes=("mfmc", "acvmf")):
    """The layout, model subset, integer sizes m, prefix sizes b, coefficients alpha (optimal for
    the integer sizes) and predicted variance that reach ``target_var`` at least cost; also each
    layout's gamma (``gammas``)."""
    C, w = np.atleast_2d(C), np.asarray(costs, float)
    scheme, order, r, g, per = select(C, w, schemes)
    Cs, ws = C[np.ix_(order, order)], w[order]
    budget = g / target_var
    m = integer_sizes("mfmc" if scheme == "mc" else scheme, r, budget / np.dot(ws, np.r_[1.0, r]), m1_min)
    layout = "mfmc" if scheme == "mc" else scheme
    alpha = optimal_alpha(Cs, m, layout)
    return {"scheme": layout, "models": order, "m": m, "b": b_sizes(layout, m), "alpha": alpha,
            "variance": variance(Cs, m, alpha, layout), "cost": float(np.dot(ws, m)), "gamma": g,
            "gammas": per}


def input_indices(scheme, m):
    """Per model the indices of its inputs in one sequence of independent inputs, and that
    sequence's length: prefixes (MFMC, ACV-MF), or the first m_0 and an own block (ACV-IS)."""
    m = [int(v) for v in m]
    if scheme != "acvis":
        return [np.arange(v) for v in m], max(m)
    out, end = [np.arange(m[0])], m[0]
    for v in m[1:]:
        out.append(np.concatenate([np.arange(m[0]), np.arange(end, end + v - m[0])]))
        end += v - m[0]
    return out, end


def combine(G, alpha, b):
    """The estimate from per-model values G[k] [m_k] (A_k all of them, B_k the first b_k)."""
    s = float(np.mean(G[0]))
    for k in range(1, len(G)):
        s += alpha[k] * (np.mean(G[k]) - np.mean(G[k][:int(b[k])]))
    return s


def combine_variance(Y, alpha, b):
    """The estimate of the variance (unbiased sample variances in place of means)."""
    s = float(np.var(Y[0], ddof=1))
    for k in range(1, len(Y)):
        s += alpha[k] * (np.var(Y[k], ddof=1) - np.var(Y[k][:int(b[k])], ddof=1))
    return s


def combine_cdf(Y, alpha, t, b):
    """The estimate of P(Y_0 <= t) at thresholds t [n_t] (indicators as g), not yet monotone."""
    t = np.asarray(t, float)

    def frac(y):
        return np.searchsorted(np.sort(y), t, side="right") / len(y)
    F = frac(Y[0])
    for k in range(1, len(Y)):
        F = F + alpha[k] * (frac(Y[k]) - frac(Y[k][:int(b[k])]))
    return F
