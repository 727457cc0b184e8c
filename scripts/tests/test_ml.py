"""scripts/pipeline/ml_correct.py on small synthetic files (tests/synth.py): the file layouts, a learnable
drift that both regressors learn, saved models reused by --predict-only, mismatched ROMs and bad
inputs refused with one clear line and nothing written."""
import json
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, SCRIPTS)
import crowdrom_io as cio  # noqa: E402
import ml_correct  # noqa: E402
import synth  # noqa: E402

SCRIPT = os.path.join(SCRIPTS, "pipeline", "ml_correct.py")
SMALL = {"n_values": [3, 6], "random_forest": {"n_estimators": 20}, "mlp": {"max_iter": 300},
         "timing_repeats": 1}


def run(*args):
    """The script as a separate process (the real command line). The synthetic database is not
    a Fortran-readable study, so the exact projection (crowd_project) and the QoIs of the corrected
    trajectories (crowd_predict), both tested on a real tiny study in test_ml_project.py, are skipped."""
    return subprocess.run([sys.executable, SCRIPT, *map(str, args), "--no-project", "--no-qoi"], capture_output=True,
                          text=True, timeout=300)


class Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def call(capsys, *args):
    """ml_correct.main in this process (fast: sklearn is imported once); same exit codes."""
    capsys.readouterr()
    try:
        code = ml_correct.main([str(a) for a in args] + ["--no-project", "--no-qoi"])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return Result(code, out, err)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ml")
    st = synth.make_study(tmp)
    cfg = tmp / "small.json"
    cfg.write_text(json.dumps(SMALL))
    out = tmp / "ml.h5"
    res = run(st["romrun"], "--setting", 1, "--config", cfg, "-o", out, "--csv", tmp / "ml.csv")
    st.update(tmp=tmp, cfg=cfg, out=out, res=res, models=str(tmp / "ml_models"))
    return st


def test_layout_of_synthetic_files(study):
    """The readers honour the Fortran-order convention: column (k-1)(N_T+1)+nu+1 = q^nu."""
    d = study["data"]["sets"]["valid"]
    with h5py.File(study["db"], "r") as f:
        raw = f["valid/positions"][...]                       # h5py ((N_T+1) n_S, n_dof)
        s = cio.read_database_set(f, "valid")
    nt = synth.N_STEPS
    k, nu = 3, 7                                              # sample 4 (1-based), step 7
    np.testing.assert_array_equal(raw[k * (nt + 1) + nu], d["q"][k, nu])
    np.testing.assert_array_equal(s["positions"][k, nu], d["q"][k, nu])
    np.testing.assert_array_equal(s["velocities"][k, nu - 1], d["u"][k, nu - 1])
    q = cio.integrate_positions(study["data"]["q0"], s["velocities"], synth.DT)
    np.testing.assert_allclose(q, s["positions"], atol=1e-13)
    with h5py.File(study["romrun"], "r") as f:
        m = cio.romrun_meta(f)
        r = cio.romrun_set(f, 1, "valid", m["n_steps"], 2 * m["n_agents"])
    assert r["alpha"].shape == (synth.N_VALID, nt, 8)
    assert r["positions"].shape == (synth.N_VALID, nt + 1, 12) and r["err_time"].shape == (synth.N_VALID, nt + 1)


def test_error_helpers_against_loops():
    rng = np.random.default_rng(1)
    q_ref, q = rng.random((3, 5, 4)), rng.random((3, 5, 4))
    h = 0.1
    e = cio.time_integrated_error(q_ref, q, h)
    for s in range(3):
        num = sum(h * np.sum((q_ref[s, nu] - q[s, nu]) ** 2) for nu in range(1, 5))
        den = sum(h * np.sum(q_ref[s, nu] ** 2) for nu in range(1, 5))
        assert e[s] == pytest.approx(np.sqrt(num / den), rel=1e-13)
    u = rng.random((2, 4, 3))
    q0 = rng.random(3)
    p = cio.integrate_positions(q0, u, h)
    for nu in range(1, 5):
        np.testing.assert_allclose(p[:, nu], p[:, nu - 1] + h * u[:, nu - 1], atol=1e-15)


def test_features_layout():
    cfg = ml_correct.load_config(overrides={"features": {"append_mu": True, "append_nu": True}})
    alpha = np.arange(2 * 3 * 4, dtype=float).reshape(2, 3, 4)   # [n_S, N_T, n_basis]
    params = np.array([[1.0, 2.0], [3.0, 4.0]])
    x = ml_correct.make_features(alpha, params, 2, cfg)
    assert x.shape == (6, 5)
    np.testing.assert_array_equal(x[4], [alpha[1, 1, 0], alpha[1, 1, 1], 3.0, 4.0, 2.0])
    assert ml_correct.feature_names(2, ["l_exit", "speed"], 2, cfg) == \
        ["alpha_1", "alpha_2", "mu:l_exit", "mu:speed", "nu"]


def test_config_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"random_forest": {"n_trees": 3}}))
    with pytest.raises(cio.InputError, match="n_trees"):
        ml_correct.load_config(bad)
    bad.write_text(json.dumps({"regresors": ["mlp"]}))
    with pytest.raises(cio.InputError, match="unknown key 'regresors'"):
        ml_correct.load_config(bad)
    bad.write_text("{not json")
    with pytest.raises(cio.InputError, match="invalid JSON"):
        ml_correct.load_config(bad)
    with pytest.raises(cio.InputError, match="n_step"):
        ml_correct.load_config(overrides={"n_step": 0})
    with pytest.raises(cio.InputError, match="project must be 'best', 'all' or 'none'"):
        ml_correct.load_config(overrides={"project": "some"})
    cfg = ml_correct.load_config()
    assert cfg["mlp"]["hidden_layer_sizes"] == [100, 50] and cfg["mlp"]["learning_rate_init"] == 0.01
    assert cfg["mlp"]["max_iter"] == 2000 and cfg["mlp"]["activation"] == "relu"
    assert cfg["mlp"]["solver"] == "adam" and cfg["regressors"] == ["random_forest", "mlp"]


def test_correction_learns_the_drift(study):
    res = study["res"]
    assert res.returncode == 0, res.stdout + res.stderr
    assert "warning" not in res.stderr
    assert "[4/4]" in res.stdout and "| random_forest | 6 |" in res.stdout
    with h5py.File(study["out"], "r") as f:
        assert f.attrs["schema"] == "crowdrom-ml" and f.attrs["mode"] == "train"
        assert list(f["n_values"][...]) == [3, 6]
        base = float(f["E_avg_baseline"][()])
        with h5py.File(study["romrun"], "r") as r:
            stored = float(r["setting_1"].attrs["E_avg"])
            np.testing.assert_allclose(f["E_mu_baseline"][...], r["setting_1/valid/E_mu"][...], rtol=1e-12)
        assert base == pytest.approx(stored, rel=1e-12)
        proj = f["E_avg_projection"][...]
        assert proj[1] < proj[0] < base
        for reg in ("random_forest", "mlp"):
            g = f[reg]
            e = g["E_avg"][...]
            assert g["E_mu"].shape == (2, synth.N_VALID)
            np.testing.assert_allclose(g["factor"][...], base / e)
            assert e[1] < base / 3, f"{reg}: corrected error {e[1]} not clearly below baseline {base}"
            assert e[0] < base
            t = g["t_predict_step"][...]
            assert np.all(t > 0)
            np.testing.assert_allclose(g["speedup"][...], synth.T_UZAWA / (2.0e-4 + t))
            np.testing.assert_allclose(g["speedup_exact"][...], synth.T_EXACT / (2.0e-4 + t))
            assert g.attrs["best_n"] == 6
            q = g["best/positions"][...]
            assert q.shape == ((synth.N_STEPS + 1) * synth.N_VALID, 12)
            q = q.reshape(synth.N_VALID, synth.N_STEPS + 1, 12)
            np.testing.assert_allclose(q[:, 0], np.tile(study["data"]["q0"], (synth.N_VALID, 1)))
            # increments lie in span(phi_1..phi_6)
            v6 = study["bases"][1][0][:, :6]
            dq = np.diff(q, axis=1).reshape(-1, 12)
            np.testing.assert_allclose(dq - (dq @ v6) @ v6.T, 0, atol=1e-12)
            et = g["best/err_time"][...]
            assert et.shape == (synth.N_VALID, synth.N_STEPS + 1) and np.all(et[:, 0] == 0)
    rows = (study["tmp"] / "ml.csv").read_text().splitlines()
    assert rows[0].startswith("regressor,n,E_avg_baseline,E_avg") and len(rows) == 5
    for reg in ("random_forest", "mlp"):
        for n in (3, 6):
            assert os.path.getsize(os.path.join(study["models"], f"{reg}_n{n}.joblib")) > 0
    assert not [p for p in os.listdir(study["tmp"]) if p.endswith(".partial")]


def test_predict_only_reuses_models(study, tmp_path, capsys):
    out = tmp_path / "po.h5"
    res = call(capsys, study["romrun"], "--setting", 1, "--config", study["cfg"], "--predict-only",
              "--models-dir", study["models"], "-o", out, "--quiet")
    assert res.returncode == 0, res.stderr
    with h5py.File(out, "r") as a, h5py.File(study["out"], "r") as b:
        assert a.attrs["mode"] == "predict-only" and a.attrs["n_train"] == 0
        for reg in ("random_forest", "mlp"):
            np.testing.assert_array_equal(a[f"{reg}/E_avg"][...], b[f"{reg}/E_avg"][...])
            np.testing.assert_array_equal(a[f"{reg}/best/positions"][...], b[f"{reg}/best/positions"][...])
            assert np.all(a[f"{reg}/t_fit"][...] == 0)


def test_predict_only_on_a_run_without_train_set(study, tmp_path, capsys):
    """Setting 3 has only a validation set (pair 2): training refuses, predict-only needs models
    of pair 2 and refuses those of pair 1."""
    res = call(capsys, study["romrun"], "--setting", 3, "--config", study["cfg"], "-o", tmp_path / "x.h5")
    assert res.returncode == 2 and "no 'train' set" in res.stderr
    res = call(capsys, study["romrun"], "--setting", 3, "--n", 3, "--config", study["cfg"], "--predict-only",
              "--models-dir", study["models"], "-o", tmp_path / "x.h5")
    assert res.returncode == 2 and "does not match this ROM" in res.stderr
    assert "ROM pair index" in res.stderr
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("variant,expect", [
    (dict(rom_variant=1), "pair POD modes n is 6 in the model, 5 here"),
    (dict(rom_variant=2), "basis fingerprint"),
    (dict(config_hash="fedcba9876543210"), "database config_hash"),
])
def test_mismatched_rom_refused(study, tmp_path, variant, expect, capsys):
    other = synth.make_study(tmp_path, name="other", **variant)
    out = tmp_path / "mm.h5"
    res = call(capsys, other["romrun"], "--setting", 1, "--n", 3, "--config", study["cfg"], "--predict-only",
              "--models-dir", study["models"], "-o", out)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ml_correct: error: model ")
    assert expect in lines[0] and "does not match this ROM" in lines[0]
    assert not out.exists()


def test_load_model_checks_n(study):
    st = ml_correct.Study(study["romrun"], 1, need_train=False)
    cfg = ml_correct.load_config(study["cfg"])
    meta = st.metadata(6, ml_correct.feature_names(6, st.param_names, 2, cfg), "mlp", cfg)
    path = ml_correct.model_path(study["models"], "mlp", 3)
    with pytest.raises(cio.InputError, match="truncation n is 3 in the model, 6 here"):
        ml_correct.load_model(path, meta)
    cfg2 = ml_correct.load_config(study["cfg"], {"features": {"append_nu": True}})
    meta = st.metadata(3, ml_correct.feature_names(3, st.param_names, 2, cfg2), "mlp", cfg2)
    with pytest.raises(cio.InputError, match="features"):
        ml_correct.load_model(path, meta)


def test_rom_database_mismatch(study, tmp_path, capsys):
    other = synth.make_study(tmp_path, name="h", config_hash="fedcba9876543210")
    res = call(capsys, study["romrun"], "--config", study["cfg"], "--database", other["db"], "-o", tmp_path / "x.h5")
    assert res.returncode == 2 and "config_hash" in res.stderr


@pytest.mark.parametrize("args,expect", [
    (["{tmp}/missing.h5"], "ROM run file not found"),
    (["{db}"], "is not a crowdrom-romrun file"),
    (["{romrun}", "--setting", "9"], "no setting 9"),
    (["{romrun}", "--n", "7"], "outside 1..6"),
    (["{romrun}", "--rom", "{tmp}/nope.h5"], "ROM file not found"),
    (["{romrun}", "--config", "{tmp}/nope.json"], "config file not found"),
])
def test_bad_inputs(study, tmp_path, args, expect, capsys):
    fill = {"tmp": tmp_path, "db": study["db"], "romrun": study["romrun"]}
    out = tmp_path / "never.h5"
    res = call(capsys, *[a.format(**fill) for a in args], "-o", out, "--config", study["cfg"]) \
        if "--config" not in args else call(capsys, *[a.format(**fill) for a in args], "-o", out)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ml_correct: error:") and expect in lines[0]
    assert not out.exists() and not os.path.exists(str(out) + ".partial")


def test_output_directory_missing(study, tmp_path, capsys):
    res = call(capsys, study["romrun"], "--config", study["cfg"], "-o", tmp_path / "no" / "x.h5")
    assert res.returncode == 2 and "output directory does not exist" in res.stderr


def test_missing_group_in_romrun(study, tmp_path, capsys):
    bad = tmp_path / "broken.h5"
    with h5py.File(study["romrun"], "r") as src, h5py.File(bad, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        for name in src:
            if name != "fom_timing":
                src.copy(name, dst)
    res = call(capsys, bad, "--config", study["cfg"], "-o", tmp_path / "x.h5")
    assert res.returncode == 2 and "missing group 'fom_timing'" in res.stderr


def test_in_process_with_mu_nu_features(study, tmp_path, capsys):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps(dict(SMALL, n_values=[4], regressors=["random_forest"],
                                   features={"append_mu": True})))
    out = tmp_path / "f.h5"
    assert ml_correct.main([study["romrun"], "--setting", "2", "--config", str(cfg), "-o", str(out),
                            "--append-nu", "--quiet", "--no-project", "--no-qoi"]) == 0
    text = capsys.readouterr().out
    assert "| random_forest | 4 |" in text
    with h5py.File(out, "r") as f:
        assert f.attrs["features"] == "alpha_1..alpha_n,mu:l_exit,mu:speed,nu"
        assert "mlp" not in f and f["random_forest/E_avg"][0] < f["E_avg_baseline"][()]


def test_cli_exit_status(tmp_path):
    """The command line itself: exit status 2 and one error line for a missing file."""
    res = run(tmp_path / "missing.h5")
    assert res.returncode == 2
    assert res.stderr.strip() == f"ml_correct: error: ROM run file not found: '{tmp_path / 'missing.h5'}'"
    res = run("--help-output")
    assert res.returncode == 0 and "crowdrom-ml" in res.stdout


def test_setting_with_diverged_samples_refused(study, tmp_path, capsys):
    """A setting whose reduced trajectories crowd_rom stopped (diverged_step > 0) is refused with
    one line: its frozen positions are not a reduced model to correct."""
    bad = tmp_path / "diverged.h5"
    shutil.copy(study["romrun"], bad)
    with h5py.File(bad, "r+") as f:
        n_s = f["setting_1/valid/params"].shape[0]
        f["setting_1/valid/diverged_step"] = np.array([0] * (n_s - 1) + [7], dtype=np.int32)
    res = call(capsys, bad, "--config", study["cfg"], "-o", tmp_path / "x.h5")
    assert res.returncode == 2 and "1 diverged reduced trajectories in its 'valid' set" in res.stderr, res.stderr
    assert not (tmp_path / "x.h5").exists()
