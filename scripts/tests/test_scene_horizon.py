"""scripts/pipeline/scene_horizon.py: evacuation times at the corners of a study's box.

Two agents, each in front of its own exit of the crowd1000_mini-like two-exit scene, walk
straight out with the exact geodesic: they leave at steps known in closed form, so t50 (one agent
of two out), t90 and t100 (both out) are known at each speed corner; a corner fixed by --corner
runs alone; a bad --corner is one line and exit 2.
"""
import json
import math
import os
import subprocess
import sys

from test_rom import BIN, ENV, ROOT  # noqa: E402

L, W, T, R, H = 4.0, 3.0, 0.3, 0.2, 0.1
P_RIGHT, P_TOP = (L - 0.55, 1.0), (2.5, W - 0.75)
SCRIPT = os.path.join(ROOT, "scripts", "pipeline", "scene_horizon.py")


def study(tmp):
    pos = tmp / "pos.txt"
    pos.write_text("%.3f %.3f\n%.3f %.3f\n" % (P_RIGHT + P_TOP))
    path = tmp / "two_exits_study.nml"
    path.write_text(f"""&scene hall_length = {L}, hall_width = {W}, l_exit = 1.0, exit_center = 2.5,
  wall_thickness = {T}, l_exit2 = 1.0, exit2_center = 1.0
/
&agents n_agents = 2, radius = {R}, speed = 1.0, init = 'file', init_file = '{pos}'
/
&desired field = 'exact'
/
&time dt = {H}, n_steps = 5
/
&output file = 'unused.h5'
/
&study n_params = 1, param_name = 'speed', param_min = 1.0, param_max = 1.5, n_train = 2, n_valid = 1,
  database = 'unused_db.h5'
/
""")
    return path


def leave_step(dist, c):
    return math.floor(dist / (c * H)) + 1


def test_corners_closed_form(tmp_path):
    nml = study(tmp_path)
    out = tmp_path / "h.json"
    p = subprocess.run([sys.executable, SCRIPT, str(nml), "--bin", BIN, "--json", str(out)], cwd=tmp_path,
                       capture_output=True, text=True, env=ENV)
    assert p.returncode == 0, p.stdout + p.stderr
    rows = json.load(open(out))
    assert [r["point"]["speed"] for r in rows] == [1.0, 1.5]
    for r in rows:
        c = r["point"]["speed"]
        first = leave_step(L + T + R - P_RIGHT[0], c)
        last = leave_step(W + T + R - P_TOP[1], c)
        assert first < last
        assert (r["step_t50"], r["step_t90"], r["step_t100"]) == (first, last, last), (c, r)
        assert r["t90"] == last * H and r["steps_run"] == last and r["agents_inside_at_end"] == 0
    p = subprocess.run([sys.executable, SCRIPT, str(nml), "--bin", BIN, "--corner", "speed=hi", "--json", str(out)],
                       cwd=tmp_path, capture_output=True, text=True, env=ENV)
    assert p.returncode == 0 and [r["point"]["speed"] for r in json.load(open(out))] == [1.5]


def test_bad_corner(tmp_path):
    p = subprocess.run([sys.executable, SCRIPT, str(study(tmp_path)), "--bin", BIN, "--corner", "width=lo"],
                       cwd=tmp_path, capture_output=True, text=True, env=ENV)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "scene_horizon: error: --corner width=lo" in p.stderr
