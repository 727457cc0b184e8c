"""The answers engine on the real models: answers.backend.PredictBackend runs crowd_predict (the
exact model and a reduced setting of the tiny study's ROM file, test_predict's fixture) and
crowd_answers.py answers a moments question with M0 and M3 end to end; a QoI the product lacks
gets one line, exit 2, and nothing written."""
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, SCRIPTS)
sys.path.insert(0, HERE)
from answers.backend import PredictBackend, PredictModel  # noqa: E402
from answers.questions import rom_box  # noqa: E402
from crowdrom_io import InputError  # noqa: E402
from test_predict import BIN, ENV, ROOT, nml_groups, predict_input, run, study, write_text_list  # noqa: E402,F401

PREDICT = os.path.join(BIN, "crowd_predict")
SETTING = {"n": 4, "r": 3, "hyper": "eq"}


def box_of(names):
    """The tiny study's training box (&study of tests/inputs/rom_tiny.nml) by component name."""
    return {n: [0.18, 0.22] if n == "l_exit" else [0.9, 1.1] for n in names}


def test_backend_exact_equals_snapshots(study):
    """The exact model through the backend gives the database's stored QoIs of the training
    parameters (crowd_snapshots), whatever the order of the box's names; t50 is censored at the
    horizon and flagged; CPU seconds are charged; a reduced setting gives finite values."""
    tmp, db, rom, names, params = study
    order = names[::-1]                         # the box need not follow the study's order
    cols = [names.index(n) for n in order]
    with h5py.File(db, "r") as f:
        t_evac, cens = f["train/qoi/t_evac"][...], f["train/qoi/censored"][...]
        disp = f["train/qoi/displacement"][...]
    ex = PredictBackend("exact", "displacement", str(rom), order, model="exact", program=PREDICT,
                        workdir=str(tmp))
    ev = ex.evaluate(params[:, cols])
    assert np.allclose(ev.values, disp, rtol=1e-12, atol=0) and not ev.censored.any()
    assert ev.cpu_seconds > 0
    t50 = PredictBackend("exact", "t50", str(rom), order, model="exact", program=PREDICT,
                         cpu="queries").evaluate(params[:, cols])
    assert np.array_equal(t50.values, t_evac[:, 0]) and np.array_equal(t50.censored, cens[:, 0] != 0)
    assert t50.censored.all() and np.all(t50.values == 12 * 0.02)    # 12 steps of 0.02 s
    low = PredictBackend("rom", "displacement", str(rom), names, setting=SETTING, program=PREDICT,
                         ranks=2, launcher="mpiexec").evaluate(params)
    assert np.all(np.isfinite(low.values)) and low.values.shape == (len(params),)
    assert not np.array_equal(low.values, disp)       # the reduced model is not the exact one
    with pytest.raises(InputError, match=r"QoI 'flow_2': the product's scene has 1 exit"):
        PredictBackend("exact", "flow_2", str(rom), names, model="exact", program=PREDICT).evaluate(params[:2])
    with pytest.raises(InputError, match=r"model 'rom': crowd_predict exited with 2: .*pair"):
        PredictBackend("rom", "t50", str(rom), names, setting={"n": 5, "r": 3},
                       program=PREDICT).evaluate(params[:2])


def _files(tmp, qoi, **models):
    tmp.mkdir(exist_ok=True)
    names = models.pop("names")
    q = {"case": "rom_tiny", "box": box_of(names), "accuracy": {"relative": [0.05], "confidence": 0.95},
         "seed": 5, "questions": [{"id": "disp", "kind": "moments", "qoi": qoi, "percentile": 95,
                                   "distributions": {n: {"kind": "uniform", "low": lo, "high": hi}
                                                     for n, (lo, hi) in box_of(names).items()}}]}
    (tmp / "q.json").write_text(json.dumps(q))
    (tmp / "models.json").write_text(json.dumps(models))
    return tmp / "q.json", tmp / "models.json"


def _answers(cwd, qfile, mfile, *extra):
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, "pipeline", "crowd_answers.py"), str(qfile),
                           "--models", str(mfile), "--out-prefix", "out", "--pilot", "12", "--quiet",
                           *extra], cwd=cwd, capture_output=True, text=True, env=ENV)


def test_answers_m0_m3_on_tiny_study(study):
    """Mean and p95 of the displacement answered by M0 (exact runs) and M3 (MFMC with the
    reduced setting): finite answers, M3's intervals hold M0's point estimates or overlap M0's,
    and the ledgers count the runs (pilot, estimation, the declared build)."""
    tmp, db, rom, names, params = study
    work = tmp / "answers"
    qf, mf = _files(work, "displacement", names=names, rom_file=str(rom), program=PREDICT,
                    exact={"name": "exact"}, lows=[{"name": "rom43", "setting": SETTING}],
                    builds=[{"model": "rom43", "cpu_seconds": 2.5, "runs": 6}])
    rep = {}
    for method in ("M0", "M3"):
        sub = work / method
        sub.mkdir()
        r = _answers(sub, qf, mf, "--methods", method)
        assert r.returncode == 0, r.stdout + r.stderr
        rep[method] = json.loads((sub / "out.json").read_text())
        assert {p.name for p in sub.iterdir()} == {"out.md", "out.json", "out.png"}
    for method, doc in rep.items():
        assert [a["statistic"] for a in doc["answers"]] == ["mean", "std", "p95"], method
        for a in doc["answers"]:
            lo, hi = a["lo"], np.inf if a["hi"] is None else a["hi"]   # p95: may be unbounded above
            assert np.isfinite([a["value"], lo]).all() and lo <= a["value"] <= hi, (method, a)
            runs = {}
            for e in a["ledger"]:
                runs[(e["stage"], e["model"])] = runs.get((e["stage"], e["model"]), 0) + e["runs"]
                assert e["cpu_seconds"] >= 0
            assert runs[("pilot", "exact")] == 12 and runs[("estimation", "exact")] >= 10, runs
            assert a["cost_cpu_seconds"] == pytest.approx(sum(e["cpu_seconds"] for e in a["ledger"]))
            if method == "M3":
                assert runs[("pilot", "rom43")] == 12, runs          # the joint pilot ran the ROM
                assert runs[("build", "rom43")] == 6, runs           # so its build is charged
            else:
                assert {m for s_, m in runs} == {"exact"}, runs
    m0 = {a["statistic"]: a for a in rep["M0"]["answers"]}
    for a in rep["M3"]["answers"]:
        b = m0[a["statistic"]]
        ahi, bhi = (np.inf if x["hi"] is None else x["hi"] for x in (a, b))
        assert a["lo"] <= b["value"] <= ahi or (a["lo"] <= bhi and b["lo"] <= ahi), (a, b)


def test_answers_qoi_the_product_lacks(study):
    """flow_2 on a scene with one exit: one line naming the models file's model and the QoI,
    exit 2, nothing written."""
    tmp, db, rom, names, params = study
    work = tmp / "bad"
    qf, mf = _files(work, "flow_2", names=names, rom_file=str(rom), program=PREDICT,
                    exact={"name": "exact"}, lows=[{"name": "rom43", "setting": SETTING}])
    r = _answers(work, qf, mf)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and "QoI 'flow_2': the product's scene has 1 exit" in r.stderr
    assert "model 'exact'" in r.stderr
    assert sorted(p.name for p in work.iterdir()) == ["models.json", "q.json"]


def test_build_cost_from_stage_summaries(tmp_path):
    """builds entries read from the stages' --summary JSON: crowd_snapshots' busy seconds summed
    over the ranks, crowd_offline's stage times times its ranks; anything else refused."""
    import crowd_answers
    snap = tmp_path / "snap.json"
    snap.write_text(json.dumps({"program": "crowd_snapshots", "samples_total": 9,
                                "busy_time_per_rank": [1.5, 2.5], "wall_time": 3.0}))
    off = tmp_path / "off.json"
    off.write_text(json.dumps({"rom_file": "r.h5", "ranks": 2, "time_read": 0.5, "time_pod": 1.0,
                               "pod_energy_retained": 0.99}))
    assert crowd_answers.build_cost("m.json", "builds[0]", {"summary": str(snap)}) == (9, 4.0)
    assert crowd_answers.build_cost("m.json", "builds[1]", {"summary": str(off)}) == (0, 3.0)
    with pytest.raises(InputError, match=r"m.json: builds\[2\].summary: .* is neither"):
        crowd_answers.build_cost("m.json", "builds[2]", {"summary": str(_write(tmp_path / "o.json", {"ranks": 2}))})


def _write(path, doc):
    path.write_text(json.dumps(doc))
    return path


def test_rom_box_and_runs_shared_between_qois(study):
    """The box comes from the ROM file (component names, &study bounds; speeds per agent); one
    model serves two QoIs: every row runs once, each QoI's backend charges the rows' CPU."""
    tmp, db, rom, names, params = study
    box, seeds = rom_box(str(rom))
    assert box.names == names and seeds == []
    assert np.allclose(box.lo, [0.18] + [0.9] * 8) and np.allclose(box.hi, [0.22] + [1.1] * 8)
    model = PredictModel("exact", str(rom), names, kind="exact", program=PREDICT, workdir=str(tmp))
    disp, t50 = model.for_qoi("displacement"), model.for_qoi("t50")
    a = disp.evaluate(params[:4])
    assert model.n_runs == 4
    b = t50.evaluate(params[:3])
    c = disp.evaluate(params)
    assert model.n_runs == len(params)                  # t50 and the first 4 rows: no new run
    assert np.array_equal(c.values[:4], a.values) and b.censored.all()
    assert b.cpu_seconds == pytest.approx(a.cpu_seconds * 3 / 4)     # charged as when run
    # --cache: a later run reads the rows (values and CPU seconds) instead of running them
    kw = dict(kind="exact", program=PREDICT, workdir=str(tmp), cache_dir=str(tmp / "cache"))
    PredictModel("exact", str(rom), names, **kw).for_qoi("displacement").evaluate(params[:4])
    again = PredictModel("exact", str(rom), names, **kw)
    d = again.for_qoi("displacement").evaluate(params[:4])
    assert again.n_runs == 0 and np.array_equal(d.values, a.values) and d.cpu_seconds > 0
    other = PredictModel("rom", str(rom), names, setting=SETTING, program=PREDICT, cache_dir=str(tmp / "cache"))
    assert other.cache_file != again.cache_file and not other.rows     # another model: its own file


def _trained_ml(tmp, rom):
    """The ML correction of the reduced setting N = 4, R = 3 trained on the tiny study (as
    test_predict.py's)."""
    romrun = tmp / "ans_romrun.h5"
    flat = ("rom_file = '%s', output = '%s', sets = 'both', fom_timing_samples = 0, timing_repeats = 1, "
            "n(1) = 4, r(1) = 3, hyper(1) = 'eq'" % (rom, romrun))
    (tmp / "ans_rom.nml").write_text(nml_groups.as_text(nml_groups.rom_groups(flat)))
    p = run(0, "crowd_rom", tmp / "ans_rom.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    cfg = tmp / "ans_ml.json"
    cfg.write_text('{"n_values": [3], "regressors": ["random_forest"], "random_forest": {"n_estimators": 10}}')
    p = subprocess.run([sys.executable, os.path.join(SCRIPTS, "pipeline", "ml_correct.py"), str(romrun), "--config", str(cfg),
                        "--no-project", "--quiet", "-o", str(tmp / "ans_ml.h5"), "--models-dir",
                        str(tmp / "ans_ml_models")], capture_output=True, text=True, env=dict(ENV, CROWDROM_BIN=BIN),
                       cwd=tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    return cfg, tmp / "ans_ml.h5", tmp / "ans_ml_models"


def test_ml_corrected_backend(study):
    """The ML-corrected model: crowd_predict (reduced, trajectories) then ml_correct.py --predict
    with the saved models; on the validation parameters its displacements are those of the
    training run's corrected positions, its CPU seconds include the reduced queries and the
    correction; the ML build cost is read from the training output."""
    import crowd_answers
    tmp, db, rom, names, params = study
    cfg, ml_out, models = _trained_ml(tmp, rom)
    with h5py.File(db, "r") as f:
        valid = f["valid/params"][...]
    with h5py.File(ml_out, "r") as f:
        q_ml = f["random_forest/best/positions"][...].reshape(len(valid), 13, 16)
    ml = PredictModel("ml", str(rom), names, kind="ml", setting=SETTING, program=PREDICT, workdir=str(tmp),
                      ml={"models_dir": str(models), "config": str(cfg), "ml_output": str(ml_out), "batch": 2})
    ev = ml.for_qoi("displacement").evaluate(valid)
    assert ml.n_runs == len(valid)
    assert np.allclose(ev.values, np.linalg.norm(q_ml[:, -1] - q_ml[:, 0], axis=1), rtol=1e-12, atol=1e-14)
    rom_only = PredictBackend("rom", "displacement", str(rom), names, setting=SETTING, program=PREDICT).evaluate(valid)
    assert not np.allclose(ev.values, rom_only.values)          # the correction changed them
    assert ev.cpu_seconds > rom_only.cpu_seconds
    runs, cpu = crowd_answers.build_cost("m.json", "builds[0]", {"ml_output": str(ml_out), "fit_threads": 2})
    with h5py.File(ml_out, "r") as f:
        want = 9 * max(f.attrs["t_query_rom"], 0.0) + 2 * np.sum(f["random_forest/t_fit"][()])
    assert runs == 9 and cpu == pytest.approx(want)
    with pytest.raises(InputError, match=r"model 'bad': ml: needs models_dir"):
        PredictModel("bad", str(rom), names, kind="ml", setting=SETTING, ml={"config": str(cfg)})
