"""Tests of scripts/post/plot_scene.py on a synthetic FOM file built with h5py (schema v1)."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "post" / "plot_scene.py"


def make_fom(path, n_agents=5, n_out=6, schema="crowdrom-fom"):
    """Write a small FOM file: a disk, a capsule and a polygon obstacle, agents walking right."""
    r = 0.25
    with h5py.File(path, "w") as f:
        f.attrs["schema"] = np.bytes_(schema)
        f.attrs["schema_version"] = 1
        f.attrs["agent_radius"] = r
        f.attrs["n_agents"] = n_agents
        f.attrs["dt"] = 0.05
        f.attrs["config"] = np.bytes_("&scene n_obstacles = 3 /\n&agents n = 5 /")
        s = f.create_group("scene")
        s["obstacle_kind"] = np.array([1, 2, 3], dtype=np.int32)
        s["obstacle_radius"] = np.array([0.5, 0.1, 0.0])
        verts = np.array([[4.0, 1.0],                              # disk centre
                          [2.0, 3.0], [5.0, 3.5],                  # capsule endpoints
                          [6.0, 0.5], [7.0, 0.5], [7.0, 1.5], [6.0, 1.5]])  # square
        s["obstacle_vertex_start"] = np.array([0, 1, 3, 7], dtype=np.int32)
        s["obstacle_vertices"] = verts
        s["exit_segment"] = np.array([[10.0, 1.5], [10.0, 2.5]])
        s["domain"] = np.array([0.0, 0.0, 10.0, 4.0])
        t = f.create_group("traj")
        t["step"] = np.arange(n_out, dtype=np.int32) * 10
        t["time"] = t["step"][()] * 0.05
        x0 = np.stack([np.full(n_agents, 1.0), 0.6 + 0.6 * np.arange(n_agents)], axis=1)
        pos = np.array([x0 + [1.6 * k, 0.0] for k in range(n_out)])       # [n_out, n, 2]
        t["positions"] = pos.reshape(n_out, 2 * n_agents)
        t["velocities"] = np.full((n_out, 2 * n_agents), 0.5)
        inside = np.ones((n_out, n_agents), dtype=np.int8)
        inside[-2:, 0] = 0
        t["inside"] = inside
        c = t.create_group("contacts")
        per_step = [[(1, 2, 0, 0.3)], [], [(2, 3, 0, 0.1), (3, 0, 1, 0.2)], [], [], [(4, 5, 0, 0.0)]]
        rows = [row for st in per_step[:n_out] for row in st]
        c["offset"] = np.concatenate([[0], np.cumsum([len(st) for st in per_step[:n_out]])]).astype(np.int64)
        c["ia"] = np.array([q[0] for q in rows], dtype=np.int32)
        c["ib"] = np.array([q[1] for q in rows], dtype=np.int32)
        c["ob"] = np.array([q[2] for q in rows], dtype=np.int32)
        c["lambda"] = np.array([q[3] for q in rows], dtype=float)
        st = f.create_group("stats")
        st["iterations"] = np.full(n_out, 7, dtype=np.int32)
    return path


def run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_help():
    res = run("--help")
    assert res.returncode == 0
    assert "--animate" in res.stdout and "--steps" in res.stdout


def test_png_default_steps(tmp_path):
    fom = make_fom(tmp_path / "fom.h5")
    out = tmp_path / "scene.png"
    res = run(fom, "-o", out, "--contacts")
    assert res.returncode == 0, res.stderr
    assert out.exists() and out.stat().st_size > 10_000
    img = pytest.importorskip("matplotlib.image").imread(out)
    assert img.shape[1] > 2 * img.shape[0]          # three panels side by side
    assert np.ptp(img[..., :3]) > 0.5               # not a blank image


def test_png_chosen_steps(tmp_path):
    fom = make_fom(tmp_path / "fom.h5")
    out = tmp_path / "two.png"
    res = run(fom, "--steps", 0, 50, "-o", out, "--hide-left")
    assert res.returncode == 0, res.stderr
    assert out.stat().st_size > 5_000


def test_unknown_step(tmp_path):
    fom = make_fom(tmp_path / "fom.h5")
    res = run(fom, "--steps", 7)
    assert res.returncode == 2 and "step 7" in res.stderr


def test_missing_file(tmp_path):
    res = run(tmp_path / "nope.h5")
    assert res.returncode == 2
    assert "nope.h5" in res.stderr and "not found" in res.stderr


def test_wrong_schema(tmp_path):
    fom = make_fom(tmp_path / "other.h5", schema="something-else")
    res = run(fom)
    assert res.returncode == 2 and "schema" in res.stderr


def test_not_hdf5(tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_text("not hdf5")
    res = run(bad)
    assert res.returncode == 2 and "bad.h5" in res.stderr


def test_animate(tmp_path):
    if importlib.util.find_spec("PIL") is None:
        pytest.skip("pillow not installed")
    fom = make_fom(tmp_path / "fom.h5")
    gif = tmp_path / "anim.gif"
    res = run(fom, "-o", tmp_path / "s.png", "--animate", gif, "--contacts")
    assert res.returncode == 0, res.stderr
    assert gif.exists() and gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    from PIL import Image
    with Image.open(gif) as im:
        assert getattr(im, "n_frames", 1) == 6
