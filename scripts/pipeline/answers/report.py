"""The outputs of a selection report: the Markdown table a user acts on, the JSON, the figure
(stated error against total cost per method, one panel per question statistic)."""
import json

import numpy as np


def fmt(v, digits=4):
    if v is None:
        return "-"
    if isinstance(v, list):
        return f"map of {len(v)} points"
    return f"{v:.{digits}g}"


def _pc(x):
    return "unbounded" if x is None else f"{100 * x:.3g}%"


def markdown(report):
    """One row per (question, statistic, accuracy)."""
    lines = [f"Answers for case '{report['case']}' ({report['questions_file']}), intervals at "
             f"{100 * report['confidence']:g}% confidence; costs in CPU seconds from nothing.", "",
             "| question | QoI | statistic | accuracy | cheapest method | answer | interval | "
             "stated error | total cost | M0 cost | gain vs M0 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        if r.get("method") is None:
            lines.append(f"| {r['question']} | {r['qoi']} | {r['statistic']} | {100 * r['accuracy']:g}% "
                         f"| none within the budget | - | - | - | - | {fmt(r['m0_cost'])} | - |")
            continue
        if isinstance(r["value"], list):
            interval = "per point (JSON)"
        else:
            interval = f"[{fmt(r['lo'])}, {fmt(r['hi'])}]"
        m0 = fmt(r["m0_cost"]) + (" (planned)" if r.get("m0_cost_planned") else "")
        reached = "" if r["reached"] else " (missed)"
        gain = f"{r['gain_vs_m0']:.3g}x" if r.get("gain_vs_m0") else "-"
        lines.append(f"| {r['question']} | {r['qoi']} | {r['statistic']} | {100 * r['accuracy']:g}% | "
                     f"{r['method']} | {fmt(r['value'])} | {interval} | "
                     f"{_pc(r['stated_error'])}{reached} | {fmt(r['cost'])} | {m0} | {gain} |")
    lines += by_method(report)
    for p in report.get("pilots", []):
        lines += ["", f"Pilot of '{p['question']}' ({p['qoi']}, {p['runs']} joint runs): what decides "
                  "between the methods.", "",
                  "| model | CPU s per run | mean | std | corr. with exact | Spearman | bias (exact - model) |",
                  "|---|---|---|---|---|---|---|"]
        for m in p["models"]:
            lines.append(f"| {m['model']} | {fmt(m['cpu_per_run'])} | {fmt(m['mean'])} | {fmt(m['std'])} | "
                         f"{fmt(m['corr'], 3)} | {fmt(m['spearman'], 3)} | {fmt(m['bias'])} |")
    return "\n".join(lines) + "\n"


METHODS = ("M0", "M1", "M2", "M3")


def uses_low(label):
    """Whether a candidate's label names a method that runs a low fidelity (M2, or M3 with one
    kept: an MFMC plan that kept the exact model alone does not)."""
    return label.startswith(("M2", "M3")) and "exact only" not in label


def cheapest_by_method(report, question, statistic, eps):
    """Per method (M0..M3) the cheapest candidate of one question statistic whose stated (or,
    planned, targeted) error reaches eps, whatever the budget; and the cheapest using a low
    fidelity. {method: candidate or None, 'low': candidate or None}."""
    cands = [c for c in report["candidates"] if (c["question"], c["statistic"]) == (question, statistic)
             and c["stated_error"] is not None and c["stated_error"] <= eps * (1 + 1e-9)]
    out = {}
    for m in METHODS:
        out[m] = min((c for c in cands if c["method"].startswith(m)), key=lambda c: c["cost"], default=None)
    out["low"] = min((c for c in cands if uses_low(c["method"])), key=lambda c: c["cost"], default=None)
    return out


def by_method(report):
    """Markdown lines: for every question statistic and accuracy the cheapest candidate of each
    method reaching it, also beyond the budget (a planned M0 / M3 is its predicted cost), and the
    gain of the cheapest method using a low fidelity over M0: what a target on the reduced
    model is judged by when another method wins the row."""
    cap = report.get("max_cost")
    keys = list(dict.fromkeys((r["question"], r["statistic"]) for r in report["rows"]))
    if not keys:
        return []
    lines = ["", "Cheapest candidate of each method reaching the accuracy (total CPU s; p: planned, "
             "predicted from the pilot; *: beyond the budget"
             + (f" of {fmt(cap)} CPU s" if cap is not None else "") + "):", "",
             "| question | statistic | accuracy | M0 | M1 | M2 | M3 | using a low fidelity: gain vs M0 |",
             "|---|---|---|---|---|---|---|---|"]

    def cell(c):
        if c is None:
            return "-"
        over = "*" if cap is not None and c["cost"] > cap else ""
        return f"{fmt(c['cost'])}{' p' if c['planned'] else ''}{over} ({c['method']})"
    for q, stat in keys:
        for eps in report["accuracy"]:
            best = cheapest_by_method(report, q, stat, eps)
            low, m0 = best["low"], best["M0"]
            gain = f"{m0['cost'] / low['cost']:.3g}x" if low and m0 and low["cost"] > 0 else "-"
            lines.append(f"| {q} | {stat} | {100 * eps:g}% | "
                         + " | ".join(cell(best[m]) for m in METHODS) + f" | {gain} |")
    return lines


def finite(obj):
    """The report with every non-finite number (an unbounded interval end) as None."""
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_json(report, path):
    """The report as JSON (unbounded interval ends as null)."""
    with open(path, "w", encoding="utf-8") as f:
        json.dump(finite(report), f, indent=1, allow_nan=False)
        f.write("\n")


def figure(report, path):
    """Stated relative error against total cost, per method, one panel per question statistic;
    planned candidates hollow, run ones filled, the chosen answers as stars."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(dict.fromkeys((c["question"], c["statistic"]) for c in report["candidates"]))
    n = max(len(keys), 1)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    colors = {"M0": "k", "M1": "tab:blue", "M2": "tab:orange", "M3": "tab:green"}
    for ax, key in zip(axes.ravel(), keys):
        for m, col in colors.items():
            pts = [c for c in report["candidates"] if (c["question"], c["statistic"]) == key
                   and c["method"].startswith(m) and c["stated_error"] is not None and c["cost"] > 0]
            for planned in (False, True):
                sel = [c for c in pts if c["planned"] == planned]
                if sel:
                    ax.scatter([c["cost"] for c in sel], [max(c["stated_error"], 1e-6) for c in sel],
                               facecolors="none" if planned else col, edgecolors=col, s=22,
                               label=f"{m}{' (planned)' if planned else ''}")
        for r in report["rows"]:
            if (r["question"], r["statistic"]) == key and r.get("method") and r["stated_error"] is not None:
                ax.scatter([r["cost"]], [max(r["stated_error"], 1e-6)], marker="*", s=90,
                           color=colors[r["method"][:2]], edgecolors="k", zorder=3)
        for eps in report["accuracy"]:
            ax.axhline(eps, color="0.7", lw=0.7, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{key[0]}: {key[1]}", fontsize=9)
        ax.set_xlabel("total cost [CPU s]")
        ax.set_ylabel("stated relative error")
        ax.legend(fontsize=6)
    for ax in axes.ravel()[len(keys):]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary_numbers(report):
    """(rows reached, rows) for a one-line progress summary."""
    reached = sum(1 for r in report["rows"] if r.get("reached"))
    return reached, len(report["rows"])

