#!/usr/bin/env python3
"""Timeline of a crowd_snapshots run: one row per rank, one bar per sample (its start and wall
time from the database's stats/start, stats/time, stats/rank), the setup before the sample loop
and the end of the database (from the run's --summary JSON; with its `phase_marks`, each rank's
own phases outside the loop as thin bars: where a rank waits for another shows there).

Usage: plot_timeline.py DATABASE.h5 SUMMARY.json --out timeline.png [--title TEXT]

Samples resumed from an earlier run carry that run's clock: the figure is meant for
uninterrupted runs.
Exit status 2 with a one-line message on a bad input; the figure is written only when complete.
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402


def load(db, summary):
    with cio.open_h5(db, cio.DB_SCHEMA, "snapshot database") as f:
        rows = []
        for s in ("train", "valid"):
            if s + "/stats/start" not in f:
                raise cio.InputError("'%s' has no %s/stats/start (written before the timeline was recorded)"
                                     % (db, s))
            st = cio.dataset(f, s + "/stats/start").reshape(-1)
            tm = cio.dataset(f, s + "/stats/time").reshape(-1)
            rk = cio.dataset(f, s + "/stats/rank").reshape(-1)
            rows.append((np.full(st.shape, s), st, tm, rk))
    sets = np.concatenate([r[0] for r in rows])
    start = np.concatenate([r[1] for r in rows])
    time = np.concatenate([r[2] for r in rows])
    rank = np.concatenate([r[3] for r in rows])
    try:
        js = json.load(open(summary))
    except (OSError, ValueError) as exc:
        raise cio.InputError("cannot read the summary '%s': %s" % (summary, exc)) from None
    return sets, start, time, rank, js


def phase_table(js):
    """Print each rank's time in each phase (ms; from the summary's phase_marks), if present."""
    if "phase_marks" not in js or "phase_names" not in js:
        return
    names = js["phase_names"].split(",")
    p = int(js["ranks"])
    flat = np.asarray(js["phase_marks"], dtype=float)
    if flat.size != len(names) * p:
        return
    m = flat.reshape(p, len(names))
    print("| phase (ends at) | " + " | ".join("rank %d (ms)" % r for r in range(p)) + " |")
    print("|---|" + "---|" * p)
    prev = np.zeros(p)
    for i, n in enumerate(names):
        print("| %s | %s |" % (n, " | ".join("%.1f" % (1e3 * (m[r, i] - prev[r])) for r in range(p))))
        prev = m[:, i]


def main():
    ap = argparse.ArgumentParser(description="timeline figure of a crowd_snapshots run")
    ap.add_argument("database")
    ap.add_argument("summary")
    ap.add_argument("--out", required=True)
    ap.add_argument("--title", default=None)
    a = ap.parse_args()
    try:
        sets, start, time, rank, js = load(a.database, a.summary)
    except cio.InputError as exc:
        print("plot_timeline.py: error: %s" % exc, file=sys.stderr)
        sys.exit(cio.EXIT_BAD_INPUT)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    phase_table(js)

    p = int(js["ranks"])
    setup = float(js.get("wall_time_setup", 0.0))
    asm0 = float(js.get("assembly_start", js["wall_time"] - js["wall_time_assembly"]))
    wall = float(js["wall_time"])
    # per-rank phase marks (s since each rank's start of the run), when the summary has them
    marks, names = None, None
    if "phase_marks" in js and "phase_names" in js:
        names = js["phase_names"].split(",")
        flat = np.asarray(js["phase_marks"], dtype=float)
        if flat.size == len(names) * p:
            marks = flat.reshape(p, len(names))
    cmap = plt.get_cmap("tab20b")
    phase_color = {n: cmap(i % 20) for i, n in enumerate(names or [])}
    fig, ax = plt.subplots(figsize=(11, 1.6 + 0.45 * p + (1.2 if marks is not None else 0.0)))
    colors = {"train": "tab:blue", "valid": "tab:orange"}
    for r in range(p):
        for s in ("train", "valid"):
            m = (rank == r) & (sets == s)
            ax.broken_barh(list(zip(start[m], time[m])), (r - 0.4, 0.8), facecolors=colors[s],
                           edgecolor="none", label=s if r == 0 else None)
        if marks is None:
            ax.broken_barh([(0.0, setup)], (r - 0.4, 0.8), facecolors="0.8", label="setup" if r == 0 else None)
            ax.broken_barh([(asm0, wall - asm0)], (r - 0.4, 0.8), facecolors="tab:green",
                           label="assembly" if r == 0 else None)
        else:
            # this rank's phases outside the sample loop (between consecutive phase marks), as
            # thin bars under the samples
            i_loop, i_last = names.index("loop_start"), names.index("last_ticket")
            t_prev = 0.0
            for i, name in enumerate(names):
                t = marks[r][i]
                if (i <= i_loop or i > i_last) and t > t_prev:
                    ax.broken_barh([(t_prev, t - t_prev)], (r - 0.45, 0.25), facecolors=phase_color[name],
                                   edgecolor="none", label=name if r == 0 else None)
                t_prev = max(t_prev, t)
    ax.set_yticks(range(p))
    ax.set_yticklabels(["rank %d" % r for r in range(p)])
    ax.set_xlabel("wall time since the start of the run (s)")
    ax.set_xlim(0, wall * 1.01)
    eff = js.get("busy_time_efficiency", js.get("parallel_efficiency"))
    ax.set_title(a.title or "%s: %d samples on %d ranks, busy-time efficiency %.2f, load balance %.3f" % (
        os.path.basename(a.database), len(start), p, eff, js["load_balance"]))
    if marks is None:
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    else:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.45), ncol=6, fontsize=7)
    fig.tight_layout()
    tmp = a.out + ".partial.png"
    fig.savefig(tmp, dpi=120)
    os.replace(tmp, a.out)
    print("wrote %s" % a.out)


if __name__ == "__main__":
    main()
