"""The quantities of interest the programs store equal those recomputed here, independently, in
numpy from the stored positions (the definitions of docs/queries.md, not crowdrom_io's code):
crowd_snapshots' per-sample QoI groups (at 1 and 2 ranks, identical), crowd_fom's QoI group;
integers and times exactly, flows and displacements to round-off. The QoI product's reader
refuses another schema version and an edited dataset."""
import os
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import crowdrom_io  # noqa: E402
from test_rom import BIN, ENV, ROOT, STUDY, offline, rom_input, run  # noqa: E402

N_STEPS = 40


def study_text(db):
    text = open(STUDY).read().replace("database = 'rom_tiny.h5'", "database = '%s'" % db)
    return re.sub(r"n_steps = \d+", "n_steps = %d" % N_STEPS, text)


def ceil_pct(p, n):
    return -(-p * n // 100)


def qoi_numpy(pos, h, y_line, width):
    """pos [N_T + 1, n_agents, 2]; one exit (the top wall) at y > y_line."""
    nf, na = pos.shape[0], pos.shape[1]
    beyond = pos[:, :, 1] > y_line
    first = np.where(beyond.any(axis=0), beyond.argmax(axis=0), nf)
    curve = np.array([(first <= c).sum() for c in range(nf)])
    times, cens = [], []
    for p in (50, 90, 100):
        hit = np.flatnonzero(curve >= ceil_pct(p, na))
        times.append(hit[0] * h if hit.size else (nf - 1) * h)
        cens.append(hit.size == 0)
    f = curve[-1]
    rate, defined = 0.0, False
    if f > 0:
        c1 = np.flatnonzero(curve >= ceil_pct(10, f))[0]
        c2 = np.flatnonzero(curve >= ceil_pct(80, f))[0]
        if c2 - c1 + 1 >= 3:
            t = np.arange(c1, c2 + 1) * h
            rate, defined = np.polyfit(t, curve[c1:c2 + 1].astype(float), 1)[0], True
    disp = np.linalg.norm((pos[-1] - pos[0]).ravel())
    return dict(curve=curve, t_evac=np.array(times), censored=np.array(cens), flow_rate=rate,
                flow=rate / width if defined else 0.0, flow_defined=defined, displacement=disp)


def check_row(got, k, want, what):
    assert np.array_equal(got["curve"][k, 0], want["curve"]), what
    assert np.array_equal(got["curve_total"][k], want["curve"]), what
    assert np.array_equal(got["t_evac"][k], want["t_evac"]), (what, got["t_evac"][k], want["t_evac"])
    assert np.array_equal(got["censored"][k], want["censored"]), what
    assert got["flow_defined"][k, 0] == want["flow_defined"], what
    np.testing.assert_allclose(got["flow_rate"][k, 0], want["flow_rate"], rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(got["flow"][k, 0], want["flow"], rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(got["displacement"][k], want["displacement"], rtol=1e-13)


@pytest.fixture(scope="module")
def databases(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("qoi")
    out = []
    for np_ in (1, 2):
        db = tmp / ("db%d.h5" % np_)
        nml = tmp / ("study%d.nml" % np_)
        nml.write_text(study_text(db))
        p = run(np_, "crowd_snapshots", nml, tmp)
        assert p.returncode == 0, p.stdout + p.stderr
        out.append(db)
    return tmp, out


def test_snapshot_qoi_equal_independent(databases):
    tmp, (db1, db2) = databases
    with h5py.File(db1, "r") as f:
        r, h = float(f.attrs["agent_radius"]), float(f.attrs["dt"])
        y_line = float(f["scene"].attrs["hall_width"]) + float(f["scene"].attrs["wall_thickness"]) + r
        reached = 0
        for s in ("train", "valid"):
            got = crowdrom_io.read_qoi_group(f, s + "/qoi")
            pos = f[s + "/positions"][...]                       # [n_S (N_T + 1), n_dof]
            ex = f[s + "/scene_exit"][...]                       # [n_S, 4]: x_lo, y, x_hi, y
            n = ex.shape[0]
            assert got["n_rows"] == n and got["n_steps"] == N_STEPS and got["n_exits"] == 1
            pos = pos.reshape(n, N_STEPS + 1, -1, 2)
            for k in range(n):
                want = qoi_numpy(pos[k], h, y_line, ex[k, 2] - ex[k, 0])
                check_row(got, k, want, "%s sample %d" % (s, k + 1))
                np.testing.assert_allclose(got["exit_width"][k, 0], ex[k, 2] - ex[k, 0], rtol=1e-15)
                reached += int(not want["censored"][0]) + int(want["flow_defined"])
        assert reached > 0, "the study reaches t50 or a defined flow somewhere (the check is not empty)"
    with h5py.File(db1, "r") as a, h5py.File(db2, "r") as b:
        for s in ("train", "valid"):
            ga, gb = crowdrom_io.read_qoi_group(a, s + "/qoi"), crowdrom_io.read_qoi_group(b, s + "/qoi")
            for key in ga:
                assert np.array_equal(np.asarray(ga[key]), np.asarray(gb[key])), (s, key)


def test_fom_qoi_equal_independent(tmp_path):
    text = open(os.path.join(ROOT, "inputs", "hall20.nml")).read()
    text = text.replace("results/hall20_fom.h5", str(tmp_path / "fom.h5"))
    (tmp_path / "fom.nml").write_text(text)
    p = run(0, "crowd_fom", tmp_path / "fom.nml", tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    fom = crowdrom_io.read_fom(tmp_path / "fom.h5")
    with h5py.File(tmp_path / "fom.h5", "r") as f:
        got = crowdrom_io.read_qoi_group(f, "qoi")
        sc = f["scene"].attrs
        y_line = float(sc["hall_width"]) + float(sc["wall_thickness"]) + fom["radius"]
        pos = f["traj/positions"][...].reshape(f["traj/positions"].shape[0], -1, 2)
        h = float(f.attrs["dt"])
        assert np.array_equal(f["traj/step"][...], np.arange(pos.shape[0])), "every step stored"
        want = qoi_numpy(pos, h, y_line, float(sc["l_exit"]))
    assert got["n_rows"] == 1 and not want["censored"][0] and want["flow_defined"]
    check_row(got, 0, want, "crowd_fom")
    assert got["n_through"][0] == 0


def test_product_reader_refuses(tmp_path):
    exe = os.path.join(os.path.dirname(BIN), "tests", "test_qoi_file")
    p = subprocess.run([exe, str(tmp_path)], cwd=tmp_path, capture_output=True, text=True, env=ENV)
    assert p.returncode == 0, p.stdout + p.stderr
    path = tmp_path / "qoi_keep.h5"
    d = crowdrom_io.read_qoi(path)
    assert d["n_queries"] == 3 and d["model"] == "rom setting 2" and d["param_names"] == ["l_exit", "speed"]
    assert d["curve"].shape == (3, 2, 31) and d["t_evac"].shape == (3, 3) and d["censored"].dtype == bool
    assert d["outside_box"].tolist() == [False, False, True]
    with h5py.File(path, "r+") as f:
        f["qoi/t_evac"][0, 0] += 0.5
    with pytest.raises(crowdrom_io.InputError, match="checksum mismatch in dataset 'qoi/t_evac'"):
        crowdrom_io.read_qoi(path)
    with h5py.File(path, "r+") as f:
        f.attrs["schema_version"] = np.int32(2)
    with pytest.raises(crowdrom_io.InputError, match="schema version 2 is not supported"):
        crowdrom_io.read_qoi(path)


def test_sweep_qoi_equal_independent(databases):
    """crowd_rom stores each setting's per-sample QoIs: equal to the numpy recomputation from the
    reduced positions it stores, and its evacuation columns are made of them."""
    tmp, (db1, _) = databases
    nml = tmp / "study1.nml"
    rom = offline(tmp, nml, db1, tmp / "rom.h5")
    with h5py.File(rom, "r") as f:
        n, r = int(f["pairs/1"].attrs["n"]), int(f["pairs/1"].attrs["r"])
    out = tmp / "run.h5"
    settings = [dict(n=n, r=r, hyper="'eq'")]
    p = run(0, "crowd_rom", rom_input(tmp, "rom.nml", rom, out, settings, sets="'both'"), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(db1, "r") as d:
        h = float(d.attrs["dt"])
        y_line = float(d["scene"].attrs["hall_width"]) + float(d["scene"].attrs["wall_thickness"]) + \
            float(d.attrs["agent_radius"])
        exits = {s: d[s + "/scene_exit"][...] for s in ("train", "valid")}
    with h5py.File(out, "r") as f:
        meta = crowdrom_io.romrun_meta(f)
        for s in ("train", "valid"):
            d = crowdrom_io.romrun_set(f, 1, s, meta["n_steps"], 2 * meta["n_agents"])
            got = d["qoi"]
            for k in range(got["n_rows"]):
                pos = d["positions"][k].reshape(N_STEPS + 1, -1, 2)
                want = qoi_numpy(pos, h, y_line, exits[s][k, 2] - exits[s][k, 0])
                check_row(got, k, want, "sweep %s sample %d" % (s, k + 1))
            assert np.array_equal(d["evac_rom"], got["curve_total"])
            assert np.array_equal(d["t_out_rom"], np.where(got["censored"], -1.0, got["t_evac"])[:, :2])
