#!/usr/bin/env python3
"""The accuracy / cost table of a study and, for each error level, the cheapest setting that has
no overlap (stage 6 of scripts/run_study.sh).

    study_table.py results/<case>_table.csv [--ml results/<case>_ml.csv ...] [--set valid]
        [--error E_avg|E_disp] [--levels 0.01 0.02 0.05 0.1 0.2 0.5] [--overlap-tol 1e-10]
        [-o table.md] [--csv cheapest.csv] [--rows-csv rows.csv]

Rows: every setting of crowd_rom's sweep table (the chosen set), the ML-corrected settings of
ml_correct.py (its --csv or its HDF5 output: one row per regressor and n, as corrected and as
corrected *and projected* by crowd_project), and the exact full model itself (error 0, no
overlap, its per-query and per-step cost from the sweep table), so that every error level has an
answer. The Markdown table keeps the columns a reader decides on: setting, E_avg, E_disp, the
deepest overlaps agent-agent / agent-wall, mobility, the cost per query and the speedup per query
against the exact full model, and "no overlap" (deepest overlap <= --overlap-tol m, no diverged
sample). Every other column (evacuation-time errors, agents not out, diverged samples, the costs
and speedups per step, columns of the sweep table this script does not know, such as a new
contacts mode's measures) goes to --rows-csv, one line per row; any contacts name is accepted.

"Cheapest per error level": for each level L, among the rows without overlap whose error (the
--error measure) is <= L, the one with the smallest cost per query (per step when the table has
no per-query columns; the script says which, and the table then shows the cost and speedup per
step); the front of such rows is also printed (rows without overlap that no other row without
overlap beats in both error and cost).

Exit status: 0, 2 for bad input (one 'study_table: error:' line), 1 for other failures.
"""
import argparse
import csv
import io
import math
import os
import sys

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "study_table"
NEEDED = ("setting", "set", "n", "r", "hyper", "E_avg", "t_step_rom", "t_step_fom_exact", "speedup_exact")
#: columns the table shows in its own way (anything else in the sweep table is an extra column)
KNOWN = set(NEEDED) | {
    "n_basis", "contacts", "solver", "m_v", "m_b", "m_d", "E_max", "E_proj_avg", "max_overlap",
    "agents_not_left", "agents_not_left_fom", "infeasible_steps", "capped_steps", "t_step_fom_uzawa",
    "speedup_uzawa", "extrapolating", "mobility", "samples_diverged", "E_disp", "max_overlap_agents",
    "max_overlap_walls", "t50_err", "t50_n", "t50_rom_missed", "t50_fom_missed", "t90_err", "t90_n",
    "t90_rom_missed", "t90_fom_missed", "t_query_rom", "t_query_fom_exact", "speedup_query_exact", "correction"}
ML_NEEDED = ("regressor", "n", "E_avg", "t_step", "speedup_exact")
DEFAULT_LEVELS = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


def _f(r, key, default=-1.0):
    """Float value of a row's column (default when absent or empty)."""
    v = r.get(key)
    if v is None or v == "":
        return default
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def read_csv(path, needed, what):
    """(header, rows) of a sweep or ML table, checked by crowdrom_io.read_csv_table (NaN, Inf,
    text in a number column, ragged rows and negative times refused)."""
    return cio.read_csv_table(path, needed, what)


def sweep_rows(path, set_name="valid"):
    """(extra column names, rows of set ``set_name``) of crowd_rom's sweep table; each row gets
    the common keys of the table (kind = 'rom', label, cost per step and per query, ...)."""
    cols, rows = read_csv(path, NEEDED, "sweep table")
    extras = [c for c in cols if c not in KNOWN]
    rows = [r for r in rows if str(r["set"]) == set_name]
    if not rows:
        raise InputError(f"'{path}': no rows of set '{set_name}'")
    return extras, [unify_row(r) for r in rows]


def unify_row(r):
    """A sweep-table row (dict of its columns) with the common keys of the table: kind = 'rom',
    label, E_avg, E_disp, overlap_agents / overlap_walls (max_overlap when the split is absent;
    -1: unknown), mobility, diverged, t_step, t_query, speedup_step, speedup_query (-1: unknown)."""
    o_aa = _f(r, "max_overlap_agents", _f(r, "max_overlap"))
    o_aw = _f(r, "max_overlap_walls", _f(r, "max_overlap"))
    corr = str(r.get("correction") or "none")
    label = f"({r['n']},{r['r']}) {r['hyper']} / {r.get('contacts') or 'cone'}"
    label += f" + {corr} correction" if corr != "none" else ""
    return dict(r, kind="rom", label=label,
                E_avg=_f(r, "E_avg"), E_disp=_f(r, "E_disp"), overlap_agents=o_aa, overlap_walls=o_aw,
                mobility=_f(r, "mobility"), diverged=int(_f(r, "samples_diverged", 0)),
                t_step=_f(r, "t_step_rom"), t_query=_f(r, "t_query_rom"),
                speedup_step=_f(r, "speedup_exact"), speedup_query=_f(r, "speedup_query_exact"))


def fom_row(rows):
    """The exact full model as a row (error 0, no overlap by construction: its projection is
    solved to the KKT tolerance), from the reference columns of the sweep table."""
    r = rows[0]
    tq = _f(r, "t_query_fom_exact")
    return {"kind": "fom", "label": "full model (exact)", "E_avg": 0.0, "E_disp": 0.0, "overlap_agents": 0.0,
            "overlap_walls": 0.0, "mobility": 1.0, "diverged": 0, "t_step": _f(r, "t_step_fom_exact"),
            "t_query": tq, "speedup_step": 1.0, "speedup_query": 1.0 if tq > 0 else -1.0,
            "t50_err": 0.0, "t90_err": 0.0, "t50_n": -1, "t90_n": -1}


def ml_rows(path):
    """Rows of an ML result (ml_correct.py --csv, or its HDF5 output): each (regressor, n) as
    corrected, and as corrected and projected when the projection columns are there (>= 0)."""
    if str(path).lower().endswith(".csv"):
        _, rows = read_csv(path, ML_NEEDED, "ML table")
    else:
        rows = ml_rows_h5(path)
    out = []
    for r in rows:
        base = f"ML {r['regressor']} n={r['n']}"
        tq = _f(r, "t_query")
        t_proj_q = _f(r, "t_project_query")
        # the corrected (not projected) query: the projected one without the projection
        tq_ml = tq - t_proj_q if tq > 0 and t_proj_q >= 0 else -1.0
        fom_q = tq * _f(r, "speedup_query_exact") if tq > 0 and _f(r, "speedup_query_exact") > 0 else -1.0
        out.append({"kind": "ml", "label": base, "E_avg": _f(r, "E_avg"), "E_disp": _f(r, "E_disp"),
                    "overlap_agents": _f(r, "overlap_agents"), "overlap_walls": _f(r, "overlap_walls"),
                    "mobility": _f(r, "mobility"), "diverged": 0, "t_step": _f(r, "t_step"), "t_query": tq_ml,
                    "speedup_uzawa": _f(r, "speedup_uzawa", _f(r, "speedup")),
                    "speedup_step": _f(r, "speedup_exact"),
                    "speedup_query": fom_q / tq_ml if fom_q > 0 and tq_ml > 0 else -1.0})
        if _f(r, "E_avg_proj") >= 0:
            t_step = _f(r, "t_step") + _f(r, "t_project_step")
            out.append({"kind": "ml+proj", "label": base + " + projection", "E_avg": _f(r, "E_avg_proj"),
                        "E_disp": _f(r, "E_disp_proj"), "overlap_agents": _f(r, "overlap_agents_proj"),
                        "overlap_walls": _f(r, "overlap_walls_proj"), "mobility": _f(r, "mobility_proj"),
                        "diverged": 0, "t_step": t_step, "t_query": tq, "speedup_step": _f(r, "speedup_exact_proj"),
                        "speedup_query": _f(r, "speedup_query_exact")})
    return out


def ml_rows_h5(path):
    """The rows of ml_correct.py's CSV rebuilt from its HDF5 output."""
    import numpy as np

    rows = []
    with cio.open_h5(path, cio.ML_SCHEMA, "ML output") as f:
        n_values = [int(x) for x in cio.dataset(f, "n_values", finite=True).ravel()]
        for reg in ("random_forest", "mlp"):
            if reg not in f:
                continue
            g = f[reg]
            cols = {k: cio.dataset(g, k, finite=True).ravel() for k in g if hasattr(g[k], "shape")
                    and g[k].ndim == 1 and g[k].shape[0] == len(n_values) and g[k].dtype.kind in "fiu"}
            for k in ("t_step", "speedup_exact"):
                if k not in cols:
                    raise InputError(f"'{path}': missing dataset '{reg}/{k}' with one entry per n")
            for i, n in enumerate(n_values):
                r = {"regressor": reg, "n": n, "t_step": float(cols["t_step"][i]),
                     "speedup_exact": float(cols["speedup_exact"][i])}
                r.update({k: float(v[i]) for k, v in cols.items()})
                rows.append(r)
    if not rows:
        raise InputError(f"'{path}': no regressor results")
    return rows


def no_overlap(r, tol):
    """Deepest overlap (agents and walls) <= tol and no diverged sample (a measured row)."""
    return (r["diverged"] == 0 and 0 <= r["overlap_agents"] <= tol and 0 <= r["overlap_walls"] <= tol)


def cost_key(rows):
    """'t_query' when every candidate row has a per-query cost, else 't_step'."""
    return "t_query" if all(r["t_query"] > 0 for r in rows) else "t_step"


def candidates(rows, tol, error):
    return [r for r in rows if no_overlap(r, tol) and r[error] >= 0]


def cheapest_per_level(rows, levels, tol=1e-10, error="E_avg"):
    """[(level, row or None)]: for each level, the cheapest row without overlap whose error <= level
    (cost per query where every candidate has one, else per step); ties go to the smaller error."""
    cand = candidates(rows, tol, error)
    key = cost_key(cand) if cand else "t_step"
    out = []
    for level in levels:
        ok = [r for r in cand if r[error] <= level and r[key] > 0]
        out.append((level, min(ok, key=lambda r: (r[key], r[error])) if ok else None))
    return out, key


def overlap_free_front(rows, tol=1e-10, error="E_avg"):
    """Rows without overlap that no other such row beats in both error and cost (sorted by cost)."""
    cand = [r for r in candidates(rows, tol, error)]
    key = cost_key(cand) if cand else "t_step"
    cand = [r for r in cand if r[key] > 0]
    front = []
    for r in cand:
        dom = any((o[key] <= r[key] and o[error] <= r[error]) and (o[key] < r[key] or o[error] < r[error])
                  for o in cand)
        if not dom:
            front.append(r)
    return sorted(front, key=lambda r: r[key]), key


def _e(x, fmt="%.2e"):
    return fmt % x if x >= 0 else "n/a"


def markdown(rows, tol, key="t_query"):
    """The decision table as Markdown lines: setting, errors, overlaps, mobility, cost and speedup
    per query (per step when ``key`` is 't_step'), no overlap."""
    per = "query" if key == "t_query" else "step"
    sp = "speedup_query" if key == "t_query" else "speedup_step"
    head = ["setting", "E_avg", "E_disp", "overlap agents / walls [m]", "mobility", f"cost per {per} [s]",
            f"speedup per {per}", "no overlap"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["label"], _e(r["E_avg"]) + ("*" if r["diverged"] > 0 else ""), _e(r["E_disp"]),
                 "%s / %s" % (_e(r["overlap_agents"]), _e(r["overlap_walls"])), _e(r["mobility"], "%.3f"),
                 _e(r[key]), _e(r[sp], "%.3g"), "yes" if no_overlap(r, tol) else "no"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


#: columns of --rows-csv after the row's label and kind (then the sweep table's unknown columns)
ROW_COLUMNS = ("setting", "n", "r", "n_basis", "hyper", "contacts", "correction", "E_avg", "E_disp", "overlap_agents",
               "overlap_walls", "mobility", "diverged", "t50_err", "t50_n", "t50_rom_missed", "t90_err", "t90_n",
               "t90_rom_missed", "agents_not_left", "agents_not_left_fom", "t_step", "t_query", "speedup_step",
               "speedup_query", "speedup_uzawa")


def rows_csv(rows, extras, tol):
    """Every row of the table with every column (the Markdown keeps the few a reader decides on)."""
    cols = ["label", "kind"] + list(ROW_COLUMNS) + ["no_overlap"] + list(extras)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        vals = []
        for c in cols:
            v = "yes" if (c == "no_overlap" and no_overlap(r, tol)) else ("no" if c == "no_overlap" else r.get(c, ""))
            vals.append(repr(v) if isinstance(v, float) else v)
        w.writerow(vals)
    return buf.getvalue()


def render(rows, levels, tol, error):
    per_level, key = cheapest_per_level(rows, levels, tol, error)
    front, fkey = overlap_free_front(rows, tol, error)
    what = "per query" if key == "t_query" else "per step (the table has no per-query cost)"
    lines = ["Validation rows: E_avg (the paper's error; * = over the samples that did not diverge), E_disp",
             "(relative to the displacement q - q0), deepest overlaps, mobility (ROM / full-model displacement),",
             f"cost {what} and speedup against the exact full model timed in the same run; 'no overlap':",
             f"deepest overlap <= {tol:g} m and no diverged sample. ML rows: the corrected positions, then the",
             "same projected exactly (crowd_project; its cost included). Every other column: --rows-csv.", ""]
    lines += markdown(rows, tol, key)
    lines += ["", f"Cheapest setting without overlap for each {error} level (cost {what}):", "",
              f"| {error} <= | setting | E_avg | E_disp | mobility | {key} [s] | speedup/query | speedup/step |",
              "|---|---|---|---|---|---|---|---|"]
    for level, r in per_level:
        if r is None:
            lines.append(f"| {level:g} | none | | | | | | |")
        else:
            lines.append(f"| {level:g} | {r['label']} | {_e(r['E_avg'])} | {_e(r['E_disp'])} | "
                         f"{_e(r['mobility'], '%.3f')} | {_e(r[key])} | {_e(r['speedup_query'], '%.3g')} | "
                         f"{_e(r['speedup_step'], '%.3g')} |")
    lines += ["", f"Front of the settings without overlap ({error} vs cost {what}): " +
              "; ".join(f"{r['label']} ({error} {_e(r[error])}, {_e(r[fkey])} s)" for r in front)]
    return lines, per_level, front, key


def front_csv(per_level, key, error):
    out = [f"level,label,kind,E_avg,E_disp,mobility,{key},speedup_query,speedup_step"]
    for level, r in per_level:
        if r is None:
            out.append(f"{level!r},none,,,,,,,")
        else:
            out.append(f"{level!r},\"{r['label']}\",{r['kind']},{r['E_avg']!r},{r['E_disp']!r},{r['mobility']!r},"
                       f"{r[key]!r},{r['speedup_query']!r},{r['speedup_step']!r}")
    return "\n".join(out) + "\n"


def load_rows(table, ml=(), set_name="valid"):
    """(extras, every row: sweep settings, ML rows, the exact full model)."""
    extras, rows = sweep_rows(table, set_name)
    fom = fom_row(rows)
    for path in ml:
        rows += ml_rows(path)
    return extras, rows + [fom]


def main(argv=None):
    ap = argparse.ArgumentParser(prog="study_table.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("table", help="sweep table of crowd_rom (CSV)")
    ap.add_argument("--ml", nargs="+", default=[], help="ML results of ml_correct.py (its --csv, or its HDF5)")
    ap.add_argument("--set", default="valid", help="which set's rows (default valid)")
    ap.add_argument("--error", default="E_avg", choices=("E_avg", "E_disp"), help="error measure of the levels")
    ap.add_argument("--levels", type=float, nargs="+", default=list(DEFAULT_LEVELS), help="error levels")
    ap.add_argument("--overlap-tol", type=float, default=1e-10, help="deepest overlap counted as none [m]")
    ap.add_argument("-o", "--output", help="also write the Markdown to this file")
    ap.add_argument("--csv", help="also write the per-level answers as CSV")
    ap.add_argument("--rows-csv", help="also write every row with every column as CSV")
    args = ap.parse_args(argv)
    if not all(math.isfinite(x) and x > 0 for x in args.levels):
        raise InputError(f"--levels must be positive numbers, got {args.levels}")
    if not (math.isfinite(args.overlap_tol) and args.overlap_tol >= 0):
        raise InputError(f"--overlap-tol must be >= 0, got {args.overlap_tol}")
    cio.check_outputs([("--output", args.output), ("--csv", args.csv), ("--rows-csv", args.rows_csv)],
                      [("sweep table", args.table)] + [("ML result", p) for p in args.ml])
    extras, rows = load_rows(args.table, args.ml, args.set)
    lines, per_level, _, key = render(rows, sorted(args.levels), args.overlap_tol, args.error)
    text = "\n".join(lines) + "\n"
    with cio.OutputSet() as outs:
        if args.output:
            with open(outs.tmp(args.output), "w") as fh:
                fh.write(text)
        if args.csv:
            with open(outs.tmp(args.csv), "w") as fh:
                fh.write(front_csv(per_level, key, args.error))
        if args.rows_csv:
            with open(outs.tmp(args.rows_csv), "w") as fh:
                fh.write(rows_csv(rows, extras, args.overlap_tol))
        outs.commit()
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
