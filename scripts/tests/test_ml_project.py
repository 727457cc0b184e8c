"""The exact projection of ML-corrected positions on a real tiny study (tests/inputs/rom_tiny.nml
through crowd_snapshots, crowd_offline, crowd_rom): crowd_project leaves no overlap (checked
here with the pair distances and the hall's walls), leaves a configuration without overlap
bit for bit, refuses bad requests with one line; ml_correct.py reports the accuracy before and
after the projection and its cost, and writes its outputs and models all together or not at all."""
import csv
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
import crowdrom_io as cio  # noqa: E402
import ml_correct  # noqa: E402
from test_rom import BIN, offline, rom_input, run, study_file  # noqa: E402

EXE = os.path.join(BIN, "crowd_project")
TOL = 1e-10


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("mlproj")
    db = tmp / "tiny.h5"
    sfile = study_file(tmp, "study.nml", db)
    p = run(0, "crowd_snapshots", sfile, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp, sfile, db, tmp / "rom.h5", extra=", rom_n = 4, rom_r = 3")
    out = tmp / "run.h5"
    p = run(0, "crowd_rom", rom_input(tmp, "rom.nml", rom, out, [dict(n=4, r=3, hyper="'none'")],
                                      sets="'both'"), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(db, "r") as f:
        meta = cio.read_database_meta(f)
        valid = cio.read_database_set(f, "valid", velocities=False)
        scenes = cio.read_sample_scenes(f, "valid")
    return dict(tmp=tmp, db=str(db), rom=str(rom), romrun=str(out), meta=meta, valid=valid, scenes=scenes)


def overlaps(q, radius, scene):
    """Deepest agent-agent overlap and deepest overlap with the hall's box (agents inside it)."""
    x = q.reshape(-1, 2)
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2) + np.eye(len(x)) * 1e9
    o_aa = max(0.0, float(2 * radius - d.min()))
    lo, hi = scene["domain"][:2] + 0, scene["domain"][2:]
    # the hall: x in [0, L], y >= 0 (walls of the reference scene: verts of the first three
    # rectangles are the left, right and bottom walls)
    L = scene["verts"][4, 0]
    inside = x[:, 1] < scene["exit"][0, 1]
    o_aw = 0.0
    if inside.any():
        xi = x[inside]
        o_aw = max(0.0, float(np.max(np.concatenate([radius - xi[:, 0], xi[:, 0] - (L - radius),
                                                         radius - xi[:, 1]]))))
    return o_aa, o_aw


def test_projection_removes_overlaps(study, tmp_path):
    """Random overlapping configurations of every validation sample (jittered full-order
    positions): no overlap left; the full-order configurations themselves come back unchanged."""
    q = study["valid"]["positions"]                                 # [n_S, N_T + 1, n_dof]
    rng = np.random.default_rng(5)
    noisy = q + rng.normal(scale=0.03, size=q.shape)
    noisy[:, 0] = q[:, 0]                                           # step 0: the full model's
    r = cio.run_projection(EXE, study["db"], study["valid"]["params"], noisy, tmp_path)
    radius = study["meta"]["agent_radius"]
    assert r["depth_in"].max() > 0.01, "the test configurations must overlap"
    assert max(r["overlap_agents_after"].max(), r["overlap_walls_after"].max()) <= TOL
    for s, sc in enumerate(study["scenes"]):
        for c in range(q.shape[1]):
            o_aa, o_aw = overlaps(r["positions"][s, c], radius, sc)
            assert o_aa <= TOL and o_aw <= TOL, (s, c, o_aa, o_aw)
    np.testing.assert_array_equal(r["positions"][:, 0], q[:, 0])
    assert np.all(r["solves"][:, 0] == 0) and np.all(r["time"] >= 0)
    # the result's schema: version 2, exactly the datasets the reader documents (version 1's
    # always-zero `grows` is gone)
    with h5py.File(tmp_path / "projection_result.h5", "r") as f:
        assert int(f.attrs["schema_version"]) == 2
        assert set(f.keys()) == {"positions", *cio.PROJ_PER_CONFIG}
    # closer to the input than the input is to the full model (a projection, not a reset)
    assert np.linalg.norm(r["positions"] - noisy) < np.linalg.norm(q - noisy)
    # without refinement: one projection per configuration, still no overlap, not closer
    r0 = cio.run_projection(EXE, study["db"], study["valid"]["params"], noisy, tmp_path, refine_max=0)
    assert np.all(r0["refines"] == 0) and r0["solves"].sum() < r["solves"].sum()
    assert max(r0["overlap_agents_after"].max(), r0["overlap_walls_after"].max()) <= TOL
    assert np.linalg.norm(r["positions"] - noisy) <= np.linalg.norm(r0["positions"] - noisy)


def test_bad_requests(study, tmp_path):
    q = study["valid"]["positions"][:, :2].copy()
    params = study["valid"]["params"]
    q[0, 1, 3] = np.nan
    with pytest.raises(cio.InputError, match=r"crowd_project: .*'positions'.*non-finite|finite"):
        cio.run_projection(EXE, study["db"], params, q, tmp_path)
    with pytest.raises(cio.InputError, match="cannot open the snapshot database"):
        cio.run_projection(EXE, tmp_path / "none.h5", params, study["valid"]["positions"][:, :2], tmp_path)
    with pytest.raises(cio.InputError, match="agents"):
        cio.run_projection(EXE, study["db"], params, study["valid"]["positions"][:, :2, :6], tmp_path)
    with pytest.raises(cio.InputError, match="'refine_max' = -1 must be >= 0"):
        cio.run_projection(EXE, study["db"], params, study["valid"]["positions"][:, :2], tmp_path, refine_max=-1)
    with pytest.raises(cio.InputError, match="not found or not executable"):
        cio.run_projection(tmp_path / "nope", study["db"], params, study["valid"]["positions"], tmp_path)


def test_project_paths(study, tmp_path):
    """The result and the --summary file are checked against the request, the database and
    each other (resolved paths: ./db.h5 is db.h5) before any work: exit 2 with one line naming
    the attribute, every file intact (a result named ./db.h5 must not replace the database)."""
    import hashlib
    import re
    import shutil
    import subprocess

    import h5py

    db = tmp_path / "db.h5"
    shutil.copy(study["db"], db)
    q = study["valid"]["positions"][:, :2]
    params = study["valid"]["params"]
    n_s, n_conf, n_dof = q.shape
    req = tmp_path / "req.h5"

    def request(output):
        with h5py.File(req, "w") as f:
            a = f.attrs
            a["schema"], a["schema_version"] = np.bytes_(cio.PROJREQ_SCHEMA), np.int32(1)
            a["database"] = np.bytes_(str(db))
            a["output"] = np.bytes_(output)
            a["solver"] = np.bytes_("")
            a["tol"] = 0.0
            a["refine_max"] = np.int32(5)
            a["n_agents"], a["configs_per_sample"] = np.int32(n_dof // 2), np.int32(n_conf)
            f["positions"] = q.reshape(n_s * n_conf, n_dof)
            f["params"] = params

    def digest(path):
        return hashlib.sha256(open(path, "rb").read()).hexdigest()

    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    cases = [(str(tmp_path / "." / "db.h5"), [], "attribute 'output'.*is the input attribute 'database'"),
             (str(tmp_path / "sub" / ".." / "req.h5"), [], "attribute 'output'.*is the input request"),
             (str(tmp_path / "out.h5"), ["--summary", str(db)], "--summary.*is the input attribute 'database'"),
             (str(tmp_path / "out.h5"), ["--summary", str(tmp_path / "out.h5.partial")], "clash"),
             (str(tmp_path / "nodir" / "out.h5"), [], "attribute 'output'.*does not exist")]
    os.makedirs(tmp_path / "sub", exist_ok=True)
    for output, extra, pattern in cases:
        request(output)
        before = (digest(db), digest(req))
        p = subprocess.run([EXE, str(req)] + extra, capture_output=True, text=True, env=env, cwd=tmp_path)
        errors = [ln for ln in (p.stdout + p.stderr).splitlines() if "error:" in ln]
        assert p.returncode == 2, (output, extra, p.stdout + p.stderr)
        assert len(errors) == 1 and re.search(pattern, errors[0]), (pattern, errors)
        assert (digest(db), digest(req)) == before, (output, extra)
        assert not os.path.exists(tmp_path / "out.h5")


def test_ml_correct_reports_projection(study, tmp_path, capsys):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"n_values": [2, 4], "regressors": ["random_forest"], "random_forest": {"n_estimators": 10}, '
                   '"timing_repeats": 1}')
    out, table, models = tmp_path / "ml.h5", tmp_path / "ml.csv", tmp_path / "models"
    args = [study["romrun"], "--setting", "1", "--config", str(cfg), "-o", str(out), "--csv", str(table),
            "--models-dir", str(models), "--crowd-project", EXE, "--quiet"]
    # a projection that fails leaves nothing behind: no output, no CSV, no models
    with pytest.raises(SystemExit) as exc:
        ml_correct.main(args[:-3] + ["--crowd-project", str(tmp_path / "nope")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ml_correct: error: crowd_project not found or not executable")
    failing = tmp_path / "fail.sh"
    failing.write_text("#!/bin/sh\necho 'error: boom' >&2\nexit 1\n")
    failing.chmod(0o755)
    with pytest.raises(RuntimeError, match="boom"):
        ml_correct.main(args[:-3] + ["--crowd-project", str(failing)])
    assert not out.exists() and not table.exists() and not models.exists()
    assert not [p for p in os.listdir(tmp_path) if ".partial" in p or p.startswith(".ml_project_")]
    # the real run
    assert ml_correct.main(args) == 0
    text = capsys.readouterr().out
    assert "After the exact projection (crowd_project; only the projected n):" in text
    assert sorted(os.listdir(models)) == ["random_forest_n2.joblib", "random_forest_n4.joblib"]
    rows = list(csv.DictReader(open(table)))
    assert len(rows) == 2

    def projected_ok(r):
        for key in ml_correct.PROJ_KEYS:
            assert key in r
        assert 0 <= float(r["overlap_agents_proj"]) <= TOL and 0 <= float(r["overlap_walls_proj"]) <= TOL
        assert float(r["t_project_query"]) > 0 and float(r["t_query"]) > float(r["t_project_query"])
        assert float(r["E_avg_proj"]) >= 0 and float(r["mobility_proj"]) > 0

    with h5py.File(out, "r") as f:
        best_n = int(f["random_forest"].attrs["best_n"])
    # by default only the best n is projected; the other n carry -1 (not measured)
    for r in rows:
        if int(r["n"]) == best_n:
            projected_ok(r)
        else:
            assert all(float(r[key]) == -1 for key in ml_correct.PROJ_KEYS)
    # --project-all (or the config's "project": "all") projects every n
    out_all, table_all = tmp_path / "ml_all.h5", tmp_path / "ml_all.csv"
    args_all = list(args)
    args_all[args_all.index(str(out))] = str(out_all)
    args_all[args_all.index(str(table))] = str(table_all)
    args_all[args_all.index(str(models))] = str(tmp_path / "models_all")
    cfg_all = tmp_path / "c_all.json"
    cfg_all.write_text(cfg.read_text()[:-1] + ', "project": "all"}')
    args_all[args_all.index(str(cfg))] = str(cfg_all)
    assert ml_correct.main(args_all) == 0
    for r in csv.DictReader(open(table_all)):
        projected_ok(r)
    # the config's "project": "none" skips the projection (as --no-project): -1 everywhere
    out_none, table_none = tmp_path / "ml_none.h5", tmp_path / "ml_none.csv"
    cfg_none = tmp_path / "c_none.json"
    cfg_none.write_text(cfg.read_text()[:-1] + ', "project": "none"}')
    args_none = [study["romrun"], "--setting", "1", "--config", str(cfg_none), "-o", str(out_none), "--csv",
                 str(table_none), "--models-dir", str(tmp_path / "models_none"), "--crowd-project",
                 str(tmp_path / "nope"), "--quiet"]
    assert ml_correct.main(args_none) == 0
    for r in csv.DictReader(open(table_none)):
        assert all(float(r[key]) == -1 for key in ml_correct.PROJ_KEYS)
    with h5py.File(out_none, "r") as f:
        assert f.attrs["projected"] == 0
    with h5py.File(out, "r") as f:
        assert f.attrs["projected"] == 1
        g = f["random_forest"]
        i_best = [int(x) for x in f["n_values"][()]].index(best_n)
        assert g["E_avg_proj"].shape == (2,) and g["overlap_walls_proj"][i_best] <= TOL
        qp = g["best/projected_positions"][...]
        assert qp.shape == g["best/positions"].shape
        m = study["meta"]
        qp = qp.reshape(-1, m["n_steps"] + 1, 2 * m["n_agents"])
        for s, sc in enumerate(study["scenes"]):
            for c in range(qp.shape[1]):
                o_aa, o_aw = overlaps(qp[s, c], m["agent_radius"], sc)
                assert o_aa <= TOL and o_aw <= TOL


def test_ml_output_carries_the_qoi_of_the_corrected_trajectories(study, tmp_path):
    """The training output holds, per regressor, the QoI groups of its corrected validation
    trajectories (best n) and of their exact projection, as crowd_predict computes them; they
    equal an independent numpy recomputation from the stored positions (test_qoi.qoi_numpy: curves,
    times and censoring exactly, displacement to round-off). --no-qoi leaves them out (qoi = 0)."""
    from test_qoi import check_row, qoi_numpy
    cfg = tmp_path / "c.json"
    cfg.write_text('{"n_values": [4], "regressors": ["random_forest"], "random_forest": {"n_estimators": 5}, '
                   '"timing_repeats": 1}')
    out = tmp_path / "ml.h5"
    env = os.environ.get("CROWDROM_BIN")
    os.environ["CROWDROM_BIN"] = BIN
    try:
        assert ml_correct.main([study["romrun"], "--setting", "1", "--config", str(cfg), "-o", str(out),
                                "--models-dir", str(tmp_path / "models"), "--crowd-project", EXE, "--quiet"]) == 0
        assert ml_correct.main([study["romrun"], "--setting", "1", "--config", str(cfg), "-o",
                                str(tmp_path / "ml_noqoi.h5"), "--models-dir", str(tmp_path / "models2"),
                                "--no-project", "--no-qoi", "--quiet"]) == 0
    finally:
        if env is None:
            del os.environ["CROWDROM_BIN"]
        else:
            os.environ["CROWDROM_BIN"] = env
    m = study["meta"]
    nt, na = m["n_steps"], m["n_agents"]
    with h5py.File(study["db"], "r") as f:
        sc = f["scene"].attrs
        y_line = float(sc["hall_width"]) + float(sc["wall_thickness"]) + m["agent_radius"]
        exits = f["valid/scene_exit"][...]
        db_params = f["valid/params"][...]
    with h5py.File(out, "r") as f:
        assert f.attrs["qoi"] == 1
        params = f["valid_params"][...]
        rows = [int(np.flatnonzero(np.all(np.isclose(db_params, p, rtol=0, atol=1e-14), axis=1))[0])
                for p in params]
        for pos_name, qoi_name in (("best/positions", "best/qoi"), ("best/projected_positions", "best/projected_qoi")):
            got = cio.read_qoi_group(f, "random_forest/" + qoi_name)
            assert (got["n_rows"], got["n_agents"], got["n_steps"]) == (len(params), na, nt)
            pos = f["random_forest/" + pos_name][...].reshape(len(params), nt + 1, na, 2)
            for k, row in enumerate(rows):
                width = exits[row, 2] - exits[row, 0]
                check_row(got, k, qoi_numpy(pos[k], m["dt"], y_line, width), f"{qoi_name} {k}")
                np.testing.assert_allclose(got["exit_width"][k, 0], width, rtol=1e-15)
            assert np.all(got["displacement"] > 0)
        # the projected trajectories' QoIs carry the projection: no overlap left
        assert f["random_forest/best/projected_qoi/overlap_agents"][...].max() <= TOL
    with h5py.File(tmp_path / "ml_noqoi.h5", "r") as f:
        assert f.attrs["qoi"] == 0 and "qoi" not in f["random_forest/best"]
    # evac_figures draws and tabulates them; an output without them is refused by name
    script = os.path.join(os.path.dirname(HERE), "post", "evac_figures.py")
    base = [sys.executable, script, "--database", study["db"], "--romrun", study["romrun"]]
    p = subprocess.run(base + ["--ml", str(out), "-o", str(tmp_path / "evac"), "--dpi", "40"],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "| ML random_forest (n = 4) + exact projection |" in (tmp_path / "evac" / "evac_table.md").read_text()
    p = subprocess.run(base + ["--ml", str(tmp_path / "ml_noqoi.h5"), "-o", str(tmp_path / "evac2")],
                       capture_output=True, text=True)
    assert p.returncode == 2 and "missing group 'random_forest/best/qoi'" in p.stderr, p.stderr
