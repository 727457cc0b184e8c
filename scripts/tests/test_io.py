"""crowdrom_io: one reader per product with the Fortran readers' version check, and refusal of
corrupt products (a generated family per class: unknown schema versions for every product,
NaN / +Inf / -Inf in every float dataset the readers use, out-of-range multiplier indices)."""
import os
import shutil
import sys

import h5py
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
import crowdrom_io as cio  # noqa: E402
import synth  # noqa: E402


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("io")
    return tmp, synth.make_study(tmp)


def _copy(src, tmp, name):
    dst = tmp / name
    shutil.copy(src, dst)
    return dst


def _read_db(path):
    with cio.open_h5(path, cio.DB_SCHEMA, "database") as f:
        for s in ("train", "valid"):
            cio.read_database_set(f, s)
        cio.multipliers_csr(f, "train")


def _read_rom(path):
    with cio.open_h5(path, cio.ROM_SCHEMA, "ROM file") as f:
        for k in cio.rom_pair_indices(f):
            cio.read_rom_pair(f, k)


def _read_romrun(path):
    with cio.open_h5(path, cio.ROMRUN_SCHEMA, "ROM run file") as f:
        cio.romrun_meta(f)


@pytest.mark.parametrize("product,version", [
    (p, v) for p in ("db", "rom", "romrun") for v in (0, 4 if p == "rom" else 3, 99)])
def test_unknown_version_refused(study, product, version):
    tmp, paths = study
    path = _copy(paths[product], tmp, f"v{version}_{product}.h5")
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = np.int32(version)
    read = {"db": _read_db, "rom": _read_rom, "romrun": _read_romrun}[product]
    with pytest.raises(cio.InputError, match=rf"schema version {version} is not supported \(supported: "):
        read(path)


@pytest.mark.parametrize("name", ["train/params", "train/positions", "train/velocities",
                                  "valid/positions", "train/lambda_value"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_database_non_finite_refused(study, name, bad):
    tmp, paths = study
    path = _copy(paths["db"], tmp, "nonfinite_db.h5")
    with h5py.File(path, "a") as f:
        a = f[name][()]
        a.flat[1] = bad
        f[name][...] = a
        # the checksum re-stamped: only the finiteness check can catch it
        f[name].attrs["checksum"] = np.bytes_(cio.digest(a))
    with pytest.raises(cio.InputError, match=rf"dataset '{name}': non-finite"):
        _read_db(path)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_rom_basis_non_finite_refused(study, bad):
    tmp, paths = study
    path = _copy(paths["rom"], tmp, "nonfinite_rom.h5")
    with h5py.File(path, "a") as f:
        a = f["pairs/1/v"][()]
        a.flat[0] = bad
        f["pairs/1/v"][...] = a
    with pytest.raises(cio.InputError, match=r"dataset 'pairs/1/v': non-finite"):
        _read_rom(path)


@pytest.mark.parametrize("index", [0, -1, 10 ** 6])
def test_multiplier_index_out_of_range(study, index):
    tmp, paths = study
    path = _copy(paths["db"], tmp, "index_db.h5")
    with h5py.File(path, "a") as f:
        a = f["train/lambda_index"][()]
        a[0] = index
        f["train/lambda_index"][...] = a
        f["train/lambda_index"].attrs["checksum"] = np.bytes_(cio.digest(a))
    with pytest.raises(cio.InputError, match=r"multiplier index outside"):
        _read_db(path)


def test_write_h5_atomic_keeps_old_file_on_failure(tmp_path):
    path = tmp_path / "out.h5"
    cio.write_h5_atomic(path, lambda f: f.attrs.__setitem__("v", 1))

    def fail(f):
        f.attrs["v"] = 2
        raise RuntimeError("disk full")
    with pytest.raises(RuntimeError):
        cio.write_h5_atomic(path, fail)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["v"]) == 1
    assert not os.path.exists(str(path) + ".partial")
