"""The reduced-model stages run the calibrated behaviour (docs/calibration.md): on the tiny
study of test_rom.py with Weidmann's diagram of a look-ahead kernel density (its parameters
scaled to the tiny hall so that the agents' speeds are cut by a factor that differs from agent
to agent and from step to step) and a social distance, run long enough for agents to leave,
crowd_rom with full bases and every assembly (exact, EQ, EIM, online contacts) reproduces the
full-order snapshots of crowd_snapshots, and its evacuation curves equal the full model's at
every frame: both count an agent out at its body radius's "has left" line, not at the contact
radius the database records. A reduced model that kept the given speeds (no density term)
would walk its agents faster than the snapshots and leave them."""
import os
import sys

import h5py
import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rom_full_basis import check_reproduces_snapshots, make_study, run_full_bases  # noqa: E402

# the hall is 0.6 m x 0.5 m with 8 agents (about 30 /m2): a kernel of width 0.1 m and a
# diagram whose jam density lies above the crowd's keep 8-61% of the speeds
DIAGRAM = ("&desired speed_model = 'weidmann', density_sigma = 0.1, density_anisotropy = 1.0, "
           "fd_gamma = 20.0, fd_rho_max = 80.0 /\n")
DS = 0.02
N_STEPS = 40


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    return make_study(tmp_path_factory.mktemp("rom_density"), "tiny_density.h5",
                      [("&time\n", DIAGRAM + "&time\n"),
                       ("seed = 3\n", "seed = 3, social_distance = %r\n" % DS),
                       ("n_steps = 12", "n_steps = %d" % N_STEPS)])


def test_snapshots_walk_at_density_dependent_speeds(study):
    tmp, db, rom, n, r = study
    with h5py.File(db, "r") as d:
        v = d["train/desired"][...]
        mu = d["train/params"][...]
        names = d.attrs["param_names"]
        n_steps = int(d.attrs["n_steps"])
    names = (names.decode() if isinstance(names, bytes) else str(names)).split(",")
    speeds = mu[:, [names.index("speed_%d" % i) for i in range(1, 9)]]
    assert v.shape == (len(mu) * n_steps, 16)
    mag = np.linalg.norm(v.reshape(v.shape[0], -1, 2), axis=2).reshape(len(mu), n_steps, 8)
    factor = mag / speeds[:, None, :]
    # the diagram cuts every speed, by different factors across agents and steps
    assert factor.max() < 0.9 and factor.min() > 0.05
    assert factor.max() - factor.min() > 0.2


@pytest.fixture(scope="module")
def full_run(study):
    """crowd_rom with full bases and every assembly on the training set: (output, settings)."""
    return run_full_bases(study)


def test_full_basis_reproduces_fom_with_density_speed(study, full_run):
    tmp, db, rom, n, r = study
    out, settings = full_run
    check_reproduces_snapshots(out, db, len(settings))
    with h5py.File(out, "r") as f:
        for k in range(1, len(settings) + 1):
            g = f["setting_%d/train" % k]
            # the same positions give the same evacuation curves (body radius on both sides)
            np.testing.assert_array_equal(g["evac_rom"][...], g["evac_fom"][...])


def test_evacuation_curves_use_the_body_radius(study, full_run):
    """The stored full-order curves count an agent out beyond y = W + t + r (body radius r), and
    the agents leave during the run, some inside the ring band (r, r + d_s / 2] at some frame:
    a count at the contact radius would differ there."""
    tmp, db, rom, n, r = study
    with h5py.File(db, "r") as d:
        q = d["train/positions"][...]
        radius = float(d.attrs["agent_radius"])
    body = radius - DS / 2
    y = q.reshape(q.shape[0], -1, 2)[:, :, 1].reshape(-1, N_STEPS + 1, 8)
    line = 0.5 + 0.05
    out_body = np.logical_or.accumulate(y > line + body, axis=1).sum(axis=2)
    out_ring = np.logical_or.accumulate(y > line + radius, axis=1).sum(axis=2)
    assert out_body[:, -1].sum() > 0
    assert (out_body != out_ring).any()
    with h5py.File(full_run[0], "r") as f:
        evac = f["setting_1/train/evac_fom"][...]
    np.testing.assert_array_equal(evac.reshape(out_body.shape), out_body)
