"""crowd_fom's trajectories in the Pedestrian Dynamics Data Archive layout (&output pdda_file)
read by PedPy in one call each (trajectory, walkable area), and the flow per exit and the
density in front of each exit cross-checked against PedPy's on a small two-exit scene:
PedPy's cumulative count at each exit's "has left" line equals crowd_fom's own count (its QoI
group, the one definition) at every output frame; scripts/post/validate_flows.py reads crowd_fom's
QoIs from that group, and its flow of a curve (the path of JuPedSim's curves) equals crowd_fom's
on crowd_fom's curve; PedPy's classic density in the 1 m deep area in front of each exit equals
the count of crowd_fom's own positions in it at every frame."""
import os
import pathlib
import subprocess
import sys

import h5py
import numpy as np
import pedpy  # a test dependency (scripts/requirements.txt)
import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import validate_flows as vf  # noqa: E402


ROOT = os.environ.get("CROWDROM_ROOT", os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
BIN = os.environ.get("CROWDROM_BIN", os.path.join(ROOT, "build", "bin"))
FOM = os.path.join(BIN, "crowd_fom")

SCENE = {"L": 6.0, "W": 5.0, "t": 0.3, "l_exit": 1.2, "exit_center": 4.0, "l_exit2": 1.0,
         "exit2_center": 1.5, "disks": [(3.0, 3.5, 0.4)]}
N = 40
DT = 0.05
EVERY = 2


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("pdda")
    text = (vf.scene_text(SCENE) +
            "&agents n_agents = %d, radius = 0.2, speed = 1.3, seed = 5, region = 0.3, 0.3, 5.7, 2.9,"
            " social_distance = 0.1 /\n" % N +
            "&desired speed_model = 'weidmann' /\n"
            "&time dt = %r, n_steps = 800 /\n" % DT)
    out, pd, nml = tmp / "fom.h5", tmp / "fom_pdda.h5", tmp / "fom.nml"
    nml.write_text(text + "&output file = '%s', every = %d, store_multipliers = .false., pdda_file = '%s',"
                   " log_level = 'warn' /\n" % (out, EVERY, pd))
    p = subprocess.run([FOM, str(nml)], capture_output=True, text=True, cwd=tmp)
    assert p.returncode == 0, p.stdout + p.stderr
    with h5py.File(out, "r") as f:
        pos = np.asarray(f["traj/positions"], dtype=float).reshape(-1, N, 2)
        times = np.asarray(f["traj/time"], dtype=float).ravel()
        exits = np.asarray(f["scene/exit_segments"], dtype=float)
        radius = float(f.attrs["agent_radius"])
    # crowd_fom's QoIs as validate_flows reads them (run_fom: the same run, every step stored)
    r = vf.run_fom(text, str(tmp), "vf", pdda=False, fom=FOM)
    np.testing.assert_array_equal(r["pos"][::EVERY], pos)
    return {"pos": pos, "time": times, "exits": exits, "radius": radius, "pdda": pathlib.Path(pd),
            "qoi": r["qoi"], "fom_qois": vf.fom_qois(r)}


def first_out_frames(pos, radius):
    """First output frame at which each agent is beyond an exit's 'has left' line [N] (-1: never)
    (y > H + t + r through the top exit, x > L + t + r through the right one)."""
    beyond = (pos[:, :, 1] > SCENE["W"] + SCENE["t"] + radius) | (pos[:, :, 0] > SCENE["L"] + SCENE["t"] + radius)
    return np.where(beyond.any(axis=0), beyond.argmax(axis=0), -1)


def test_layout_loads_in_one_call(run):
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=run["pdda"])
    area = pedpy.load_walkable_area_from_ped_data_archive_hdf5(trajectory_file=run["pdda"])
    assert traj.frame_rate == pytest.approx(1.0 / (DT * EVERY), rel=1e-12)
    assert sorted(traj.data.id.unique()) == list(range(1, N + 1))
    # the walkable area holds the hall, both doorways and the pillar as a hole
    poly = area.polygon
    assert len(poly.interiors) == 1
    assert poly.contains(pedpy.MeasurementLine([(1.0, 1.0), (2.0, 1.0)]).line)
    # crowd_fom's own file stores every exit
    assert run["exits"].shape == (2, 4)
    np.testing.assert_array_equal(run["exits"][1], [6.0, 1.0, 6.0, 2.0])


def test_agents_removed_once_out(run):
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=run["pdda"])
    first = first_out_frames(run["pos"], run["radius"])
    assert (first > 0).sum() >= N - 5, "nearly everybody leaves within the horizon"
    last = traj.data.groupby("id").frame.max()
    for i in range(N):
        # written up to one frame after the first frame out (PedPy's crossing needs it)
        want = min(first[i] + 1, len(run["time"]) - 1) if first[i] >= 0 else len(run["time"]) - 1
        assert last[i + 1] == want, "agent %d: last frame %d, first frame out %d" % (i + 1, last[i + 1], want)
    # the positions are crowd_fom's own
    d = traj.data.sort_values(["frame", "id"])
    f0 = d[d.frame == 0]
    np.testing.assert_array_equal(f0[["x", "y"]].to_numpy(), run["pos"][0])


def has_left_line(e, radius):
    """PedPy measurement line across exit e's outside strip at its 'has left' line."""
    x0, y0, x1, y1 = vf_exits()[e]
    t = SCENE["t"]
    if e == 0:
        return pedpy.MeasurementLine([(x0 - 0.5, y0 + t + radius), (x1 + 0.5, y0 + t + radius)])
    return pedpy.MeasurementLine([(x0 + t + radius, y0 - 0.5), (x0 + t + radius, y1 + 0.5)])


def vf_exits():
    ex = []
    for (w, axis, face) in vf.exits_of(SCENE):
        c = SCENE["exit_center"] if axis == 1 else SCENE["exit2_center"]
        ex.append((c - w / 2, face, c + w / 2, face) if axis == 1 else (face, c - w / 2, face, c + w / 2))
    return ex


def test_flow_per_exit_matches_pedpy(run):
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=run["pdda"])
    q, fq = run["qoi"], run["fom_qois"]
    steps = DT * np.arange(q["n_steps"] + 1)
    for e, (w, _, _) in enumerate(vf.exits_of(SCENE)):
        nt, _ = pedpy.compute_n_t(traj_data=traj, measurement_line=has_left_line(e, run["radius"]))
        # crowd_fom counts at every step; output frame k is step EVERY k
        mine = q["curve"][0, e, EVERY * nt.frame.to_numpy()]
        np.testing.assert_array_equal(nt.cumulative_pedestrians.to_numpy(), mine,
                                      err_msg="cumulative count at exit %d" % (e + 1))
        assert q["curve"][0, e, -1] >= 10, "exit %d is used" % (e + 1)
        # validate_flows' flows are crowd_fom's; its flow of a curve (JuPedSim's path) agrees
        assert q["flow_defined"][0, e]
        assert (fq["flow"][e], fq["flow_rate"][e]) == (q["flow"][0, e], q["flow_rate"][0, e])
        assert vf.flow_rate(q["curve"][0, e], steps) / w == pytest.approx(fq["flow"][e], rel=1e-12)
    assert fq["out"] == q["curve_total"][0, -1] == q["curve"][0, :, -1].sum()
    for k, p in enumerate((50, 90, 100)):
        t, cens = vf.t_percent(q["curve_total"][0], steps, p, N)
        assert (fq["t%d" % p], fq["t%d_censored" % p]) == (t, cens) == (q["t_evac"][0, k], q["censored"][0, k])


def test_density_at_exits_matches_pedpy(run):
    traj = pedpy.load_trajectory_from_ped_data_archive_hdf5(trajectory_file=run["pdda"])
    dens = vf.exit_densities(run["pos"], SCENE, run["radius"])
    for e, box in enumerate(vf.exit_boxes(SCENE)):
        area = pedpy.MeasurementArea(box)
        cd = pedpy.compute_classic_density(traj_data=traj, measurement_area=area)
        frames = cd.index.to_numpy() if "frame" not in cd.columns else cd.frame.to_numpy()
        np.testing.assert_allclose(cd.density.to_numpy(), dens[frames, e], rtol=1e-12, atol=0,
                                   err_msg="density in front of exit %d" % (e + 1))
        assert dens[:, e].max() > 1.0, "a crowd forms in front of exit %d" % (e + 1)
