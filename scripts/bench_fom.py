#!/usr/bin/env python3
"""Benchmark of the full-order model (not a test): per-step time, iterations and KKT
residual of each projection solver on hall20 and congested150 at several tolerances, and
the scaling of the per-step cost with the number of agents at constant density.

Usage: .venv/bin/python scripts/bench_fom.py [--quick] [--out results/bench_fom.md]

Runs build/bin/crowd_fom (Release) on generated namelists and prints Markdown tables.
Uzawa (the paper's scheme) needs 1e5-1e6 iterations per step in the congested scene, so it
is run on the first --uzawa-steps steps only; its rows say so.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

SOLVERS = ["active_set", "apgd", "uzawa"]
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FOM = os.path.join(ROOT, "build", "bin", "crowd_fom")


def read_nml(path):
    with open(path) as f:
        return f.read()


def run(nml_text, workdir, tag, timeout=None):
    nml = os.path.join(workdir, tag + ".nml")
    out = os.path.join(workdir, tag + ".h5")
    js = os.path.join(workdir, tag + ".json")
    nml_text = nml_text + "\n&output file = '%s', store_multipliers = .false., log_level = 'warn' /\n" % out
    with open(nml, "w") as f:
        f.write(nml_text)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    try:
        p = subprocess.run([FOM, nml, "--summary", js], capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"failed": "no result within %d s" % timeout}
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        err = [l for l in (p.stdout + p.stderr).splitlines() if l.startswith("error:")]
        return {"failed": err[0] if err else "exit status %d" % p.returncode}
    with open(js) as f:
        s = json.load(f)
    s["wall"] = wall
    for f_ in (out, js):
        if os.path.exists(f_):
            os.remove(f_)
    return s


def strip_groups(text, groups):
    """Remove the given namelist groups from a namelist text."""
    out, skip = [], False
    for line in text.splitlines():
        t = line.strip().lower()
        if any(t.startswith("&" + g) for g in groups):
            skip = True
        if not skip:
            out.append(line)
        if skip and t.endswith("/"):
            skip = False
    return "\n".join(out) + "\n"


def solver_table(scenes, tols, uzawa_steps, workdir):
    rows = []
    for scene in scenes:
        base = strip_groups(read_nml(os.path.join(ROOT, "inputs", scene + ".nml")), ["solver", "output"])
        for solver in SOLVERS:
            for tol in (tols if solver != "uzawa" else [None]):
                text = base
                if solver == "uzawa":
                    text = strip_groups(text, ["time"])
                    dt = 0.05 if scene == "hall20" else 0.005
                    text += "&time dt = %g, n_steps = %d /\n" % (dt, uzawa_steps)
                    text += "&solver name = 'uzawa', uzawa_eps = 1e-12, uzawa_max_iter = 10000000 /\n"
                else:
                    text += "&solver name = '%s', tol = %g, max_iter = 1000000 /\n" % (solver, tol)
                s = run(text, workdir, "%s_%s_%s" % (scene, solver, tol))
                if "failed" in s:
                    raise SystemExit("crowd_fom failed: %s" % s["failed"])
                rows.append((scene, solver, "paper (eps=1e-12)" if tol is None else "%g" % tol, s))
                print("  %-13s %-10s tol %-18s %8.3f ms/step  it mean %10.1f max %9d  KKT %.2e  failed %d" % (
                    scene, solver, rows[-1][2], 1e3 * s["solver_time_per_step"], s["iterations_mean"],
                    s["iterations_max"], s["largest_kkt_residual"], s["failed_steps"]), flush=True)
    return rows


def scaling_table(ns, steps, solvers, workdir, timeout):
    rows = []
    # congested150 density: 150 agents in 2.0 x 1.25 (minus a disk of radius 0.15)
    for n in ns:
      for solver in solvers:
        scale = math.sqrt(n / 150.0)
        L, H = 2.0 * scale, 1.25 * scale
        text = ("&scene hall_length = %.6f, hall_width = %.6f, l_exit = 0.32, wall_thickness = 0.1 /\n"
                "&obstacles n_disks = 1, disk_x = %.6f, disk_y = %.6f, disk_r = 0.15 /\n"
                "&agents n_agents = %d, radius = 0.05, speed = 5.0, seed = 1 /\n"
                "&time dt = 0.005, n_steps = %d /\n&solver name = '%s', tol = 1e-10, max_iter = 1000000 /\n"
                % (L, H, L / 2, H / 2, n, steps, solver))
        s = run(text, workdir, "scale_%d_%s" % (n, solver), timeout=timeout)
        rows.append((n, solver, s))
        if "failed" in s:
            print("  N = %6d %-10s: %s" % (n, solver, s["failed"]), flush=True)
        else:
            print("  N = %6d %-10s: %8.3f ms/step (solver %8.3f ms), KKT %.2e, failed steps %d" % (
                n, solver, 1e3 * s["time_per_step"], 1e3 * s["solver_time_per_step"], s["largest_kkt_residual"],
                s["failed_steps"]), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer cases (smoke run)")
    ap.add_argument("--uzawa-steps", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(ROOT, "results", "bench_fom.md"))
    ap.add_argument("--solvers", nargs="+", default=["active_set", "apgd", "uzawa"])
    ap.add_argument("--scaling-solvers", nargs="+", default=["active_set", "apgd"])
    ap.add_argument("--scaling-timeout", type=int, default=900, help="seconds per scaling run")
    ap.add_argument("--skip-solvers", action="store_true")
    a = ap.parse_args()
    if not os.path.exists(FOM):
        raise SystemExit("build/bin/crowd_fom not found: run scripts/setup.sh first")
    tols = [1e-6, 1e-9, 1e-12] if not a.quick else [1e-9]
    ns = [150, 1000, 10000] if not a.quick else [150, 1000]
    with tempfile.TemporaryDirectory() as wd:
        global SOLVERS
        SOLVERS = a.solvers
        srows = []
        if not a.skip_solvers:
            print("solvers:")
            srows = solver_table(["hall20", "congested150"], tols, a.uzawa_steps, wd)
        print("scaling:")
        crows = scaling_table(ns, 20, a.scaling_solvers, wd, a.scaling_timeout)
    lines = ["| scene | solver | tolerance | steps | time/step (ms) | iterations mean | iterations max | largest KKT | failed steps |",
             "|---|---|---|---|---|---|---|---|---|"]
    for scene, solver, tol, s in srows:
        lines.append("| %s | %s | %s | %d | %.3f | %.1f | %d | %.1e | %d |" % (
            scene, solver, tol, s["steps"], 1e3 * s["solver_time_per_step"], s["iterations_mean"],
            s["iterations_max"], s["largest_kkt_residual"], s["failed_steps"]))
    lines += ["", "| agents | solver | time/step (ms) | solver part (ms) | per agent (us) | largest KKT | failed steps |",
              "|---|---|---|---|---|---|---|"]
    for n, solver, s in crows:
        if "failed" in s:
            lines.append("| %d | %s | %s | | | | |" % (n, solver, s["failed"]))
        else:
            lines.append("| %d | %s | %.3f | %.3f | %.2f | %.1e | %d |" % (
                n, solver, 1e3 * s["time_per_step"], 1e3 * s["solver_time_per_step"],
                1e6 * s["time_per_step"] / n, s["largest_kkt_residual"], s["failed_steps"]))
    text = "\n".join(lines) + "\n"
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()
