"""crowd_offline end to end on a tiny study: ROM file content, the same bases at 1 and 2
ranks, and bad inputs (missing database, N larger than the data allows, delta <= 0) that
fail with a clear message and write nothing."""
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
STUDY = os.path.join(ROOT, "tests", "inputs", "snap_tiny.nml")
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


def mpirun(np_, prog, nml, cwd):
    return subprocess.run(["mpiexec", "-n", str(np_), os.path.join(BIN, prog), str(nml)], cwd=cwd,
                          capture_output=True, text=True, env=ENV)


def offline_input(tmp, db, rom, **kw):
    text = open(STUDY).read().replace("database = 'snap_tiny.h5'", "database = '%s'" % db)
    opts = dict(database="'%s'" % db, rom_file="'%s'" % rom, pod_method="'tsqr'", pod_energy="1e-6",
                cone_method="'gis'", cone_compare=".true.", mcpg_r_max="8", pga_delta="1e-6",
                infsup_samples="4", infsup_n="2, 4", infsup_r="2, 4")
    opts.update(kw)
    text += nml_groups.as_text(nml_groups.offline_groups(", ".join("%s = %s" % (k, v) for k, v in opts.items())))
    path = tmp / ("off_%d.nml" % abs(hash(tuple(sorted(opts.items())))))
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("offline")
    db = tmp / "tiny.h5"
    text = open(STUDY).read().replace("database = 'snap_tiny.h5'", "database = '%s'" % db)
    (tmp / "study.nml").write_text(text)
    p = mpirun(2, "crowd_snapshots", tmp / "study.nml", tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    return tmp, db


def test_rom_file(study):
    tmp, db = study
    rom = tmp / "rom1.h5"
    p = mpirun(1, "crowd_offline", offline_input(tmp, db, rom), tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "velocity POD" in p.stdout and "supremizer" in p.stdout
    with h5py.File(rom, "r") as f:
        assert f.attrs["schema"].decode() == "crowdrom-rom"
        v = f["basis/v"][...].T                      # [n_dof, N]
        n_pod = int(f["basis"].attrs["n_pod"])
        assert v.shape[0] == 16 and n_pod <= v.shape[1] <= 16
        np.testing.assert_allclose(v.T @ v, np.eye(v.shape[1]), atol=1e-12)
        idx = f["cone/indices"][...]
        nd = f["contacts/ia"].shape[0]
        assert len(set(idx)) == len(idx) and idx.min() >= 1 and idx.max() <= nd
        e = f["cone/err_max"][...]
        assert e[0] == 1.0 and np.all(np.diff(e) <= 1e-15)
        assert "cone_mcpg" in f and f["cone_mcpg/psi"][...].min() >= 0
        assert f["pga/err"][-1] <= 1e-6
        assert f["infsup/gamma_up_min"].shape == (4,)
        assert np.all(f["infsup/gamma_low_min"][...] <= f["infsup/gamma_up_min"][...] * (1 + 1e-12))


def test_ranks_agree(study):
    tmp, db = study
    roms = []
    for np_ in (1, 2):
        rom = tmp / ("rom_np%d.h5" % np_)
        p = mpirun(np_, "crowd_offline", offline_input(tmp, db, rom), tmp)
        assert p.returncode == 0, p.stdout + p.stderr
        roms.append(h5py.File(rom, "r"))
    a, b = roms
    np.testing.assert_array_equal(a["cone/indices"][...], b["cone/indices"][...])
    assert a["basis/v"].shape == b["basis/v"].shape
    np.testing.assert_allclose(a["basis/v"][...], b["basis/v"][...], atol=1e-10)
    np.testing.assert_allclose(a["pod/sigma"][...], b["pod/sigma"][...], rtol=1e-12, atol=1e-14)
    # the prepared pair: supremizers, EIM indices and EQ points from Gramians summed over ranks
    assert a.attrs["n_pairs"] == b.attrs["n_pairs"] == 1
    np.testing.assert_allclose(a["pairs/1/v"][...], b["pairs/1/v"][...], atol=1e-10)
    for t in ("s1", "s2", "s3"):
        np.testing.assert_array_equal(a["pairs/1/eim/%s/indices" % t][...], b["pairs/1/eim/%s/indices" % t][...])
        # near-ties may be taken in another order (Gramians summed in another order): the
        # chosen points and the error history agree
        ia, ib = a["pairs/1/eq/%s/indices" % t][...], b["pairs/1/eq/%s/indices" % t][...]
        assert sorted(ia) == sorted(ib)
        np.testing.assert_allclose(a["pairs/1/eq/%s/err" % t][...], b["pairs/1/eq/%s/err" % t][...],
                                   rtol=1e-6, atol=1e-10)


@pytest.mark.parametrize("kw,message", [
    (dict(database="'missing.h5'"), r"&offline: database: .*missing\.h5"),
    (dict(pod_n="100"), r"&pod: n = 100 is larger than the number of velocity dofs \(16\)"),
    (dict(pga_delta="0.0"), r"&pga: delta must be > 0"),
    (dict(pod_method="'qr'"), r"&pod: method must be"),
])
def test_bad_input(study, kw, message):
    tmp, db = study
    rom = tmp / "bad_rom.h5"
    if rom.exists():
        rom.unlink()
    nml = offline_input(tmp, db, rom, **kw)
    p = mpirun(2, "crowd_offline", nml, tmp)
    assert p.returncode != 0
    err = [l for l in (p.stdout + p.stderr).splitlines() if l.startswith("error:")]
    assert len(err) >= 1 and re.search(message, err[0]), p.stdout + p.stderr
    assert not rom.exists() and not os.path.exists(str(rom) + ".partial")


def test_database_checksums(study):
    """Every dataset of the database carries a checksum that the Python reader recomputes
    (crowdrom_io.digest, the algorithm of src/io/cr_digest.f90), and crowd_offline refuses a
    database whose velocities were overwritten, naming the dataset."""
    import shutil
    import sys
    sys.path.insert(0, os.path.join(ROOT, "scripts"))
    import crowdrom_io as cio
    tmp, db = study
    names = []
    with h5py.File(db, "r") as f:
        f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) and "checksum" in o.attrs else None)
        for n in names:
            cio.verify_checksum(f, n)
        off, nbytes = f["train/velocities"].id.get_offset(), f["train/velocities"].id.get_storage_size()
    assert {"train/velocities", "train/lambda_value", "valid/positions", "contacts/key"} <= set(names)
    bad = tmp / "corrupt.h5"
    shutil.copy(db, bad)
    with open(bad, "r+b") as fh:
        fh.seek(off + nbytes // 2)
        fh.write(np.random.default_rng(3).integers(0, 256, 32, dtype=np.uint8).tobytes())
    with h5py.File(bad, "r") as f, pytest.raises(cio.InputError, match="checksum mismatch in dataset 'train/velocities'"):
        cio.verify_checksum(f, "train/velocities")
    for np_ in (1, 2):
        p = mpirun(np_, "crowd_offline", offline_input(tmp, bad, tmp / "rom_bad.h5"), tmp)
        assert p.returncode != 0
        assert re.search(r"error: .*checksum mismatch in dataset 'train/velocities'", p.stdout + p.stderr), \
            p.stdout + p.stderr
        assert not (tmp / "rom_bad.h5").exists()
