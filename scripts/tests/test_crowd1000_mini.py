"""The 1 000-agent evacuation study's shape at test size.

* Two exits in different walls (&scene l_exit2, exit2_center: a second opening in the right wall):
  an agent in front of each opening walks straight out of it and leaves at the step given in
  closed form (exact geodesic and grid desired velocity; the 'left' rule of the model, +x beyond
  the right wall); a second exit wider than the wall is refused with one line naming it.
* ``scripts/run_study.sh crowd1000_mini`` (inputs/crowd1000_mini_*: two exits, two pillars, the two
  exit widths and the speed as parameters, 40 agents) runs the whole pipeline (snapshots and
  offline on 2 ranks, sweep, ML, figures, table): the table has its columns and the figures exist.
"""
import csv
import json
import math
import os
import shutil
import subprocess
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import crowdrom_io as cio  # noqa: E402
from test_rom import BIN, ENV, ROOT  # noqa: E402

L, W, T, R, C, H = 4.0, 3.0, 0.3, 0.2, 1.2, 0.1
Y2 = 1.0          # centre of the second exit (right wall)
X1 = 2.5          # centre of the first exit (top wall)
P_RIGHT = (L - 0.55, Y2)      # in front of the right opening
P_TOP = (X1, W - 0.75)        # in front of the top opening
NT = 20


def two_exit_scene(tmp, field, extra_scene=""):
    (tmp / "pos.txt").write_text("%.3f %.3f\n%.3f %.3f\n" % (P_RIGHT + P_TOP))
    text = f"""&scene hall_length = {L}, hall_width = {W}, l_exit = 1.0, exit_center = {X1},
  wall_thickness = {T}, l_exit2 = 1.0, exit2_center = {Y2} {extra_scene} /
&obstacles n_disks = 1, disk_x = 1.0, disk_y = 2.0, disk_r = 0.3 /
&agents n_agents = 2, radius = {R}, speed = {C}, init = 'file', init_file = 'pos.txt' /
&desired field = '{field}' /
&time dt = {H}, n_steps = {NT} /
&output file = 'two_exits_{field}.h5' /
"""
    path = tmp / f"two_exits_{field}.nml"
    path.write_text(text)
    return path


def leave_step(dist):
    """First step at which an agent walking straight at speed C has covered dist."""
    return math.floor(dist / (C * H)) + 1


@pytest.mark.parametrize("field", ["exact", "grid"])
def test_two_exits_each_agent_takes_its_own(tmp_path, field):
    nml = two_exit_scene(tmp_path, field)
    p = subprocess.run([os.path.join(BIN, "crowd_fom"), str(nml), "--summary", "s.json"], cwd=tmp_path,
                       capture_output=True, text=True, env=ENV)
    assert p.returncode == 0, p.stdout + p.stderr
    assert json.load(open(tmp_path / "s.json"))["agents_left"] == 2
    d = cio.read_fom(str(tmp_path / f"two_exits_{field}.h5"))
    pos, inside = d["pos"], d["inside"]
    # agent 1 leaves through the right wall, agent 2 through the top wall
    assert pos[-1, 0, 0] > L + T + R and abs(pos[-1, 0, 1] - Y2) < 0.5
    assert pos[-1, 1, 1] > W + T + R and abs(pos[-1, 1, 0] - X1) < 0.5
    # with the exact geodesic both walk in a straight line: the leaving step in closed form
    if field == "exact":
        for a, dist in ((0, L + T + R - P_RIGHT[0]), (1, W + T + R - P_TOP[1])):
            k = leave_step(dist)
            assert k <= NT
            assert inside[k - 1, a] and not inside[k, a], (a, k, inside[:, a])
        assert abs(pos[5, 0, 1] - Y2) < 1e-12 and abs(pos[5, 1, 0] - X1) < 1e-12


def test_second_exit_wider_than_wall_refused(tmp_path):
    nml = two_exit_scene(tmp_path, "exact")
    nml.write_text(nml.read_text().replace("l_exit2 = 1.0", "l_exit2 = 3.5"))
    p = subprocess.run([os.path.join(BIN, "crowd_fom"), str(nml)], cwd=tmp_path, capture_output=True,
                       text=True, env=ENV)
    assert p.returncode == 2
    assert "&scene: l_exit2" in p.stderr + p.stdout
    assert not (tmp_path / "two_exits_exact.h5").exists()


def test_crowd1000_mini_pipeline(tmp_path):
    case = "crowd1000_mini"
    (tmp_path / "inputs").mkdir()
    for suffix in ("_study.nml", "_rom.nml", "_ml.json"):
        shutil.copy(os.path.join(ROOT, "inputs", case + suffix), tmp_path / "inputs")
    env = dict(ENV, CROWDROM_BIN=BIN, CROWDROM_WORK=str(tmp_path), NP="2")
    p = subprocess.run([os.path.join(ROOT, "scripts", "run_study.sh"), case], cwd=tmp_path,
                       capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-4000:]
    res = tmp_path / "results"
    rows = list(csv.DictReader(open(res / f"{case}_table.csv")))
    for col in ("E_avg", "E_disp", "t50_err", "t90_err", "max_overlap_agents", "max_overlap_walls",
                "mobility", "speedup_exact", "speedup_query_exact", "t_query_rom", "t_query_fom_exact"):
        assert col in rows[0], col
    valid = [r for r in rows if r["set"] == "valid"]
    assert len(valid) == 5 and {r["contacts"] for r in valid} == {"cone", "online"}
    # the local exact correction leaves no overlap beyond the exact solver's bound
    # (KKT tolerance 1e-10 scaled by h 2 max|u| < 1 m: below 1e-10 m), and nothing diverges
    local = [r for r in valid if r["correction"] == "local"]
    assert len(local) == 1 and int(local[0]["samples_diverged"]) == 0
    assert float(local[0]["max_overlap_agents"]) <= 1e-10 and float(local[0]["max_overlap_walls"]) <= 1e-10
    assert 0 < float(local[0]["corrected_fraction"]) <= 1
    # &sweep sets(5) = 'valid': the local correction is not run on the training set
    train = [r for r in rows if r["set"] == "train"]
    assert len(train) == 4 and not [r for r in train if r["correction"] == "local"]
    # both exits are used and the full model evacuates: t90 defined for some validation sample
    assert any(int(r["t90_n"]) + int(r["t90_rom_missed"]) > 0 for r in valid)
    figs = res / f"{case}_figures"
    for name in ("evac/evac_curves.png", "evac/t90_map.png", "evac/train_convergence.png", "tradeoff.png",
                 "pod_decay.png"):
        assert (figs / name).stat().st_size > 1000, name
    table = (figs / "evac" / "evac_table.md").read_text()
    assert "speedup/query" in table and table.count("| valid") == 0
    assert len([ln for ln in table.splitlines() if "| cone |" in ln or "| online |" in ln]) == 4
    assert len([ln for ln in table.splitlines() if "| cone+local |" in ln]) == 1
    # the ML row (corrected positions, overlaps not removed) and the same after the exact
    # position projection: no overlap beyond the projection's bound (tolerance 1e-10 x depth)
    ml = [ln for ln in table.splitlines() if ln.startswith("| ML random_forest (n = 20)")]
    assert len(ml) == 2 and "not projected" in ml[0] and "+ exact projection" in ml[1]
    cells = [c.strip() for c in ml[1].strip("|").split("|")]
    over = [float(x) for x in cells[9].split("/")]
    assert all(0 <= x <= 1e-10 for x in over), cells[9]
    assert cells[7] != "" and float(cells[16]) > 0, ml[1]
    assert "=== run_study [crowd1000_mini] stage 6 of 7" in p.stdout
    assert "=== run_study [crowd1000_mini] stage 7 of 7: skipped" in p.stdout
