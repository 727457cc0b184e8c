"""Checksums verified wherever data is read: the digest of crowdrom_io equals the Fortran one
(cr_digest) on a database crowd_snapshots wrote (every dataset's checksum and every entry of the
per-sample block tables); a dataset scaled by 1.001 with its checksum left stale is refused by the
Python readers (whole and partial reads) and by crowd_rom reading only some samples; a version 1
database (no block table) is refused for a partial read and read whole."""
import os
import shutil
import sys

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)
import crowdrom_io as cio  # noqa: E402
from test_rom import BIN, offline, rom_input, run, study_file  # noqa: E402

pytestmark = pytest.mark.skipif(not os.path.exists(os.path.join(BIN, "crowd_snapshots")),
                                reason="needs the Fortran build")


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("checksums")
    db = tmp / "db.h5"
    p = run(1, "crowd_snapshots", study_file(tmp, "study.nml", db), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp, tmp / "study.nml", db, tmp / "rom.h5")
    return tmp, db, rom


def _copy(src, tmp, name):
    dst = tmp / name
    shutil.copy(src, dst)
    return dst


def test_fortran_and_python_digests_agree(study):
    _, db, _ = study
    n_checked = 0
    with h5py.File(db, "r") as f:
        def visit(name, obj):
            nonlocal n_checked
            if hasattr(obj, "shape") and "checksum" in obj.attrs:
                assert cio.digest(obj[()]) == cio.text(obj.attrs["checksum"]), name
                n_checked += 1
        f.visititems(visit)
        assert int(f.attrs["schema_version"][()]) == 2
        nt, n_dof = int(f.attrs["n_steps"][()]), 2 * int(f.attrs["n_agents"][()])
        for s in ("train", "valid"):
            t = cio.sample_block_table(f, s)
            off = f[f"{s}/lambda_offset"][()]
            for k in range(t.shape[0]):
                blocks = {"params": (f[f"{s}/params"][k], k * f[f"{s}/params"].shape[1]),
                          "positions": (f[f"{s}/positions"][k * (nt + 1):(k + 1) * (nt + 1)], k * (nt + 1) * n_dof),
                          "velocities": (f[f"{s}/velocities"][k * nt:(k + 1) * nt], k * nt * n_dof),
                          "lambda_offset": (off[k * nt + 1:(k + 1) * nt + 1], k * nt + 1)}
                lo, hi = int(off[k * nt]), int(off[(k + 1) * nt])
                blocks["lambda_value"] = (f[f"{s}/lambda_value"][lo:hi], lo)
                blocks["lambda_index"] = (f[f"{s}/lambda_index"][lo:hi], lo)
                for name, (data, o) in blocks.items():
                    q = cio.SAMPLE_CHECKSUM_DATASETS.index(name)
                    d = cio.digest(data, o)
                    if name == "lambda_offset" and k == 0:      # the leading 0 is sample 1's
                        a, b = int(d[:8], 16), int(d[8:], 16)
                        z = cio.digest(off[:1], 0)
                        d = "%08x%08x" % ((a + int(z[:8], 16)) % cio._M, (b + int(z[8:], 16)) % cio._M)
                    assert d == "%08x%08x" % tuple(t[k, 2 * q:2 * q + 2]), (s, k, name)
    assert n_checked > 30


@pytest.mark.parametrize("name", ["train/velocities", "valid/positions", "train/params"])
def test_scaled_dataset_refused_by_python(study, name):
    tmp, db, _ = study
    bad = _copy(db, tmp, "scaled.h5")
    with h5py.File(bad, "a") as f:
        f[name][...] = f[name][()] * 1.001
    s = name.split("/")[0]
    with cio.open_h5(bad, cio.DB_SCHEMA, "snapshot database") as f:
        with pytest.raises(cio.InputError, match=rf"checksum mismatch in dataset '{name}'"):
            cio.read_database_set(f, s)
        with pytest.raises(cio.InputError, match=rf"block checksum mismatch in dataset '{name}'"):
            cio.read_database_samples(f, s, 0, 2)


def test_partial_read_clean_and_version1(study):
    tmp, db, _ = study
    with cio.open_h5(db, cio.DB_SCHEMA, "snapshot database") as f:
        part = cio.read_database_samples(f, "train", 1, 3)
        whole = cio.read_database_set(f, "train")
    assert np.array_equal(part["positions"], whole["positions"][1:3])
    assert np.array_equal(part["params"], whole["params"][1:3])
    old = _copy(db, tmp, "v1.h5")
    with h5py.File(old, "a") as f:
        f.attrs["schema_version"] = np.int32(1)
        for s in ("train", "valid"):
            del f[f"{s}/sample_checksums"]
    with cio.open_h5(old, cio.DB_SCHEMA, "snapshot database") as f:
        with pytest.raises(cio.InputError, match="schema version 1 has no per-sample checksums"):
            cio.read_database_samples(f, "train", 0, 2)
        cio.read_database_set(f, "train")


@pytest.mark.parametrize("sets,name", [("train", "train/positions"), ("valid", "valid/positions"),
                                       ("train", "train/velocities")])
def test_crowd_rom_partial_read_refuses_scaled(study, sets, name):
    tmp, db, rom = study
    work = tmp / f"rom_{sets}_{name.replace('/', '_')}"
    work.mkdir()
    bad = _copy(db, work, "db.h5")
    with h5py.File(bad, "a") as f:
        f[name][...] = f[name][()] * 1.001
    nml = rom_input(work, "rom.nml", rom, work / "out.h5", [{"n": 2, "r": 2}], database="'%s'" % bad,
                    sets="'%s'" % sets, n_samples=2)
    p = run(0, "crowd_rom", nml, work)
    text = p.stdout + p.stderr
    assert p.returncode == 2, text
    err = [ln for ln in text.splitlines() if ln.startswith("error:")]
    assert len(err) == 1 and f"block checksum mismatch in dataset '{name}'" in err[0], text
    assert not (work / "out.h5").exists()
