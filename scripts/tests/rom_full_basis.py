"""The full-basis set-up shared by the reduced-model tests of a scene behaviour
(test_rom_density.py, test_rom_social.py): the tiny study of test_rom.py with edits to its
namelist, its snapshots (crowd_snapshots), full bases (crowd_offline), and crowd_rom with full
bases and every assembly (exact, EQ, EIM, online contacts) on the training set, which must then
reproduce the snapshots."""
import os
import sys

import h5py
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_rom import run, offline, run_full_bases, STUDY  # noqa: E402


def make_study(tmp, db_name, edits):
    """Snapshots and full bases of the tiny study edited by ``edits`` ((old, new) text
    replacements of its namelist, each of which must match: an edit that matched nothing would
    leave the behaviour under test out); returns (tmp, database, ROM file, N, R) of the bases."""
    db = tmp / db_name
    text = open(STUDY).read()
    for old, new in [("database = 'rom_tiny.h5'", "database = '%s'" % db)] + list(edits):
        assert old in text, "the tiny study has no '%s' to edit" % old
        text = text.replace(old, new)
    sfile = tmp / "study.nml"
    sfile.write_text(text)
    p = run(1, "crowd_snapshots", sfile, tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    rom = offline(tmp, sfile, db, tmp / "rom_full.h5")
    with h5py.File(rom, "r") as f:
        n_full, r_full = int(f["pairs/1"].attrs["n"]), int(f["pairs/1"].attrs["r"])
    return tmp, db, rom, n_full, r_full


def check_reproduces_snapshots(out, db, n_settings):
    """Every setting of the crowd_rom output ``out`` reproduces the training positions of the
    database ``db``: E_mu <= 1e-8 and the positions within 1e-9 m (full bases: the reduced
    problems are the full-order ones up to round-off)."""
    with h5py.File(out, "r") as f, h5py.File(db, "r") as d:
        q_fom = d["train/positions"][...]
        for k in range(1, n_settings + 1):
            g = f["setting_%d/train" % k]
            assert g["E_mu"][...].max() <= 1e-8, (k, g["E_mu"][...])
            np.testing.assert_allclose(g["positions"][...], q_fom, atol=1e-9)
