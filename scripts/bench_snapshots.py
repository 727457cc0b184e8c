#!/usr/bin/env python3
"""Benchmark of crowd_snapshots (not a test): the hall20 and congested150 studies at 1 and 2
ranks with the Release build; prints a Markdown table (wall time, time per sample, parallel
efficiency, load balance, database size).

Usage: .venv/bin/python scripts/bench_snapshots.py [--ranks 1 2] [--studies hall20 congested150]
       [--out results/bench_snapshots.md]

Efficiency: "reported" is the driver's sum of per-sample times / (P x wall time of the whole
run); "speed-up" is T(1 rank) / (P x T(P ranks)) from the two runs of this script.
"""
import argparse
import json
import os
import re
import subprocess
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin", "crowd_snapshots")


def run(study, np_, workdir):
    src = os.path.join(ROOT, "inputs", study + "_study.nml")
    text = open(src).read()
    db = os.path.join(workdir, "%s_np%d.h5" % (study, np_))
    text = re.sub(r"database\s*=\s*'[^']*'", "database = '%s'" % db, text)
    nml = os.path.join(workdir, "%s_np%d.nml" % (study, np_))
    open(nml, "w").write(text)
    js = nml.replace(".nml", ".json")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    t0 = time.perf_counter()
    p = subprocess.run(["mpiexec", "-np", str(np_), BIN, nml, "--summary", js],
                       capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit("crowd_snapshots failed:\n" + p.stdout + p.stderr)
    s = json.load(open(js))
    s["wall_outside"] = wall
    return s


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--studies", nargs="+", default=["hall20", "congested150"])
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    rows = ["| study | ranks | samples | wall time (s) | time per sample (s) | efficiency (reported) "
            "| efficiency (speed-up) | load balance | non-converged steps | database (MB) |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as wd:
        for study in a.studies:
            t1 = None
            for np_ in a.ranks:
                s = run(study, np_, wd)
                if np_ == 1:
                    t1 = s["wall_time"]
                sp = "%.3f" % (t1 / (np_ * s["wall_time"])) if t1 else "-"
                rows.append("| %s | %d | %d | %.2f | %.4f | %.3f | %s | %.3f | %d | %.1f |" % (
                    study, np_, s["samples_total"], s["wall_time"], s["time_per_sample_mean"],
                    s["parallel_efficiency"], sp, s["load_balance"], s["nonconverged_steps"],
                    s["database_bytes"] / 1e6))
                print(rows[-1], flush=True)
    table = "\n".join(rows)
    print()
    print(table)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        open(a.out, "w").write(table + "\n")


if __name__ == "__main__":
    main()
