"""crowd_rom end to end on a tiny study (tests/inputs/rom_tiny.nml): with full bases the
reduced model reproduces the full-order trajectories of the training parameters (exact
assembly, EQ and EIM with all points, online contacts); a small ROM runs and reports its
failure modes; a parameter outside the training box is flagged; bad inputs fail with one
clear line and write nothing."""
import csv
import json
import os
import re
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


def run(np_, prog, nml, cwd):
    cmd = [os.path.join(BIN, prog), str(nml)]
    if np_ > 0:
        cmd = ["mpiexec", "-n", str(np_)] + cmd
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=ENV)


def study_file(tmp, name, db, seed=None):
    text = open(STUDY).read().replace("database = 'rom_tiny.h5'", "database = '%s'" % db)
    if seed is not None:
        text = text.replace("seed = 7", "seed = %d" % seed)
    path = tmp / name
    path.write_text(text)
    return path


def offline(tmp, study, db, rom, extra=""):
    text = open(study).read()
    text += nml_groups.as_text(nml_groups.offline_groups(
        "database = '%s', rom_file = '%s', pod_energy = 0.0, cone_delta = 0.0, pga_delta = 1e-8, "
        "infsup_samples = 2, infsup_n = 2, infsup_r = 2%s" % (db, rom, extra)))
    path = tmp / (os.path.basename(str(rom)) + ".nml")
    path.write_text(text)
    p = run(1, "crowd_offline", path, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    return rom


def rom_input(tmp, name, rom, out, settings, **kw):
    opts = dict(rom_file="'%s'" % rom, output="'%s'" % out, fom_timing_samples="1", timing_repeats="1")
    opts.update(kw)
    flat = [", ".join("%s = %s" % (k, v) for k, v in opts.items())]
    for k, s in enumerate(settings, 1):
        flat.append(", ".join("%s(%d) = %s" % (key, k, val) for key, val in s.items()))
    path = tmp / name
    path.write_text(nml_groups.as_text(nml_groups.rom_groups(", ".join(flat))))
    return path


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rom")
    db = tmp / "tiny.h5"
    sfile = study_file(tmp, "study.nml", db)
    p = run(2, "crowd_snapshots", sfile, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom0 = offline(tmp, sfile, db, tmp / "rom_full.h5")
    with h5py.File(rom0, "r") as f:
        n_full, r_full = int(f["pairs/1"].attrs["n"]), int(f["pairs/1"].attrs["r"])
    rom = offline(tmp, sfile, db, tmp / "rom.h5",
                  extra=", rom_n = %d, 4, rom_r = %d, 3" % (n_full, r_full))
    return tmp, db, rom, n_full, r_full


def stored_m(rom, method, term, pair=1):
    with h5py.File(rom, "r") as f:
        return int(f["pairs/%d/%s/%s" % (pair, method, term)].attrs["m"])


def run_full_bases(study):
    """crowd_rom with full bases and every assembly (exact, EQ, EIM with all points, online
    contacts) on the training set: (output, settings)."""
    tmp, db, rom, n, r = study
    full = dict(n=n, r=r)
    m_eim = dict(m_v=stored_m(rom, "eim", "s1"), m_b=stored_m(rom, "eim", "s2"), m_d=stored_m(rom, "eim", "s3"))
    settings = [dict(full, hyper="'none'"), dict(full, hyper="'eq'"), dict(full, hyper="'eim'", **m_eim),
                dict(full, hyper="'none'", contacts="'online'")]
    out = tmp / "full.h5"
    p = run(0, "crowd_rom", rom_input(tmp, "full.nml", rom, out, settings, sets="'train'"), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    return out, settings


def test_full_basis_reproduces_fom(study):
    tmp, db, rom, n, r = study
    out, settings = run_full_bases(study)
    with h5py.File(out, "r") as f, h5py.File(db, "r") as d:
        assert f.attrs["schema"].decode() == "crowdrom-romrun"
        q_fom = d["train/positions"][...]
        for k in range(1, len(settings) + 1):
            g = f["setting_%d/train" % k]
            e = g["E_mu"][...]
            assert e.shape == (6,)
            assert e.max() <= 1e-8, (k, e)
            np.testing.assert_allclose(g["positions"][...], q_fom, atol=1e-9)
            assert g["max_overlap"][...].max() <= 1e-9
            assert np.all(g["n_infeasible"][...] == 0) and np.all(g["n_capped"][...] == 0)
            assert g["alpha"].shape == (6 * 12, f["setting_%d" % k].attrs["n_basis"])
    rows = list(csv.DictReader(open(tmp / "full.csv")))
    assert len(rows) == 4 and all(float(r_["E_avg"]) <= 1e-8 for r_ in rows)
    assert all(float(r_["t_step_fom_uzawa"]) > 0 and float(r_["speedup_exact"]) > 0 for r_ in rows)
    # the cost of one whole query (setup + trajectory) is at least the trajectory's steps
    with h5py.File(out, "r") as f:
        n_steps = int(f.attrs["n_steps"])
        t_query_h5 = f["table/t_query_rom"][...]
    for j, r_ in enumerate(rows):
        for col in ("t_query_rom", "t_query_fom_exact", "speedup_query_exact"):
            assert float(r_[col]) > 0, (col, r_[col])
        assert float(r_["t_query_rom"]) >= n_steps * float(r_["t_step_rom"])
        assert float(r_["t_query_fom_exact"]) >= n_steps * float(r_["t_step_fom_exact"])
        np.testing.assert_allclose(float(r_["t_query_rom"]), t_query_h5[j], rtol=1e-5)


def test_small_rom_reports(study):
    tmp, db, rom, n, r = study
    # the shape of the congested150 sweep: EQ, online contacts, exact and EIM (paper's default m)
    settings = [dict(n=4, r=3, hyper="'eq'"), dict(n=4, r=3, hyper="'none'", contacts="'online'"),
                dict(n=4, r=3, hyper="'none'"), dict(n=4, r=3, hyper="'eim'")]
    out = tmp / "small.h5"
    p = run(0, "crowd_rom", rom_input(tmp, "small.nml", rom, out, settings, sets="'both'", solver="'nnls'"), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "| setting | set |" in p.stdout
    rows = list(csv.DictReader(open(tmp / "small.csv")))
    assert len(rows) == 8
    for r_ in rows:
        n_s = 6 if r_["set"] == "train" else 3
        div = int(r_["samples_diverged"])
        assert 0 <= div <= n_s
        for t in ("t50", "t90"):    # every kept sample is in exactly one class
            assert int(r_[t + "_n"]) + int(r_[t + "_rom_missed"]) + int(r_[t + "_fom_missed"]) == n_s - div
        if div < n_s:
            assert float(r_["E_disp"]) >= 0 and float(r_["E_avg"]) >= 0
            assert float(r_["max_overlap"]) == max(float(r_["max_overlap_agents"]), float(r_["max_overlap_walls"]))
    with h5py.File(out, "r") as f:
        for k in (1, 2, 3):
            for s in ("train", "valid"):
                g = f["setting_%d/%s" % (k, s)]
                for name in ("E_mu", "E_proj", "max_overlap", "time"):
                    x = g[name][...]
                    assert np.all(np.isfinite(x)) and np.all(x >= 0), name
                assert g["err_time"][...][:, 0].max() == 0.0   # same initial positions
            assert f["setting_%d" % k].attrs["speedup_uzawa"] > 0
        # the exact projection and EQ with the default R points of the same pair agree
        np.testing.assert_allclose(f["setting_1/valid/positions"][...], f["setting_3/valid/positions"][...],
                                   atol=1e-8)
        # 'online' enforces every near contact: no overlap deeper than round-off
        assert f["setting_2/valid/max_overlap"][...].max() <= 1e-9


def test_local_correction_full_basis_reproduces_fom(study):
    """With full bases the reduced step is the full model's, the local correction finds
    (up to round-off) nothing to correct, and the carried positions are the full model's."""
    tmp, db, rom, n, r = study
    settings = [dict(n=n, r=r, hyper="'none'", correction="'local'"),
                dict(n=n, r=r, hyper="'eq'", correction="'local'")]
    out = tmp / "full_local.h5"
    p = run(0, "crowd_rom", rom_input(tmp, "full_local.nml", rom, out, settings, sets="'train'"), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(out, "r") as f, h5py.File(db, "r") as d:
        q_fom = d["train/positions"][...]
        for k in (1, 2):
            g = f["setting_%d/train" % k]
            assert f["setting_%d" % k].attrs["correction"].decode() == "local"
            assert g["E_mu"][...].max() <= 1e-8
            np.testing.assert_allclose(g["positions"][...], q_fom, atol=1e-8)
            assert g["n_corrected"].shape == (6, 12)
            assert np.all(g["t_correct"][...] >= 0)
    rows = list(csv.DictReader(open(tmp / "full_local.csv")))
    assert [r_["correction"] for r_ in rows] == ["local", "local"]
    for r_ in rows:
        assert 0 <= float(r_["corrected_fraction"]) <= float(r_["corrected_fraction_max"]) <= 1
        assert 0 <= float(r_["t_correct_step"]) <= float(r_["t_step_rom"])
        assert r_["fom_exact_solver"] in ("sparse_active_set", "active_set")


def test_local_correction_small_basis_no_overlap(study):
    """Any basis: after the local exact correction no agent overlaps another or a wall beyond
    the exact solver's accuracy (scaled KKT tol 1e-10: a linearised gap >= -tol h s with
    s <= 2 max|u| ~ 4 m/s here, i.e. ~1e-11 m; the true gap is above the linearised one)."""
    tmp, db, rom, n, r = study
    settings = [dict(n=4, r=3, hyper="'eq'", correction="'local'"),
                dict(n=4, r=3, hyper="'none'", correction="'local'"),
                dict(n=4, r=3, hyper="'eim'", correction="'local'"),
                dict(n=4, r=3, hyper="'eq'")]
    out = tmp / "small_local.h5"
    summary = tmp / "small_local.json"
    nml = rom_input(tmp, "small_local.nml", rom, out, settings, sets="'both'")
    p = subprocess.run([os.path.join(BIN, "crowd_rom"), str(nml), "--summary", str(summary)], cwd=tmp,
                       capture_output=True, text=True, env=ENV)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = list(csv.DictReader(open(tmp / "small_local.csv")))
    assert len(rows) == 8
    for r_ in rows:
        # every corrected step is solved to the tolerance here (the column counts those that are not)
        assert int(r_["correction_unsolved_steps"]) == 0
        if r_["correction"] == "local":
            assert int(r_["samples_diverged"]) == 0
            assert float(r_["max_overlap_agents"]) <= 1e-10 and float(r_["max_overlap_walls"]) <= 1e-10, r_
        else:
            assert r_["correction"] == "none" and float(r_["corrected_fraction"]) == 0
    with h5py.File(out, "r") as f:
        for k in (1, 2, 3):
            for s in ("train", "valid"):
                g = f["setting_%d/%s" % (k, s)]
                assert g["max_overlap"][...].max() <= 1e-10
                nc = g["n_corrected"][...]
                assert nc.min() >= 0 and nc.max() <= int(f.attrs["n_agents"])
        assert "n_corrected" not in f["setting_4/valid"]
        np.testing.assert_allclose(f["table/corrected_fraction"][...], [float(r_["corrected_fraction"]) for r_ in rows],
                                   rtol=1e-5)
    # the Python reader mirrors the new attributes and datasets
    sys.path.insert(0, os.path.join(ROOT, "scripts"))
    import crowdrom_io as cio
    with cio.open_h5(out, cio.ROMRUN_SCHEMA, "ROM run file") as f:
        meta = cio.romrun_meta(f)
        assert meta["exact_solver_asked"] == "fastest" and meta["exact_solver"] in meta["exact_solver_timings"]
        assert [cio.romrun_setting(f, k)["correction"] for k in (1, 4)] == ["local", "none"]
        rs = cio.romrun_set(f, 1, "valid", meta["n_steps"], 2 * meta["n_agents"])
        assert rs["n_corrected"].shape == (3, meta["n_steps"]) and rs["t_correct"].shape == (3,)
        assert "n_corrected" not in cio.romrun_set(f, 4, "valid", meta["n_steps"], 2 * meta["n_agents"])
    js = json.load(open(summary))
    assert js["rows"]["correction_local"] == [1, 1, 1, 1, 1, 1, 0, 0]
    assert js["rows"]["correction_unsolved_steps"] == [0] * 8 and js["correction_unsolved_steps"] == 0
    assert js["fom_exact_solver"] in ("sparse_active_set", "active_set") and js["fom_exact_solver_asked"] == "fastest"
    np.testing.assert_allclose(js["rows"]["corrected_fraction"], [float(r_["corrected_fraction"]) for r_ in rows],
                               rtol=1e-5)


def test_uzawa_reduced_solver(study):
    tmp, db, rom, n, r = study
    out = tmp / "uz.h5"
    nml = rom_input(tmp, "uz.nml", rom, out, [dict(n=n, r=r, hyper="'none'")], sets="'train'", solver="'uzawa'",
                    uzawa_eps="1e-14", n_samples="2")
    p = run(0, "crowd_rom", nml, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(out, "r") as f:
        assert f["setting_1/train/E_mu"][...].max() <= 1e-5


def test_given_parameter_extrapolates(study):
    tmp, db, rom, n, r = study
    out = tmp / "given.h5"
    mu = ", ".join(["0.3"] + ["1.0"] * 8)           # l_exit 0.3 is outside [0.18, 0.22]
    nml = rom_input(tmp, "given.nml", rom, out, [dict(n=4, r=3, hyper="'eq'")], sets="'given'", mu=mu)
    p = run(0, "crowd_rom", nml, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "outside the training box" in p.stdout + p.stderr
    with h5py.File(out, "r") as f:
        g = f["setting_1/given"]
        assert g["extrapolating"][...].tolist() == [1]
        assert g["E_mu"][...].tolist() == [-1.0]        # no full-order reference
        assert np.all(np.isfinite(g["positions"][...]))


@pytest.mark.parametrize("case,message", [
    ("missing_rom", r"&rom: rom_file '.*missing\.h5': cannot open"),
    ("other_study", r"was built from another study"),
    ("not_prepared", r"\(N, R\) = \(5, 2\) is not prepared in ROM file"),
    ("m_too_large", r"m_b = 1000 is larger than the \d+ EQ candidates"),
    ("bad_hyper", r"&sweep: hyper\(1\) must be one of none, eim, eq, eq_deim"),
    ("bad_correction", r"&sweep: correction\(1\) must be 'none' or 'local' \(got 'global'\)"),
    ("bad_sets", r"&sweep: sets\(1\) must be '' or one of the sets of &rom sets = 'valid' \(got 'train'\)"),
    ("bad_exact_solver", r"&fom_timing: exact_solver must be 'fastest', .*\(got 'uzawa'\)"),
    ("misspelt", r"namelist group &rom"),
    ("misplaced", r"namelist group &rom: .*solver"),
    ("unread_group", r"unknown namelist group &basis"),
    ("unread_variable", r"namelist group &hyper: .*eq_toll"),
    ("no_rom_group", r"namelist group &rom is missing"),
    ("parallel", r"crowd_rom is serial"),
])
def test_bad_input(study, case, message):
    tmp, db, rom, n, r = study
    out = tmp / ("bad_%s.h5" % case)
    setting = [dict(n=4, r=3, hyper="'eq'")]
    kw = {}
    np_ = 0
    if case == "missing_rom":
        rom = tmp / "missing.h5"
    elif case == "other_study":
        db2 = tmp / "other.h5"
        s2 = study_file(tmp, "other.nml", db2, seed=8)
        p = run(1, "crowd_snapshots", s2, tmp)
        assert p.returncode == 0, p.stdout + p.stderr
        kw["database"] = "'%s'" % db2
    elif case == "not_prepared":
        setting = [dict(n=5, r=2)]
    elif case == "m_too_large":
        setting = [dict(n=4, r=3, hyper="'eq'", m_b=1000)]
    elif case == "bad_hyper":
        setting = [dict(n=4, r=3, hyper="'deim'")]
    elif case == "bad_correction":
        setting = [dict(n=4, r=3, hyper="'eq'", correction="'global'")]
    elif case == "bad_sets":
        setting = [dict(n=4, r=3, hyper="'eq'", setting_sets="'train'")]
    elif case == "bad_exact_solver":
        kw["fom_exact_solver"] = "'uzawa'"
    elif case == "parallel":
        np_ = 2
    nml = rom_input(tmp, "bad_%s.nml" % case, rom, out, setting, **kw)
    if case == "misspelt":
        nml.write_text(nml.read_text().replace("timing_repeats", "timing_repeat"))
    if case == "misplaced":     # a variable of &reduced given in &rom
        nml.write_text(nml.read_text().replace("&rom ", "&rom solver = 'nnls', "))
    if case == "unread_group":  # a group no program reads
        nml.write_text(nml.read_text() + "&basis n = 3 /\n")
    if case == "unread_variable":  # a variable crowd_offline's &hyper does not have, seen by crowd_rom too
        nml.write_text(nml.read_text() + "&hyper eq_toll = 1e-3 /\n")
    if case == "no_rom_group":
        nml.write_text("&scene l_exit = 0.2 /\n")
    p = run(np_, "crowd_rom", nml, tmp)
    assert p.returncode != 0
    err = [l for l in (p.stdout + p.stderr).splitlines() if l.startswith("error:")]
    assert len(err) >= 1 and re.search(message, err[0]), p.stdout + p.stderr
    assert not out.exists() and not os.path.exists(str(out) + ".partial")
