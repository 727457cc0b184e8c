"""scripts/pipeline/answers/acv.py (approximate control variates) on a synthetic family of
correlated models with known covariance: the variance formula against the empirical variance
over repetitions, unbiasedness, the MFMC layout against MFMC's closed forms, ACV-MF's optimum
with one low fidelity equal to MFMC's, ACV beating MFMC where the low fidelities are weakly
correlated with each other, and M3 choosing the ACV layout end to end."""
import os
import sys

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "pipeline"))
from answers import acv, methods, mfmc, sampling  # noqa: E402
from answers.backend import SyntheticFamily  # noqa: E402
from answers.coverage import coverage  # noqa: E402
from answers.ledger import CostLedger  # noqa: E402
from answers.questions import Distribution, JointDistribution, ParamBox, Question  # noqa: E402

BOX = ParamBox(["a", "b", "c"], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
# two low fidelities each correlated 0.8 with the exact model, 0.4 with each other: MFMC's gain
# is bounded by 1 / (1 - 0.8^2) = 2.8, ACV's by 1 / (1 - R^2) = 11.7 (R^2 = 2 0.64 / 1.4)
CORR = np.array([[1.0, 0.8, 0.8], [0.8, 1.0, 0.4], [0.8, 0.4, 1.0]])
STDS = np.array([2.0, 1.5, 3.0])
COV = CORR * np.outer(STDS, STDS)
R2 = 2 * 0.64 / 1.4


def family(costs=(1.0, 0.002, 0.002)):
    return SyntheticFamily(BOX, [10.0, 7.0, 12.0], STDS, CORR, costs, "gauss")


def uniform_question():
    dist = JointDistribution(BOX, {n: Distribution("uniform", low=0.0, high=1.0) for n in BOX.names})
    return Question("q", "moments", "t90", distribution=dist, percentile=95.0)


def test_mfmc_layout_matches_mfmc_closed_forms():
    m = np.array([12, 40, 90])
    alpha = acv.optimal_alpha(COV, m, "mfmc")
    assert alpha == pytest.approx(mfmc.optimal_alpha(COV), rel=1e-10)
    for a in (alpha, np.array([1.0, 0.3, -0.2])):
        assert acv.variance(COV, m, a, "mfmc") == pytest.approx(mfmc.variance(COV, m, a), rel=1e-12)
    order, g = mfmc.select_models(COV, [1.0, 0.01, 0.002])
    scheme, order2, _, g2, _ = acv.select(COV, [1.0, 0.01, 0.002], ("mfmc",))
    assert (scheme, order2) == ("mfmc", order) and g2 == pytest.approx(g, rel=1e-12)


@pytest.mark.parametrize("scheme", ["acvmf", "acvis"])
def test_acv_variance_and_unbiasedness_by_repetition(scheme):
    """Fixed sizes and coefficients (optimal, and not): over R repetitions the estimates' mean
    is the truth within 4 standard errors and their variance the formula's within 4 sd of a
    variance estimate (relative sd sqrt(2 / (R - 1)))."""
    fam, R = family(), 4000
    m = np.array([15, 120, 60])
    idx, n = acv.input_indices(scheme, m)
    b = acv.b_sizes(scheme, m)
    rng = np.random.default_rng(7)
    x = rng.uniform(0.0, 1.0, (R * n, 3))
    Y = [fam.values(k, x).reshape(R, n)[:, idx[k]] for k in range(3)]
    for alpha in (acv.optimal_alpha(COV, m, scheme), np.array([1.0, 0.5, 0.2])):
        est = Y[0].mean(1) + sum(alpha[k] * (Y[k].mean(1) - Y[k][:, :b[k]].mean(1)) for k in (1, 2))
        assert est[0] == pytest.approx(acv.combine([y[0] for y in Y], alpha, b), rel=1e-13)
        v = acv.variance(COV, m, alpha, scheme)
        assert abs(est.mean() - fam.mean()) < 4 * np.sqrt(v / R)
        assert est.var(ddof=1) / v == pytest.approx(1.0, abs=4 * np.sqrt(2 / (R - 1)))
    # the optimal coefficients give less than both plain MC on m_0 runs and the other alpha
    assert acv.variance(COV, m, acv.optimal_alpha(COV, m, scheme), scheme) < min(
        COV[0, 0] / m[0], acv.variance(COV, m, np.array([1.0, 0.5, 0.2]), scheme))


@pytest.mark.parametrize("scheme", ["acvmf", "acvis"])
def test_one_low_fidelity_acv_optimum_is_mfmc_closed_form(scheme):
    C, w = COV[:2, :2], np.array([1.0, 0.01])
    r, g = acv.optimal_ratios(C, w, scheme)
    rho = CORR[0, 1]
    closed_g = C[0, 0] * (np.sqrt(w[0] * (1 - rho ** 2)) + np.sqrt(w[1] * rho ** 2)) ** 2
    assert g <= closed_g * (1 + 1e-6)
    assert g == pytest.approx(closed_g, rel=1e-6)
    assert r[0] == pytest.approx(np.sqrt(w[0] * rho ** 2 / (w[1] * (1 - rho ** 2))), rel=1e-3)


def test_acv_beats_mfmc_with_weakly_related_low_fidelities():
    """Costs 1 : 1e-4: MFMC stays above its bound (1 - 0.64) C_00, ACV-MF and ACV-IS go below
    it, and above their own bound (1 - R^2) C_00."""
    w = np.array([1.0, 1e-4, 1e-4])
    scheme, order, r, g, per = acv.select(COV, w, acv.SCHEMES)
    assert per["mfmc"] >= (1 - 0.64) * COV[0, 0]
    for s in ("acvmf", "acvis"):
        assert (1 - R2) * COV[0, 0] <= per[s] < 0.8 * (1 - 0.64) * COV[0, 0]
    assert scheme in ("acvmf", "acvis") and order == [0, 1, 2] and g == min(per.values())


def test_m3_plans_and_runs_acv_mf_without_bias():
    """M3 end to end on the family: the pilot's plan takes ACV-MF with both low fidelities, and
    its stated 95% intervals for the mean hold the truth in >= 90% of 100 repetitions."""
    fam = family()
    models = [fam.model(k) for k in range(3)]
    q = uniform_question()

    def run(seed):
        led = CostLedger()
        pilot = sampling.Pilot(q, models, 40, seed, led)
        tsd = sampling.target_sd("mean", pilot.Y[:, 0], 0.01, 1.96)
        plan = methods.m3_plan(pilot, "mean", tsd, q)
        assert plan["scheme"] == "acvmf" and plan["models"] == [0, 1, 2], plan
        a = methods.m3(q, "mean", models, pilot, plan, seed, 0.95, led)
        assert a.details["layout"] == "ACV-MF"
        return a
    c = coverage(run, fam.mean(), range(100))
    assert c["coverage"] >= 0.90 and c["coverage_hi"] >= 0.95, c
