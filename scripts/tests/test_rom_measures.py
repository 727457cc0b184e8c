"""crowd_rom's accuracy measures on a synthetic study with a known answer: six agents in a
column under the exit centre walk straight up and out at the sample's common speed c (no
contact is ever active), so agent i is out at step nu_i = floor((y_out - y0_i) / (c h)) + 1 and
the times at which 50% and 90% of the crowd are out are known in closed form. The reduced model
with the full basis reproduces the walk: the evacuation curves, the times, the new table columns
(CSV, HDF5 table, JSON summary) and the per-sample datasets are checked against the closed form."""
import csv
import json
import math
import os

import subprocess

import h5py
import numpy as np

from test_rom import BIN, ENV, run, offline, rom_input

N, R_AG, H, NT = 6, 0.02, 0.02, 40
Y0 = [0.053 + 0.07 * i for i in range(N)]
Y_OUT = 0.5 + 0.05 + R_AG          # hall width + wall + radius


def study(tmp):
    (tmp / "col.txt").write_text("".join("0.3 %.3f\n" % y for y in Y0))
    db = tmp / "col.h5"
    text = """&scene hall_length = 0.6, hall_width = 0.5, l_exit = 0.2, wall_thickness = 0.05 /
&agents n_agents = %d, radius = %g, speed = 1.0, init = 'file', init_file = '%s' /
&time dt = %g, n_steps = %d /
&output log_level = 'info' /
&study n_params = 1, param_name = 'speed', param_min = 0.9, param_max = 1.1,
  sampling = 'random', n_train = 4, n_valid = 3, seed = 5, database = '%s' /
""" % (N, R_AG, tmp / "col.txt", H, NT, db)
    path = tmp / "col.nml"
    path.write_text(text)
    return path, db


def t_closed(c, pct):
    """Time at which pct % of the agents are out (-1 after the horizon)."""
    k = math.ceil(pct * N / 100)
    nu = sorted(math.floor((Y_OUT - y) / (c * H)) + 1 for y in Y0)[k - 1]
    return nu * H if nu <= NT else -1.0


def test_straight_walk_measures(tmp_path):
    sfile, db = study(tmp_path)
    p = run(1, "crowd_snapshots", sfile, tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp_path, sfile, db, tmp_path / "col_rom.h5")
    with h5py.File(rom, "r") as f:
        n, r = int(f["pairs/1"].attrs["n"]), int(f["pairs/1"].attrs["r"])
    out = tmp_path / "col_run.h5"
    summary = tmp_path / "col.json"
    nml = rom_input(tmp_path, "col_rom.nml", rom, out, [dict(n=n, r=r, hyper="'none'")], sets="'both'")
    p = subprocess.run([os.path.join(BIN, "crowd_rom"), str(nml), "--summary", str(summary)], cwd=tmp_path,
                       capture_output=True, text=True, env=ENV)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = list(csv.DictReader(open(tmp_path / "col_run.csv")))
    js = json.load(open(summary))
    # the whole-query costs: the same figures in the CSV, the HDF5 table and the JSON rows
    with h5py.File(out, "r") as f:
        for col in ("t_query_rom", "t_query_fom_exact", "speedup_query_exact"):
            h5col = f["table/" + col][...]
            assert len(h5col) == len(rows) == len(js["rows"][col])
            for j, r_ in enumerate(rows):
                assert float(r_[col]) > 0
                np.testing.assert_allclose([float(r_[col]), js["rows"][col][j]], h5col[j], rtol=1e-5)
        for j, r_ in enumerate(rows):
            assert float(r_["t_query_rom"]) >= NT * float(r_["t_step_rom"])
    with h5py.File(out, "r") as f:
        for s in ("train", "valid"):
            g = f["setting_1/%s" % s]
            speeds = g["params"][...][:, 0]
            t_fom, t_rom = g["t_out_fom"][...], g["t_out_rom"][...]      # [n_S, 2]
            ev_fom, ev_rom = g["evac_fom"][...], g["evac_rom"][...]      # [n_S, N_T + 1]
            assert t_fom.shape == (len(speeds), 2) and ev_fom.shape == (len(speeds), NT + 1)
            for k, c in enumerate(speeds):
                assert t_closed(c, 50) > 0 and t_closed(c, 90) > 0
                assert abs(t_fom[k, 0] - t_closed(c, 50)) < 1e-12, (c, t_fom[k], t_closed(c, 50))
                assert abs(t_fom[k, 1] - t_closed(c, 90)) < 1e-12
                np.testing.assert_array_equal(t_rom[k], t_fom[k])
                out_at = [sum(1 for y in Y0 if math.floor((Y_OUT - y) / (c * H)) + 1 <= nu) for nu in range(NT + 1)]
                assert ev_fom[k].tolist() == out_at and ev_rom[k].tolist() == out_at
            assert np.all(g["E_disp"][...] <= 1e-8) and np.all(g["diverged_step"][...] == 0)
            assert np.all(g["max_overlap_agents"][...] == 0) and np.all(g["max_overlap_walls"][...] == 0)
            row = [x for x in rows if x["set"] == s][0]
            assert float(row["t50_err"]) <= 1e-12 and int(row["t50_n"]) == len(speeds)
            assert float(row["t90_err"]) <= 1e-12 and int(row["t90_n"]) == len(speeds)
            for col in ("t50_rom_missed", "t50_fom_missed", "t90_rom_missed", "t90_fom_missed", "samples_diverged"):
                assert int(row[col]) == 0, col
            assert float(row["E_disp"]) <= 1e-8 and abs(float(row["mobility"]) - 1) <= 1e-8
            assert float(row["max_overlap_agents"]) == 0 and float(row["max_overlap_walls"]) == 0
        tab = f["table"]
        assert tab["t50_n"][...].tolist() == [4, 3] and tab["samples_diverged"][...].tolist() == [0, 0]
    assert js["rows"]["t90_n"] == [4, 3] and js["samples_diverged"] == 0
    assert max(js["rows"]["E_disp"]) <= 1e-8


def test_local_correction_without_conflict_changes_nothing(tmp_path):
    """The straight walk has no contact: the local exact correction finds no conflict, corrects
    no agent, and the positions it carries in full are the uncorrected reduced ones (to the
    round-off of summing the steps in another order: 40 steps of O(1) m)."""
    sfile, db = study(tmp_path)
    p = run(1, "crowd_snapshots", sfile, tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp_path, sfile, db, tmp_path / "col_rom.h5")
    with h5py.File(rom, "r") as f:
        n, r = int(f["pairs/1"].attrs["n"]), int(f["pairs/1"].attrs["r"])
    out = tmp_path / "col_local.h5"
    settings = [dict(n=n, r=r, hyper="'none'"), dict(n=n, r=r, hyper="'none'", correction="'local'")]
    p = run(0, "crowd_rom", rom_input(tmp_path, "col_local.nml", rom, out, settings, sets="'valid'"), tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = list(csv.DictReader(open(tmp_path / "col_local.csv")))
    assert [x["correction"] for x in rows] == ["none", "local"]
    assert float(rows[1]["corrected_fraction"]) == 0 and float(rows[1]["corrected_fraction_max"]) == 0
    with h5py.File(out, "r") as f:
        a, b = f["setting_1/valid"], f["setting_2/valid"]
        assert np.all(b["n_corrected"][...] == 0)
        np.testing.assert_allclose(b["positions"][...], a["positions"][...], rtol=0, atol=1e-13)
        np.testing.assert_allclose(b["alpha"][...], a["alpha"][...], rtol=0, atol=1e-10)
        np.testing.assert_array_equal(b["evac_rom"][...], a["evac_rom"][...])
