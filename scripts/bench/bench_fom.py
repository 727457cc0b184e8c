#!/usr/bin/env python3
"""Benchmark of the full-order model (not a test): per-step time, iterations, KKT
residual, failed steps and (sparse_active_set) factorisations and factor row updates per step
of each projection solver on hall20 and congested150 at several tolerances, and the scaling of
the per-step cost and peak memory with the number of agents at the density of congested150
(inputs/congested150.nml and inputs/congested{1000,10000,100000}.nml: hall and disk position
scaled by sqrt(N / 150)).

Usage: .venv/bin/python scripts/bench/bench_fom.py [--quick] [--out results/bench_fom.md]
       [--scenes congested150] [--ns 150 1000 10000] [--skip-solvers] [--skip-scaling]
       [--fom PATH ...] [--repeat K] [--cpu K]

--fom runs several crowd_fom binaries (e.g. before and after a change, built from two commits)
back to back on every case, alternating, K times each (--repeat): on a shared machine only
ratios measured that way mean something. Rows are labelled by the binary's file name.
--cpu K pins every run to CPU K (sched_setaffinity): on this 2-core virtual machine unpinned
congested150 runs fall into two modes about 25% apart from run to run; pinned runs scatter
by a few percent, with rare outliers (hence --repeat, the fastest kept).

The solver table's column "x active_set" is the dense cross-check's time over the row's (same
scene, tolerance and binary; blank when active_set is not run): the dense code is kept
unchanged, so the ratio says what a time means across machines, whose speed moves the same
binary's time by up to 1.5x (docs/benchmarks.md#full-order-model).

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

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from crowdrom_io import InputError, one_line_errors  # noqa: E402

DEFAULT_SOLVERS = ("sparse_active_set", "active_set", "gpcg", "apgd", "uzawa")
SOLVERS = list(DEFAULT_SOLVERS)
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FOM = os.path.join(ROOT, "build", "bin", "crowd_fom")
FOMS = [FOM]
REPEAT = 1
CPU = None


def read_nml(path):
    with open(path) as f:
        return f.read()


def run(nml_text, workdir, tag, timeout=None, fom=None):
    nml = os.path.join(workdir, tag + ".nml")
    out = os.path.join(workdir, tag + ".h5")
    js = os.path.join(workdir, tag + ".json")
    nml_text = nml_text + "\n&output file = '%s', store_multipliers = .false., log_level = 'warn' /\n" % out
    with open(nml, "w") as f:
        f.write(nml_text)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    logf = os.path.join(workdir, tag + ".log")
    with open(logf, "w") as lf:
        pin = None if CPU is None else (lambda: os.sched_setaffinity(0, {CPU}))
        p = subprocess.Popen([fom or FOM, nml, "--summary", js], stdout=lf, stderr=subprocess.STDOUT, env=env,
                             preexec_fn=pin)
        deadline = None if timeout is None else t0 + timeout
        while True:
            pid, status, ru = os.wait4(p.pid, os.WNOHANG)
            if pid != 0:
                break
            if deadline is not None and time.perf_counter() > deadline:
                p.kill()
                os.wait4(p.pid, 0)
                return {"failed": "no result within %d s" % timeout}
            time.sleep(0.05)
    wall = time.perf_counter() - t0
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        with open(logf) as lf:
            err = [l for l in lf.read().splitlines() if l.startswith("error:")]
        return {"failed": err[0] if err else "exit status %d" % rc}
    with open(js) as f:
        s = json.load(f)
    s["wall"] = wall
    s["cpu"] = ru.ru_utime + ru.ru_stime  # whole run (setup included)
    s["peak_rss_mb"] = ru.ru_maxrss / 1024.0  # Linux: kilobytes
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


def label(solver, fom):
    """Row label: the solver, plus the binary's name when several are compared."""
    return solver if fom is None else "%s [%s]" % (solver, os.path.basename(fom))


def best(runs):
    """The fastest of repeated runs of one case (least disturbed by the machine's load)."""
    ok = [r for r in runs if "failed" not in r]
    if not ok:
        return runs[0]
    return min(ok, key=lambda r: r["solver_time_per_step"])


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
                runs = {f: [] for f in FOMS}
                for rep in range(REPEAT):
                    for f in FOMS:
                        runs[f].append(run(text, workdir, "%s_%s_%s" % (scene, solver, tol), fom=f))
                for f in FOMS:
                    s = best(runs[f])
                    if "failed" in s:
                        raise SystemExit("crowd_fom failed: %s" % s["failed"])
                    rows.append((scene, label(solver, f if len(FOMS) > 1 else None),
                                 "paper (eps=1e-12)" if tol is None else "%g" % tol, s, solver, f))
                    print_solver_row(rows[-1])
    return rows


def dense_ratios(rows):
    """The dense cross-check's solver time over each row's, from the active_set row of the same
    scene, tolerance and binary (None where there is none or a time is not positive). rows:
    (scene, label, tolerance, summary, solver, binary) as solver_table makes them."""
    dense = {(r[0], r[2], r[5]): r[3]["solver_time_per_step"] for r in rows if r[4] == "active_set"}
    out = []
    for r in rows:
        t, td = r[3]["solver_time_per_step"], dense.get((r[0], r[2], r[5]))
        out.append(td / t if td is not None and t > 0 and td > 0 else None)
    return out


def print_solver_row(row):
    scene, solver, tol, s = row[:4]
    print("  %-13s %-17s tol %-18s %8.3f ms/step  it mean %10.1f max %9d  KKT %.2e  failed %d"
          "  fact/step %.2f  updates/step %.1f  changes/step %.1f  fallbacks %d" % (
              scene, solver, tol, 1e3 * s["solver_time_per_step"], s["iterations_mean"],
              s["iterations_max"], s["largest_kkt_residual"], s["failed_steps"],
              s.get("factorizations_per_step", 0), s.get("factor_updates_per_step", 0),
              s.get("active_set_changes_per_step", 0), s.get("fallback_solves", 0)), flush=True)


def scaling_table(ns, steps, solvers, workdir, timeout):
    """congested150 and its scaled copies inputs/congested<N>.nml, tol 1e-10, `steps` steps."""
    rows = []
    for n in ns:
        base = strip_groups(read_nml(os.path.join(ROOT, "inputs", "congested%d.nml" % n)),
                            ["solver", "output", "time"])
        for solver in solvers:
            text = base + "&time dt = 0.005, n_steps = %d /\n" % steps
            text += "&solver name = '%s', tol = 1e-10, max_iter = 1000000 /\n" % solver
            runs = {f: [] for f in FOMS}
            for rep in range(REPEAT):
                for f in FOMS:
                    runs[f].append(run(text, workdir, "scale_%d_%s" % (n, solver), timeout=timeout, fom=f))
            for f in FOMS:
                s = best(runs[f])
                rows.append((n, label(solver, f if len(FOMS) > 1 else None), s))
                print_scaling_row(rows[-1])
    return rows


def print_scaling_row(row):
    n, solver, s = row
    if "failed" in s:
        print("  N = %6d %-17s: %s" % (n, solver, s["failed"]), flush=True)
    else:
        print("  N = %6d %-17s: %9.3f ms/step (solver %9.3f ms), %.2f us/step/agent, peak RSS %.0f MB, "
              "KKT %.2e, failed steps %d, fallbacks %d" % (
                  n, solver, 1e3 * s["time_per_step"], 1e3 * s["solver_time_per_step"],
                  1e6 * s["time_per_step"] / n, s["peak_rss_mb"], s["largest_kkt_residual"],
                  s["failed_steps"], s.get("fallback_solves", 0)), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer cases (smoke run)")
    ap.add_argument("--uzawa-steps", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(ROOT, "results", "bench_fom.md"))
    ap.add_argument("--scenes", nargs="+", default=["hall20", "congested150"])
    ap.add_argument("--solvers", nargs="+", default=list(DEFAULT_SOLVERS))
    ap.add_argument("--scaling-solvers", nargs="+", default=["sparse_active_set", "gpcg", "apgd"])
    ap.add_argument("--ns", nargs="+", type=int, default=[150, 1000, 10000, 100000])
    ap.add_argument("--steps", type=int, default=20, help="steps of each scaling run")
    ap.add_argument("--scaling-timeout", type=int, default=1800, help="seconds per scaling run")
    ap.add_argument("--skip-solvers", action="store_true")
    ap.add_argument("--skip-scaling", action="store_true")
    ap.add_argument("--nice", action="store_true", help="run everything at niceness 10 (shared machine)")
    ap.add_argument("--fom", nargs="+", default=[FOM],
                    help="crowd_fom binaries to compare back to back (default build/bin/crowd_fom)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each case and binary; the fastest is kept")
    ap.add_argument("--cpu", type=int, default=None, help="pin every run to this CPU (see above)")
    a = ap.parse_args(argv)
    global FOMS, REPEAT, CPU
    if a.cpu is not None:
        if a.cpu not in os.sched_getaffinity(0):
            raise InputError("--cpu %d: not a CPU this process may run on (%s)" % (
                a.cpu, ", ".join(map(str, sorted(os.sched_getaffinity(0))))))
        CPU = a.cpu
    FOMS = [os.path.abspath(f) for f in a.fom]
    REPEAT = max(1, a.repeat)
    for f in FOMS:
        if not os.path.exists(f):
            raise SystemExit("%s not found: run scripts/setup.sh first" % f)
    if a.nice:
        os.nice(10)
    tols = [1e-6, 1e-9, 1e-12] if not a.quick else [1e-9]
    ns = a.ns if not a.quick else [150, 1000]
    with tempfile.TemporaryDirectory() as wd:
        global SOLVERS
        SOLVERS = a.solvers
        srows, crows = [], []
        if not a.skip_solvers:
            print("solvers:")
            srows = solver_table(a.scenes, tols, a.uzawa_steps, wd)
        if not a.skip_scaling:
            print("scaling:")
            crows = scaling_table(ns, a.steps, a.scaling_solvers, wd, a.scaling_timeout)
    lines = ["| scene | solver | tolerance | steps | time/step (ms) | iterations mean | iterations max | largest KKT "
             "| failed steps | factorisations/step | factor updates/step | active-set changes/step | fallbacks "
             "| x active_set |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row, ratio in zip(srows, dense_ratios(srows)):
        scene, solver, tol, s = row[:4]
        lines.append("| %s | %s | %s | %d | %.3f | %.1f | %d | %.1e | %d | %.2f | %.1f | %.1f | %d | %s |" % (
            scene, solver, tol, s["steps"], 1e3 * s["solver_time_per_step"], s["iterations_mean"],
            s["iterations_max"], s["largest_kkt_residual"], s["failed_steps"],
            s.get("factorizations_per_step", 0), s.get("factor_updates_per_step", 0),
            s.get("active_set_changes_per_step", 0), s.get("fallback_solves", 0),
            "" if ratio is None else "%.2f" % ratio))
    lines += ["", "| agents | solver | time/step (ms) | solver part (ms) | per agent (us) | peak RSS (MB) | largest KKT "
              "| failed steps | fallbacks |", "|---|---|---|---|---|---|---|---|---|"]
    for n, solver, s in crows:
        if "failed" in s:
            lines.append("| %d | %s | %s | | | | | | |" % (n, solver, s["failed"]))
        else:
            lines.append("| %d | %s | %.3f | %.3f | %.2f | %.0f | %.1e | %d | %d |" % (
                n, solver, 1e3 * s["time_per_step"], 1e3 * s["solver_time_per_step"],
                1e6 * s["time_per_step"] / n, s["peak_rss_mb"], s["largest_kkt_residual"], s["failed_steps"],
                s.get("fallback_solves", 0)))
    text = "\n".join(lines) + "\n"
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    sys.exit(one_line_errors("bench_fom.py", main))
