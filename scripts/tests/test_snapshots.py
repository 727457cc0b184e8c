"""crowd_snapshots on the tiny study (serial singleton run), read back with h5py: schema,
metadata, shapes (h5py shows the Fortran shapes reversed), sparse multipliers and the global
contact dictionary."""
import json
import os
import subprocess

import h5py
import numpy as np

ROOT = os.environ.get("CROWDROM_ROOT", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BIN = os.environ.get("CROWDROM_BIN", os.path.join(ROOT, "build", "bin"))
INPUT = os.path.join(ROOT, "tests", "inputs", "snap_tiny.nml")


def test_snapshot_database(tmp_path):
    r = subprocess.run([os.path.join(BIN, "crowd_snapshots"), INPUT, "--summary", "s.json"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["samples_total"] == 9 and summary["samples_computed"] == 9
    with h5py.File(tmp_path / "snap_tiny.h5", "r") as f:
        a = f.attrs
        assert a["schema"].decode() == "crowdrom-snapshots" and a["schema_version"] == 2
        assert a["complete"] == 1
        na, ns = int(a["n_agents"]), int(a["n_steps"])
        assert (na, ns) == (8, 10)
        assert a["dt"] == 0.02 and a["agent_radius"] == 0.04
        names = a["param_names"].decode().split(",")
        assert names == ["l_exit"] + [f"speed_{i}" for i in range(1, 9)]
        assert int(a["n_params"]) == len(names)
        assert "&study" in a["config"].decode() and "&study" in a["input_text"].decode()
        assert len(a["config_hash"].decode()) == 16
        for key in ("units", "version", "hdf5_version", "mpi_version", "compiler"):
            assert len(a[key].decode()) > 0
        q0 = f["initial_positions"][...]
        assert q0.shape == (2 * na,)
        key = f["contacts/key"][...]
        nd = key.size
        assert nd > 0 and np.all(np.diff(key) > 0), "dictionary sorted by key, no duplicates"
        ia, ib, ob = f["contacts/ia"][...], f["contacts/ib"][...], f["contacts/ob"][...]
        assert np.all((ib == 0) == (ob > 0)) and np.all(ia >= 1) and np.all(ia <= na)
        for s, n in (("train", 6), ("valid", 3)):
            g = f[s]
            mu = g["params"][...]
            assert mu.shape == (n, len(names))
            assert np.all(mu[:, 0] >= 0.18) and np.all(mu[:, 0] <= 0.22)
            assert np.all(mu[:, 1:] >= 0.9) and np.all(mu[:, 1:] <= 1.1)
            pos = g["positions"][...]
            assert pos.shape == (n * (ns + 1), 2 * na)
            for k in range(n):
                assert np.array_equal(pos[k * (ns + 1)], q0), "every sample starts from q0"
            for d in ("velocities", "desired"):
                assert g[d].shape == (n * ns, 2 * na)
            # q^nu = q^{nu-1} + dt u^nu
            u = g["velocities"][...]
            for k in range(n):
                qk = pos[k * (ns + 1):(k + 1) * (ns + 1)]
                assert np.allclose(qk[1:] - qk[:-1], 0.02 * u[k * ns:(k + 1) * ns], atol=1e-14)
            off = g["lambda_offset"][...]
            assert off.shape == (n * ns + 1,) and off[0] == 0 and np.all(np.diff(off) >= 0)
            idx, val = g["lambda_index"][...], g["lambda_value"][...]
            assert idx.shape == val.shape == (off[-1],)
            assert np.all(idx >= 1) and np.all(idx <= nd) and np.all(val > 0)
            for st in ("kkt", "iterations", "converged", "n_active", "min_gap"):
                assert g["stats/" + st].shape == (n, ns)
            assert g["stats/time"].shape == (n,) and g["stats/rank"].shape == (n,)
            assert np.array_equal(np.diff(off).reshape(n, ns), g["stats/n_active"][...])
        assert not np.any(np.all(f["valid/params"][...][:, None, :] == f["train/params"][...][None], axis=2))
