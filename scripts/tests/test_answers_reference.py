"""The honest reference and the coverage served from a pool (scripts/pipeline/answers/reference.py,
pool.py): chunked runs that resume, the truth table's statistics and standard errors, the pool
drawn without replacement and looked up bit for bit with its CPU seconds, M0 and M3 coverage from
a pool of a synthetic family against its closed forms, and the map interval of a GP on a model
whose output jitters below the kernel's scale (a chaotic crowd's t90)."""
import os
import sys
import warnings

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
from answers import methods, pool, reference, sampling  # noqa: E402
from answers.backend import Backend, Evaluation, SyntheticFamily  # noqa: E402
from answers.coverage import coverage  # noqa: E402
from answers.intervals import z_value  # noqa: E402
from answers.ledger import CostLedger  # noqa: E402
from answers.questions import Distribution, JointDistribution, ParamBox, Question  # noqa: E402

BOX = ParamBox(["l_exit", "speed", "other"], [0.28, 4.5, 0.0], [0.36, 5.5, 1.0])


def uniform_question(kind="moments", **kw):
    dist = JointDistribution(BOX, {n: Distribution("uniform", low=BOX.lo[j], high=BOX.hi[j])
                                   for j, n in enumerate(BOX.names)})
    return Question("q", kind, "t90", distribution=dist, **kw)


class FakeProductModel(Backend):
    """Stands for reference.ProductBackend: t90 = 1 + l_exit, per-query CPU 0.5 s, calls counted."""

    name = "fake"

    def __init__(self):
        self.calls = 0

    def evaluate(self, params, seeds=None):
        self.calls += 1
        n = len(params)
        t = np.column_stack([params[:, 0], 1 + params[:, 0], 2 + params[:, 0]])
        self.last = {"t_evac": t, "censored": np.zeros((n, 3), int), "cpu_seconds": np.full(n, 0.5)}
        self.last_cpu = 0.5 * n + 1.0
        return Evaluation(t[:, 1], self.last_cpu)


def test_batch_runs_in_chunks_resumes_and_refuses_other_parameters(tmp_path):
    P = np.column_stack([np.linspace(0.28, 0.36, 7), np.full(7, 5.0), np.zeros(7)])
    m = FakeProductModel()
    b = reference.Batch(m, P, tmp_path, "s", chunk=3, log=open(os.devnull, "w"))
    assert m.calls == 3 and b.calls == 3
    assert np.array_equal(b.values("t90")[0], 1 + P[:, 0])
    assert b.process_cpu == pytest.approx(7 * 0.5 + 3.0) and b.overhead == pytest.approx(1.0)
    again = reference.Batch(m, P, tmp_path, "s", chunk=3, log=open(os.devnull, "w"))
    assert m.calls == 3 and np.array_equal(again.t_evac, b.t_evac)
    with pytest.raises(ValueError, match="not this chunk's"):
        reference.Batch(m, P[::-1], tmp_path, "s", chunk=3, log=open(os.devnull, "w"))


def test_truth_table_from_the_rows_after_the_pool():
    """Truth = the rows after the pool; its standard errors are those of the M0 intervals."""
    rng = np.random.default_rng(3)
    y = rng.normal(1.0, 0.05, 1500)
    y[:500] += 10.0                 # the pool's rows, kept out of the truth

    class B:
        def values(self, qoi):
            return y, np.zeros(len(y), bool)
    q = uniform_question(percentile=95.0)
    q.id = "q"
    qs = type("Qs", (), {"questions": [q], "seed": 0, "box": BOX})()
    t = reference.truth_table(qs, {"q": "s"}, {"s": {"exact": B()}}, "exact", 500)["q"]
    tail = y[500:]
    assert t["mean"]["value"] == pytest.approx(tail.mean())
    assert t["mean"]["se"] == pytest.approx(np.std(tail, ddof=1) / np.sqrt(1000), rel=0.01)
    assert t["std"]["value"] == pytest.approx(np.std(tail, ddof=1))
    assert t["p95"]["n"] == 1000 and t["mean"]["pool_value"] == pytest.approx(y[:500].mean())


def test_plan_shares_a_distribution_and_keeps_rows_when_the_truth_grows():
    q1, q2 = uniform_question(), uniform_question("exceedance", threshold=1.0)
    q1.id, q2.id = "a", "b"
    qs = type("Qs", (), {"questions": [q1, q2], "seed": 4, "box": BOX})()
    s, of = reference.plan(qs, 100, 50)
    assert of == {"a": "dist_a", "b": "dist_a"} and s["dist_a"].shape == (150, 3)
    s2, _ = reference.plan(qs, 300, 50)
    assert np.array_equal(s2["dist_a"][:150], s["dist_a"])


def test_lookup_serves_stored_rows_and_charges_their_cpu():
    P = np.random.default_rng(1).random((20, 3))
    lk = pool.LookupBackend("exact", overhead=2.0).add(P, np.arange(20.0), np.arange(20) % 2 == 0,
                                                        np.full(20, 0.25))
    ev = lk.evaluate(P[[5, 3]])
    assert np.array_equal(ev.values, [5.0, 3.0]) and list(ev.censored) == [False, False]
    assert ev.cpu_seconds == pytest.approx(2 * 0.25 + 2.0)
    bumped = P[:1].copy()
    bumped[0, 0] = np.nextafter(bumped[0, 0], 2.0)
    with pytest.raises(ValueError, match="not run beforehand"):
        lk.evaluate(bumped)


def test_pool_draws_without_replacement_and_nested_in_n():
    P = np.arange(300.0).reshape(100, 3)
    q = pool.pool_question(uniform_question(), P)
    a = sampling.draw(q, sampling.stream(7, 2), 30)[0]
    b = sampling.draw(q, sampling.stream(7, 2), 60)[0]
    assert np.array_equal(a, b[:30]) and len(np.unique(b[:, 0])) == 60
    with pytest.raises(ValueError, match="pool of 100"):
        sampling.draw(q, sampling.stream(7, 2), 101)


def test_coverage_served_from_a_pool_holds_the_closed_forms():
    """M0 (mean, exceedance) and M3 (mean) on 100 repetitions drawn from a pool of 3000 joint runs
    of a Gaussian pair (rho 0.9): coverage >= 0.9 of the closed-form truth, and the pool's own
    value is reported beside."""
    warnings.simplefilter("ignore")
    fam = SyntheticFamily(BOX, [1.0, 0.4], [0.05, 0.02], [[1, 0.9], [0.9, 1]], [0.2, 0.02], "gauss",
                          ["exact", "rom"])
    q = uniform_question("moments")
    P = q.distribution.sample(np.random.default_rng(11), 3000)
    look = [pool.LookupBackend(n).add(P, fam.values(k, P), np.zeros(3000, bool), np.full(3000, fam.costs[k]))
            for k, n in enumerate(fam.names)]
    pq = pool.pool_question(q, P)

    def m0(stat, thr=None):
        qq = pool.pool_question(uniform_question("exceedance", threshold=thr) if thr else q, P)
        return lambda s: methods.m0(qq, stat, look[0], 40, s, 0.95, CostLedger())

    def m3(s):
        led = CostLedger()
        pilot = sampling.Pilot(pq, look, 40, s, led)
        tsd = sampling.target_sd("mean", pilot.Y[:, 0], 0.004, z_value(0.95))
        return methods.m3(pq, "mean", look, pilot, methods.m3_plan(pilot, "mean", tsd, pq), s, 0.95, led)
    pool_mean = float(np.mean(fam.values(0, P)))
    for est, truth in ((m0("mean"), 1.0), (m0("exceedance", 1.03), fam.exceedance(1.03)), (m3, 1.0)):
        c = coverage(est, truth, range(100), pool_truth=pool_mean if truth == 1.0 else None)
        assert c["coverage"] >= 0.9, c
    assert "coverage_pool" in c and c["cost_mean"] > 40 * 0.2


def jittery(x):
    """A smooth trend plus a deterministic jitter at scales far below any design's spacing (the
    way t90 of the congested crowd changes by 3% between l_exit = 0.34 and its neighbouring
    double): a pseudo-random function of the input's bits."""
    u = np.asarray(x, float)[:, 0]
    jitter = np.array([np.random.default_rng(np.frombuffer(v.tobytes(), np.uint32).tolist()).normal()
                       for v in u])
    return 1.3 - 3.0 * (u - 0.28) + 0.03 * jitter


class Jittery(Backend):
    name = "exact"

    def evaluate(self, params, seeds=None):
        return Evaluation(jittery(params), 0.2 * len(params))


def test_gp_map_interval_holds_a_jittery_models_values():
    """M1's map on 8 training runs of a model with a 3% jitter: the pointwise 95% intervals hold
    the model's values at >= 90% of 9 points x 30 designs (the latent posterior alone, without
    the fitted noise, holds far fewer)."""
    warnings.simplefilter("ignore")
    q = Question("map", "map", "t90", grid={"l_exit": list(np.linspace(0.28, 0.36, 9))},
                 nominal={"speed": 5.0, "other": 0.5})
    pts, _ = q.grid_points(BOX)
    truth = jittery(pts)
    hit = []
    for s in range(30):
        tr = sampling.TrainingSet(q, BOX, [Jittery()], s, CostLedger())
        a = methods.m1_map(q, BOX, tr, 8, s, 0.95, CostLedger(), restarts=1)
        hit.append((a.lo <= truth) & (truth <= a.hi))
    assert np.mean(hit) >= 0.9, np.mean(hit)
