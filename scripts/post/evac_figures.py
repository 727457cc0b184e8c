#!/usr/bin/env python3
"""Evacuation figures and table of a crowdrom study, for a safety engineer.

Inputs (files only, read through crowdrom_io):
  --database   snapshot database (crowdrom-snapshots): the full-order trajectories, parameters
  --romrun     ROM run file of crowd_rom (crowdrom-romrun): evacuation curves and times per setting
  --csv        sweep table of crowd_rom (the table below; default: the romrun's name with .csv)
  --ml         output of scripts/pipeline/ml_correct.py (crowdrom-ml; optional): the QoIs of the ML-corrected
               trajectories (groups <regressor>/best/qoi and best/projected_qoi, computed by
               crowd_predict from the one definition in src/model/cr_qoi.f90)
  -o/--outdir  output directory (created)

Figures (PNG):
  evac_curves.png     agents out of the hall vs time for a few validation parameters: full model,
                      reduced model (several settings) and ML-corrected reduced model; 50% / 90%
                      lines
  t90_map.png         the time at which 90% of the crowd is out over the parameter box (the two
                      exit widths; marker size = desired speed), full vs reduced, and the relative
                      error; training (circles) and validation (triangles) parameters
  train_convergence.png
                      the offline error curves against the training-set size: the validation
                      velocity error of a POD basis of N modes built from the first n training
                      samples (1 - captured energy, from Gramians), for several N; flat curves
                      mean more samples would not improve the bases
Table (markdown, ``<outdir>/evac_table.md``, also printed): per validation setting the per-step
and per-query speedups against the exact full model, E_avg, E_disp, t50 / t90 errors,
overlaps, agents not out, mobility, diverged samples; ML rows from --ml (the corrected positions,
and the same after the exact position projection when --ml has them).
A second table: per reduced setting and ML row, the correlation of its t50 and t90 with the
full model's over the samples (Pearson r / Spearman rho, validation set, and training set for the
settings run on it); then the offline error against the training-set size.

Every argument is checked before any input is read, and against the inputs before anything is
drawn; the inputs are read through crowdrom_io (checksums, finiteness, shapes against the
attributes, the sweep table's cells). The four outputs are written together or not at all: into
a temporary folder next to --outdir, put in place at the end (crowdrom_io.OutputDir), so an
earlier set survives any failure, SIGTERM or SIGKILL.

Exit codes: 0 success, 2 bad input or arguments (one 'evac_figures: error:' line), 1 any other
failure or an interrupt.
"""
import argparse
import math
import os
import re
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)
import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "evac_figures"
#: largest --dpi (a figure of 15 x 4.4 inches is then 30 000 pixels wide)
MAX_DPI = 2000
#: columns of the sweep CSV this script needs
NEEDED = ("setting", "set", "n", "r", "n_basis", "hyper", "contacts", "E_avg", "E_disp", "t50_err", "t50_n",
          "t50_rom_missed", "t90_err", "t90_n", "t90_rom_missed", "max_overlap_agents", "max_overlap_walls",
          "agents_not_left", "agents_not_left_fom", "mobility", "samples_diverged", "t_step_rom",
          "t_step_fom_exact", "speedup_exact", "t_query_rom", "t_query_fom_exact", "speedup_query_exact")
#: columns of evac_table.md
TABLE_HEADER = ("N", "R", "Nb", "hyper", "contacts", "E_avg", "E_disp", "t50 err (n)", "t90 err (n)",
                "overlap agents / walls", "not out ROM (FOM)", "mobility", "diverged", "t_step [s]",
                "speedup/step", "t_query [s]", "speedup/query")


def mode(s):
    """The contacts mode of a setting (or table row), '+local' with the local exact correction."""
    return (s.get("contacts") or "cone") + ("+local" if s.get("correction") == "local" else "")


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


# ------------------------------------------------------------------------------ inputs

def database_meta(db):
    """The database's attributes (agents, steps, step, parameter names)."""
    with cio.open_h5(db, cio.DB_SCHEMA, "snapshot database") as f:
        return cio.read_database_meta(f)


def read_rows(path):
    """Rows of the sweep CSV, checked (crowdrom_io.read_csv_table: no NaN, Inf, text in a number
    column, ragged row or negative time)."""
    return cio.read_csv_table(path, NEEDED, "sweep table")[1]


def read_runs(romrun):
    """Per setting: attributes and, per set present, params, evacuation curves and times."""
    out = {}
    with cio.open_h5(romrun, cio.ROMRUN_SCHEMA, "ROM run") as f:
        meta = cio.romrun_meta(f)
        n_dof = 2 * meta["n_agents"]
        for k in range(1, meta["n_settings"] + 1):
            s = cio.romrun_setting(f, k)
            s["data"] = {}
            for name in s["sets"]:
                d = cio.romrun_set(f, k, name, meta["n_steps"], n_dof)
                if "evac_rom" not in d:
                    raise InputError(f"'{romrun}': setting {k} has no evacuation curves (older crowd_rom)")
                d.pop("positions"); d.pop("alpha")
                if "qoi" in d:
                    # the reduced trajectories' QoIs as crowd_rom stored them (src/model/cr_qoi.f90)
                    q = d["qoi"]
                    d["evac_rom"] = q["curve_total"]
                    d["t_out_rom"] = np.where(q["censored"], -1.0, q["t_evac"])[:, :2]
                s["data"][name] = d
            out[k] = s
    return meta, out


def ml_qoi(f, path, name, n_s, meta):
    """The QoI group ``name`` of the ML output (the corrected validation trajectories' QoIs, as
    crowd_predict computed them): one row per validation sample, the study's agents and steps."""
    if name not in f:
        raise InputError(f"'{path}': missing group '{name}' (the QoIs of the ML-corrected trajectories: "
                         "rerun scripts/pipeline/ml_correct.py without --no-qoi)")
    q = cio.read_qoi_group(f, name)
    if (q["n_rows"], q["n_agents"], q["n_steps"]) != (n_s, meta["n_agents"], meta["n_steps"]):
        raise InputError(f"'{path}': group '{name}' has {q['n_rows']} rows, {q['n_agents']} agents and "
                         f"{q['n_steps']} steps; expected {n_s} validation samples, {meta['n_agents']} agents "
                         f"and {meta['n_steps']} steps")
    return q


def read_ml(path, meta):
    """Per regressor (best n): the QoIs of the ML-corrected validation trajectories (``qoi``:
    evacuation curves, times with their censoring, ...), and of the same after the exact
    projection when the output has it, with the figures of the ML output."""
    res = {}
    with cio.open_h5(path, cio.ML_SCHEMA, "ML output") as f:
        params = cio.dataset(f, "valid_params", finite=True)
        n_s = params.shape[0]
        n_values = cio.dataset(f, "n_values", finite=True).ravel()
        for reg in ("random_forest", "mlp"):
            if reg not in f:
                continue
            g = cio.group(f, reg)
            best_n = int(cio.attr(g, "best_n", int))
            if best_n not in [int(x) for x in n_values]:
                raise InputError(f"'{path}': attribute '{reg}/best_n' = {best_n} is not in n_values "
                                 f"{[int(x) for x in n_values]}")
            e_avg = float(cio.attr(g, "best_E_avg", float))
            if not (math.isfinite(e_avg) and e_avg >= 0):
                raise InputError(f"'{path}': attribute '{reg}/best_E_avg' = {e_avg}: must be a finite number >= 0")
            sp = cio.dataset(g, "speedup_exact", finite=True).ravel()
            if sp.size != n_values.size:
                raise InputError(f"'{path}': dataset '{reg}/speedup_exact' has {sp.size} entries, n_values "
                                 f"{n_values.size}")
            res[reg] = {"qoi": ml_qoi(f, path, f"{reg}/best/qoi", n_s, meta), "best_n": best_n, "E_avg": e_avg,
                        "speedup_exact": sp, "n_values": n_values}
            if "best/projected_positions" in g:
                # the same trajectories after the exact position projection (crowd_project)
                proj = {"qoi": ml_qoi(f, path, f"{reg}/best/projected_qoi", n_s, meta)}
                for name in ("E_avg_proj", "overlap_agents_proj", "overlap_walls_proj", "mobility_proj",
                             "speedup_exact_proj", "t_query", "speedup_query_exact"):
                    proj[name] = cio.dataset(g, name, finite=True).ravel() if name in g else None
                res[reg]["projected"] = proj
    return params, res


# ------------------------------------------------------------------------------ figures

def fig_curves(meta, runs, settings, samples, ml, out, dpi):
    plt = _plt()
    h, na, nt = meta["dt"], meta["n_agents"], meta["n_steps"]
    t = h * np.arange(nt + 1)
    first = runs[settings[0]]["data"]["valid"]
    samples = [i for i in samples if i < first["params"].shape[0]]
    fig, axes = plt.subplots(1, len(samples), figsize=(4.6 * len(samples), 4.0), squeeze=False)
    names = meta["param_names"]
    for ax, i in zip(axes[0], samples):
        ax.plot(t, 100 * first["evac_fom"][i] / na, "k-", lw=2.4, label="full model")
        for k in settings:
            s = runs[k]
            d = s["data"]["valid"]
            ax.plot(t, 100 * d["evac_rom"][i] / na, lw=1.3,
                    label=f"ROM ({s['n']}, {s['r']}) {s['hyper']}/{mode(s)}")
        for reg, r in ml.items():
            ax.plot(t, 100 * r["qoi"]["curve_total"][i] / na, "--", lw=1.5,
                    label=f"ML-corrected ({reg}, n = {r['best_n']})")
            if "projected" in r:
                ax.plot(t, 100 * r["projected"]["qoi"]["curve_total"][i] / na, "-.", lw=1.5,
                        label=f"ML-corrected + exact projection ({reg}, n = {r['best_n']})")
        for p in (50, 90):
            ax.axhline(p, color="0.6", lw=0.8, ls=":")
        mu = ", ".join(f"{n} = {v:.3g}" for n, v in zip(names, first["params"][i]))
        ax.set_title(f"validation sample {i + 1}\n{mu}", fontsize=9)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("agents out [%]")
        ax.set_ylim(0, 101)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)


def unit(name):
    """The unit of a parameter component (speeds m/s, widths m, the speed draw's seed none)."""
    return "m/s" if name.startswith("speed") and name != "speed_seed" else ("-" if name == "speed_seed" else "m")


def fig_t90_map(meta, runs, setting, out, dpi):
    plt = _plt()
    names = meta["param_names"]
    s = runs[setting]
    ix = [names.index(n) for n in ("l_exit", "l_exit2") if n in names]
    if len(ix) < 2:
        ix = [0, 1] if len(names) > 1 else [0, 0]
    isp = next((names.index(n) for n in ("speed", "speed_mean") if n in names), None)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    pts = []
    for name, marker in (("train", "o"), ("valid", "^")):
        if name not in s["data"]:
            continue
        d = s["data"][name]
        tf, tr = d["t_out_fom"][:, 1], d["t_out_rom"][:, 1]
        pts.append((name, marker, d["params"], tf, tr))
    allf = np.concatenate([p[3][p[3] > 0] for p in pts] + [np.array([])])
    allr = np.concatenate([p[4][p[4] > 0] for p in pts] + [np.array([])])
    both = np.concatenate([allf, allr]) if allf.size + allr.size else np.array([0.0, 1.0])
    vmin, vmax = float(both.min()), float(both.max())
    errs = []
    for name, marker, P, tf, tr in pts:
        ok = (tf > 0) & (tr > 0)
        errs.append(np.where(ok, 100 * np.abs(tr - tf) / np.where(tf > 0, tf, 1.0), np.nan))
    emax = max([np.nanmax(e) for e in errs if np.isfinite(e).any()] + [1.0])
    for (name, marker, P, tf, tr), e in zip(pts, errs):
        size = 30.0 if isp is None else 15 + 60 * (P[:, isp] - P[:, isp].min()) / max(np.ptp(P[:, isp]), 1e-12)
        x, y = P[:, ix[0]], P[:, ix[1]]
        for ax, val in ((axes[0], tf), (axes[1], tr)):
            good = val > 0
            sc = ax.scatter(x[good], y[good], c=val[good], s=size if np.isscalar(size) else size[good],
                            marker=marker, cmap="viridis", vmin=vmin, vmax=vmax, edgecolors="k", linewidths=0.3)
            ax.scatter(x[~good], y[~good], marker="x", c="r", s=25)
        sc2 = axes[2].scatter(x, y, c=e, s=size, marker=marker, cmap="magma_r", vmin=0, vmax=emax,
                              edgecolors="k", linewidths=0.3)
        bad = ~np.isfinite(e)
        axes[2].scatter(x[bad], y[bad], marker="x", c="r", s=25)
    if pts:
        fig.colorbar(sc, ax=axes[0], label="t90 [s]")
        fig.colorbar(sc, ax=axes[1], label="t90 [s]")
        fig.colorbar(sc2, ax=axes[2], label="|t90 ROM - t90 FOM| / t90 FOM [%]")
    titles = ("full model t90", f"ROM t90: ({s['n']}, {s['r']}) {s['hyper']}/{mode(s)}",
              "relative error of t90 (x: not reached)")
    for ax, title in zip(axes, titles):
        ax.set_xlabel(f"{names[ix[0]]} [{unit(names[ix[0]])}]")
        ax.set_ylabel(f"{names[ix[1]]} [{unit(names[ix[1]])}]")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    if isp is not None:
        fig.suptitle("circles: training, triangles: validation; marker size grows with the desired speed", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)


def train_convergence(u_tr, u_va, n_modes, sizes, stride):
    """Validation velocity error of POD bases of N modes built from the first n training samples:
    1 - tr(V_N^T G_val V_N) / tr(G_val), G the Gramian [n_dof, n_dof] of the (strided) snapshots;
    u_tr, u_va: velocities [n_S, N_T, n_dof] of the training and validation sets."""
    n_tr = u_tr.shape[0]
    sizes = sorted({min(max(1, s), n_tr) for s in sizes} | {n_tr})
    g_val = np.zeros((u_va.shape[2],) * 2)
    for k in range(u_va.shape[0]):
        a = u_va[k, ::stride]
        g_val += a.T @ a
    tot = np.trace(g_val)
    if not tot > 0:
        raise InputError("the validation velocities are all zero: no convergence curve")
    g = np.zeros_like(g_val)
    err = np.full((len(sizes), len(n_modes)), np.nan)
    done = 0
    for i, n in enumerate(sizes):
        for k in range(done, n):
            a = u_tr[k, ::stride]
            g += a.T @ a
        done = n
        w, v = np.linalg.eigh(g)
        v = v[:, ::-1]
        for j, m in enumerate(n_modes):
            m = min(m, v.shape[1])
            vm = v[:, :m]
            err[i, j] = max(1.0 - np.trace(vm.T @ g_val @ vm) / tot, 0.0)
    return np.array(sizes), err


def fig_convergence(sizes, err, n_modes, out, dpi):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.6, 4.2))
    for j, m in enumerate(n_modes):
        ax.semilogy(sizes, err[:, j], "o-", label=f"N = {m}")
    ax.set_xlabel("training samples used")
    ax.set_ylabel("validation velocity error of the POD basis\n(1 - captured energy)")
    ax.set_title("offline error vs training-set size", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)


# ------------------------------------------------------------------------------ table

def _f(x, fmt="%.2e"):
    x = float(x)
    return "n/a" if x < 0 else fmt % x


def ml_times(qoi, t_fom, which):
    """Mean relative error of t50 (which = 0) or t90 (1) of the ML-corrected trajectories (their
    QoIs) against the full model's times t_fom [n_S, 2] (-1: not reached), over the samples where
    both reach it, as the table's 't50 err (n)' text ('ML never k': censored in the ML
    trajectories where the full model reaches it)."""
    errs, missed = [], 0
    for t_m, cens, t_f in zip(qoi["t_evac"][:, which], qoi["censored"][:, which], t_fom[:, which]):
        if t_f <= 0:
            continue
        if cens:
            missed += 1
        else:
            errs.append(abs(t_m - t_f) / t_f)
    s = "%.2e (%d)" % (np.mean(errs), len(errs)) if errs else "n/a"
    return s + (", ML never %d" % missed if missed else "")


def table_lines(rows, ml, t_fom=None):
    """The table's lines; ML rows get the evacuation-time errors of their QoIs when the full
    model's validation times ``t_fom`` [n_S, 2] (t50, t90; -1 not reached) are given: unprojected,
    and after the exact position projection when the ML output has it (one more row)."""
    def t(r, k):
        n = int(r[k + "_n"])
        s = "%.2e (%d)" % (float(r[k + "_err"]), n) if n > 0 else "n/a"
        if int(r[k + "_rom_missed"]) > 0:
            s += ", ROM never %s" % r[k + "_rom_missed"]
        return s
    out = ["| " + " | ".join(TABLE_HEADER) + " |", "|" + "---|" * len(TABLE_HEADER)]
    for r in rows:
        if r["set"] != "valid":
            continue
        out.append("| " + " | ".join(str(x) for x in [
            r["n"], r["r"], r["n_basis"], r["hyper"], mode(r),
            _f(r["E_avg"]) + ("*" if int(r["samples_diverged"]) > 0 else ""), _f(r["E_disp"]),
            t(r, "t50"), t(r, "t90"),
            "%s / %s" % (_f(r["max_overlap_agents"]), _f(r["max_overlap_walls"])),
            "%s (%s)" % (r["agents_not_left"], r["agents_not_left_fom"]), _f(r["mobility"], "%.3f"),
            r["samples_diverged"], _f(r["t_step_rom"]), _f(r["speedup_exact"], "%.1f"), _f(r["t_query_rom"]),
            _f(r["speedup_query_exact"], "%.1f")]) + " |")
    for reg, m in ml.items():
        sp = m["speedup_exact"]
        k = list(m["n_values"]).index(m["best_n"]) if m["best_n"] in list(m["n_values"]) else -1
        t50 = ml_times(m["qoi"], t_fom, 0) if t_fom is not None else ""
        t90 = ml_times(m["qoi"], t_fom, 1) if t_fom is not None else ""
        out.append(f"| ML {reg} (n = {m['best_n']}) | | | | | {m['E_avg']:.2e} | | {t50} | {t90} | "
                   f"not projected | | | | | {sp[k]:.1f} | | |")
        pr = m.get("projected")
        if pr is not None and k >= 0:
            def v(name, fmt="%.2e"):
                a = pr[name]
                return _f(a[k], fmt) if a is not None and a.size > k else "n/a"
            t50 = ml_times(pr["qoi"], t_fom, 0) if t_fom is not None else ""
            t90 = ml_times(pr["qoi"], t_fom, 1) if t_fom is not None else ""
            out.append(f"| ML {reg} (n = {m['best_n']}) + exact projection | | | | | {v('E_avg_proj')} | | {t50} | "
                       f"{t90} | {v('overlap_agents_proj')} / {v('overlap_walls_proj')} | | "
                       f"{v('mobility_proj', '%.3f')} | | | {v('speedup_exact_proj', '%.1f')} | {v('t_query')} | "
                       f"{v('speedup_query_exact', '%.1f')} |")
    return out


def time_correlation(t_model, t_ref):
    """Pearson r and Spearman rho of a model's evacuation times t_model [n_S] against the full
    model's t_ref [n_S] (<= 0: not reached) over the samples where both reach them, and their
    count: (r, rho, n); r / rho None when undefined (fewer than 3 samples, or a constant side)."""
    from scipy.stats import rankdata
    ok = (np.asarray(t_model) > 0) & (np.asarray(t_ref) > 0)
    a, b = np.asarray(t_model, float)[ok], np.asarray(t_ref, float)[ok]
    n = int(ok.sum())
    if n < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None, None, n
    r = float(np.corrcoef(a, b)[0, 1])
    rho = float(np.corrcoef(rankdata(a), rankdata(b))[0, 1])
    return r, rho, n


def _corr_cell(t_model, t_ref):
    r, rho, n = time_correlation(t_model, t_ref)
    return "n/a (%d)" % n if r is None else "%.2f / %.2f (%d)" % (r, rho, n)


def correlation_lines(runs, ml):
    """The table of the evacuation times' correlations with the full model: per reduced setting
    (validation set, and training set when run on it) and per ML regressor (its corrected and
    projected validation trajectories' QoIs), Pearson r / Spearman rho of t50 and of t90 over
    the samples where both models reach them (a diverged reduced sample is left out)."""
    head = ("model", "t50 r / rho (n), valid", "t90 r / rho (n), valid", "t50 r / rho (n), train",
            "t90 r / rho (n), train")
    out = ["", "Evacuation times against the full model's, sample by sample: Pearson r / Spearman rho "
           "over the (n) samples where both reach them:",
           "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k, s in runs.items():
        cells = []
        for name in ("valid", "train"):
            d = s["data"].get(name)
            for w in (0, 1):
                if not d:
                    cells.append("")
                    continue
                # a diverged reduced trajectory (stopped at diverged_step > 0) has no time
                t = np.where(np.asarray(d.get("diverged_step", 0)) > 0, -1.0, d["t_out_rom"][:, w])
                cells.append(_corr_cell(t, d["t_out_fom"][:, w]))
        out.append(f"| ({s['n']}, {s['r']}) {s['hyper']} / {mode(s)} | " + " | ".join(cells) + " |")
    valid = [s["data"]["valid"] for s in runs.values() if "valid" in s["data"]]
    if not valid:
        return out
    t_fom = valid[0]["t_out_fom"]
    for reg, m in ml.items():
        for label, q in ((f"ML-corrected {reg} (n = {m['best_n']})", m["qoi"]),
                         (f"ML-corrected {reg} (n = {m['best_n']}) + exact projection",
                          m["projected"]["qoi"] if "projected" in m else None)):
            if q is None:
                continue
            t = np.where(q["censored"][:, :2], -1.0, q["t_evac"][:, :2])
            out.append(f"| {label} | {_corr_cell(t[:, 0], t_fom[:, 0])} | {_corr_cell(t[:, 1], t_fom[:, 1])} | | |")
    return out


# ------------------------------------------------------------------------------ main

def check_args(args):
    """The numeric arguments on their own, before any input is read (InputError)."""
    def need(ok, text):
        if not ok:
            raise InputError(text)
    for key in ("samples", "modes", "sizes", "settings"):
        v = getattr(args, key)
        need(v is None or all(x >= 1 for x in v), f"--{key} {' '.join(map(str, v or []))}: every value must be >= 1")
    need(args.map_setting is None or args.map_setting >= 1, f"--map-setting {args.map_setting}: must be >= 1")
    need(args.stride >= 1, f"--stride {args.stride}: must be >= 1")
    need(1 <= args.dpi <= MAX_DPI, f"--dpi {args.dpi}: must be in 1..{MAX_DPI}")


def check_against_inputs(args, meta, runs, n_train, n_valid, valid_settings):
    """The arguments against the inputs, before any figure is drawn (InputError)."""
    if args.samples and max(args.samples) > n_valid:
        raise InputError(f"--samples {' '.join(map(str, args.samples))}: the validation set of "
                         f"'{args.romrun}' has {n_valid} samples")
    if args.modes and max(args.modes) > 2 * meta["n_agents"]:
        raise InputError(f"--modes {' '.join(map(str, args.modes))}: at most n_dof = {2 * meta['n_agents']} "
                         "modes")
    if args.sizes and max(args.sizes) > n_train:
        raise InputError(f"--sizes {' '.join(map(str, args.sizes))}: the database has {n_train} training samples")
    if args.stride > meta["n_steps"]:
        raise InputError(f"--stride {args.stride}: must be <= n_steps = {meta['n_steps']}")
    for key, ks in (("settings", args.settings or []), ("map-setting", [args.map_setting] if args.map_setting else [])):
        for k in ks:
            if k not in runs:
                raise InputError(f"--{key} {k}: '{args.romrun}' has settings 1..{meta['n_settings']}")
            if k not in valid_settings:
                raise InputError(f"--{key} {k}: setting {k} of '{args.romrun}' has no validation set")


def main(argv=None):
    ap = cio.ArgumentParser(prog="evac_figures.py", description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--database", required=True)
    ap.add_argument("--romrun", required=True)
    ap.add_argument("--csv")
    ap.add_argument("--ml")
    ap.add_argument("-o", "--outdir", required=True)
    ap.add_argument("--settings", type=int, nargs="+", help="settings of the curves (default: the first two "
                    "plain cone settings and up to three overlap-free ones, else the first four)")
    ap.add_argument("--map-setting", type=int, help="setting of the t90 map (default: the valid row with "
                    "the smallest t90 error among those without agent overlap, else the smallest t90 error)")
    ap.add_argument("--samples", type=int, nargs="+", help="validation samples (1-based; "
                    "default 1 2 3, those the set has)")
    ap.add_argument("--modes", type=int, nargs="+", help="N of the convergence curves (default: 10 25 50 100, "
                    "those <= n_dof)")
    ap.add_argument("--sizes", type=int, nargs="+", help="training sizes of the convergence curves "
                    "(default: 8 sizes up to n_train)")
    ap.add_argument("--stride", type=int, default=3, help="step stride of the convergence Gramians")
    ap.add_argument("--dpi", type=int, default=110)
    args = ap.parse_args(argv)
    check_args(args)
    csv_path = args.csv or os.path.splitext(args.romrun)[0] + ".csv"
    outs = cio.OutputDir(args.outdir)
    names = ("evac_curves.png", "t90_map.png", "train_convergence.png", "evac_table.md")
    inputs = [("--database", args.database), ("--romrun", args.romrun), ("--csv", csv_path), ("--ml", args.ml)]
    for what, p in inputs:
        if p and os.path.exists(p) and os.path.realpath(p) == os.path.realpath(args.outdir):
            raise InputError(f"--outdir '{args.outdir}' is the input {what} '{p}'")
    cio.check_outputs([(n, os.path.join(args.outdir, n)) for n in names if os.path.isdir(args.outdir)], inputs)
    # every input read and checked before anything is drawn
    dbmeta = database_meta(args.database)
    meta, runs = read_runs(args.romrun)
    rows = read_rows(csv_path)
    if meta["n_agents"] != dbmeta["n_agents"] or meta["n_steps"] != dbmeta["n_steps"]:
        raise InputError(f"'{args.romrun}' has {meta['n_agents']} agents and {meta['n_steps']} steps, "
                         f"'{args.database}' {dbmeta['n_agents']} and {dbmeta['n_steps']}")
    valid_settings = [k for k, s in runs.items() if "valid" in s["data"]]
    if not valid_settings:
        raise InputError(f"'{args.romrun}': no setting has a validation set")
    with cio.open_h5(args.database, cio.DB_SCHEMA, "snapshot database") as f:
        tr = cio.read_database_set(f, "train")
        va = cio.read_database_set(f, "valid", velocities=True)
    n_train, n_valid = tr["params"].shape[0], runs[valid_settings[0]]["data"]["valid"]["params"].shape[0]
    check_against_inputs(args, meta, runs, n_train, n_valid, valid_settings)
    # default: the first two plain cone settings, then up to three without overlap by
    # construction (local correction, online contacts): the trade a user chooses from
    plain = [k for k in valid_settings if mode(runs[k]) == "cone"]
    safe = [k for k in valid_settings if k not in plain]
    settings = args.settings or (plain[:2] + safe[:3] if safe else valid_settings[:4])
    samples = [i - 1 for i in (args.samples or [k for k in (1, 2, 3) if k <= n_valid])]
    ml = {}
    if args.ml:
        ml_params, ml = read_ml(args.ml, meta)
        if ml_params.shape[0] != n_valid:
            raise InputError(f"'{args.ml}': {ml_params.shape[0]} validation samples, '{args.romrun}' {n_valid}")
    ms = args.map_setting
    if ms is None:
        cand = [r for r in rows if r["set"] == "valid" and int(r["t90_n"]) > 0 and int(r["setting"]) in valid_settings]
        clean = [r for r in cand if float(r["max_overlap_agents"]) <= 1e-6]
        pool = clean or cand
        ms = int(min(pool, key=lambda r: float(r["t90_err"]))["setting"]) if pool else valid_settings[0]
    sizes = args.sizes or sorted({max(1, round(n_train * x)) for x in (0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)})
    modes = args.modes or [m for m in (10, 25, 50, 100) if m <= 2 * meta["n_agents"]] or [2 * meta["n_agents"]]
    sz, err = train_convergence(tr["velocities"], va["velocities"], modes, sizes, args.stride)
    lines = table_lines(rows, ml, runs[valid_settings[0]]["data"]["valid"]["t_out_fom"])
    conv = ["", "Validation velocity error of a POD basis vs training samples (strided snapshots):",
            "| samples | " + " | ".join(f"N = {m}" for m in modes) + " |", "|---|" + "---|" * len(modes)]
    conv += ["| %d | %s |" % (n, " | ".join("%.3e" % e for e in err[i])) for i, n in enumerate(sz)]
    text = "\n".join(lines + correlation_lines(runs, ml) + conv) + "\n"
    if re.search(r"\b(nan|inf)\b", text, re.IGNORECASE):
        raise InputError("the table would hold a non-finite value (NaN or Inf) from the inputs: nothing written")
    # the output set, all or nothing
    with outs:
        fig_curves(meta, runs, settings, samples, ml, outs.path("evac_curves.png"), args.dpi)
        fig_t90_map(meta, runs, ms, outs.path("t90_map.png"), args.dpi)
        fig_convergence(sz, err, modes, outs.path("train_convergence.png"), args.dpi)
        with open(outs.path("evac_table.md"), "w") as fh:
            fh.write(text)
        outs.commit()
    print(text, end="")
    print(f"{PROG}: evac_curves.png, t90_map.png, train_convergence.png, evac_table.md written to {args.outdir}")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
