"""scripts/post/study_table.py (stage 6 of run_study.sh) and the trade-off plot on a synthetic sweep
table with a known answer: for each error level, the cheapest setting without overlap (overlap
tolerance, diverged samples, ML rows before and after the exact projection, the full model as the
answer when no reduced setting qualifies); unknown columns and contacts names pass through;
bad inputs give one line and exit status 2."""
import csv
import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
sys.path.insert(0, SCRIPTS)
import ml_correct  # noqa: E402
import plot_tradeoff  # noqa: E402
import study_table  # noqa: E402

T_FOM_QUERY, T_FOM_STEP = 0.08, 1.6e-3
# (setting, hyper, contacts, E_avg, overlap agents, overlap walls, t_query, diverged, extra column)
SETTINGS = [
    (1, "eq", "cone", 0.25, 0.1, 0.1, 0.004, 0, -1.0),
    (2, "none", "online", 0.16, 2e-13, 6e-15, 0.7, 0, -1.0),
    (3, "eq", "local", 0.04, 5e-11, 0.0, 0.010, 0, 0.3),
    (4, "eq", "local", 0.09, 0.0, 0.0, 0.005, 0, 0.1),
    (5, "eq", "local", 0.01, 2e-10, 0.0, 0.002, 0, 0.5),     # overlaps more than 1e-10 m
    (6, "eq", "local", 0.001, 0.0, 0.0, 0.001, 1, 0.2),      # a diverged sample
]
EXPECT = {0.01: "full model (exact)", 0.02: "ML mlp n=4 + projection", 0.05: "(10,20) eq / local",
          0.1: "(10,20) eq / local", 0.2: "(10,20) eq / local", 0.5: "(10,20) eq / local"}
EXPECT_SETTING = {0.05: 3, 0.1: 4, 0.2: 4, 0.5: 4}


def write_sweep(path, with_query=True, settings=SETTINGS):
    cols = ["setting", "set", "n", "r", "n_basis", "hyper", "contacts", "solver", "E_avg", "E_disp",
            "max_overlap", "max_overlap_agents", "max_overlap_walls", "agents_not_left", "agents_not_left_fom",
            "t_step_rom", "t_step_fom_uzawa", "t_step_fom_exact", "speedup_uzawa", "speedup_exact", "mobility",
            "samples_diverged", "t50_err", "t50_n", "t50_rom_missed", "t50_fom_missed", "t90_err", "t90_n",
            "t90_rom_missed", "t90_fom_missed", "frac_corrected", "t_correct", "correction"]
    if with_query:
        cols += ["t_query_rom", "t_query_fom_exact", "speedup_query_exact"]
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for k, hyper, contacts, e, oa, ow, tq, div, frac in settings:
            for s in ("train", "valid"):
                t_step = tq / 50
                row = dict(setting=k, set=s, n=10, r=20, n_basis=30, hyper=hyper, contacts=contacts, solver="dual",
                           E_avg=e if s == "valid" else 9.0, E_disp=4 * e, max_overlap=max(oa, ow),
                           max_overlap_agents=oa, max_overlap_walls=ow, agents_not_left=3, agents_not_left_fom=2,
                           t_step_rom=t_step, t_step_fom_uzawa=0.1, t_step_fom_exact=T_FOM_STEP,
                           speedup_uzawa=0.1 / t_step, speedup_exact=T_FOM_STEP / t_step, mobility=0.95,
                           samples_diverged=div, t50_err=0.1, t50_n=5, t50_rom_missed=0, t50_fom_missed=0,
                           t90_err=-1.0, t90_n=0, t90_rom_missed=0, t90_fom_missed=5, frac_corrected=frac,
                           t_correct=1e-5, correction="local" if k == 6 else "none",
                           t_query_rom=tq, t_query_fom_exact=T_FOM_QUERY,
                           speedup_query_exact=T_FOM_QUERY / tq)
                w.writerow({c: row[c] for c in cols})
    return path


def write_ml(path):
    """Rows as ml_correct.py --csv writes them (its own column list)."""
    keys = ["regressor", "n", "E_avg_baseline", "E_avg", "E_avg_projection", "factor", "t_fit", "t_predict_step",
            "t_step", "speedup_uzawa", "speedup_exact", "E_disp", "mobility"] + list(ml_correct.PROJ_KEYS)
    rows = []
    for reg, n, e, e_proj, o_proj, tq in (("mlp", 4, 0.015, 0.02, 1e-12, 0.02), ("random_forest", 4, 0.012, 0.018,
                                                                             3e-10, 0.003)):
        rows.append(dict(regressor=reg, n=n, E_avg_baseline=0.25, E_avg=e, E_avg_projection=0.01, factor=10.0,
                         t_fit=1.0, t_predict_step=1e-6, t_step=1e-4, speedup_uzawa=1000.0, speedup_exact=16.0,
                         E_disp=0.05, mobility=1.1, overlap_agents=0.05, overlap_walls=0.02, E_avg_proj=e_proj,
                         E_disp_proj=0.06, mobility_proj=1.0, overlap_agents_proj=o_proj, overlap_walls_proj=0.0,
                         moved_fraction=0.4, t_project_step=2e-4, t_project_query=tq / 2, t_query=tq,
                         speedup_query_exact=T_FOM_QUERY / tq, speedup_exact_proj=5.0))
    assert set(rows[0]) == set(keys)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    return path


def run(*args):
    return subprocess.run([sys.executable, os.path.join(SCRIPTS, "post", "study_table.py"), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_cheapest_per_level(tmp_path):
    extras, rows = study_table.load_rows(write_sweep(tmp_path / "t.csv"), [write_ml(tmp_path / "ml.csv")])
    assert extras == ["frac_corrected", "t_correct"]
    per_level, key = study_table.cheapest_per_level(rows, sorted(EXPECT), 1e-10)
    assert key == "t_query"
    for level, r in per_level:
        assert r["label"] == EXPECT[level], (level, r["label"])
        if level in EXPECT_SETTING:
            assert r["setting"] == EXPECT_SETTING[level]
    # with a looser tolerance setting 5 (overlap 2e-10) and the random forest's projected row
    # (3e-10) qualify, and setting 5 is the cheapest at 0.02
    per_level, _ = study_table.cheapest_per_level(rows, [0.02], 1e-9)
    assert per_level[0][1]["setting"] == 5
    rf = [r for r in rows if r["label"] == "ML random_forest n=4 + projection"][0]
    assert study_table.no_overlap(rf, 1e-9) and not study_table.no_overlap(rf, 1e-10)
    # the corrected (not projected) ML rows overlap: never candidates
    assert all(not study_table.no_overlap(r, 1e-3) for r in rows if r["kind"] == "ml")
    front, _ = study_table.overlap_free_front(rows, 1e-10)
    assert [r["label"] for r in front] == ["(10,20) eq / local", "(10,20) eq / local", "ML mlp n=4 + projection",
                                           "full model (exact)"]
    assert [r.get("setting") for r in front[:2]] == [4, 3]


def test_cost_per_step_without_query_columns(tmp_path):
    _, rows = study_table.load_rows(write_sweep(tmp_path / "t.csv", with_query=False))
    per_level, key = study_table.cheapest_per_level(rows, [0.05, 0.1], 1e-10)
    assert key == "t_step"
    assert [r["setting"] for _, r in per_level] == [3, 4]


def test_cli_writes_table_and_answers(tmp_path):
    md, out_csv, rows_csv = tmp_path / "table.md", tmp_path / "cheapest.csv", tmp_path / "rows.csv"
    res = run(write_sweep(tmp_path / "t.csv"), "--ml", write_ml(tmp_path / "ml.csv"), "-o", md, "--csv", out_csv,
              "--rows-csv", rows_csv)
    assert res.returncode == 0, res.stderr
    text = md.read_text()
    assert res.stdout == text
    # the decision table: the few columns a reader decides on, nothing else
    head = [ln for ln in text.splitlines() if ln.startswith("| setting |")][0]
    assert head == ("| setting | E_avg | E_disp | overlap agents / walls [m] | mobility | cost per query [s] | "
                    "speedup per query | no overlap |")
    assert "| (10,20) eq / local | 4.00e-02 | 1.60e-01 | 5.00e-11 / 0.00e+00 | 0.950 | 1.00e-02 | 8 | yes |" in text
    # the diverged setting, over the other samples; a corrected setting says so
    assert "| (10,20) eq / local + local correction | 1.00e-03* |" in text
    assert "| ML mlp n=4 + projection |" in text and "| full model (exact) |" in text
    assert "frac_corrected" not in text and "t50" not in text
    assert "| 0.05 | (10,20) eq / local | 4.00e-02 |" in text
    rows = list(csv.DictReader(open(out_csv)))
    assert [r["label"] for r in rows] == [EXPECT[k] for k in sorted(EXPECT)]
    # every row with every column, the sweep table's unknown columns last
    full = list(csv.DictReader(open(rows_csv)))
    assert len(full) == len(SETTINGS) + 4 + 1
    cols = list(full[0])
    assert cols[:2] == ["label", "kind"] and cols[-2:] == ["frac_corrected", "t_correct"]
    for c in ("t50_err", "t90_n", "agents_not_left", "speedup_step", "speedup_uzawa", "t_step", "diverged"):
        assert c in cols, c
    s3 = [r for r in full if r["kind"] == "rom" and r["setting"] == "3"][0]
    assert float(s3["frac_corrected"]) == 0.3 and float(s3["t50_err"]) == 0.1 and s3["no_overlap"] == "yes"
    assert not [p for p in os.listdir(tmp_path) if ".partial" in p]


def test_cli_per_step_table_without_query_columns(tmp_path):
    res = run(write_sweep(tmp_path / "t.csv", with_query=False))
    assert res.returncode == 0, res.stderr
    head = [ln for ln in res.stdout.splitlines() if ln.startswith("| setting |")][0]
    assert "| cost per step [s] | speedup per step |" in head


@pytest.mark.parametrize("args,expect", [
    (["{tmp}/missing.csv"], "sweep table not found"),
    (["{bad}"], "missing column(s)"),
    (["{good}", "--levels", "0", "0.1"], "--levels must be positive"),
    (["{good}", "--ml", "{bad}"], "missing column(s)"),
    (["{good}", "-o", "{good}"], "refusing to overwrite an input"),
])
def test_bad_inputs(tmp_path, args, expect):
    bad = tmp_path / "bad.csv"
    bad.write_text("setting,set,n\n1,valid,4\n")
    good = write_sweep(tmp_path / "t.csv")
    res = run(*[a.format(tmp=tmp_path, bad=bad, good=good) for a in args])
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("study_table: error:") and expect in lines[0], lines


def test_tradeoff_plot_marks_overlap_free_and_front(tmp_path, capsys):
    table = write_sweep(tmp_path / "t.csv")
    out = tmp_path / "p.png"
    # plot_tradeoff takes ML HDF5 files; the CSV rows go through study_table.ml_rows
    rows = plot_tradeoff.read_rows(table)
    mlr = study_table.ml_rows(write_ml(tmp_path / "ml.csv"))
    front = plot_tradeoff.plot_tradeoff(rows, out, ml_rows=mlr)
    assert os.path.getsize(out) > 5000 and front
    assert plot_tradeoff.main([str(table), "-o", str(tmp_path / "q.png")]) == 0
    text = capsys.readouterr().out
    assert "E_avg <= 0.05: cheapest without overlap (t_query): (10,20) eq / local (1.00e-02 s)" in text
    assert "E_avg <= 0.01: cheapest without overlap (t_query): full model (exact)" in text


def test_tradeoff_labels_only_the_fronts_and_never_overlap(tmp_path):
    """Ten settings on one crowded front plus four dominated ones: only the front's points carry a
    label, and no two labels of a panel overlap."""
    from matplotlib.text import Annotation

    crowded = [(k, "eq", "cone", 0.1 * (1 - 0.02 * k), 0.1, 0.1, 0.005 * (1 + 0.03 * k), 0, -1.0)
               for k in range(1, 11)]
    crowded += [(k, "none", "cone", 0.2, 0.1, 0.1, 0.01 * k, 0, -1.0) for k in range(11, 15)]
    table = write_sweep(tmp_path / "t.csv", settings=crowded)
    rows = plot_tradeoff.read_rows(table)
    fig, front = plot_tradeoff.draw_tradeoff(rows, ml_rows=study_table.ml_rows(write_ml(tmp_path / "ml.csv")))
    assert sorted(r["setting"] for r in front) == list(range(1, 11))
    renderer = fig.canvas.get_renderer()
    ax1, ax2, ax3 = fig.axes
    n_labels = {}
    for ax in (ax1, ax2, ax3):
        boxes = [a.get_window_extent(renderer) for a in ax.texts if isinstance(a, Annotation)]
        n_labels[ax] = len(boxes)
        for i in range(len(boxes)):
            for j in range(i):
                assert not boxes[i].overlaps(boxes[j]), (ax.get_title(), i, j)
    assert n_labels[ax1] == len(front)                # the dominated settings carry no label
    assert n_labels[ax2] == len(front)
