"""Careless and hostile use of the Python scripts, as generated families: bad arguments
(zero or negative counts, --dpi 0, --fps 0), outputs naming an input (directly, ./x, dir/../x,
a symbolic link), outputs in a missing directory or under a directory's name, and failures
while drawing all end with one `error:` line (no traceback), a non-zero exit, and no output
written: an earlier figure set is left exactly as it was (all or nothing)."""
import json
import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import synth  # noqa: E402


def run(script, *args, cwd=None):
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, script), *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)


def listing(d):
    out = {}
    for root, _, files in os.walk(d):
        for f in files:
            p = os.path.join(root, f)
            st = os.lstat(p)
            out[os.path.relpath(p, d)] = (st.st_size, st.st_mtime_ns)
    return out


def assert_refused(res, expect, code=2):
    text = res.stdout + res.stderr
    assert res.returncode == code, text
    assert "Traceback" not in text, text
    err = [l for l in res.stderr.splitlines() if ": error:" in l]
    assert len(err) == 1 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert expect in err[0], err[0]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("errs")
    st = synth.make_study(tmp)
    st["tmp"] = tmp
    return st


@pytest.fixture(scope="module")
def fom(tmp_path_factory):
    """A small FOM file for plot_scene (built by test_plot_scene's writer)."""
    import test_plot_scene
    tmp = tmp_path_factory.mktemp("fom")
    path = tmp / "fom.h5"
    test_plot_scene.make_fom(path)
    return path


# ---------------------------------------------------------------- make_figures: bad arguments
BAD_FIGURE_ARGS = [
    (["--sample", "0"], "--sample 0: must be >= 1"),
    (["--sample", "-3"], "--sample -3: must be >= 1"),
    (["--pair", "0"], "--pair 0: must be >= 1"),
    (["--setting", "0"], "--setting 0: must be >= 1"),
    (["--settings", "1", "0"], "--settings 1 0: every value must be >= 1"),
    (["--agents", "0", "2"], "--agents 0 2: every value must be >= 1"),
    (["--steps", "-1"], "--steps -1: every value must be >= 0"),
    (["--dpi", "0"], "--dpi 0: must be >= 1"),
    (["--sample", "99"], "--sample 99"),                    # found while drawing: nothing written
    (["--pair", "9"], "no pair 9"),
    (["--agents", "999"], "--agents [999]"),
    (["--settings", "99"], "99"),
]


@pytest.mark.parametrize("extra,expect", BAD_FIGURE_ARGS)
def test_make_figures_bad_arguments_write_nothing(study, tmp_path, extra, expect):
    out = tmp_path / "figs"
    out.mkdir()
    (out / "pod_decay.png").write_text("an earlier figure")
    before = listing(out)
    res = run("post/make_figures.py", "--database", study["db"], "--rom", study["rom"], "--romrun",
              study["romrun"], "--csv", study["csv"], "-o", out, "--dpi", 40, *extra)
    assert res.returncode != 0, res.stdout + res.stderr
    assert_refused(res, expect, code=res.returncode)
    assert listing(out) == before


def test_make_figures_output_dir_is_a_file(study, tmp_path):
    f = tmp_path / "figs"
    f.write_text("a file")
    res = run("post/make_figures.py", "--rom", study["rom"], "-o", f)
    assert_refused(res, "is a file")
    assert f.read_text() == "a file"


def test_make_figures_missing_output_dir_left_absent_on_error(study, tmp_path):
    out = tmp_path / "new" / "figs"
    res = run("post/make_figures.py", "--rom", study["rom"], "--romrun", study["romrun"], "--database", study["db"],
              "--sample", "99", "-o", out)
    assert_refused(res, "--sample 99")
    assert not out.exists()


# ---------------------------------------------------------------- plot_scene
@pytest.mark.parametrize("extra,expect", [
    (["--dpi", "0"], "--dpi 0: must be >= 1"),
    (["--fps", "0", "--animate", "a.gif"], "--fps 0: must be >= 1"),
    (["-o", "fom.h5"], "is the input file"),
    (["-o", "./fom.h5"], "is the input file"),
    (["-o", "sub/../fom.h5"], "is the input file"),
    (["-o", "link.h5"], "is the input file"),
    (["-o", "hard.h5"], "is the input file"),
    (["-o", "nodir/x.png"], "does not exist"),
    (["-o", "sub"], "is a directory"),
    (["-o", "x.png", "--animate", "./x.png"], "are the same file"),
    (["--animate", "fom.h5"], "is the input file"),
])
def test_plot_scene_refusals(fom, tmp_path, extra, expect):
    d = tmp_path / "w"
    d.mkdir()
    (d / "sub").mkdir()
    (d / "fom.h5").write_bytes(fom.read_bytes())
    os.symlink("fom.h5", d / "link.h5")
    os.link(d / "fom.h5", d / "hard.h5")
    before = listing(d)
    res = run("post/plot_scene.py", "fom.h5", *extra, cwd=d)
    assert_refused(res, expect)
    assert listing(d) == before


def test_plot_scene_writes_png_and_gif_together(fom, tmp_path):
    pytest.importorskip("PIL")
    d = tmp_path / "w"
    d.mkdir()
    res = run("post/plot_scene.py", fom, "-o", d / "s.png", "--animate", d / "s.gif", "--dpi", 40)
    assert res.returncode == 0, res.stderr
    assert sorted(os.listdir(d)) == ["s.gif", "s.png"]


# ---------------------------------------------------------------- plot_tradeoff, ml_correct
@pytest.mark.parametrize("how", ["same", "dot", "link"])
def test_tradeoff_output_is_input(study, tmp_path, how):
    src = study["csv"]
    out = {"same": src, "dot": os.path.join(os.path.dirname(src), ".", os.path.basename(src))}.get(how)
    if how == "link":
        out = tmp_path / "l.csv"
        os.symlink(src, out)
    before = open(src).read()
    res = run("post/plot_tradeoff.py", src, "-o", out)
    assert_refused(res, "is the input")
    assert open(src).read() == before


def test_tradeoff_dpi_zero(study, tmp_path):
    res = run("post/plot_tradeoff.py", study["csv"], "-o", tmp_path / "t.png", "--dpi", "0")
    assert_refused(res, "--dpi 0")
    assert not (tmp_path / "t.png").exists()


@pytest.mark.parametrize("which", ["romrun", "rom", "db"])
def test_ml_correct_output_is_input(study, tmp_path, which):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"n_values": [3], "random_forest": {"n_estimators": 2}, "timing_repeats": 1,
                               "regressors": ["random_forest"]}))
    target = study[which]
    with open(target, "rb") as fh:
        before = fh.read()
    res = run("pipeline/ml_correct.py", study["romrun"], "--config", cfg, "-o", target, "--quiet")
    assert_refused(res, "refusing to overwrite an input")
    with open(target, "rb") as fh:
        assert fh.read() == before


def test_ml_correct_csv_is_input(study, tmp_path):
    link = tmp_path / "db_link.h5"
    os.symlink(study["db"], link)
    res = run("pipeline/ml_correct.py", study["romrun"], "-o", tmp_path / "ml.h5", "--csv", link, "--quiet")
    assert_refused(res, "refusing to overwrite an input")
    assert not (tmp_path / "ml.h5").exists()


def test_ml_correct_output_and_csv_same(study, tmp_path):
    res = run("pipeline/ml_correct.py", study["romrun"], "-o", tmp_path / "ml.h5", "--csv", tmp_path / "." / "ml.h5",
              "--quiet")
    assert_refused(res, "are the same file")
    assert not (tmp_path / "ml.h5").exists()


def test_bench_fom_cpu_outside_affinity(tmp_path):
    """bench_fom.py --cpu names a CPU this process may not run on: one error line, exit 2,
    no table written (checked before any run)."""
    out = tmp_path / "bench.md"
    res = run("bench/bench_fom.py", "--cpu", 4096, "--skip-solvers", "--skip-scaling", "--out", out)
    assert_refused(res, "--cpu 4096")
    assert not out.exists()


def test_bench_project_without_build(tmp_path):
    """bench_project.py with a --bindir holding no crowd_snapshots: one error line, exit 2,
    nothing made in the work directory but the directory itself."""
    work = tmp_path / "work"
    res = run("bench/bench_project.py", "--bindir", tmp_path / "nobin", "--workdir", work, "--configs", 2,
              "--steps", 2)
    assert_refused(res, "no crowd_snapshots in --bindir")
    assert listing(work) == {}
