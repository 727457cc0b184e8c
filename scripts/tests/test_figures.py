"""scripts/post/make_figures.py and scripts/post/plot_tradeoff.py on small synthetic files (tests/synth.py):
every figure is produced and is a real picture, missing optional inputs skip only their figures,
bad inputs fail with exit status 2; the Pareto front and the multiplier POD against direct
computations."""
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
import make_figures  # noqa: E402
import ml_correct  # noqa: E402
import plot_tradeoff  # noqa: E402
import synth  # noqa: E402

ALL = [name for name, _ in make_figures.FIGURES]


def run(script, *args):
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, script), *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def assert_picture(path, min_bytes=5000):
    assert os.path.exists(path), path
    assert os.path.getsize(path) > min_bytes, path
    import matplotlib.image as mpimg
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert np.ptp(img[..., :3]) > 0.5, f"{path} looks blank"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("figs")
    st = synth.make_study(tmp)
    cfg = tmp / "small.json"
    cfg.write_text(json.dumps({"n_values": [3, 6], "random_forest": {"n_estimators": 10},
                               "mlp": {"max_iter": 200}, "timing_repeats": 1}))
    st["ml"] = str(tmp / "ml.h5")
    assert ml_correct.main([st["romrun"], "--setting", "1", "--config", str(cfg), "-o", st["ml"],
                            "--quiet", "--no-project", "--no-qoi"]) == 0
    st["tmp"] = tmp
    return st


def test_all_figures(study, tmp_path):
    out = tmp_path / "figs"
    res = run("post/make_figures.py", "--database", study["db"], "--rom", study["rom"], "--romrun",
              study["romrun"], "--csv", study["csv"], "--ml", study["ml"], "-o", out, "--dpi", 70)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "make_figures: skip" not in res.stdout
    assert f"{len(ALL)} figures written" in res.stdout
    for name in ALL:
        assert_picture(out / f"{name}.png")
    img = pytest.importorskip("matplotlib.image").imread(out / "positions.png")
    assert img.shape[0] > 2 * img.shape[1] / 3 * 0.9     # three rows: FOM, ROM, ML-corrected


def test_only_rom_skips_the_rest(study, tmp_path):
    out = tmp_path / "rom_only"
    written, skipped = make_figures.make_all({"rom": study["rom"]}, str(out), log=lambda m: None, dpi=70)
    offline = {"pod_decay", "cone_max_error", "infsup_heatmap", "pga_convergence", "eim_sigma",
               "eq_error", "pod_rpod"}
    assert {os.path.basename(p)[:-4] for p in written} == offline
    assert set(skipped) == set(ALL) - offline
    assert "--database" in skipped["cone_vs_pod_mean"] and "--romrun" in skipped["error_in_time"]
    assert "--ml" in skipped["ml_correction"]
    for p in written:
        assert_picture(p)


def test_romrun_without_ml_and_csv(study, tmp_path):
    out = tmp_path / "noml"
    ctx = {"romrun": study["romrun"], "database": study["db"], "settings": [2, 3], "sample": 2,
           "agents": [1, 6], "steps": [0, 5, 10]}
    written, skipped = make_figures.make_all(ctx, str(out), log=lambda m: None, dpi=70)
    names = {os.path.basename(p)[:-4] for p in written}
    assert {"error_in_time", "tradeoff", "trajectories", "positions"} <= names
    assert "ml_correction" in skipped
    for p in written:
        assert_picture(p)


def test_rom_version1_skips_pair_figures(study, tmp_path):
    old = tmp_path / "rom_v1.h5"
    shutil.copy(study["rom"], old)
    with h5py.File(old, "a") as f:
        del f["pairs"], f["pod_compare"]
        f.attrs["schema_version"] = np.int32(1)
    written, skipped = make_figures.make_all({"rom": str(old)}, str(tmp_path / "v1"),
                                             log=lambda m: None, dpi=70)
    assert {"eim_sigma", "eq_error", "pod_rpod"} <= set(skipped)
    assert "pairs" in skipped["eim_sigma"] or "schema_version 2" in skipped["eim_sigma"]
    assert "pga_convergence" in {os.path.basename(p)[:-4] for p in written}


@pytest.mark.parametrize("args,expect", [
    (["--rom", "{db}"], "is not a crowdrom-rom file"),
    (["--romrun", "{tmp}/none.h5"], "romrun not found"),
    (["--csv", "{tmp}/none.csv"], "sweep table not found"),
    (["--rom", "{rom}", "--pair", "9", "--only", "eim_sigma"], "no pair 9"),
    (["--romrun", "{romrun}", "--database", "{db}", "--sample", "99", "--only", "positions"], "--sample 99"),
])
def test_bad_inputs(study, tmp_path, args, expect, capsys):
    fill = {"tmp": tmp_path, "db": study["db"], "rom": study["rom"], "romrun": study["romrun"]}
    capsys.readouterr()
    code = make_figures.main([a.format(**fill) for a in args] + ["-o", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("make_figures: error:") and expect in err


def test_tradeoff_cli(study, tmp_path, capsys):
    out = tmp_path / "csv.png"
    res = run("post/plot_tradeoff.py", study["csv"], "-o", out, "--ml", study["ml"])
    assert res.returncode == 0, res.stderr
    assert "Pareto front: (6,4,eq)" in res.stdout
    assert_picture(out)
    out = tmp_path / "romrun.png"
    assert plot_tradeoff.main([study["romrun"], "-o", str(out)]) == 0
    assert "Pareto front: (6,4,eq)" in capsys.readouterr().out
    assert_picture(out)


def test_tradeoff_rows_agree(study):
    a = plot_tradeoff.read_rows(study["csv"])
    b = plot_tradeoff.read_rows(study["romrun"])
    key = lambda r: (r["setting"], r["set"])  # noqa: E731
    b = {key(r): r for r in b}
    assert len(a) == len(b) == 5
    for r in a:
        s = b[key(r)]
        for k in ("n", "r", "hyper", "t_step_rom", "speedup_uzawa"):
            assert r[k] == s[k]
        assert r["E_avg"] == pytest.approx(s["E_avg"], rel=1e-14)


def test_tradeoff_bad_csv(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("setting,set,n\n1,valid,4\n")
    assert plot_tradeoff.main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert "missing column" in err and "E_avg" in err
    assert plot_tradeoff.main([str(tmp_path / "none.csv")]) == 2
    assert "not found" in capsys.readouterr().err


def test_pareto_mask():
    cost = np.array([1.0, 2.0, 3.0, 2.5, 1.0, 4.0])
    err = np.array([5.0, 3.0, 1.0, 3.5, 6.0, 1.0])
    np.testing.assert_array_equal(plot_tradeoff.pareto_mask(cost, err),
                                  [True, True, True, False, False, False])


def test_multiplier_pod_errors_against_svd():
    from scipy.sparse import random as sprandom

    lam = sprandom(12, 60, density=0.2, random_state=3, format="csc")
    lam.data = np.abs(lam.data)
    mean, mx = make_figures.multiplier_pod_errors(lam, 8)
    a = lam.toarray()
    u, _, _ = np.linalg.svd(a, full_matrices=False)
    n1 = np.linalg.norm(a, axis=0).max()
    for r in (0, 3, 8):
        res = a - u[:, :r] @ (u[:, :r].T @ a)
        rel = np.linalg.norm(res, axis=0) / n1
        assert mean[r] == pytest.approx(rel.mean(), rel=1e-8, abs=1e-12)
        assert mx[r] == pytest.approx(rel.max(), rel=1e-8, abs=1e-12)
    assert mean[0] > mean[3] > mean[8]


def test_sample_scenes_are_read_from_the_database(study):
    """The figures draw each sample's scene as the model mapped it (stored by crowd_snapshots),
    not a geometry re-computed in Python."""
    with h5py.File(study["db"], "r") as f:
        ref = cio.read_scene(f)
        scenes = cio.read_sample_scenes(f, "valid")
        params = f["valid/params"][()]
        stored = f["valid/scene_exit"][()]
    assert len(scenes) == params.shape[0]
    for sc, p, e in zip(scenes, params, stored):
        assert sc["exit"].ravel() == pytest.approx(e)
        assert sc["exit"][1, 0] - sc["exit"][0, 0] == pytest.approx(p[0])   # l_exit of the sample
        assert sc["verts"].shape == ref["verts"].shape
    assert np.array_equal(ref["exit"][:, 0], [0.35, 0.65])     # the reference is untouched


def test_tradeoff_diverged_rows_off_the_front(study, tmp_path):
    """A setting with diverged samples (crowd_rom's samples_diverged) is drawn but never on the
    Pareto front, even when its E_avg (over the other samples) and its cost would put it there;
    a row without any E_avg (every sample diverged: -1) is left out of the plot."""
    rows = plot_tradeoff.read_rows(study["csv"])
    valid = [r for r in rows if r["set"] == "valid"]
    base = {_r["setting"] for _r in plot_tradeoff.plot_tradeoff(rows, tmp_path / "a.png")}
    best = min(valid, key=lambda r: float(r["E_avg"]))
    assert best["setting"] in base
    marked = [dict(r, samples_diverged=(2 if r is best else 0)) for r in rows]
    front = {_r["setting"] for _r in plot_tradeoff.plot_tradeoff(marked, tmp_path / "b.png")}
    assert best["setting"] not in front and front
    gone = [dict(r, E_avg=(-1.0 if r is best else r["E_avg"])) for r in rows]
    front = {_r["setting"] for _r in plot_tradeoff.plot_tradeoff(gone, tmp_path / "c.png")}
    assert best["setting"] not in front


def test_evac_table_ml_times_are_read_from_the_qoi():
    """evac_figures' ML rows take t50 / t90 and their censoring from the QoI group of the ML
    output (crowd_predict's), not from positions: a censored ML time counts as 'ML never', a
    sample the full model does not evacuate is left out."""
    import evac_figures
    qoi = {"t_evac": np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 5.0], [1.5, 5.0, 5.0]]),
           "censored": np.array([[0, 0, 0], [0, 1, 1], [0, 1, 1]], dtype=bool)}
    t_fom = np.array([[1.25, 2.5], [5.0, 4.0], [-1.0, -1.0]])
    ml = {"mlp": {"qoi": qoi, "best_n": 4, "E_avg": 0.1, "speedup_exact": np.array([3.0]),
                  "n_values": np.array([4])}}
    row = evac_figures.table_lines([], ml, t_fom)[2]
    # t50: |1 - 1.25| / 1.25 = |4 - 5| / 5 = 0.2 over two samples; t90: 0.2 on sample 1, sample 2
    # censored in the ML trajectories although the full model evacuates it
    assert "| 2.00e-01 (2) | 2.00e-01 (1), ML never 1 |" in row, row


def test_evac_table_correlations_of_the_times():
    """evac_figures' second table: Pearson r / Spearman rho of a model's t50 / t90 against the
    full model's over the samples where both reach them (a time <= 0 or a censored ML time is
    left out, never counted as a value); undefined (n/a) below 3 samples or for a constant side."""
    import evac_figures
    t_ref = np.array([2.0, 4.0, 6.0, 9.0, 5.0, -1.0])
    t_mod = np.array([1.0, 2.0, 3.0, 4.0, -1.0, 7.0])
    r, rho, n = evac_figures.time_correlation(t_mod, t_ref)
    assert n == 4 and rho == pytest.approx(1.0)
    assert r == pytest.approx(np.corrcoef([1, 2, 3, 4], [2, 4, 6, 9])[0, 1], rel=1e-14) and r < 1 - 1e-3
    assert evac_figures.time_correlation(t_mod[:2], t_ref[:2]) == (None, None, 2)
    assert evac_figures.time_correlation(np.ones(4), t_ref[:4])[:2] == (None, None)
    # one reduced setting on both sets, one ML regressor whose third sample is censored at t90
    d = {"t_out_fom": np.array([[1.0, 2.0], [2.0, 3.0], [3.0, 5.0], [4.0, 6.0]]),
         "t_out_rom": np.array([[4.0, 1.0], [3.0, 2.0], [2.0, 3.0], [1.0, 4.0]])}
    # the same setting with its first sample diverged (its times are left out)
    d2 = dict(d, diverged_step=np.array([7, 0, 0, 0]))
    runs = {1: {"n": 5, "r": 10, "hyper": "eq", "contacts": "cone", "data": {"valid": d, "train": d}},
            2: {"n": 5, "r": 10, "hyper": "eim", "contacts": "cone", "data": {"valid": d2}}}
    qoi = {"t_evac": np.array([[1.0, 2.0, 9.0], [2.0, 3.0, 9.0], [3.0, 9.0, 9.0], [4.0, 7.0, 9.0]]),
           "censored": np.array([[0, 0, 1], [0, 0, 1], [0, 1, 1], [0, 0, 1]], dtype=bool)}
    ml = {"mlp": {"qoi": qoi, "best_n": 4}}
    lines = evac_figures.correlation_lines(runs, ml)
    rom = [ln for ln in lines if ln.startswith("| (5, 10) eq / cone |")]
    r90 = np.corrcoef([1, 2, 3, 4], [2, 3, 5, 6])[0, 1]            # t90: ranks equal, values not
    assert rom == ["| (5, 10) eq / cone | -1.00 / -1.00 (4) | %.2f / 1.00 (4) | -1.00 / -1.00 (4) "
                   "| %.2f / 1.00 (4) |" % (r90, r90)], lines
    r90 = np.corrcoef([2, 3, 4], [3, 5, 6])[0, 1]
    assert "| (5, 10) eim / cone | -1.00 / -1.00 (3) | %.2f / 1.00 (3) |  |  |" % r90 in lines, lines
    r90 = np.corrcoef([2, 3, 7], [2, 3, 6])[0, 1]                   # sample 3 censored: left out
    assert "| ML-corrected mlp (n = 4) | 1.00 / 1.00 (4) | %.2f / 1.00 (3) | | |" % r90 in lines, lines
