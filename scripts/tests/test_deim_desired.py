"""The reader of the stored DEIM of the desired velocity (crowdrom_io.read_rom_pair_vdeim) and
scripts/post/deim_desired_accuracy.py on small synthetic files: with every mode and dof the reduced
vhat is exact (round-off), with fewer modes the reported error obeys the DEIM bound, and a
corrupt index is refused with one line (exit 2)."""
import os
import sys

import h5py
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import crowdrom_io as cio  # noqa: E402
import deim_desired_accuracy as dda  # noqa: E402

NA, NT, NS, NB = 6, 4, 5, 5


def _files(tmp, bad_index=False):
    rng = np.random.default_rng(3)
    nd = 2 * NA
    # desired velocities of the validation set, Fortran [n_dof, NT NS] seen by h5py as (NT NS, n_dof)
    desired = rng.standard_normal((NT * NS, nd))
    u, _, _ = np.linalg.svd(desired.T, full_matrices=False)   # [n_dof, n_dof]: every mode
    # DEIM indices (greedy)
    idx = [int(np.argmax(np.abs(u[:, 0])))]
    for k in range(1, nd):
        c = np.linalg.solve(u[idx, :k], u[idx, k])
        r = u[:, k] - u[:, :k] @ c
        idx.append(int(np.argmax(np.abs(r))))
    v, _ = np.linalg.qr(rng.standard_normal((nd, NB)))
    rom = os.path.join(tmp, "rom.h5")
    with h5py.File(rom, "w") as f:
        f.attrs["schema"] = "crowdrom-rom"
        f.attrs["schema_version"] = 2
        g = f.create_group("pairs/1")
        for k, x in (("n", 3), ("r", 0), ("n_pga", 2), ("n_basis", NB)):
            g.attrs[k] = x
        g["v"] = v.T
        d = g.create_group("eq/v_deim")
        d.attrs["p"] = nd
        d.attrs["m"] = nd
        d["basis"] = u.T
        ind = np.array(idx) + 1
        if bad_index:
            ind[2] = nd + 1
        d["indices"] = ind.astype(np.int32)
        d["err"] = np.zeros(nd)
    db = os.path.join(tmp, "db.h5")
    with h5py.File(db, "w") as f:
        f.attrs["schema"] = "crowdrom-snapshots"
        f.attrs["schema_version"] = 1
        f.attrs["n_agents"] = NA
        f.attrs["n_steps"] = NT
        f.attrs["dt"] = 0.1
        f.attrs["agent_radius"] = 0.01
        f["valid/params"] = rng.random((NS, 1))
        f["valid/desired"] = desired
        cio.stamp_checksums(f)          # as crowd_snapshots writes every dataset
    return rom, db, desired, u, np.array(idx), v


def test_reader_and_accuracy(tmp_path, capsys):
    rom, db, desired, u, idx, v = _files(str(tmp_path))
    with cio.open_h5(rom, "crowdrom-rom") as f:
        d = cio.read_rom_pair_vdeim(f, 1)
    assert np.array_equal(d["U"], u) and np.array_equal(d["indices"], idx + 1)
    assert dda.main([rom, db, "--m", str(2 * NA), "4"]) == 0
    out = capsys.readouterr().out
    rows = {int(line.split("|")[1]): line for line in out.splitlines() if line.startswith("| ") and "m_v" not in line}
    # every mode and dof: exact to round-off
    full = rows[2 * NA].split("|")
    assert float(full[3].split("/")[1]) < 1e-12
    # m = 4: the oversampled DEIM error obeys |V^T (v - U (U_P)^+ v_P)| <= |(U_P)^+| |(I - U U^T) v|
    agents = np.unique(idx[:4] // 2)
    p = np.ravel(np.column_stack([2 * agents, 2 * agents + 1]))
    u4 = u[:, :4]
    smin = np.linalg.svd(u4[p, :], compute_uv=False)[-1]
    ref = desired @ v
    bound = np.linalg.norm(desired - desired @ u4 @ u4.T, axis=1) / smin / np.linalg.norm(ref, axis=1)
    got_max = float(rows[4].split("|")[3].split("/")[1])
    assert 0 < got_max <= bound.max() * (1 + 1e-2)   # printed with 3 digits
    assert int(rows[4].split("|")[2]) == len(agents)


def test_bad_index_refused(tmp_path, capsys):
    rom, db, *_ = _files(str(tmp_path), bad_index=True)
    assert dda.main.__name__ == "main"
    assert cio.one_line_errors("deim_desired_accuracy", dda.main, [rom, db]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "eq/v_deim/indices" in err


def test_no_vdeim(tmp_path):
    rom, db, *_ = _files(str(tmp_path))
    with h5py.File(rom, "a") as f:
        del f["pairs/1/eq/v_deim"]
    with cio.open_h5(rom, "crowdrom-rom") as f:
        assert cio.read_rom_pair_vdeim(f, 1) is None
