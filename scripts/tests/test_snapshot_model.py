"""The snapshot-stage scaling model (scripts/bench/snapshot_model.py) and the timeline figure
(scripts/post/plot_timeline.py): schedule simulation on cases with known answers, validation and
prediction on a real (tiny) run, the figure written, bad input refused."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.environ.get("CROWDROM_ROOT", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BIN = os.environ.get("CROWDROM_BIN", os.path.join(ROOT, "build", "bin"))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import snapshot_model as sm  # noqa: E402

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


def test_schedule_known_cases():
    ones = np.ones(8)
    # equal samples, no overheads: ceil(n / P) rounds
    assert sm.simulate_loop(ones, 2, 0.0, 1e9, 0.0, 0.0) == pytest.approx(4.0)
    assert sm.simulate_loop(ones, 3, 0.0, 1e9, 0.0, 0.0) == pytest.approx(3.0)
    # more ranks than samples: one round
    assert sm.simulate_loop(ones, 16, 0.0, 1e9, 0.0, 0.0) == pytest.approx(1.0)
    # one long sample and many short ones: the long one sets the end
    t = np.array([5.0] + [0.1] * 20)
    assert sm.simulate_loop(t, 2, 0.0, 1e9, 0.0, 0.0) == pytest.approx(5.0)
    # counter latency: one ticket per sample plus the final (empty) ticket, per rank
    assert sm.simulate_loop(ones, 1, 0.01, 1e9, 0.0, 0.0) == pytest.approx(8 + 9 * 0.01)
    # piece writes: every slice (here every sample) plus nothing left at the end
    assert sm.simulate_loop(ones, 1, 0.0, 0.0, 100.0, 0.001) == pytest.approx(8 * 1.1)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("snapmodel")
    text = open(os.path.join(ROOT, "tests", "inputs", "snap_tiny.nml")).read()
    runs = []
    for np_ in (1, 2):
        db = tmp / ("tiny_np%d.h5" % np_)
        nml = tmp / ("tiny_np%d.nml" % np_)
        nml.write_text(text.replace("database = 'snap_tiny.h5'", "database = '%s'" % db))
        js = tmp / ("tiny_np%d.json" % np_)
        p = subprocess.run(["mpiexec", "-n", str(np_), os.path.join(BIN, "crowd_snapshots"), str(nml),
                            "--summary", str(js)], cwd=tmp, capture_output=True, text=True, env=ENV)
        assert p.returncode == 0, p.stdout + p.stderr
        runs.append((str(js), str(db)))
    bench = []
    for np_ in (1, 2):
        out = tmp / ("bench_np%d.json" % np_)
        p = subprocess.run(["mpiexec", "-n", str(np_), os.path.join(BIN, "crowd_snapbench"), str(tmp / "sb.tmp"),
                            "1", "65536"], cwd=tmp, capture_output=True, text=True, env=ENV)
        assert p.returncode == 0, p.stdout + p.stderr
        out.write_text(p.stdout)
        b = json.loads(p.stdout.strip().splitlines()[-1])
        assert b["ranks"] == np_ and b["write_bandwidth_per_rank"] > 0 and b["counter_latency"] > 0
        assert not (tmp / "sb.tmp").exists()
        bench.append(str(out))
    return tmp, runs, bench


def test_validate_and_predict(tiny_run):
    tmp, runs, bench = tiny_run
    rows = sm.validate(runs, bench)
    assert [r["ranks"] for r in rows] == [1, 2]
    for r in rows:
        assert np.isfinite(r["model"]) and r["model"] > 0
        # the model's loop cannot be shorter than the work of the busiest rank allows
        assert r["loop_model"] >= 0
    # the counter latency of each row is the run's own (its summary), crowd_snapbench's is kept
    # beside it, and choosing it gives the other model
    for r, (js, _) in zip(rows, runs):
        assert r["latency_source"] == "run"
        assert r["latency_run"] == json.load(open(js))["counter_latency_mean"]
        assert r["model"] == r["model_run"] and np.isfinite(r["model_bench"])
    rows_b = sm.validate(runs, bench, latency="bench")
    for r, rb in zip(rows, rows_b):
        assert rb["model"] == rb["model_bench"] == r["model_bench"] and rb["model_run"] == r["model_run"]
    with pytest.raises(SystemExit):
        sm.validate(runs, bench, latency="guess")
    pred = sm.predict(runs[0][1], runs[0][0], ranks=(1, 4, 64))
    eff = [r["efficiency"] for r in pred]
    assert all(0 < e <= 1 for e in eff)
    # 9 samples: 64 ranks cannot be more than 9/64 efficient
    assert eff[2] <= 9 / 64 + 1e-12


def test_timeline(tiny_run):
    tmp, runs, _ = tiny_run
    js, db = runs[1]
    out = tmp / "timeline.png"
    p = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "post", "plot_timeline.py"), db, js, "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    assert out.exists() and out.stat().st_size > 1000
    s = json.load(open(js))
    assert 0 < s["busy_time_efficiency"] <= 1
    # a study finished within one time slice writes no piece (its last, unfinished slice goes
    # only into the database) and leaves no pieces directory
    assert s["pieces_written"] == 0 and s["batch_seconds"] > s["wall_time"]
    assert not os.path.exists(db + ".pieces")
    # every rank's phase marks: in time order, the last one its end of the run (rank 0's is the
    # wall time); the figure's script prints each rank's phases
    names = s["phase_names"].split(",")
    marks = np.asarray(s["phase_marks"]).reshape(s["ranks"], len(names))
    assert names[0] == "setup_local" and names[-1] == "end" and "loop_start" in names
    assert np.all(np.diff(marks, axis=1) >= 0) and np.all(marks[:, 0] >= 0)
    assert marks[0, 1] + np.max(marks[:, -1] - marks[:, 1]) == pytest.approx(s["wall_time"], rel=1e-9)
    assert marks[0, names.index("loop_start")] == pytest.approx(s["wall_time_setup"], abs=1e-6)
    assert "| phase (ends at) | rank 0 (ms) | rank 1 (ms) |" in p.stdout
    # the end's multiplier blocks are part of each rank's busy time
    assert len(s["end_block_time_per_rank"]) == s["ranks"]
    assert all(b >= e >= 0 for b, e in zip(s["busy_time_per_rank"], s["end_block_time_per_rank"]))
    bad = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "post", "plot_timeline.py"), str(tmp / "nothing.h5"), js,
                          "--out", str(tmp / "bad.png")], capture_output=True, text=True)
    assert bad.returncode == 2 and "plot_timeline.py: error:" in bad.stderr
    assert not (tmp / "bad.png").exists()
