"""The reduced-model stages use the social distance of the scene: on the tiny study of
test_rom.py with &agents social_distance = 0.01 m (contacts at gap d_s between agents, d_s / 2
from walls), crowd_rom with full bases and every assembly (exact, EQ, EIM, online contacts)
reproduces the full-order snapshots of crowd_snapshots, and no agent pair comes closer than
d_s. Were the offline or online stages to evaluate their gaps without d_s, the reduced
trajectories would leave the snapshots (their contacts would stop agents at gap 0)."""
import os
import sys

import h5py
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rom_full_basis import check_reproduces_snapshots, make_study, run_full_bases  # noqa: E402

DS = 0.01


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    return make_study(tmp_path_factory.mktemp("rom_social"), "tiny_social.h5",
                      [("seed = 3\n", "seed = 3, social_distance = %r\n" % DS)])


def test_snapshots_keep_the_social_distance(study):
    tmp, db, rom, n, r = study
    with h5py.File(db, "r") as d:
        q = d["train/positions"][...]
        n_steps = int(d.attrs["n_steps"])
        radius = float(d.attrs["agent_radius"])
    pos = q.reshape(q.shape[0], -1, 2)
    # after each sample's first step (its initial positions are placed with the body radius)
    gaps = [np.linalg.norm(p[:, None] - p[None], axis=2)[np.triu_indices(p.shape[0], 1)].min()
            for k, p in enumerate(pos) if k % (n_steps + 1) > 0]
    # body radius 0.04: centres at least 2 r + d_s apart (to the solver's accuracy), and the
    # distance is reached (contacts at d_s are active in the study)
    assert min(gaps) >= 2 * 0.04 + DS - 1e-9
    assert min(gaps) <= 2 * 0.04 + DS + 1e-6
    # the database holds the contact radius, which the reduced stages use
    assert radius == pytest.approx(0.04 + DS / 2, rel=1e-15)


def test_full_basis_reproduces_fom_with_social_distance(study):
    out, settings = run_full_bases(study)
    check_reproduces_snapshots(out, study[1], len(settings))
