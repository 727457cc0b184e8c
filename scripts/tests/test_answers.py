"""scripts/pipeline/answers (answers with a stated error) on synthetic models with known moments: MFMC's
allocation and variance against the closed forms, the 1 / (1 - rho^2) bound, unbiasedness, the
coverage of the stated 95% intervals over repetitions, the surrogates' map intervals, the
questions file's errors and the crowd_answers.py driver end to end."""
import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, SCRIPTS)
from answers import acv, methods, mfmc, sampling  # noqa: E402
from answers.backend import SyntheticFamily  # noqa: E402
from answers.coverage import coverage, wilson  # noqa: E402
from answers.ledger import CostLedger  # noqa: E402
from answers.questions import (Distribution, JointDistribution, ParamBox, Question,  # noqa: E402
                               QuestionsError, load_questions)

BOX = ParamBox(["l_exit", "l_exit2", "speed"], [2.0, 2.0, 1.0], [3.0, 3.0, 1.4])
RHO = 0.9


def family(kind="gauss", costs=(1.0, 0.01, 0.002)):
    return SyntheticFamily(BOX, [20.0, 15.0, 18.0], [2.0, 1.5, 1.8],
                           [[1, RHO, 0.8], [RHO, 1, 0.75], [0.8, 0.75, 1]], costs, kind)


def uniform_question(kind="moments", **kw):
    dist = JointDistribution(BOX, {n: Distribution("uniform", low=BOX.lo[j], high=BOX.hi[j])
                                   for j, n in enumerate(BOX.names)})
    return Question("q", kind, "t90", distribution=dist, **kw)


def pair_cov(fam):
    s = fam.stds[:2]
    return np.array([[s[0] ** 2, RHO * s[0] * s[1]], [RHO * s[0] * s[1], s[1] ** 2]])


# ------------------------------------------------------------------------------ closed forms

def test_allocation_and_variance_match_the_closed_forms():
    fam = family()
    C, w, p = pair_cov(fam), fam.costs[:2], 500.0
    m = mfmc.allocation([1.0, RHO], w, p)
    r2 = np.sqrt(w[0] * RHO ** 2 / (w[1] * (1 - RHO ** 2)))
    assert m[1] / m[0] == pytest.approx(r2, rel=1e-12)
    assert np.dot(w, m) == pytest.approx(p, rel=1e-12)
    alpha = mfmc.optimal_alpha(C)
    assert alpha[1] == pytest.approx(RHO * fam.stds[0] / fam.stds[1], rel=1e-12)
    closed = C[0, 0] / p * (np.sqrt(w[0] * (1 - RHO ** 2)) + np.sqrt(w[1] * RHO ** 2)) ** 2
    assert mfmc.variance(C, m, alpha) == pytest.approx(closed, rel=1e-12)
    assert mfmc.variance_per_budget(fam.stds[0], [1.0, RHO], w) / p == pytest.approx(closed, rel=1e-12)


def test_estimator_variance_and_unbiasedness_by_repetition():
    """Fixed sizes and coefficients (one optimal, one not): over R repetitions the estimates'
    mean is the truth within 4 standard errors and their variance the formula's within 4 sd of
    a variance estimate (relative sd sqrt(2 / (R - 1)))."""
    fam = family()
    C, R = pair_cov(fam), 3000
    m = np.array([20, 400])
    rng = np.random.default_rng(1)
    for alpha in (mfmc.optimal_alpha(C), np.array([1.0, 0.5])):
        x = rng.uniform(BOX.lo, BOX.hi, (R * m[1], 3))
        y0 = fam.values(0, x).reshape(R, m[1])[:, :m[0]]
        y1 = fam.values(1, x).reshape(R, m[1])
        est = y0.mean(1) + alpha[1] * (y1.mean(1) - y1[:, :m[0]].mean(1))
        assert est[0] == pytest.approx(acv.combine([y0[0], y1[0]], alpha, acv.b_sizes("mfmc", m)), rel=1e-14)
        v = mfmc.variance(C, m, alpha)
        assert abs(est.mean() - fam.mean()) < 4 * np.sqrt(v / R)
        assert est.var(ddof=1) / v == pytest.approx(1.0, abs=4 * np.sqrt(2 / (R - 1)))


def test_variance_estimator_is_unbiased():
    fam = family(kind="uniform")
    C, R, m = pair_cov(fam), 3000, [15, 300]
    alpha = mfmc.optimal_alpha(C)
    rng = np.random.default_rng(2)
    x = rng.uniform(BOX.lo, BOX.hi, (R * m[1], 3))
    y0 = fam.values(0, x).reshape(R, m[1])[:, :m[0]]
    y1 = fam.values(1, x).reshape(R, m[1])
    est = y0.var(1, ddof=1) + alpha[1] * (y1.var(1, ddof=1) - y1[:, :m[0]].var(1, ddof=1))
    assert est[0] == pytest.approx(acv.combine_variance([y0[0], y1[0]], alpha, acv.b_sizes("mfmc", m)), rel=1e-12)
    assert abs(est.mean() - fam.std() ** 2) < 4 * est.std(ddof=1) / np.sqrt(R)


def test_gain_bounded_by_one_over_one_minus_rho_squared():
    sig = 2.0
    mc = sig ** 2 * 1.0                     # plain Monte Carlo: sigma^2 w_1 / p
    for w2 in (0.5, 0.1, 1e-3, 1e-8):
        ratio = mfmc.variance_per_budget(sig, [1.0, RHO], np.array([1.0, w2])) / mc
        assert ratio >= 1 - RHO ** 2 - 1e-15
    assert ratio == pytest.approx(1 - RHO ** 2, rel=1e-3)
    # the cost condition w1 / w2 > (1 - rho^2) / rho^2 (= 0.235 here), and plain Monte Carlo
    # kept where the optimal MFMC does not beat it: (sqrt(0.19) + sqrt(0.81 w2))^2 >= 1
    C = np.array([[4.0, RHO * 2], [RHO * 2, 1.0]])
    assert not mfmc.admissible([1.0, RHO], np.array([1.0, 5.0]))
    assert mfmc.admissible([1.0, RHO], np.array([1.0, 3.0]))
    assert mfmc.select_models(C, [1.0, 3.0])[0] == [0]
    assert mfmc.select_models(C, [1.0, 0.3])[0] == [0, 1]
    assert mfmc.select_models(C, [1.0, 0.3])[1] == pytest.approx(
        4.0 * (np.sqrt(1 - RHO ** 2) + np.sqrt(0.3 * RHO ** 2)) ** 2, rel=1e-12)


# ------------------------------------------------------------------------------ coverage

def _m3(q, stat, models, eps):
    def run(seed):
        led = CostLedger()
        pilot = sampling.Pilot(q, models, 30, seed, led)
        tsd = sampling.target_sd(stat, pilot.Y[:, 0], eps, 1.96, q.threshold, q.percentile)
        return methods.m3(q, stat, models, pilot, methods.m3_plan(pilot, stat, tsd, q), seed, 0.95, led)
    return run


@pytest.mark.parametrize("method,stat,reps", [
    ("M0", "mean", 200), ("M0", "std", 200), ("M0", "p95", 200), ("M0", "exceedance", 200),
    ("M3", "mean", 200), ("M3", "std", 100), ("M3", "p95", 100), ("M3", "exceedance", 100)])
def test_stated_intervals_cover_the_truth(method, stat, reps):
    """Coverage of the stated 95% intervals >= 90% (seeds fixed). With R repetitions and a true
    coverage of 95% the estimate's sd is sqrt(0.95 0.05 / R) (0.015 at R = 200, 0.022 at 100):
    90% is 3.2 (2.3) sd below, and the Wilson interval of the estimate must contain 0.95 so
    that intervals wider than stated fail too."""
    fam = family()
    models = [fam.model(k) for k in range(3)]
    q = uniform_question("exceedance" if stat == "exceedance" else "moments",
                         percentile=95.0, threshold=21.0)
    truth = fam.truth(stat, 95.0, 21.0)
    if method == "M0":
        def run(seed):
            return methods.m0(q, stat, models[0], 100, seed, 0.95, CostLedger())
    else:
        run = _m3(q, stat, models, 0.05 if stat in ("mean", "std") else 0.15)
    c = coverage(run, truth, range(reps))
    assert c["coverage"] >= 0.90, c
    assert c["coverage_hi"] >= 0.95 or method == "M0" and stat in ("p95", "exceedance"), c


def test_wilson_interval():
    lo, hi = wilson(190, 200)
    assert lo < 0.95 < hi and hi - lo < 0.07


def test_mfmc_beats_plain_monte_carlo_at_equal_accuracy():
    """The MFMC plan costs less than M0 for the same target variance, by at least the factor
    the pilot correlation promises (minus the integer rounding)."""
    fam = family()
    models = [fam.model(k) for k in range(3)]
    q = uniform_question(percentile=95.0)
    pilot = sampling.Pilot(q, models, 200, 3, CostLedger())
    tsd = sampling.target_sd("mean", pilot.Y[:, 0], 0.005, 1.96)
    plan = methods.m3_plan(pilot, "mean", tsd, q)
    m0_cost = np.var(pilot.Y[:, 0], ddof=1) / tsd ** 2 * pilot.costs[0]
    assert plan["models"][0] == 0 and len(plan["models"]) >= 2
    assert plan["cost"] < 0.5 * m0_cost
    assert plan["variance"] <= tsd ** 2 * 1.05


# ------------------------------------------------------------------------------ surrogates

def test_surrogate_maps_cover_the_exact_values():
    """M1 (GP on exact runs) and M3 (autoregressive GP with the low fidelity) on a 4 x 3 grid:
    the stated intervals hold the exact values at >= 10 of 12 points, M3 states a smaller error
    than M1 on the same exact runs, M0 is exact."""
    warnings.simplefilter("ignore")
    fam = family(kind="uniform")
    exact, low = fam.model(0), fam.model(1)
    q = Question("map", "map", "t90", grid={"l_exit": [2.1, 2.4, 2.7, 2.9], "l_exit2": [2.2, 2.5, 2.8]},
                 nominal={"speed": 1.2})
    pts, _ = q.grid_points(BOX)
    truth = fam.values(0, pts)
    tr = sampling.TrainingSet(q, BOX, [exact, low], 5, CostLedger())
    a1 = methods.m1_map(q, BOX, sampling.TrainingSet(q, BOX, [exact], 5, CostLedger()), 12, 5, 0.95,
                        CostLedger(), restarts=1)
    a3 = methods.m3_map(q, BOX, low, tr, 12, 5, 0.95, CostLedger(), restarts=1)
    for a in (a1, a3):
        assert np.sum((a.lo <= truth) & (truth <= a.hi)) >= 10
    assert a3.stated_error < a1.stated_error
    a0 = methods.m0_map(q, BOX, exact, 5, 0.95, CostLedger())
    assert np.array_equal(a0.value, truth) and a0.stated_error == 0.0
    assert a0.cost == pytest.approx(len(pts) * fam.costs[0])


def test_gp_surrogate_answers_hold_the_truth():
    """M1 on 16 exact runs of the linear ('uniform') family: mean, std, 95th percentile and
    exceedance intervals hold the closed forms; the training runs are charged."""
    warnings.simplefilter("ignore")
    fam = family(kind="uniform")
    for stat, q in (("mean", uniform_question()), ("std", uniform_question()),
                    ("p95", uniform_question(percentile=95.0)),
                    ("exceedance", uniform_question("exceedance", threshold=21.0))):
        led = CostLedger()
        tr = sampling.TrainingSet(q, BOX, [fam.model(0)], 6, led)
        a = methods.m1(q, stat, tr, 16, 6, 0.95, led, restarts=0, n_large=5000, n_draws=100, n_sub=150)
        assert a.covers(fam.truth(stat, 95.0, 21.0)), (stat, a.value, a.lo, a.hi)
        assert a.stated_error < 0.05
        assert led.by_stage()["training"] == pytest.approx(16 * fam.costs[0])


def test_low_fidelity_alone_states_its_bias():
    """M2: the low fidelity's mean (15) is 25% off the exact one (20): the answer is the low
    value, its interval reaches the truth and its stated error is at least the bias."""
    fam = family()
    q = uniform_question()
    a = methods.m2(q, "mean", fam.model(1), fam.model(0), 1000, 30, 4, 0.95, CostLedger())
    assert a.value == pytest.approx(15.0, rel=0.02)
    assert a.lo <= 20.0 <= a.hi
    assert a.stated_error >= 0.3


# ------------------------------------------------------------------------------ questions file

GOOD = {"case": "t", "box": {"l_exit": [2.0, 3.0], "l_exit2": [2.0, 3.0], "speed": [1.0, 1.4]},
        "accuracy": {"relative": [0.02, 0.05], "confidence": 0.95}, "seed": 3,
        "questions": [
            {"id": "m", "kind": "map", "qoi": "t90", "grid": {"l_exit": [2.2, 2.8]},
             "nominal": {"l_exit2": 2.5, "speed": 1.2}},
            {"id": "s", "kind": "moments", "qoi": "t90", "percentile": 95,
             "distributions": {"l_exit": {"kind": "uniform", "low": 2.0, "high": 3.0},
                               "l_exit2": {"kind": "fixed", "value": 2.4},
                               "speed": {"kind": "truncnormal", "mean": 1.2, "std": 0.1,
                                         "low": 1.0, "high": 1.4}}}]}


def _write(tmp_path, doc, name="q.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return str(p)


def _bad(mutate):
    doc = json.loads(json.dumps(GOOD))
    mutate(doc)
    return doc


BAD = [
    ("unknown QoI", lambda d: d["questions"][0].update(qoi="t95"), "questions[0].qoi: unknown QoI 't95'"),
    ("empty grid", lambda d: d["questions"][0].update(grid={}), "questions[0].grid: empty grid"),
    ("empty grid values", lambda d: d["questions"][0]["grid"].update(l_exit=[]),
     "questions[0].grid.l_exit: empty grid"),
    ("negative accuracy", lambda d: d["accuracy"].update(relative=[-0.01]),
     "accuracy.relative[0]: must be > 0"),
    ("distribution outside the box", lambda d: d["questions"][1]["distributions"]["l_exit"].update(high=3.5),
     "questions[1].distributions.l_exit.high: 3.5 lies outside the trained box [2.0, 3.0]"),
    ("unknown key", lambda d: d["questions"][1].update(percentil=90),
     "questions[1].percentil: unknown key"),
    ("grid point outside the box", lambda d: d["questions"][0]["grid"].update(l_exit=[1.5, 2.0]),
     "questions[0].grid.l_exit[0]: 1.5 lies outside"),
    ("missing nominal", lambda d: d["questions"][0].update(nominal={"speed": 1.2}),
     "questions[0].nominal: missing key 'l_exit2'"),
    ("unknown distribution", lambda d: d["questions"][1]["distributions"]["speed"].update(kind="normal"),
     "questions[1].distributions.speed.kind: unknown distribution 'normal'"),
]


def test_good_questions_file(tmp_path):
    qs = load_questions(_write(tmp_path, GOOD))
    assert [q.statistics() for q in qs.questions] == [["map"], ["mean", "std", "p95"]]
    pts, shape = qs.questions[0].grid_points(qs.box)
    assert shape == (2,) and np.allclose(pts, [[2.2, 2.5, 1.2], [2.8, 2.5, 1.2]])
    x = qs.questions[1].distribution.sample(np.random.default_rng(0), 500)
    assert np.all(x[:, 1] == 2.4) and x[:, 2].min() >= 1.0 and x[:, 2].max() <= 1.4


@pytest.mark.parametrize("what,mutate,message", BAD, ids=[b[0] for b in BAD])
def test_bad_questions_file(tmp_path, what, mutate, message):
    path = _write(tmp_path, _bad(mutate))
    with pytest.raises(QuestionsError) as exc:
        load_questions(path)
    assert str(exc.value).startswith(f"{path}: ") and message in str(exc.value)
    assert "\n" not in str(exc.value)


def test_distribution_outside_the_callers_box(tmp_path):
    """The trained box given by the caller (from the ROM file) is narrower than the file's."""
    trained = ParamBox(BOX.names, [2.0, 2.0, 1.1], [3.0, 3.0, 1.4])
    doc = _bad(lambda d: d.pop("box"))
    with pytest.raises(QuestionsError, match=r"speed.low: 1.0 lies outside the trained box \[1.1, 1.4\]"):
        load_questions(_write(tmp_path, doc), trained)


# ------------------------------------------------------------------------------ driver

MODELS = {"synthetic": {"means": [20, 15, 18], "stds": [2, 1.5, 1.8],
                        "corr": [[1, 0.9, 0.8], [0.9, 1, 0.75], [0.8, 0.75, 1]],
                        "costs": [6.0, 0.05, 0.02], "kind": "gauss", "names": ["exact", "rom", "rom_ml"]},
          "builds": [{"model": "rom", "cpu_seconds": 300.0, "runs": 36}]}


def _driver(tmp_path, qdoc, *extra):
    q, m = _write(tmp_path, qdoc), _write(tmp_path, MODELS, "models.json")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, "pipeline", "crowd_answers.py"), q, "--models", m,
                           "--out-prefix", str(tmp_path / "out"), "--quiet", *extra],
                          capture_output=True, text=True, env=env)


def test_driver_end_to_end(tmp_path):
    doc = json.loads(json.dumps(GOOD))
    doc["questions"] = [{"id": "late", "kind": "exceedance", "qoi": "t90", "threshold": 21.0,
                         "distributions": {n: {"kind": "uniform", "low": lo, "high": hi}
                                           for n, (lo, hi) in GOOD["box"].items()}}]
    doc["accuracy"]["relative"] = [0.1]
    r = _driver(tmp_path, doc, "--methods", "M0", "M3")
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "out.json").read_text())
    row, = rep["rows"]
    assert row["method"].startswith("M3") and row["reached"]
    assert row["lo"] <= row["value"] <= row["hi"]
    a, = rep["answers"]
    stages = {e["stage"] for e in a["ledger"]}
    assert {"build", "pilot", "estimation"} <= stages          # the ROM's build is charged
    assert a["cost_cpu_seconds"] == pytest.approx(sum(e["cpu_seconds"] for e in a["ledger"]))
    assert row["m0_cost"] > row["cost"]
    assert "| late | t90 | exceedance | 10% | M3" in (tmp_path / "out.md").read_text()
    pilot, = rep["pilots"]                      # what decides: correlations, costs, biases
    corr = {m["model"]: m for m in pilot["models"]}
    assert pilot["runs"] == 40 and corr["exact"]["corr"] == pytest.approx(1.0)
    assert abs(corr["rom"]["corr"] - 0.9) < 0.15 and corr["rom"]["cpu_per_run"] == pytest.approx(0.05)
    assert abs(corr["rom"]["bias"] - 5.0) < 1.0         # means 20 and 15
    assert (tmp_path / "out.png").stat().st_size > 0


def test_driver_bad_questions_writes_nothing(tmp_path):
    r = _driver(tmp_path, _bad(lambda d: d["accuracy"].update(relative=[0.02, -0.05])))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "accuracy.relative[1]: must be > 0" in r.stderr
    assert "q.json" in r.stderr
    assert not any(p.name.startswith("out") for p in tmp_path.iterdir())


# ------------------------------------------------------------------------------ shared builds, shared runs

def test_shared_build_charged_once(tmp_path):
    """Two low fidelities of one ROM file share the snapshot stage (the same summary named under
    each): an answer using both is charged it once, and the ML model's own training on top."""
    import crowd_answers
    from answers.select import Setup
    snap = _write(tmp_path, {"program": "crowd_snapshots", "samples_total": 36,
                             "busy_time_per_rank": [100.0, 110.0]}, "snap.json")
    doc = {"builds": [{"model": "rom", "summary": snap}, {"model": "rom_ml", "summary": snap},
                      {"model": "rom_ml", "cpu_seconds": 50.0, "runs": 36}]}
    setup = Setup(None, [], crowd_answers.load_builds("m.json", doc))
    assert setup.ledger(["rom", "rom_ml"]).total() == pytest.approx(210.0 + 50.0)
    assert setup.ledger(["rom"]).total() == pytest.approx(210.0)
    assert setup.ledger(["exact"]).total() == 0.0
    doc = {"builds": [{"name": "snapshots", "models": ["rom", "rom_ml"], "summary": snap}]}
    led = Setup(None, [], crowd_answers.load_builds("m.json", doc)).ledger(["exact", "rom", "rom_ml"])
    assert [(e[1], e[2]) for e in led.entries] == [("snapshots", 36)]


class _TwoQoIModel:
    """A deterministic model with two QoIs that records every row it runs."""

    def __init__(self, name, shift, log):
        self.name, self.shift, self.log = name, shift, log

    def for_qoi(self, qoi):
        model = self

        class View:
            name = model.name

            def evaluate(self, params, seeds=None):
                for r in np.atleast_2d(params):
                    model.log.append((model.name, r.tobytes()))
                base = 10.0 + 5.0 * params[:, 2] - params[:, 0] + model.shift
                return sampling_eval(base * (1.0 if qoi == "t50" else 1.8), 0.01 * len(params))
        return View()


def sampling_eval(values, cpu):
    from answers.backend import Evaluation
    return Evaluation(values, cpu)


def test_questions_on_two_qois_share_the_runs():
    """The moments of t50 and of t90 over one distribution: the second question runs no
    parameter row the first did not (the rows are drawn from the region, not the question's
    place), and each question reads its own QoI."""
    from answers.questions import Questions
    from answers.select import Setup, answer_questions
    dist = JointDistribution(BOX, {n: Distribution("uniform", low=BOX.lo[j], high=BOX.hi[j])
                                   for j, n in enumerate(BOX.names)})
    qs = [Question(f"{qoi}_spread", "moments", qoi, distribution=dist) for qoi in ("t50", "t90")]
    log = []
    # M1 alone: the rows are the pilot and the nested training design of the region; a planned
    # M0 would draw as many fresh rows as each QoI's own variance asks (legitimately more for
    # one QoI than for the other), and its choice against M1 hangs on the measured fitting CPU
    setup = Setup(_TwoQoIModel("exact", 0.0, log), [_TwoQoIModel("rom", 0.5, log)], seed=3, n_pilot=12,
                  m1_ladder=(8, 16), methods=("M1",), gp_restarts=0)
    first = Questions("q.json", "two", BOX, [0.05], 0.95, 3, qs[:1])
    answer_questions(first, setup)
    rows_first = set(log)
    rep = answer_questions(Questions("q.json", "two", BOX, [0.05], 0.95, 3, qs), setup)
    assert set(log) == rows_first                       # t90's rows are t50's rows
    means = {r["question"]: r["value"] for r in rep["rows"] if r["statistic"] == "mean"}
    assert means["t90_spread"] == pytest.approx(1.8 * means["t50_spread"], rel=0.05)


def test_box_must_be_the_rom_files(tmp_path):
    """A questions file whose box differs from the ROM file's (narrower too) is refused with one
    line naming the file, the key and the component; without a box it takes the ROM file's."""
    trained = ParamBox(BOX.names, BOX.lo, BOX.hi)
    for speed in ([1.0, 1.5], [1.0, 1.3]):
        doc = _bad(lambda d: d["box"].update(speed=speed))
        path = _write(tmp_path, doc)
        with pytest.raises(QuestionsError) as exc:
            load_questions(path, trained, "ROM file 'r.h5'")
        msg = str(exc.value)
        assert msg.startswith(f"{path}: box.speed: ") and "disagrees with the trained box [1.0, 1.4] of " \
            "ROM file 'r.h5'" in msg and "\n" not in msg
    doc = _bad(lambda d: d["box"].pop("l_exit2"))
    with pytest.raises(QuestionsError, match=r"box.l_exit2: missing"):
        load_questions(_write(tmp_path, doc), trained, "ROM file 'r.h5'")
    qs = load_questions(_write(tmp_path, _bad(lambda d: d.pop("box"))), trained, "ROM file 'r.h5'")
    assert qs.box is trained
