"""The answers' report on a real case: the cheapest candidate of every method reaching each
accuracy, beyond the budget too, and the gain of the cheapest one using a low fidelity over M0
(what a target on the reduced model is judged by when another method wins the row)."""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.join(os.path.dirname(HERE), "pipeline"), os.path.dirname(HERE)]
from answers import report  # noqa: E402
from answers.backend import SyntheticFamily  # noqa: E402
from answers.questions import Distribution, JointDistribution, ParamBox, Question, Questions  # noqa: E402
from answers.select import Setup, answer_questions  # noqa: E402


def cand(method, cost, err, planned):
    return {"question": "q", "statistic": "mean", "method": method, "cost": cost,
            "stated_error": err, "planned": planned}


def fake_report():
    return {"case": "c", "questions_file": "q.json", "confidence": 0.95, "accuracy": [0.02, 0.05],
            "max_cost": 100.0,
            "rows": [{"question": "q", "qoi": "t90", "statistic": "mean", "accuracy": e,
                      "method": None, "m0_cost": 500.0} for e in (0.02, 0.05)],
            "candidates": [cand("M0 exact MC", 500.0, 0.02, True), cand("M0 exact MC", 150.0, 0.05, True),
                           cand("M1 gp n=8", 40.0, 0.03, False), cand("M2 rom n=8", 20.0, 0.3, False),
                           cand("M3 MFMC rom", 60.0, 0.02, True), cand("M3 MFMC rom", 45.0, 0.05, True),
                           cand("M3 MFMC (exact only)", 30.0, 0.05, True)]}


def test_cheapest_of_each_method_beyond_the_budget():
    rep = fake_report()
    at2 = report.cheapest_by_method(rep, "q", "mean", 0.02)
    assert at2["M0"]["cost"] == 500.0 and at2["M1"] is None and at2["M2"] is None
    assert at2["M3"]["cost"] == 60.0 and at2["low"]["cost"] == 60.0
    at5 = report.cheapest_by_method(rep, "q", "mean", 0.05)
    assert at5["M0"]["cost"] == 150.0 and at5["M1"]["cost"] == 40.0
    # MFMC that kept the exact model alone is the cheapest M3 but uses no low fidelity
    assert at5["M3"]["method"] == "M3 MFMC (exact only)" and at5["low"]["cost"] == 45.0
    lines = report.markdown(rep).splitlines()
    row2 = [ln for ln in lines if ln.startswith("| q | mean | 2% | 500 p*")]
    assert row2 and row2[0].endswith("| 60 p (M3 MFMC rom) | 8.33x |")
    row5 = [ln for ln in lines if ln.startswith("| q | mean | 5% | 150 p*")]
    assert row5 and "| 40 (M1 gp n=8) |" in row5[0] and row5[0].endswith("| 3.33x |")
    assert any("beyond the budget of 100 CPU s" in ln for ln in lines)


def test_engine_report_carries_the_budget():
    box = ParamBox(["a", "b"], [0.0, 0.0], [1.0, 1.0])
    fam = SyntheticFamily(box, [10.0, 8.0], [1.0, 1.0], [[1, 0.95], [0.95, 1]], [1.0, 0.01], "gauss")
    dist = JointDistribution(box, {n: Distribution("uniform", low=0.0, high=1.0) for n in box.names})
    qs = Questions("q.json", "c", box, [0.05], 0.95, 3, [Question("q", "moments", "t90", distribution=dist)])
    rep = answer_questions(qs, Setup(fam.model(0), [fam.model(1)], seed=3, n_pilot=20,
                                     methods=("M0", "M3"), max_cost=50.0))
    assert rep["max_cost"] == 50.0
    text = report.markdown(rep)
    assert "beyond the budget of 50 CPU s" in text
    assert "| q | std | 5% |" in text.split("Cheapest candidate of each method")[1]


def test_planned_m0_percentile_has_a_bounded_interval():
    from answers.intervals import quantile_ci
    from answers.select import quantile_min_runs
    n = quantile_min_runs(0.95, 0.95)
    assert n == 72
    assert all(abs(v) < 1e9 for v in quantile_ci(range(n), 0.95, 0.95))
    assert quantile_ci(range(n - 1), 0.95, 0.95)[2] == float("inf")
    # a narrow family: the variance alone would plan about 50 runs for the 95th percentile at 5%
    box = ParamBox(["a", "b"], [0.0, 0.0], [1.0, 1.0])
    fam = SyntheticFamily(box, [10.0, 8.0], [1.0, 1.0], [[1, 0.95], [0.95, 1]], [1.0, 0.01], "gauss")
    dist = JointDistribution(box, {n: Distribution("uniform", low=0.0, high=1.0) for n in box.names})
    qs = Questions("q.json", "c", box, [0.05], 0.95, 3,
                   [Question("q", "moments", "t90", distribution=dist)])
    rep = answer_questions(qs, Setup(fam.model(0), [fam.model(1)], seed=3, n_pilot=20,
                                     methods=("M0",), max_cost=0.0))
    m0 = [c for c in rep["candidates"] if c["statistic"] == "p95" and c["method"].startswith("M0")]
    assert m0 and all(c["cost"] >= 20 + 72 - 1e-9 for c in m0)


def test_planned_extension_stays_within_the_budget():
    # P(QoI > 14) of a normal (10, 1): about 3e-5, so neither the 20-run pilot nor the planned
    # 10 runs see an exceedance; the interval of 0 of 10 has no finite relative error and the
    # planner would extend the sample to 40 runs (60 CPU s with the pilot) beyond the 35 allowed
    box = ParamBox(["a", "b"], [0.0, 0.0], [1.0, 1.0])
    fam = SyntheticFamily(box, [10.0, 8.0], [1.0, 1.0], [[1, 0.95], [0.95, 1]], [1.0, 0.01], "gauss")
    dist = JointDistribution(box, {n: Distribution("uniform", low=0.0, high=1.0) for n in box.names})
    qs = Questions("q.json", "c", box, [0.05], 0.95, 3,
                   [Question("q", "exceedance", "t90", distribution=dist, threshold=14.0)])
    rep = answer_questions(qs, Setup(fam.model(0), [fam.model(1)], seed=3, n_pilot=20,
                                     methods=("M0",), max_cost=35.0))
    row = [r for r in rep["rows"] if r["statistic"] == "exceedance"][0]
    assert row["method"] == "M0 exact MC" and row["reached"] is False
    assert 30.0 - 1e-9 <= row["cost"] <= 35.0
