"""Multi-fidelity Monte Carlo (Peherstorfer, Willcox & Gunzburger, SIAM J. Sci. Comput. 38 (2016)
A3163-A3194; variances: Qian et al., SIAM/ASA JUQ 6 (2018) 683-706), written from the formulas.

Models 1..K (model 1 the exact one) are evaluated on the first m_1 <= m_2 <= ... <= m_K points
of one sequence of independent inputs. For a per-sample quantity g (the QoI, its squared
deviation, an indicator), with G_k^(m) the mean of g over the first m samples of model k:

    s = G_1^(m_1) + sum_{k>=2} alpha_k (G_k^(m_k) - G_k^(m_{k-1}))                     (unbiased)
    Var s = C_11 / m_1 + sum_{k>=2} (1/m_{k-1} - 1/m_k) (alpha_k^2 C_kk - 2 alpha_k C_1k)

(C the covariance of g across models; exact for fixed alpha). Optimal alpha_k = C_1k / C_kk;
with models ordered by |rho_1k| decreasing (rho_{1,K+1} = 0) and costs w_k satisfying
w_{k-1}/w_k > (rho_{1,k-1}^2 - rho_{1,k}^2) / (rho_{1,k}^2 - rho_{1,k+1}^2), the budget p is
best spent as m_k = r_k m_1, r_k = sqrt(w_1 (rho_1k^2 - rho_{1,k+1}^2) / (w_k (1 - rho_12^2))),
m_1 = p / sum_k w_k r_k, for the variance

    Var s = C_11 / p (sum_k sqrt(w_k (rho_1k^2 - rho_{1,k+1}^2)))^2                       (rho_11 = 1)

which tends to (1 - rho_12^2) times plain Monte Carlo's C_11 w_1 / p as the low fidelities
become free: the gain is bounded by 1 / (1 - rho_12^2). ``select_models`` tries every subset of
low fidelities (the paper's model selection) and keeps the one of least variance per budget
(plain Monte Carlo when no subset beats it). The estimators themselves, for MFMC and the
approximate control variates alike, are `acv.combine*` (MFMC: B_k the first m_{k-1} samples).
"""
import itertools

import numpy as np


def nested_cov(G):
    """Covariance [K, K] of a per-sample quantity from nested samples G[k] [m_k], every entry
    from the first m_1 joint samples (a covariance matrix of one joint sample, so the variance
    formula below stays non-negative; mixing in the low fidelities' extra samples would not)."""
    m1 = len(G[0])
    return np.atleast_2d(np.cov(np.vstack([g[:m1] for g in G]), ddof=1))


def correlations(C):
    """sigma [K] and rho_1k [K] (rho_11 = 1) of a covariance matrix; rho = 0 for constant g."""
    sig = np.sqrt(np.maximum(np.diag(C), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(sig * sig[0] > 0, C[0] / (sig * sig[0]), 0.0)
    rho[0] = 1.0
    return sig, rho


def optimal_alpha(C):
    """alpha_k = C_1k / C_kk [K] (alpha_1 unused, set to 1)."""
    d = np.diag(C)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(d > 0, C[0] / d, 0.0)
    a[0] = 1.0
    return a


def variance(C, m, alpha):
    """Var s for sample sizes m [K] (non-decreasing) and coefficients alpha [K]."""
    v = C[0, 0] / m[0]
    for k in range(1, len(m)):
        v += (1.0 / m[k - 1] - 1.0 / m[k]) * (alpha[k] ** 2 * C[k, k] - 2 * alpha[k] * C[0, k])
    return float(v)


def admissible(rho, w):
    """The ordering and cost conditions of the optimal allocation for models in this order."""
    r2 = np.append(np.asarray(rho, float) ** 2, 0.0)
    if np.any(np.diff(r2[:-1]) >= 0) or r2[-2] <= 0:
        return len(w) == 1
    for k in range(1, len(w)):
        if not w[k - 1] / w[k] > (r2[k - 1] - r2[k]) / (r2[k] - r2[k + 1]):
            return False
    return True


def allocation(rho, w, budget):
    """Optimal real sample sizes m [K] (models in the order given, rho ordered) for a budget."""
    r2 = np.append(np.asarray(rho, float) ** 2, 0.0)
    if len(w) == 1:
        return np.array([budget / w[0]])
    r = np.sqrt(w[0] * (r2[:-1] - r2[1:]) / (w * (1.0 - r2[1])))
    r[0] = 1.0
    m1 = budget / np.dot(w, r)
    return m1 * r


def variance_per_budget(sigma1, rho, w):
    """gamma with Var s = gamma / p at the optimal allocation (plain Monte Carlo: sigma1^2 w_1)."""
    r2 = np.append(np.asarray(rho, float) ** 2, 0.0)
    return float(sigma1 ** 2 * np.sum(np.sqrt(w * (r2[:-1] - r2[1:]))) ** 2)


def select_models(C, costs):
    """The subset of models (indices, model 0 first, then by |rho| decreasing) of least variance
    per unit budget among those meeting the allocation's conditions; and that gamma."""
    sig, rho = correlations(C)
    w = np.asarray(costs, float)
    best = ([0], variance_per_budget(sig[0], [1.0], w[:1]))
    for size in range(1, len(w)):
        for sub in itertools.combinations(range(1, len(w)), size):
            order = [0] + sorted(sub, key=lambda k: -abs(rho[k]))
            ro, wo = np.abs(rho[order]), w[order]
            if admissible(ro, wo):
                g = variance_per_budget(sig[0], ro, wo)
                if g < best[1]:
                    best = (order, g)
    return best


def integer_sizes(m, m1_min=2):
    """Non-decreasing integer sample sizes from real ones, m_1 >= m1_min."""
    out, prev = [], 0
    for k, v in enumerate(m):
        n = max(int(np.ceil(v)) if k == 0 else int(np.round(v)), m1_min if k == 0 else prev, prev)
        out.append(n)
        prev = n
    return np.array(out, dtype=int)


def monotone_cdf(F):
    """A CDF estimate made non-decreasing and clipped to [0, 1] (average of the running max
    from the left and running min from the right: a rearrangement that leaves a monotone F
    unchanged)."""
    up = np.maximum.accumulate(F)
    down = np.minimum.accumulate(F[::-1])[::-1]
    return np.clip(0.5 * (up + down), 0.0, 1.0)
