"""crowd_predict end to end on the tiny study of the reduced-model tests (tests/inputs/rom_tiny.nml):
the prediction for the database's own parameters equals crowd_rom's reduced trajectories bit for
bit; 2 ranks give the product of 1 rank bit for bit; the exact model equals crowd_fom; queries
outside the training box are flagged (or refused); bad parameter lists and an older ROM file get
one clear line, exit 2, and nothing is written."""
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import nml_groups  # noqa: E402

ROOT = os.environ.get("CROWDROM_ROOT", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BIN = os.environ.get("CROWDROM_BIN", os.path.join(ROOT, "build", "bin"))
STUDY = os.path.join(ROOT, "tests", "inputs", "rom_tiny.nml")
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
#: datasets that hold timings (everything else must not depend on the rank count)
TIMINGS = {"cpu_seconds"}


def run(np_, prog, nml, cwd):
    cmd = [os.path.join(BIN, prog), str(nml)]
    if np_ > 0:
        cmd = ["mpiexec", "-n", str(np_)] + cmd
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=ENV)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """The tiny study's database and a ROM file with a full pair and a small one."""
    tmp = tmp_path_factory.mktemp("predict")
    db = tmp / "tiny.h5"
    text = open(STUDY).read().replace("database = 'rom_tiny.h5'", "database = '%s'" % db)
    (tmp / "study.nml").write_text(text)
    p = run(2, "crowd_snapshots", tmp / "study.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = tmp / "rom.h5"
    off = text + nml_groups.as_text(nml_groups.offline_groups(
        "database = '%s', rom_file = '%s', pod_energy = 0.0, cone_delta = 0.0, pga_delta = 1e-8, "
        "infsup_samples = 2, infsup_n = 2, infsup_r = 2, rom_n = 4, 6, rom_r = 3, 4" % (db, rom)))
    (tmp / "offline.nml").write_text(off)
    p = run(1, "crowd_offline", tmp / "offline.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(db, "r") as f:
        names = f.attrs["param_names"].decode().split(",")
        params = f["train/params"][...]
        lo, hi = f.attrs["param_min"] if "param_min" in f.attrs else None, None
    return tmp, db, rom, names, params


def write_text_list(path, names, rows, header=None):
    with open(path, "w") as f:
        f.write("# queries\n")
        f.write((header if header is not None else ", ".join(names)) + "\n")
        for r in rows:
            f.write(" ".join("%.17g" % x for x in r) + "\n")
    return path


def predict_input(tmp, name, rom, out, **kw):
    opts = dict(rom_file="'%s'" % rom, output="'%s'" % out)
    opts.update(kw)
    path = tmp / name
    path.write_text("&predict %s /\n" % ", ".join("%s = %s" % (k, v) for k, v in opts.items()))
    return path


def product(path):
    """Every dataset of a product by its path (e.g. 'qoi/curve_total') and the root attributes."""
    d = {}
    with h5py.File(path, "r") as f:
        assert f.attrs["schema"].decode() == "crowdrom-qoi"
        f.visititems(lambda name, obj: d.__setitem__(name, obj[...]) if isinstance(obj, h5py.Dataset) else None)
        return d, dict(f.attrs)


@pytest.mark.parametrize("setting", [
    dict(n=4, r=3, hyper="'eq'"),
    dict(n=6, r=4, hyper="'none'", contacts="'online'"),
])
def test_equals_sweep_trajectories(study, setting):
    """Prediction for the training parameters = crowd_rom's reduced positions, bit for bit
    (text list for one setting, HDF5 list for the other)."""
    tmp, db, rom, names, params = study
    tag = "_".join(str(v).strip("'") for v in setting.values())
    sweep_out = tmp / ("sweep_%s.h5" % tag)
    flat = "rom_file = '%s', output = '%s', sets = 'train', fom_timing_samples = 0, timing_repeats = 1, %s" % (
        rom, sweep_out, ", ".join("%s(1) = %s" % (k, v) for k, v in setting.items()))
    (tmp / ("sweep_%s.nml" % tag)).write_text(nml_groups.as_text(nml_groups.rom_groups(flat)))
    p = run(0, "crowd_rom", tmp / ("sweep_%s.nml" % tag), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    if setting["hyper"] == "'eq'":
        plist = write_text_list(tmp / "train.txt", names, params)
    else:
        plist = tmp / "train_list.h5"
        with h5py.File(plist, "w") as f:
            d = f.create_dataset("queries", data=params)
            d.attrs["param_names"] = np.bytes_(",".join(names))
        setting = dict(setting, params_dataset="'queries'")
    out = tmp / ("pred_%s.h5" % tag)
    nml = predict_input(tmp, "pred_%s.nml" % tag, rom, out, params_file="'%s'" % plist, trajectories=".true.",
                        **setting)
    p = run(0, "crowd_predict", nml, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    d, a = product(out)
    with h5py.File(sweep_out, "r") as f:
        q_sweep = f["setting_1/train/positions"][...]
        evac = f["setting_1/train/evac_rom"][...]
    assert d["positions"].shape == q_sweep.shape
    assert np.array_equal(d["positions"], q_sweep)
    assert np.array_equal(d["qoi/curve_total"], evac.astype(d["qoi/curve_total"].dtype))
    assert np.array_equal(d["params"], params)
    assert not d["outside_box"].any()


def test_two_ranks_equal_one(study):
    """A sampled list (some queries outside the box) on 1 and 2 ranks: the same product."""
    tmp, db, rom, names, params = study
    outs = []
    for np_ in (1, 2):
        out = tmp / ("ranks%d.h5" % np_)
        nml = predict_input(tmp, "ranks%d.nml" % np_, rom, out, n=4, r=3, n_queries=7, seed=11,
                            dist_param="'l_exit'", dist="'normal'", dist_a=0.2, dist_b=0.03, trajectories=".true.")
        p = run(np_, "crowd_predict", nml, tmp)
        assert p.returncode == 0, p.stdout + p.stderr
        outs.append(product(out)[0])
    assert set(outs[0]) == set(outs[1])
    for k in outs[0]:
        if k not in TIMINGS:
            assert np.array_equal(outs[0][k], outs[1][k]), k
    assert outs[0]["positions"].shape[0] == 7 * 13


def test_out_of_box_flagged_and_refused(study):
    tmp, db, rom, names, params = study
    rows = params[:3].copy()
    rows[1, 0] = 0.25      # l_exit beyond the box [0.18, 0.22]
    rows[2, 3] = 0.85      # one agent's speed below the box [0.9, 1.1]
    plist = write_text_list(tmp / "box.txt", names, rows)
    out = tmp / "box.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "box.nml", rom, out, n=4, r=3, params_file="'%s'" % plist), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    d, a = product(out)
    assert d["outside_box"].tolist() == [0, 1, 1]
    assert "2 outside the training box" in p.stdout
    out2 = tmp / "box_refused.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "box2.nml", rom, out2, n=4, r=3, params_file="'%s'" % plist,
                                              out_of_box="'refuse'"), tmp)
    assert p.returncode == 2 and not out2.exists()
    assert "2 of 3 queries lie outside the training box (first: query 2" in p.stderr


def test_exact_equals_crowd_fom(study):
    """model = 'exact' on a new parameter = crowd_fom with that exit width and those speeds."""
    tmp, db, rom, names, params = study
    mu = params[0].copy()
    mu[0] = 0.195
    plist = write_text_list(tmp / "exact.txt", names, [mu])
    out = tmp / "exact.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "exact.nml", rom, out, model="'exact'", params_file="'%s'" % plist,
                                              trajectories=".true."), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    d, a = product(out)
    (tmp / "speeds.txt").write_text("\n".join("%.17g" % s for s in mu[1:]) + "\n")
    text = open(STUDY).read().replace("l_exit = 0.2,", "l_exit = %.17g," % mu[0])
    text = text.replace("speed = 1.0,", "speed = 1.0, speed_file = 'speeds.txt',")
    text = text.replace("log_level = 'info'", "log_level = 'info', file = 'fom.h5'")
    text = text[:text.index("&study")]
    (tmp / "fom.nml").write_text(text)
    p = run(0, "crowd_fom", tmp / "fom.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(tmp / "fom.h5", "r") as f:
        q = f["traj/positions"][...]          # frames 0..n_steps
    assert d["positions"].shape == q.shape == (13, 16)
    assert np.array_equal(d["positions"], q)
    assert not d["outside_box"].any() and a["model"].decode().startswith("exact")


BAD = [
    ("count", "rows", "line 3 has 8 values, the header names 9 columns"),
    ("nan", "nan", "line 3, column 1: 'nan' is not a finite number"),
    ("empty", "empty", "the list holds no query"),
    ("unknown", "unknown", "column 'l_exits' is not a parameter of the study"),
    ("spread", "spread", "&predict: dist(1): the spread dist_b must be > 0 (got -1.00000E-02)"),
    ("dist_name", "dist_name", "dist_param(1) = 'width' is not a parameter of the study (parameters: l_exit, speeds)"),
]


@pytest.mark.parametrize("case,kind,message", BAD)
def test_bad_lists(study, case, kind, message):
    tmp, db, rom, names, params = study
    out = tmp / ("bad_%s.h5" % case)
    kw = dict(n=4, r=3)
    if kind in ("rows", "nan", "empty", "unknown"):
        path = tmp / ("bad_%s.txt" % case)
        rows = [list(params[0])]
        if kind == "rows":
            rows = [list(params[0][:-1])]
        if kind == "empty":
            rows = []
        header = None if kind != "unknown" else ", ".join(["l_exits"] + names[1:])
        write_text_list(path, names, rows, header=header)
        if kind == "nan":
            text = path.read_text().splitlines()
            text[2] = "nan " + text[2].split(" ", 1)[1]
            path.write_text("\n".join(text) + "\n")
        kw["params_file"] = "'%s'" % path
    elif kind == "spread":
        kw.update(n_queries=3, dist_param="'l_exit'", dist="'normal'", dist_a=0.2, dist_b=-0.01)
    else:
        kw.update(n_queries=3, dist_param="'width'", dist="'uniform'", dist_a=0.1, dist_b=0.2)
    p = run(0, "crowd_predict", predict_input(tmp, "bad_%s.nml" % case, rom, out, **kw), tmp)
    assert p.returncode == 2, p.stdout + p.stderr
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    assert message in lines[0], lines[0]
    assert not out.exists()
    assert not [f for f in os.listdir(tmp) if f.startswith("bad_%s.h5" % case)]


def test_older_rom_file_refused(study):
    tmp, db, rom, names, params = study
    old = tmp / "rom_v2.h5"
    shutil.copy(rom, old)
    with h5py.File(old, "a") as f:
        del f["study"]
        f.attrs["schema_version"] = np.int32(2)
    plist = write_text_list(tmp / "one.txt", names, params[:1])
    out = tmp / "old.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "old.nml", old, out, n=4, r=3, params_file="'%s'" % plist), tmp)
    assert p.returncode == 2 and not out.exists()
    lines = [l for l in p.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and "ROM file version 2 holds no study" in lines[0], p.stderr


def test_ml_predict_any_list(study):
    """ml_correct.py --predict: the saved models correct crowd_predict's coefficients; the QoIs of the
    corrected positions (by crowd_predict, model = 'positions') match those of the training run's
    corrected validation positions, with no ROM run file or database."""
    tmp, db, rom, names, params = study
    romrun = tmp / "ml_romrun.h5"
    flat = ("rom_file = '%s', output = '%s', sets = 'both', fom_timing_samples = 0, timing_repeats = 1, "
            "n(1) = 4, r(1) = 3, hyper(1) = 'eq'" % (rom, romrun))
    (tmp / "ml_rom.nml").write_text(nml_groups.as_text(nml_groups.rom_groups(flat)))
    p = run(0, "crowd_rom", tmp / "ml_rom.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    cfg = tmp / "ml_small.json"
    cfg.write_text('{"n_values": [3], "regressors": ["random_forest"], "random_forest": {"n_estimators": 10}}')
    script = os.path.join(ROOT, "scripts", "pipeline", "ml_correct.py")
    env = dict(ENV, CROWDROM_BIN=BIN)
    p = subprocess.run([sys.executable, script, str(romrun), "--config", str(cfg), "--no-project", "--quiet",
                        "-o", str(tmp / "ml.h5"), "--models-dir", str(tmp / "ml_models")],
                       capture_output=True, text=True, env=env, cwd=tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(db, "r") as f:
        valid = f["valid/params"][...]
    with h5py.File(tmp / "ml.h5", "r") as f:
        q_ml = f["random_forest/best/positions"][...].reshape(len(valid), 13, 16)
    plist = write_text_list(tmp / "valid.txt", names, valid)
    pred = tmp / "pred_valid.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "pred_valid.nml", rom, pred, n=4, r=3,
                                              params_file="'%s'" % plist, trajectories=".true."), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    out = tmp / "pred_valid_ml.h5"
    p = subprocess.run([sys.executable, script, "--predict", str(pred), "--ml-output", str(tmp / "ml.h5"),
                        "--config", str(cfg), "--models-dir", str(tmp / "ml_models"), "-o", str(out), "--quiet"],
                       capture_output=True, text=True, env=env, cwd=tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    d, a = product(out)
    base, _ = product(pred)
    assert a["model"].decode() == "ml random_forest n=3"
    assert np.array_equal(d["params"], valid)
    # the tiny hall (no second exit): out when the centre is above hall_width + wall + radius
    curve = (q_ml[:, :, 1::2] > 0.5 + 0.05 + 0.04).sum(axis=2)
    assert np.array_equal(d["qoi/curve_total"], curve)
    assert np.all(d["cpu_seconds"] > base["cpu_seconds"])
    # a product without coefficients is refused with one line
    p = subprocess.run([sys.executable, script, "--predict", str(out), "--n", "3", "--config", str(cfg),
                        "--models-dir", str(tmp / "ml_models"), "-o", str(tmp / "nope.h5")],
                       capture_output=True, text=True, env=env, cwd=tmp)
    assert p.returncode == 2 and "no reduced coefficients" in p.stderr and not (tmp / "nope.h5").exists()


def test_sampling_rule(study):
    """Distributions per parameter: truncnormal stays in its window, lognormal is positive, a parameter
    without a distribution stays in its training box; the list depends only on the seed."""
    tmp, db, rom, names, params = study
    kw = dict(n=4, r=3, n_queries=40, dist_param="'l_exit', 'speeds'", dist="'truncnormal', 'lognormal'",
              dist_a="0.2, 0.0", dist_b="0.05, 0.05", dist_lo="0.195, 0", dist_hi="0.205, 0")
    outs = []
    for seed in (3, 3, 4):
        out = tmp / ("sample_%d_%d.h5" % (seed, len(outs)))
        p = run(0, "crowd_predict", predict_input(tmp, "sample_%d.nml" % len(outs), rom, out, seed=seed, **kw), tmp)
        assert p.returncode == 0, p.stdout + p.stderr
        outs.append(product(out)[0]["params"])
    mu = outs[0]
    assert mu.shape == (40, len(names))
    assert np.all((mu[:, 0] >= 0.195) & (mu[:, 0] <= 0.205)) and np.unique(mu[:, 0]).size == 40
    assert np.all(mu[:, 1:] > 0) and np.unique(mu[:, 1:]).size == mu[:, 1:].size
    # exp(N(0, 0.05)): about a third of the speeds below 0.95 or above 1.05
    assert 0.05 < np.mean(np.abs(np.log(mu[:, 1:])) > 0.05) < 0.6
    assert np.array_equal(outs[0], outs[1]) and not np.array_equal(outs[0], outs[2])
    out = tmp / "sample_default.h5"
    p = run(0, "crowd_predict", predict_input(tmp, "sample_default.nml", rom, out, n=4, r=3, n_queries=40), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    d, _ = product(out)
    assert np.all((d["params"][:, 0] >= 0.18) & (d["params"][:, 0] <= 0.22)) and not d["outside_box"].any()
