"""Hostile and careless inputs to the Python scripts, as generated families: each ends with one
`error:` line (no traceback), exit 2 (1 for an interrupt), and no output changed; the checks are
those of crowdrom_io's readers (checksums, finiteness, shapes against attributes, CSV tables).

* evac_figures.py on a real tiny study (crowd_snapshots, crowd_offline, crowd_rom): bad
  arguments, outputs naming a file or an input, corrupt or lying inputs (sweep table, run file,
  database, ML output), SIGTERM and SIGKILL while drawing: an earlier good set survives exactly;
* study_table.py: tables with NaN, Inf, text, ragged rows, negative times; an ML file with Inf;
* plot_tradeoff.py --overlap-tol -1 / nan / inf; make_figures.py --steps beyond n_steps;
* ml_correct.py on a database whose velocities or positions were scaled (stale checksum) and on a
  run file with NaN positions."""
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, SCRIPTS)
sys.path.insert(0, HERE)
import crowdrom_io as cio  # noqa: E402
import synth  # noqa: E402
from test_rom import BIN, offline, rom_input, run as run_fortran, study_file  # noqa: E402
from test_script_errors import assert_refused, listing, run  # noqa: E402

HAVE_BIN = os.path.exists(os.path.join(BIN, "crowd_rom"))


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """A tiny real study: database, ROM run file and sweep table, an ML output made to match
    read_ml's layout (its QoI group copied from the run file's), and a good figure set (the
    'earlier' set every refusal must leave alone)."""
    if not HAVE_BIN:
        pytest.skip("needs the Fortran build")
    tmp = tmp_path_factory.mktemp("evac")
    db = tmp / "db.h5"
    p = run_fortran(1, "crowd_snapshots", study_file(tmp, "study.nml", db), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp, tmp / "study.nml", db, tmp / "rom.h5")
    nml = rom_input(tmp, "rom.nml", rom, tmp / "run.h5",
                    [{"n": 16, "r": 9}, {"n": 16, "r": 9, "contacts": "'online'", "hyper": "'none'"}], sets="'both'")
    p = run_fortran(0, "crowd_rom", nml, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    ml = tmp / "ml.h5"
    with h5py.File(tmp / "run.h5", "r") as f:
        q = f["setting_1/valid/positions"][()]
        mu = f["setting_1/valid/params"][()]

    def write(fh):
        fh.attrs["schema"], fh.attrs["schema_version"] = np.bytes_(cio.ML_SCHEMA), np.int32(cio.ML_VERSION)
        fh["valid_params"], fh["n_values"] = mu, np.array([2, 4], dtype=np.int32)
        g = fh.create_group("random_forest")
        g.attrs["best_n"], g.attrs["best_E_avg"] = np.int32(4), 0.01
        g["speedup_exact"] = np.array([3.0, 2.5])
        g["best/positions"] = q + 1e-4
        with h5py.File(tmp / "run.h5", "r") as src:     # a QoI group of the layout crowd_predict writes
            src.copy("setting_1/valid/qoi", g["best"], name="qoi")
    cio.write_h5_atomic(ml, write)
    good = tmp / "figs"
    r = run("post/evac_figures.py", *base_args(tmp, ml), "-o", good)
    assert r.returncode == 0, r.stdout + r.stderr
    assert sorted(os.listdir(good)) == ["evac_curves.png", "evac_table.md", "t90_map.png", "train_convergence.png"]
    return {"tmp": tmp, "db": db, "run": tmp / "run.h5", "csv": tmp / "run.csv", "ml": ml, "good": good}


def base_args(tmp, ml=None, db=None, runf=None, csvf=None):
    a = ["--database", db or tmp / "db.h5", "--romrun", runf or tmp / "run.h5"]
    if csvf:
        a += ["--csv", csvf]
    if ml:
        a += ["--ml", ml]
    return a


def refused_keeping(real, args, expect, code=2):
    before = listing(real["good"])
    r = run("post/evac_figures.py", *args)
    assert_refused(r, expect, code)
    assert listing(real["good"]) == before
    assert not [n for n in os.listdir(real["tmp"]) if ".partial" in n]


BAD_ARGS = [
    (["--samples", "999"], "--samples 999: the validation set"),
    (["--samples", "0"], "--samples 0: every value must be >= 1"),
    (["--samples", "-1"], "--samples -1: every value must be >= 1"),
    (["--dpi", "0"], "--dpi 0: must be in 1.."),
    (["--dpi", "-5"], "--dpi -5: must be in 1.."),
    (["--modes", "0"], "--modes 0: every value must be >= 1"),
    (["--modes", "-3"], "--modes -3: every value must be >= 1"),
    (["--modes", "1000"], "--modes 1000: at most n_dof"),
    (["--sizes", "0"], "--sizes 0: every value must be >= 1"),
    (["--sizes", "999"], "--sizes 999: the database has"),
    (["--stride", "1e6"], "--stride: invalid int value"),
    (["--stride", "1000000"], "--stride 1000000: must be <= n_steps"),
    (["--stride", "0"], "--stride 0: must be >= 1"),
    (["--map-setting", "99"], "--map-setting 99"),
    (["--settings", "1", "99"], "--settings 99"),
]


@pytest.mark.parametrize("extra,expect", BAD_ARGS)
def test_evac_bad_arguments(real, extra, expect):
    refused_keeping(real, [*base_args(real["tmp"]), "-o", real["good"], *extra], expect)


@pytest.mark.parametrize("which", ["run", "db", "csv", "ml"])
def test_evac_output_names_an_input(real, which):
    refused_keeping(real, [*base_args(real["tmp"], real["ml"]), "-o", real[which]], "is a file")


def _table_variant(real, name, edit):
    rows = list(csv.reader(open(real["csv"])))
    edit(rows)
    path = real["tmp"] / f"{name}.csv"
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return path


def _cell(rows, col, value, line=1):
    rows[line][rows[0].index(col)] = value


CSV_CASES = [
    ("nan_cell", lambda r: _cell(r, "E_avg", "nan"), "column 'E_avg' holds nan (not a finite number)"),
    ("inf_cell", lambda r: _cell(r, "t90_err", "inf"), "column 't90_err' holds inf"),
    ("text_cell", lambda r: _cell(r, "speedup_exact", "fast"), "column 'speedup_exact' holds 'fast', not a number"),
    ("ragged_long", lambda r: r[1].append("7"), "cells, the header has"),
    ("ragged_short", lambda r: r[2].pop(), "cells, the header has"),
    ("negative_time", lambda r: _cell(r, "t_step_rom", "-3e-6"), "column 't_step_rom' = -3e-6: a time must be >= 0"),
]


@pytest.mark.parametrize("name,edit,expect", CSV_CASES)
def test_evac_bad_sweep_table(real, name, edit, expect):
    path = _table_variant(real, name, edit)
    refused_keeping(real, [*base_args(real["tmp"], csvf=path), "-o", real["good"]], expect)


def _h5_variant(real, key, name, edit):
    path = real["tmp"] / f"{name}_{os.path.basename(real[key])}"
    shutil.copy(real[key], path)
    with h5py.File(path, "a") as f:
        edit(f)
    return path


def _set(f, name, fn):
    a = f[name][()]
    a = fn(a)
    f[name][...] = a
    if "checksum" in f[name].attrs:       # re-stamped: only the other checks can catch it
        f[name].attrs["checksum"] = np.bytes_(cio.digest(a))


def _nan_first(a):
    a = a.astype(float)
    a.flat[0] = np.nan
    return a


H5_CASES = [
    ("db", "scaled_positions", lambda f: f["valid/positions"].__setitem__(Ellipsis, f["valid/positions"][()] * 1.001),
     "checksum mismatch in dataset 'valid/positions'"),
    ("db", "scaled_velocities", lambda f: f["train/velocities"].__setitem__(Ellipsis, f["train/velocities"][()] * 1.001),
     "checksum mismatch in dataset 'train/velocities'"),
    ("db", "radius_zero", lambda f: f.attrs.__setitem__("agent_radius", 0.0), "agent_radius = 0.0"),
    ("db", "n_train_lie", lambda f: f.attrs.__setitem__("n_train", np.int32(60)), "n_train says 60"),
    ("run", "dt_nan", lambda f: f.attrs.__setitem__("dt", np.nan), "dt = nan"),
    ("run", "nan_positions", lambda f: _set(f, "setting_1/valid/positions", _nan_first),
     "dataset 'setting_1/valid/positions': non-finite"),
    ("ml", "ml_nan", lambda f: _set(f, "random_forest/best/qoi/t_evac", _nan_first),
     "dataset 'random_forest/best/qoi/t_evac': non-finite"),
    ("ml", "ml_without_qoi", lambda f: f["random_forest/best"].__delitem__("qoi"),
     "missing group 'random_forest/best/qoi' (the QoIs of the ML-corrected trajectories"),
    ("ml", "ml_inf_speedup", lambda f: _set(f, "random_forest/speedup_exact", lambda a: a * np.inf),
     "dataset 'random_forest/speedup_exact': non-finite"),
    ("ml", "best_n_not_listed", lambda f: f["random_forest"].attrs.__setitem__("best_n", np.int32(7)),
     "best_n' = 7 is not in n_values"),
    ("ml", "fewer_rows", lambda f: f["random_forest/best/qoi"].attrs.__setitem__("n_rows", np.int32(1)),
     "dataset 'random_forest/best/qoi/curve' has shape"),
]


@pytest.mark.parametrize("key,name,edit,expect", H5_CASES, ids=[c[1] for c in H5_CASES])
def test_evac_corrupt_or_lying_inputs(real, key, name, edit, expect):
    path = _h5_variant(real, key, name, edit)
    kw = {"db": {"db": path}, "run": {"runf": path}, "ml": {"ml": path}}[key]
    kw.setdefault("ml", real["ml"])
    csvf = real["csv"] if key == "run" else None
    refused_keeping(real, [*base_args(real["tmp"], csvf=csvf, **kw), "-o", real["good"]], expect)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_evac_interrupted_keeps_the_earlier_set(real, sig):
    """Interrupted while drawing (its temporary folder exists): the earlier set is untouched; after
    SIGTERM no temporary is left, after SIGKILL the next run removes it."""
    before = listing(real["good"])
    cmd = [sys.executable, os.path.join(SCRIPTS, "post", "evac_figures.py"), *map(str, base_args(real["tmp"], real["ml"])),
           "-o", str(real["good"]), "--dpi", "200"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tmp_dir = real["tmp"] / f".figs.partial-{p.pid}"
    t0 = time.time()
    while not tmp_dir.exists() and p.poll() is None and time.time() - t0 < 120:
        time.sleep(0.01)
    assert tmp_dir.exists(), "the run ended before it was interrupted"
    p.send_signal(sig)
    out, err = p.communicate(timeout=120)
    assert listing(real["good"]) == before
    if sig == signal.SIGTERM:
        assert p.returncode == 1 and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1 and "evac_figures: error:" in err, err
        assert not tmp_dir.exists()
    else:
        assert tmp_dir.exists()
        r = run("post/evac_figures.py", *base_args(real["tmp"], real["ml"]), "-o", real["good"])
        assert r.returncode == 0, r.stderr
        assert not tmp_dir.exists()
        assert sorted(os.listdir(real["good"])) == sorted(before)


def test_evac_table_has_no_nan(real):
    text = open(real["good"] / "evac_table.md").read()
    assert "nan" not in text.lower() and "inf " not in text.lower()


# ---------------------------------------------------------------- study_table, plot_tradeoff, make_figures

@pytest.fixture(scope="module")
def synth_study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tables")
    st = synth.make_study(tmp)
    st["tmp"] = tmp
    return st


STUDY_CSV_CASES = [
    ("nan", lambda r: _cell(r, "E_avg", "NaN"), "column 'E_avg' holds NaN"),
    ("inf", lambda r: _cell(r, "speedup_exact", "Inf"), "column 'speedup_exact' holds Inf"),
    ("text", lambda r: _cell(r, "E_avg", "small"), "column 'E_avg' holds 'small', not a number"),
    ("ragged", lambda r: r[1].extend(["1", "2"]), "cells, the header has"),
    ("negative_time", lambda r: _cell(r, "t_step_fom_exact", "-1e-3"), "a time must be >= 0"),
]


@pytest.mark.parametrize("name,edit,expect", STUDY_CSV_CASES)
def test_study_table_refuses_bad_tables(synth_study, tmp_path, name, edit, expect):
    rows = list(csv.reader(open(synth_study["csv"])))
    edit(rows)
    path = tmp_path / "t.csv"
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    out = tmp_path / "table.md"
    r = run("post/study_table.py", path, "-o", out)
    assert_refused(r, expect)
    assert not out.exists()


def test_study_table_refuses_inf_in_ml_file(synth_study, tmp_path):
    ml = tmp_path / "ml.h5"

    def write(f):
        f.attrs["schema"], f.attrs["schema_version"] = np.bytes_(cio.ML_SCHEMA), np.int32(cio.ML_VERSION)
        f["n_values"] = np.array([2, 4], dtype=np.int32)
        g = f.create_group("mlp")
        g["t_step"], g["speedup_exact"], g["E_avg"] = np.array([1e-4, 1e-4]), np.array([2.0, np.inf]), \
            np.array([0.1, 0.05])
    cio.write_h5_atomic(ml, write)
    out = tmp_path / "table.md"
    r = run("post/study_table.py", synth_study["csv"], "--ml", ml, "-o", out)
    assert_refused(r, "dataset 'mlp/speedup_exact': non-finite")
    assert not out.exists()


@pytest.mark.parametrize("tol", ["-1", "nan", "inf"])
def test_plot_tradeoff_bad_overlap_tol(synth_study, tmp_path, tol):
    out = tmp_path / "t.png"
    r = run("post/plot_tradeoff.py", synth_study["csv"], "-o", out, "--overlap-tol", tol)
    assert_refused(r, f"--overlap-tol {float(tol)}: must be a finite number >= 0")
    assert not out.exists()


def test_make_figures_steps_beyond_the_run(synth_study, tmp_path):
    out = tmp_path / "figs"
    r = run("post/make_figures.py", "--database", synth_study["db"], "--romrun", synth_study["romrun"], "-o", out,
            "--steps", "0", "9999")
    assert_refused(r, "--steps 0 9999: every value must be <= n_steps")
    assert not out.exists()


# ---------------------------------------------------------------- ml_correct

@pytest.mark.parametrize("name", ["train/velocities", "valid/positions"])
def test_ml_correct_refuses_scaled_database(synth_study, tmp_path, name):
    db = tmp_path / "db.h5"
    shutil.copy(synth_study["db"], db)
    with h5py.File(db, "a") as f:
        f[name][...] = f[name][()] * 1.001
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"n_values": [3], "random_forest": {"n_estimators": 2}, "timing_repeats": 1,
                               "regressors": ["random_forest"]}))
    out = tmp_path / "ml.h5"
    r = run("pipeline/ml_correct.py", synth_study["romrun"], "--database", db, "--config", cfg, "-o", out, "--csv",
            tmp_path / "ml.csv", "--no-project", "--quiet")
    assert_refused(r, f"checksum mismatch in dataset '{name}'")
    assert not out.exists() and not (tmp_path / "ml.csv").exists()


def test_ml_correct_refuses_nan_in_run_file(synth_study, tmp_path):
    runf = tmp_path / "run.h5"
    shutil.copy(synth_study["romrun"], runf)
    with h5py.File(runf, "a") as f:
        _set(f, "setting_1/valid/positions", _nan_first)
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"n_values": [3], "random_forest": {"n_estimators": 2}, "timing_repeats": 1,
                               "regressors": ["random_forest"]}))
    out = tmp_path / "ml.h5"
    r = run("pipeline/ml_correct.py", runf, "--database", synth_study["db"], "--rom", synth_study["rom"], "--config", cfg,
            "-o", out, "--csv", tmp_path / "ml.csv", "--no-project", "--quiet")
    assert_refused(r, "dataset 'setting_1/valid/positions': non-finite")
    assert not out.exists() and not (tmp_path / "ml.csv").exists()
