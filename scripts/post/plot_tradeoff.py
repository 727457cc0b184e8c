#!/usr/bin/env python3
"""Accuracy vs cost of the reduced models of a crowd_rom sweep (the paper's Pareto plots).

Input: the sweep table written by crowd_rom (CSV with the header
setting,set,n,r,n_basis,hyper,...,E_avg,...,t_step_rom,t_step_fom_uzawa,t_step_fom_exact,
speedup_uzawa,speedup_exact) or the ROM run file itself (schema crowdrom-romrun; E_avg and E_max
then come from each setting's validation E_mu). One PNG with two panels:
(a) E_avg vs the ROM time per step, with the FOM times per step (Uzawa and exact solver) as
reference lines; (b) E_avg vs the speedup against both FOM references. The Pareto front
(settings no other setting beats in both error and cost) is highlighted, and only its points
are labelled (N, R, hyper); the other settings are told apart by their marker (the legend names
the hyper-reduction). Labels that would overlap are moved apart. A setting with diverged samples (column samples_diverged: crowd_rom stopped
them, its E_avg is over the other samples) is drawn as a red cross, labelled with the count, and
kept off the Pareto front (the legend gives the count); one whose samples all diverged (E_avg -1) is left out, with a note.
ML-corrected results (files of scripts/pipeline/ml_correct.py) can be overlaid (--ml):
the best n of each regressor, at the ROM step time plus the prediction time per step.

Settings without overlap (deepest agent-agent and agent-wall overlap <= --overlap-tol m, no
diverged sample; the columns max_overlap_agents / max_overlap_walls, or max_overlap) are ringed in
green. A third panel (c) answers "for each error level, the cheapest setting that has no
overlap": E_avg against the cost per query (per step when the table has no per-query columns),
the front of the settings without overlap as a staircase, the exact full model as a reference
(error 0: a vertical line), and the ML-corrected positions after their exact projection
(crowd_project; from --ml) as green diamonds; only the points of that staircase are labelled;
the answers are also printed per level
(scripts/post/study_table.py prints the whole table). Columns the script does not know are ignored,
and any contacts name is accepted.

Exit codes: 0 success, 2 missing/unreadable input or missing columns (message on stderr).
"""
import argparse
import math
import os
import sys

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402
import study_table  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "plot_tradeoff"
NEEDED = ("setting", "set", "n", "r", "hyper", "E_avg", "t_step_rom", "t_step_fom_uzawa",
          "t_step_fom_exact", "speedup_uzawa", "speedup_exact")
HYPER_MARKERS = {"none": "s", "eim": "D", "eq": "o"}


def read_csv_rows(path):
    """Rows of the sweep CSV as dicts (numbers converted; checked by crowdrom_io.read_csv_table)."""
    return cio.read_csv_table(path, NEEDED, "sweep table")[1]


def read_romrun_rows(path):
    """The same rows from a ROM run file (validation set of every setting)."""
    rows = []
    with cio.open_h5(path, cio.ROMRUN_SCHEMA, "ROM run file") as f:
        m = cio.romrun_meta(f)
        for k in range(1, m["n_settings"] + 1):
            s = cio.romrun_setting(f, k)
            for name in s["sets"]:
                e = cio.dataset(f, f"setting_{k}/{name}/E_mu", finite=True).ravel()
                g = f[f"setting_{k}/{name}"]
                div = cio.dataset(g, "diverged_step").ravel() > 0 if "diverged_step" in g else np.zeros(e.size, bool)
                kept = e[~div]
                rows.append({"setting": k, "set": name, "n": s["n"], "r": s["r"],
                             "n_basis": s["n_basis"], "hyper": s["hyper"],
                             "contacts": s["contacts"], "E_avg": float(kept.mean()) if kept.size else -1.0,
                             "E_max": float(kept.max()) if kept.size else -1.0, "t_step_rom": s["t_step"],
                             "samples_diverged": int(div.sum()),
                             "t_step_fom_uzawa": m["t_step_uzawa"], "t_step_fom_exact": m["t_step_exact"],
                             "speedup_uzawa": s["speedup_uzawa"], "speedup_exact": s["speedup_exact"]})
    if not rows:
        raise InputError(f"'{path}': no settings")
    return rows


def read_rows(path):
    """Rows from a CSV (by extension) or a ROM run file."""
    if str(path).lower().endswith(".csv"):
        return read_csv_rows(path)
    return read_romrun_rows(path)


def read_ml_points(paths):
    """Best-n point of each regressor of each ML output file."""
    pts = []
    for path in paths:
        with cio.open_h5(path, cio.ML_SCHEMA, "ML output") as f:
            a = f.attrs
            t_rom = float(cio.scalar(a["t_step_rom"]))
            for reg in ("random_forest", "mlp"):
                if reg not in f:
                    continue
                g = f[reg]
                i = int(np.argmin(cio.dataset(g, "E_avg")))
                n_vals = cio.dataset(f, "n_values")
                pts.append({"label": f"ML {reg} ({int(cio.scalar(a['pair_n']))},{int(cio.scalar(a['pair_r']))}) "
                                     f"n={int(n_vals[i])}",
                            "E_avg": float(g["E_avg"][i]), "t_step": float(g["t_step"][i]),
                            "speedup_uzawa": float(g["speedup"][i]),
                            "speedup_exact": float(g["speedup_exact"][i]), "t_step_rom": t_rom})
    return pts


def pareto_mask(cost, err):
    """True for points not dominated: no other point has cost <= and err <= with one strict."""
    cost, err = np.asarray(cost, float), np.asarray(err, float)
    mask = np.ones(cost.size, bool)
    for i in range(cost.size):
        dom = (cost <= cost[i]) & (err <= err[i]) & ((cost < cost[i]) | (err < err[i]))
        mask[i] = not dom.any()
    return mask


def _label(r):
    corr = str(r.get("correction") or "none")
    return f"({r['n']},{r['r']},{r['hyper']})" + (f" + {corr} correction" if corr != "none" else "")


def _no_overlap_labels(fig, ax, labels, max_moves=40):
    """Move the labels ``labels`` (annotations of ``ax``) down or up, one line at a time, until no
    two of their boxes intersect (at most ``max_moves`` moves each)."""
    renderer = fig.canvas.get_renderer()
    placed = []
    for lab in labels:
        x0, y0 = lab.xyann
        for k in range(max_moves + 1):
            box = lab.get_window_extent(renderer).expanded(1.02, 1.1)
            if not any(box.overlaps(p) for p in placed):
                break
            step = (k // 2 + 1) * (1 if k % 2 else -1)         # below, above, further below, ...
            lab.xyann = (x0, y0 + step * 1.15 * lab.get_fontsize())
        placed.append(lab.get_window_extent(renderer))


def plot_tradeoff(rows, out, ml_points=(), set_name="valid", title=None, dpi=120, ml_rows=(),
                  overlap_tol=1e-10):
    """Draw the three panels into ``out`` (PNG); return the Pareto-optimal rows of panel (a).
    ``ml_rows``: rows of study_table.ml_rows (ML results, corrected and projected) for panel (c)."""
    import matplotlib.pyplot as plt

    fig, front = draw_tradeoff(rows, ml_points, set_name, title, ml_rows, overlap_tol)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return front


def draw_tradeoff(rows, ml_points=(), set_name="valid", title=None, ml_rows=(), overlap_tol=1e-10):
    """The figure of ``plot_tradeoff`` and the Pareto-optimal rows of panel (a)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if str(r["set"]) == set_name]
    if not rows:
        raise InputError(f"no rows of set '{set_name}'")
    lost = [r for r in rows if float(r["E_avg"]) < 0]
    rows = [r for r in rows if float(r["E_avg"]) >= 0]
    if not rows:
        raise InputError(f"no row of set '{set_name}' has an E_avg (every sample diverged, or no reference)")
    err = np.array([float(r["E_avg"]) for r in rows])
    t = np.array([float(r["t_step_rom"]) for r in rows])
    sp_u = np.array([float(r["speedup_uzawa"]) for r in rows])
    sp_e = np.array([float(r["speedup_exact"]) for r in rows])
    div = np.array([int(r.get("samples_diverged", 0) or 0) for r in rows])
    # a setting with diverged samples is not a trade-off a user can take: off the front
    big = np.full(t.size, np.inf)
    front = pareto_mask(np.where(div > 0, big, t), np.where(div > 0, big, err)) & (div == 0)
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(18, 5.5))
    for hyper in sorted({str(r["hyper"]) for r in rows}):
        sel = np.array([str(r["hyper"]) == hyper for r in rows]) & (div == 0)
        mk = HYPER_MARKERS.get(hyper, "^")
        ax1.scatter(t[sel], err[sel], marker=mk, c="tab:blue", alpha=0.6, label=f"ROM, hyper = {hyper}")
        ax2.scatter(sp_u[sel], err[sel], marker=mk, c="tab:blue", alpha=0.6,
                    label=f"vs Uzawa FOM, hyper = {hyper}")
        ax2.scatter(sp_e[sel], err[sel], marker=mk, facecolors="none", edgecolors="tab:orange",
                    label=f"vs exact FOM, hyper = {hyper}")
    o = np.argsort(t[front])
    ax1.plot(t[front][o], err[front][o], "-", color="tab:red", lw=1.5, label="Pareto front")
    ax1.scatter(t[front], err[front], s=90, facecolors="none", edgecolors="tab:red", lw=1.5)
    if np.any(div > 0):
        ax1.scatter(t[div > 0], err[div > 0], marker="x", c="tab:red", label="with diverged samples")
        ax2.scatter(sp_u[div > 0], err[div > 0], marker="x", c="tab:red", label="with diverged samples")
    fronts2 = {}
    for name, sp, color in (("uzawa", sp_u, "tab:red"), ("exact", sp_e, "tab:purple")):
        f2 = pareto_mask(np.where(div > 0, np.inf, -sp), np.where(div > 0, np.inf, err)) & (div == 0)
        o2 = np.argsort(sp[f2])
        ax2.plot(sp[f2][o2], err[f2][o2], "-", color=color, lw=1.2)
        fronts2[name] = f2
    # labels on the fronts only (every other point is named by its marker in the legend)
    labels = {ax1: [], ax2: [], ax3: []}
    for i in np.flatnonzero(front)[np.argsort(t[front])]:
        labels[ax1].append(ax1.annotate(_label(rows[i]), (t[i], err[i]), fontsize=7, xytext=(4, 3),
                                        textcoords="offset points"))
    for i in np.flatnonzero(fronts2["uzawa"])[np.argsort(sp_u[fronts2["uzawa"]])]:
        labels[ax2].append(ax2.annotate(_label(rows[i]), (sp_u[i], err[i]), fontsize=7, xytext=(4, 3),
                                        textcoords="offset points"))
    if np.any(div > 0):
        ax1.plot([], [], ls="none", label="diverged samples: " + ", ".join(
            f"{_label(r)} {d}" for r, d in zip(rows, div) if d > 0))
    if lost:
        fig.text(0.01, 0.01, "not drawn (every sample diverged or no reference): " +
                 ", ".join(_label(r) for r in lost), fontsize=7)
    t_uz, t_ex = float(rows[0]["t_step_fom_uzawa"]), float(rows[0]["t_step_fom_exact"])
    ax1.axvline(t_uz, color="k", ls="--", lw=1, label=f"FOM Uzawa {t_uz:.2e} s")
    ax1.axvline(t_ex, color="0.4", ls=":", lw=1, label=f"FOM exact {t_ex:.2e} s")
    ax2.axvline(1.0, color="0.5", ls=":", lw=1)
    for p in ml_points:
        ax1.scatter([p["t_step"]], [p["E_avg"]], marker="*", s=140, c="tab:green", zorder=5)
        labels[ax1].append(ax1.annotate(p["label"], (p["t_step"], p["E_avg"]), fontsize=7, color="tab:green",
                                        xytext=(4, -9), textcoords="offset points"))
        ax2.scatter([p["speedup_uzawa"]], [p["E_avg"]], marker="*", s=140, c="tab:green", zorder=5)
        ax2.scatter([p["speedup_exact"]], [p["E_avg"]], marker="*", s=140, facecolors="none",
                    edgecolors="tab:green", zorder=5)
        labels[ax2].append(ax2.annotate(p["label"], (p["speedup_uzawa"], p["E_avg"]), fontsize=7,
                                        color="tab:green", xytext=(4, -9), textcoords="offset points"))
    if ml_points:
        ax1.scatter([], [], marker="*", c="tab:green", label="ML-corrected (best n)")
        ax2.scatter([], [], marker="*", c="tab:green", label="ML-corrected (best n)")
    # settings without overlap, and panel (c): the cheapest of them for each error level
    uni = [study_table.unify_row(r) for r in rows]
    free = np.array([study_table.no_overlap(u, overlap_tol) for u in uni])
    if free.any():
        ax1.scatter(t[free], err[free], s=160, facecolors="none", edgecolors="tab:green", lw=1.2,
                    label=f"no overlap (<= {overlap_tol:g} m)")
    cand = uni + [study_table.fom_row(rows)] + list(ml_rows)
    free_front, key = study_table.overlap_free_front(cand, overlap_tol, "E_avg")
    for u in cand:
        if u["kind"] == "fom" or u[key] <= 0 or u["E_avg"] < 0:
            continue
        ok = study_table.no_overlap(u, overlap_tol)
        mk = {"rom": HYPER_MARKERS.get(str(u.get("hyper")), "^"), "ml": "*", "ml+proj": "D"}[u["kind"]]
        col = "tab:green" if u["kind"] != "rom" else "tab:blue"
        ax3.scatter([u[key]], [u["E_avg"]], marker=mk, s=60 if u["kind"] != "rom" else 36,
                    facecolors=col if ok else "none", edgecolors=col, zorder=4)
    fom = study_table.fom_row(rows)
    if fom[key] > 0:
        ax3.axvline(fom[key], color="k", ls="--", lw=1, label=f"exact full model {fom[key]:.2e} s (error 0)")
    pts = [u for u in free_front if u["E_avg"] > 0]
    if pts:
        xs, ys = [pts[0][key]], [pts[0]["E_avg"]]
        for u in pts[1:]:
            xs += [u[key], u[key]]
            ys += [ys[-1], u["E_avg"]]
        ax3.plot(xs, ys, "-", color="tab:red", lw=1.5, label="cheapest without overlap per error level")
        for u in pts:
            labels[ax3].append(ax3.annotate(u["label"], (u[key], u["E_avg"]), fontsize=6, xytext=(4, 3),
                                            textcoords="offset points"))
    ax3.scatter([], [], marker="o", c="tab:blue", label="ROM (filled: no overlap)")
    if ml_rows:
        ax3.scatter([], [], marker="*", facecolors="none", edgecolors="tab:green", label="ML-corrected")
        ax3.scatter([], [], marker="D", c="tab:green", label="ML-corrected + exact projection")
    ax3.set_xlabel("cost per query (s)" if key == "t_query" else "cost per step (s) (no per-query columns)")
    ax3.set_title("(c) the cheapest setting without overlap for each error level")
    for ax in (ax1, ax2, ax3):
        ax.set_xscale("log")
        ax.margins(x=0.25, y=0.1)
        if np.all(err > 0) and ax is not ax3:
            ax.set_yscale("log")
        if ax is ax3 and any(u["E_avg"] > 0 for u in cand):
            ax.set_yscale("log")
        ax.set_ylabel(r"$E_{\rm avg}$ (validation)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    ax1.set_xlabel("time per step (s)")
    ax1.set_title("(a) accuracy vs cost")
    ax2.set_xlabel("speedup with respect to the FOM")
    ax2.set_title("(b) accuracy vs speedup (filled: Uzawa FOM, open: exact FOM)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    for ax, labs in labels.items():
        _no_overlap_labels(fig, ax, labs)
    return fig, [r for r, m in zip(rows, front) if m]


def main(argv=None):
    ap = argparse.ArgumentParser(prog="plot_tradeoff.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", help="sweep CSV of crowd_rom, or the ROM run file (HDF5)")
    ap.add_argument("-o", "--output", help="PNG to write (default: <input>_tradeoff.png)")
    ap.add_argument("--set", default="valid", help="which set's rows to draw (default valid)")
    ap.add_argument("--ml", nargs="+", default=[], help="ML output files of ml_correct.py to overlay")
    ap.add_argument("--overlap-tol", type=float, default=1e-10,
                    help="deepest overlap counted as none [m] (default 1e-10)")
    ap.add_argument("--title", default=None)
    ap.add_argument("--dpi", type=int, default=120)
    args = ap.parse_args(argv)
    out = args.output or (os.path.splitext(args.input)[0] + "_tradeoff.png")
    try:
        if args.dpi < 1:
            raise InputError(f"--dpi {args.dpi}: must be >= 1")
        if not (math.isfinite(args.overlap_tol) and args.overlap_tol >= 0):
            raise InputError(f"--overlap-tol {args.overlap_tol}: must be a finite number >= 0")
        cio.check_outputs([("output", out)], [("input", args.input)] + [("ML output", p) for p in args.ml])
        rows = read_rows(args.input)
        mlr = [u for p in args.ml for u in study_table.ml_rows(p)]
        with cio.OutputSet() as outs:
            front = plot_tradeoff(rows, outs.tmp(out), read_ml_points(args.ml), args.set, args.title, args.dpi,
                                  ml_rows=mlr, overlap_tol=args.overlap_tol)
            outs.commit()
        uni = [study_table.unify_row(r) for r in rows if str(r["set"]) == args.set]
        per_level, key = study_table.cheapest_per_level(uni + [study_table.fom_row(uni)] + mlr,
                                                        study_table.DEFAULT_LEVELS, args.overlap_tol)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return cio.EXIT_BAD_INPUT
    print(f"{PROG}: Pareto front: " + ", ".join(_label(r) for r in front))
    for level, r in per_level:
        print(f"{PROG}: E_avg <= {level:g}: cheapest without overlap ({key}): " +
              (f"{r['label']} ({r[key]:.2e} s)" if r else "none"))
    print(f"{PROG}: wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
