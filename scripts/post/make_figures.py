#!/usr/bin/env python3
"""All figures of the paper's numerical results from one crowdrom study, as PNG files.

Inputs (each optional; the figures that need a missing input are skipped with a message):
  --database   snapshot database (crowdrom-snapshots)
  --rom        ROM file (crowdrom-rom, schema_version 2 for the pair figures)
  --romrun     ROM run file of crowd_rom (crowdrom-romrun)
  --csv        sweep table of crowd_rom (else the tradeoff figure is drawn from --romrun)
  --ml         one or more outputs of scripts/pipeline/ml_correct.py (crowdrom-ml)
  -o/--outdir  output directory (created)

Figures (file name: content [inputs]):
  pod_decay.png         POD eigenvalue decay l_k/l_1 and relative squared truncation error E_k [rom]
  cone_max_error.png    gIS vs mCPG maximum relative projection error of the multipliers vs r [rom]
  cone_vs_pod_mean.png  gIS vs POD mean projection error of the training multipliers (the POD is
                        computed here from the database's sparse multipliers) [rom, database]
  infsup_heatmap.png    reduced inf-sup constant over (N, R) without and with PGA supremizers [rom]
  pga_convergence.png   PGA (supremizer enrichment) error vs added vectors, global and per pair [rom]
  eim_sigma.png         normalised singular values of s1, s2, s3 (EIM) for one pair [rom v2]
  eq_error.png          relative EQ error vs number of points for s1, s2, s3, every pair [rom v2]
  error_in_time.png     relative position error vs step: mean line and min-max band over the
                        validation parameters, several settings [romrun]
  tradeoff.png          E_avg vs time per step and vs speedup, Pareto front [csv or romrun (+ ml)]
  trajectories.png      three agents, FOM vs ROM trajectories of several settings [romrun, database]
  positions.png         agents at steps 0, 9, 18: FOM, ROM and ML-corrected ROM [romrun, database (+ ml)]
  ml_correction.png     ML-corrected vs baseline vs projection E_avg, and speedups, vs n [ml]
  pod_rpod.png          exact POD vs randomized POD: CPU time and spectra (/pod_compare) [rom]
The FOM Uzawa convergence history and the valid-set inf-sup bounds of the paper have no data in
these files and are not drawn.

Exit codes: 0 success (figures skipped for missing inputs are not an error), 2 an input given is
missing, unreadable or of the wrong schema.
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)
import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "make_figures"


class Skip(Exception):
    """A figure that cannot be drawn from the inputs given (not an error)."""


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, out, dpi):
    plt = _plt()
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out


def _need(ctx, *keys):
    for k in keys:
        if not ctx.get(k):
            raise Skip(f"needs --{k}")


# ------------------------------------------------------------------------------ offline figures

def fig_pod_decay(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        sig = cio.dataset(f, "pod/sigma").ravel()
        n_pod = int(cio.scalar(f["basis"].attrs["n_pod"])) if "basis" in f and "n_pod" in f["basis"].attrs else None
    ell = sig ** 2
    k = np.arange(1, ell.size + 1)
    tail = np.concatenate([np.cumsum(ell[::-1])[::-1][1:], [0.0]]) / ell.sum()
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    a1.semilogy(k, ell / ell[0], ".-")
    a1.set_xlabel("k")
    a1.set_ylabel(r"$\ell_k / \ell_1$")
    a1.set_title("(a) decay of the POD eigenvalues")
    pos = tail > 0
    a2.semilogy(k[pos], tail[pos], ".-")
    a2.set_xlabel("k (POD modes)")
    a2.set_ylabel(r"$E_k = \sum_{j>k} \ell_j / \sum_j \ell_j$")
    a2.set_title("(b) relative squared truncation error")
    if n_pod:
        for a in (a1, a2):
            a.axvline(n_pod, color="tab:red", ls="--", lw=1, label=f"N = {n_pod} (ROM basis)")
            a.legend(fontsize=8)
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
    return _save(fig, out, dpi)


def _cone_groups(f):
    """{method: group} for the cone groups of a ROM file."""
    out = {}
    for name in f:
        if name == "cone" or name.startswith("cone_"):
            g = f[name]
            if hasattr(g, "keys") and "err_max" in g:
                meth = cio.text(g.attrs["method"]) if "method" in g.attrs else name[5:] or "cone"
                out.setdefault(meth, g)
    return out


def fig_cone_max(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        cones = {m: cio.dataset(g, "err_max").ravel() for m, g in _cone_groups(f).items()}
    if not cones:
        raise Skip("the ROM file has no cone group")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    names = {"gis": "gIS", "mcpg": "mCPG"}
    for m, e in sorted(cones.items()):
        r = np.arange(e.size)
        pos = e > 0
        ax.semilogy(r[pos], e[pos], ".-", label=names.get(m, m))
    ax.set_xlabel("r (cone vectors)")
    ax.set_ylabel("max relative projection error")
    ax.set_title("Dual reduced cone: maximum projection error (training multipliers)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    return _save(fig, out, dpi)


def multiplier_pod_errors(lam, r_max):
    """POD of the sparse multiplier snapshots lam [n_dict, n_col] (scipy sparse): relative
    projection errors onto the first r modes, r = 0..r_max, normalised like the cones (by the
    largest snapshot norm): (mean over snapshots, max over snapshots) [r_max + 1] each."""
    lam = lam.tocsc()
    n_dict = lam.shape[0]
    r_max = int(min(r_max, n_dict))
    nrm2 = np.asarray(lam.multiply(lam).sum(axis=0)).ravel()
    n1 = np.sqrt(nrm2.max()) if nrm2.size else 0.0
    if not n1 > 0:
        return np.zeros(r_max + 1), np.zeros(r_max + 1)
    if n_dict <= 4000:
        gram = (lam @ lam.T).toarray()
        w, u = np.linalg.eigh(gram)
        u = u[:, np.argsort(w)[::-1][:r_max]]
    else:
        from scipy.sparse.linalg import svds
        u, s, _ = svds(lam, k=min(r_max, n_dict - 1))
        u = u[:, np.argsort(s)[::-1]]
    c2 = np.asarray((lam.T @ u)) ** 2                                  # [n_col, r]
    res2 = np.maximum(nrm2[:, None] - np.concatenate([np.zeros((nrm2.size, 1)),
                                                       np.cumsum(c2, axis=1)], axis=1), 0.0)
    res2[res2 <= 1e2 * np.finfo(float).eps * nrm2[:, None]] = 0.0      # round-off of the subtraction
    rel = np.sqrt(res2) / n1
    return rel.mean(axis=0), rel.max(axis=0)


def fig_cone_vs_pod(ctx, out, dpi):
    _need(ctx, "rom", "database")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        cones = _cone_groups(f)
        if "gis" not in cones:
            raise Skip("the ROM file has no gIS cone")
        e_mean = cio.dataset(cones["gis"], "err_mean").ravel()
        e_max = cio.dataset(cones["gis"], "err_max").ravel()
    with cio.open_h5(ctx["database"], cio.DB_SCHEMA, "database") as f:
        lam = cio.multipliers_csr(f, "train")
    r_max = max(e_mean.size - 1, 1)
    p_mean, p_max = multiplier_pod_errors(lam, r_max)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for e, lab, st in ((e_mean, "gIS mean", "o-"), (p_mean, "POD mean", "s-"),
                       (e_max, "gIS max", "o:"), (p_max, "POD max", "s:")):
        r = np.arange(e.size)
        pos = e > 0
        ax.semilogy(r[pos], e[pos], st, ms=3, label=lab)
    ax.set_xlabel("r (dimension of the cone / POD space)")
    ax.set_ylabel("relative projection error (/ max snapshot norm)")
    ax.set_title("Multipliers: gIS cone vs POD, training snapshots")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, out, dpi)


def fig_infsup(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        if "infsup" not in f or "n" not in f["infsup"]:
            raise Skip("the ROM file has no inf-sup table")
        g = f["infsup"]
        n = cio.dataset(g, "n").ravel()
        r = cio.dataset(g, "r").ravel()
        tabs = [(cio.dataset(g, k).ravel(), t) for k, t in
                (("gamma_up_min", "without PGA"), ("gamma_up_min_pga", "with PGA supremizers"))
                if k in g]
    ns, rs = np.unique(n), np.unique(r)
    plt = _plt()
    fig, axes = plt.subplots(1, len(tabs), figsize=(5.5 * len(tabs), 4.5), squeeze=False)
    vmax = max(float(np.nanmax(v)) for v, _ in tabs) or 1.0
    for ax, (val, title) in zip(axes[0], tabs):
        grid = np.full((ns.size, rs.size), np.nan)
        for a, b, v in zip(n, r, val):
            grid[np.searchsorted(ns, a), np.searchsorted(rs, b)] = v
        im = ax.imshow(grid, origin="lower", cmap="viridis", vmin=0, vmax=vmax, aspect="auto")
        for i in range(ns.size):
            for j in range(rs.size):
                if np.isfinite(grid[i, j]):
                    ax.text(j, i, "0" if grid[i, j] == 0 else f"{grid[i, j]:.2g}", ha="center",
                            va="center", fontsize=8, color="w" if grid[i, j] < 0.6 * vmax else "k")
        ax.set_xticks(range(rs.size), [str(x) for x in rs])
        ax.set_yticks(range(ns.size), [str(x) for x in ns])
        ax.set_xlabel("R (cone vectors)")
        ax.set_ylabel("N (POD modes)")
        ax.set_title(f"reduced inf-sup (min over samples), {title}", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.85)
    return _save(fig, out, dpi)


def _pairs(f):
    out = []
    for k in cio.rom_pair_indices(f):
        g = f[f"pairs/{k}"]
        out.append((k, int(cio.scalar(g.attrs["n"])), int(cio.scalar(g.attrs["r"])), g))
    return out


def fig_pga(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        curves = []
        if "pga/err" in f:
            curves.append(("offline basis (all POD modes, all cone vectors)", cio.dataset(f, "pga/err").ravel()))
        for k, n, r, g in _pairs(f):
            if "pga_err" in g:
                curves.append((f"pair {k}: (N, R) = ({n}, {r})", cio.dataset(g, "pga_err").ravel()))
    if not curves:
        raise Skip("the ROM file has no PGA history")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for lab, e in curves:
        it = np.arange(e.size)
        pos = e > 0
        ax.semilogy(it[pos], e[pos], ".-", label=lab)
    ax.set_xlabel("supremizers added")
    ax.set_ylabel("max relative projection error of the candidates")
    ax.set_title("PGA convergence")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out, dpi)


def fig_eim(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        pairs = _pairs(f)
        if not pairs:
            raise Skip("the ROM file has no prepared pairs (schema_version 2)")
        want = ctx["pair"] if ctx.get("pair") is not None else pairs[0][0]
        sel = [p for p in pairs if p[0] == want]
        if not sel:
            raise InputError(f"'{ctx['rom']}': no pair {want} (pairs {[p[0] for p in pairs]})")
        k, n, r, g = sel[0]
        sig = {s: cio.dataset(g, f"eim/{s}/sigma").ravel() for s in ("s1", "s2", "s3")
               if f"eim/{s}/sigma" in g}
    if not sig:
        raise Skip(f"pair {k} has no EIM data")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    names = {"s1": r"$s_1$ (desired velocity)", "s2": r"$s_2$ (contact matrix B)", "s3": r"$s_3$ (gaps d)"}
    for s, v in sig.items():
        v = v[v > 0]
        if v.size:
            ax.semilogy(np.arange(1, v.size + 1), v / v[0], ".-", ms=3, label=names[s])
    ax.set_xlabel(r"$m^{\rm EIM}$")
    ax.set_ylabel(r"$\sigma_m / \sigma_1$")
    ax.set_title(f"EIM: singular value decay, pair {k} (N, R) = ({n}, {r})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, out, dpi)


def fig_eq(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        pairs = _pairs(f)
        data = [(k, n, r, {s: cio.dataset(g, f"eq/{s}/err").ravel() for s in ("s1", "s2", "s3")
                           if f"eq/{s}/err" in g}) for k, n, r, g in pairs]
    data = [d for d in data if d[3]]
    if not data:
        raise Skip("the ROM file has no EQ data (schema_version 2 pairs)")
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, s in zip(axes, ("s1", "s2", "s3")):
        for k, n, r, e in data:
            if s in e:
                v = e[s]
                m = np.arange(1, v.size + 1)
                pos = v > 0
                ax.semilogy(m[pos], v[pos], ".-", ms=3, label=f"(N, R) = ({n}, {r})")
        ax.set_xlabel(r"$m^{\rm EQ}$ (points)")
        ax.set_ylabel("relative EQ error")
        ax.set_title(f"EQ, ${s[0]}_{s[1]}$")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    return _save(fig, out, dpi)


def fig_pod_rpod(ctx, out, dpi):
    _need(ctx, "rom")
    with cio.open_h5(ctx["rom"], cio.ROM_SCHEMA, "ROM file") as f:
        if "pod_compare" not in f:
            raise Skip("the ROM file has no /pod_compare group")
        g = f["pod_compare"]
        n, te, tr = (np.asarray(cio.dataset(g, k)).ravel() for k in ("n", "t_exact", "t_rpod"))
        se = np.asarray(cio.dataset(g, "sigma_exact")).ravel()
        sr = np.asarray(cio.dataset(g, "sigma_rpod")).ravel()
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    a1.semilogy(n, te, "o-", label="exact POD")
    a1.semilogy(n, tr, "s-", label="randomized POD")
    a1.set_xlabel("N (requested modes)")
    a1.set_ylabel("CPU time (s)")
    a1.set_title("(a) POD vs rPOD: time")
    for s, lab, st in ((se, "exact POD", "-"), (sr, "randomized POD", "--")):
        ev = s[s > 0] ** 2
        if ev.size:
            a2.semilogy(np.arange(1, ev.size + 1), ev / ev[0], st, label=lab)
    a2.set_xlabel("k")
    a2.set_ylabel(r"$\ell_k / \ell_1$")
    a2.set_title("(b) eigenvalue decay")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    return _save(fig, out, dpi)


# ------------------------------------------------------------------------------ online figures

def _settings(ctx, f, meta):
    want = ctx.get("settings") or list(range(1, meta["n_settings"] + 1))
    out = [cio.romrun_setting(f, k) for k in want]
    if not ctx.get("settings") and len(out) > 6:
        eq = [s for s in out if s["hyper"] == "eq"]
        pool = eq if len(eq) >= 2 else out
        out = [pool[i] for i in np.unique(np.linspace(0, len(pool) - 1, 6).round().astype(int))]
    return out


def _slabel(s):
    return f"(N, R) = ({s['n']}, {s['r']}), {s['hyper']}"


def fig_error_in_time(ctx, out, dpi):
    _need(ctx, "romrun")
    with cio.open_h5(ctx["romrun"], cio.ROMRUN_SCHEMA, "ROM run file") as f:
        meta = cio.romrun_meta(f)
        curves = []
        for s in _settings(ctx, f, meta):
            if "valid" in s["sets"]:
                et = cio.dataset(f, f"setting_{s['index']}/valid/err_time")
                curves.append((s, et))
    if not curves:
        raise Skip("no setting has a validation set")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for i, (s, et) in enumerate(curves):
        c = f"C{i % 10}"
        nu = np.arange(et.shape[1])
        ax.plot(nu, et.mean(axis=0), "-", color=c, label=_slabel(s))
        ax.fill_between(nu, et.min(axis=0), et.max(axis=0), color=c, alpha=0.2)
    ax.set_xlabel(r"time step $\nu$")
    ax.set_ylabel(r"$|q - \hat q| / |q|$")
    ax.set_title("Relative position error in time (mean, min-max over validation parameters)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out, dpi)


def fig_tradeoff(ctx, out, dpi):
    import plot_tradeoff as pt

    src = ctx.get("csv") or ctx.get("romrun")
    if not src:
        raise Skip("needs --csv or --romrun")
    rows = pt.read_rows(src)
    import study_table
    ml = ctx.get("ml") or []
    pt.plot_tradeoff(rows, out, pt.read_ml_points(ml), dpi=dpi,
                     ml_rows=[u for p in ml for u in study_table.ml_rows(p)])
    return out


def _load_run_and_db(ctx, setting_index):
    """Validation data of one setting with the matching FOM positions and the scene."""
    with cio.open_h5(ctx["romrun"], cio.ROMRUN_SCHEMA, "ROM run file") as f:
        meta = cio.romrun_meta(f)
        s = cio.romrun_setting(f, setting_index)
        rv = cio.romrun_set(f, setting_index, "valid", meta["n_steps"], 2 * meta["n_agents"])
    with cio.open_h5(ctx["database"], cio.DB_SCHEMA, "database") as f:
        dbm = cio.read_database_meta(f)
        dv = cio.read_database_set(f, "valid", velocities=False)
        scenes = cio.read_sample_scenes(f, "valid")
    idx = cio.match_samples(dv["params"], rv["params"], ctx["database"],
                            f"'{ctx['romrun']}' setting {setting_index}/valid")
    return meta, s, rv, dv["positions"][idx], [scenes[i] for i in idx], dbm


def _sample(ctx, n_s):
    k = ctx["sample"] if ctx.get("sample") is not None else 1
    if not 1 <= k <= n_s:
        raise InputError(f"--sample {k} outside 1..{n_s} (validation samples)")
    return k - 1


def _pick_agents(ctx, q0, scene, n_agents):
    if ctx.get("agents"):
        bad = [a for a in ctx["agents"] if not 1 <= a <= n_agents]
        if bad:
            raise InputError(f"--agents {bad} outside 1..{n_agents}")
        return [a - 1 for a in ctx["agents"]]
    d = np.linalg.norm(q0.reshape(-1, 2) - scene["exit"].mean(axis=0), axis=1)
    o = np.argsort(d)
    return sorted({int(o[0]), int(o[len(o) // 2]), int(o[-1])})


def fig_trajectories(ctx, out, dpi):
    _need(ctx, "romrun", "database")
    import plot_scene

    with cio.open_h5(ctx["romrun"], cio.ROMRUN_SCHEMA, "ROM run file") as f:
        meta = cio.romrun_meta(f)
        sets = [s for s in _settings(ctx, f, meta) if "valid" in s["sets"]]
    if not sets:
        raise Skip("no setting has a validation set")
    runs = [_load_run_and_db(ctx, s["index"]) for s in sets]
    _, _, rv0, q_fom, scenes, dbm = runs[0]
    k = _sample(ctx, q_fom.shape[0])
    sc = scene = scenes[k]
    agents = _pick_agents(ctx, q_fom[k, 0], scene, meta["n_agents"])
    plt = _plt()
    fig, axes = plt.subplots(1, len(agents), figsize=(4.8 * len(agents), 4.6), squeeze=False)
    for ax, a in zip(axes[0], agents):
        plot_scene.draw_scene(ax, sc)
        tr = q_fom[k][:, 2 * a:2 * a + 2]
        ax.plot(tr[:, 0], tr[:, 1], "k-o", ms=2.5, lw=2, label="FOM")
        ax.plot(tr[0, 0], tr[0, 1], "ko", ms=7, mfc="w", label="start")
        pts = [tr]
        for i, (_, s, rv, _, _, _) in enumerate(runs):
            t = rv["positions"][k][:, 2 * a:2 * a + 2]
            pts.append(t)
            ax.plot(t[:, 0], t[:, 1], "--", color=f"C{i % 10}", lw=1.3, label="ROM " + _slabel(s))
        _fit_limits(ax, sc, np.vstack(pts))
        ax.set_title(f"agent {a + 1}", fontsize=9)
        ax.legend(fontsize=6, loc="lower left")
    fig.suptitle(f"Trajectories, validation sample {k + 1} (params "
                 f"{np.array2string(rv0['params'][k], precision=3)})", fontsize=9)
    return _save(fig, out, dpi)


def _fit_limits(ax, scene, pts):
    xmin, ymin, xmax, ymax = scene["domain"]
    lo = np.minimum([xmin, ymin], pts.min(axis=0))
    hi = np.maximum([xmax, ymax], pts.max(axis=0))
    pad = 0.03 * float(np.max(hi - lo))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)


def _overlapping(q, radius):
    """Agents overlapping another agent (true gap < -1e-3 radius): boolean [n_a]."""
    p = q.reshape(-1, 2)
    d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p)) * 1e9
    return (d - 2 * radius < -1e-3 * radius).any(axis=1)


def _draw_agents(ax, q, radius, color):
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    p = q.reshape(-1, 2)
    bad = _overlapping(q, radius)
    ax.add_collection(PatchCollection([Circle(x, radius) for x in p[~bad]], facecolor=color,
                                      edgecolor="k", lw=0.4))
    if bad.any():
        ax.add_collection(PatchCollection([Circle(x, radius) for x in p[bad]], facecolor="tab:red",
                                          edgecolor="k", lw=0.4))
    return int(bad.sum())


def _best_ml(path, regressor=None):
    with cio.open_h5(path, cio.ML_SCHEMA, "ML output") as f:
        regs = [r for r in ("random_forest", "mlp") if r in f]
        if regressor:
            if regressor not in regs:
                raise InputError(f"'{path}' has no regressor '{regressor}' (has {regs})")
            regs = [regressor]
        if not regs:
            raise InputError(f"'{path}' has no regressor results")
        reg = min(regs, key=lambda r: float(cio.scalar(f[r].attrs["best_E_avg"])))
        g = f[reg]
        n_s, nt = int(cio.scalar(f.attrs["n_valid"])), int(cio.scalar(f.attrs["n_steps"]))
        q = cio.dataset(g, "best/positions")
        return {"regressor": reg, "best_n": int(cio.scalar(g.attrs["best_n"])),
                "setting": int(cio.scalar(f.attrs["setting"])),
                "params": cio.dataset(f, "valid_params"),
                "positions": q.reshape(n_s, nt + 1, q.shape[1])}


def fig_positions(ctx, out, dpi):
    _need(ctx, "romrun", "database")
    import plot_scene

    ml = _best_ml(ctx["ml"][0], ctx.get("regressor")) if ctx.get("ml") else None
    setting = ctx.get("setting") or (ml["setting"] if ml else 1)
    meta, s, rv, q_fom, scenes, dbm = _load_run_and_db(ctx, setting)
    k = _sample(ctx, q_fom.shape[0])
    rows = [("FOM", q_fom[k], "tab:blue"), (f"ROM {_slabel(s)}", rv["positions"][k], "tab:orange")]
    if ml is not None:
        if ml["setting"] != setting or ml["params"].shape != rv["params"].shape or \
                not np.allclose(ml["params"], rv["params"], rtol=1e-12, atol=0):
            print(f"{PROG}: positions: the ML output is for another setting/validation set; "
                  "ML row left out")
        else:
            rows.append((f"ML-corrected ({ml['regressor']}, n = {ml['best_n']})", ml["positions"][k],
                         "tab:green"))
    if ctx.get("steps") is not None and any(st > meta["n_steps"] for st in ctx["steps"]):
        raise InputError(f"--steps {' '.join(map(str, ctx['steps']))}: every value must be <= n_steps = "
                         f"{meta['n_steps']} of '{ctx['romrun']}'")
    steps = ctx.get("steps") or [min(st, meta["n_steps"]) for st in (0, 9, 18)]
    sc = scene = scenes[k]
    plt = _plt()
    fig, axes = plt.subplots(len(rows), len(steps), figsize=(3.8 * len(steps), 3.6 * len(rows)),
                             squeeze=False)
    for i, (name, q, color) in enumerate(rows):
        for j, st in enumerate(steps):
            ax = axes[i, j]
            plot_scene.draw_scene(ax, sc)
            nb = _draw_agents(ax, q[st], meta["agent_radius"], color)
            _fit_limits(ax, sc, np.vstack([r[1][st].reshape(-1, 2) for r in rows]))
            ax.set_title(f"{name}\nstep {st}" + (f", {nb} overlapping (red)" if nb else ""), fontsize=8)
    fig.suptitle(f"Agent positions, validation sample {k + 1}", fontsize=9)
    return _save(fig, out, dpi)


def fig_ml(ctx, out, dpi):
    _need(ctx, "ml")
    data = []
    for path in ctx["ml"]:
        with cio.open_h5(path, cio.ML_SCHEMA, "ML output") as f:
            a = f.attrs
            d = {"label": f"({int(cio.scalar(a['pair_n']))},{int(cio.scalar(a['pair_r']))}) "
                          f"{cio.text(a['hyper'])}",
                 "n": cio.dataset(f, "n_values").ravel(),
                 "base": float(cio.scalar(cio.dataset(f, "E_avg_baseline"))),
                 "proj": cio.dataset(f, "E_avg_projection").ravel(),
                 "sp_base": float(cio.scalar(a["speedup_rom_uzawa"])), "regs": {}}
            for reg in ("random_forest", "mlp"):
                if reg in f:
                    d["regs"][reg] = (cio.dataset(f, f"{reg}/E_avg").ravel(),
                                      cio.dataset(f, f"{reg}/speedup").ravel())
            data.append(d)
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    styles = {"random_forest": ("o-", "RF"), "mlp": ("s-.", "MLP")}
    for i, d in enumerate(data):
        c = f"C{i % 10}"
        a1.axhline(d["base"], color=c, ls="--", lw=1, label=f"Galerkin ROM {d['label']}")
        if np.all(np.isfinite(d["proj"])):
            a1.plot(d["n"], d["proj"], ":", color=c, label=f"projection on $V_n$ {d['label']}")
        a2.axhline(d["sp_base"], color=c, ls="--", lw=1, label=f"Galerkin ROM {d['label']}")
        for reg, (e, sp) in d["regs"].items():
            st, nm = styles[reg]
            a1.plot(d["n"], e, st, color=c, ms=4, label=f"ML {nm} {d['label']}")
            a2.plot(d["n"], sp, st, color=c, ms=4, label=f"ML {nm} {d['label']}")
    a1.set_yscale("log")
    a1.set_xlabel("n (corrected coefficients)")
    a1.set_ylabel(r"$E_{\rm avg}$ (validation)")
    a1.set_title("(a) accuracy of the ML-corrected ROM")
    a2.set_xlabel("n (corrected coefficients)")
    a2.set_ylabel("speedup vs the Uzawa FOM")
    a2.set_title("(b) speedup including the ML prediction")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=6)
    return _save(fig, out, dpi)


FIGURES = [
    ("pod_decay", fig_pod_decay), ("cone_max_error", fig_cone_max),
    ("cone_vs_pod_mean", fig_cone_vs_pod), ("infsup_heatmap", fig_infsup),
    ("pga_convergence", fig_pga), ("eim_sigma", fig_eim), ("eq_error", fig_eq),
    ("error_in_time", fig_error_in_time), ("tradeoff", fig_tradeoff),
    ("trajectories", fig_trajectories), ("positions", fig_positions),
    ("ml_correction", fig_ml), ("pod_rpod", fig_pod_rpod),
]


def check_args(ctx):
    """Every numeric argument checked before anything is drawn (InputError)."""
    for key in ("sample", "pair", "setting", "dpi"):
        v = ctx.get(key)
        if v is not None and v < 1:
            raise InputError(f"--{key} {v}: must be >= 1")
    for key in ("settings", "agents"):
        v = ctx.get(key)
        if v is not None and any(x < 1 for x in v):
            raise InputError(f"--{key} {' '.join(map(str, v))}: every value must be >= 1")
    if ctx.get("steps") is not None and any(x < 0 for x in ctx["steps"]):
        raise InputError(f"--steps {' '.join(map(str, ctx['steps']))}: every value must be >= 0")


def make_all(ctx, outdir, only=None, dpi=120, log=print):
    """Draw every figure possible; return (written paths, {name: reason skipped}).

    All or nothing: the figures are drawn under temporary names and renamed together at the
    end; any failure (a bad argument found while drawing, a full disk) leaves every earlier
    figure in `outdir` untouched and no new one."""
    if os.path.exists(outdir) and not os.path.isdir(outdir):
        raise InputError(f"output directory '{outdir}' is a file")
    inputs = [(k, ctx.get(k)) for k in ("database", "rom", "romrun", "csv")] + \
        [("ML output", p) for p in ctx.get("ml") or []]
    created = not os.path.isdir(outdir)
    try:
        os.makedirs(outdir, exist_ok=True)
        cio.check_outputs([(f"figure {name}", os.path.join(outdir, name + ".png")) for name, _ in FIGURES],
                          inputs)
        written, skipped = [], {}
        with cio.OutputSet() as outs:
            for name, fn in FIGURES:
                if only and name not in only:
                    continue
                out = os.path.join(outdir, name + ".png")
                try:
                    fn(ctx, outs.tmp(out), dpi)
                except Skip as exc:
                    t, _ = outs.items.pop()
                    if os.path.exists(t):
                        os.remove(t)
                    skipped[name] = str(exc)
                    log(f"{PROG}: skip {name}: {exc}")
                    continue
                written.append(out)
            outs.commit()
    except BaseException:
        if created:
            try:
                os.rmdir(outdir)
            except OSError:
                pass
        raise
    for out in written:
        log(f"{PROG}: wrote {out}")
    return written, skipped


def main(argv=None):
    ap = argparse.ArgumentParser(prog="make_figures.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--database")
    ap.add_argument("--rom")
    ap.add_argument("--romrun")
    ap.add_argument("--csv", help="sweep table of crowd_rom (tradeoff figure)")
    ap.add_argument("--ml", nargs="+", default=[], help="outputs of ml_correct.py")
    ap.add_argument("-o", "--outdir", required=True)
    ap.add_argument("--settings", type=int, nargs="+", help="ROM run settings for the error-in-time "
                    "and trajectory figures (default: all, at most 6)")
    ap.add_argument("--setting", type=int, help="setting of the positions figure (default: the ML "
                    "output's, else 1)")
    ap.add_argument("--sample", type=int, default=1, help="validation sample (1-based) of the "
                    "trajectory and position figures")
    ap.add_argument("--agents", type=int, nargs="+", help="agents (1-based) of the trajectory figure "
                    "(default: nearest, median and farthest from the exit)")
    ap.add_argument("--steps", type=int, nargs="+", help="steps of the positions figure (default 0 9 18, "
                    "at most n_steps)")
    ap.add_argument("--pair", type=int, help="ROM pair of the EIM figure (default: the first)")
    ap.add_argument("--regressor", choices=("random_forest", "mlp"),
                    help="ML regressor of the positions figure (default: the more accurate)")
    ap.add_argument("--only", nargs="+", choices=[n for n, _ in FIGURES], help="draw only these")
    ap.add_argument("--dpi", type=int, default=120)
    args = ap.parse_args(argv)
    ctx = vars(args).copy()
    try:
        check_args(ctx)
        for key, schema in (("database", cio.DB_SCHEMA), ("rom", cio.ROM_SCHEMA),
                            ("romrun", cio.ROMRUN_SCHEMA)):
            if ctx.get(key):
                cio.open_h5(ctx[key], schema, key).close()
        for p in ctx["ml"]:
            cio.open_h5(p, cio.ML_SCHEMA, "ML output").close()
        if ctx.get("steps") and ctx.get("romrun"):
            with cio.open_h5(ctx["romrun"], cio.ROMRUN_SCHEMA, "romrun") as f:
                nt = cio.attr(f, "n_steps", int)
            if any(st > nt for st in ctx["steps"]):
                raise InputError(f"--steps {' '.join(map(str, ctx['steps']))}: every value must be <= n_steps = "
                                 f"{nt} of '{ctx['romrun']}'")
        if ctx.get("csv") and not os.path.exists(ctx["csv"]):
            raise InputError(f"sweep table not found: '{ctx['csv']}'")
        written, skipped = make_all(ctx, args.outdir, args.only, args.dpi)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return cio.EXIT_BAD_INPUT
    print(f"{PROG}: {len(written)} figures written to {args.outdir}, {len(skipped)} skipped")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
