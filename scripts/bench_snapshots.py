#!/usr/bin/env python3
"""Benchmark of crowd_snapshots (not a test): the hall20 and congested150 studies at 1, 2 and 4
ranks (4 oversubscribed on this 2-core machine) with the Release build; prints Markdown tables
(efficiencies, load balance, overheads), measures the machine's inputs of the scaling model with
the micro-benchmark crowd_snapbench at each rank count, validates the model
(scripts/snapshot_model.py) against the measured wall times (no constant fitted on them), predicts the 1 000-agent study on 16, 128 and 1 024 ranks and
draws the timeline of each 2-rank run.

Usage: .venv/bin/python scripts/bench_snapshots.py [--ranks 1 2 4] [--studies hall20 congested150]
       [--out results/bench_snapshots.md] [--keep DIR]

Efficiencies (all from the same session; the machine is shared, so compare ratios within it):
* busy-time efficiency = sum over ranks of busy time (samples + their piece files) / (P x wall
  time), for the sample loop and for the whole run;
* speed-up efficiency = T(1 rank) / (P x T(P ranks));
* load balance = mean / max busy time.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import snapshot_model  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin", "crowd_snapshots")


def run(study, np_, workdir, tag=""):
    src = os.path.join(ROOT, "inputs", study + "_study.nml")
    text = open(src).read()
    db = os.path.join(workdir, "%s_np%d%s.h5" % (study, np_, tag))
    for p in (db, db + ".partial"):
        if os.path.exists(p):
            os.remove(p)
    text = re.sub(r"database\s*=\s*'[^']*'", "database = '%s'" % db, text)
    nml = db.replace(".h5", ".nml")
    open(nml, "w").write(text)
    js = db.replace(".h5", ".json")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    t0 = time.perf_counter()
    p = subprocess.run(["mpiexec", "-np", str(np_), BIN, nml, "--summary", js],
                       capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit("crowd_snapshots failed:\n" + p.stdout + p.stderr)
    s = json.load(open(js))
    s["wall_outside"] = wall
    return s, js, db


def snapbench(np_, workdir):
    """crowd_snapbench at np_ ranks: its JSON file."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    p = subprocess.run(["mpiexec", "-np", str(np_), os.path.join(ROOT, "build", "bin", "crowd_snapbench"),
                        os.path.join(workdir, "snapbench.tmp"), "20", "65536"], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise SystemExit("crowd_snapbench failed:\n" + p.stdout + p.stderr)
    out = os.path.join(workdir, "snapbench_np%d.json" % np_)
    open(out, "w").write(p.stdout)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--studies", nargs="+", default=["hall20", "congested150"])
    ap.add_argument("--out", default=None)
    ap.add_argument("--keep", default=None, help="keep databases, summaries and figures in DIR")
    a = ap.parse_args()
    out = []
    head = ("| study | ranks | wall (s) | loop (s) | end of database (s) | busy-time eff. (loop) | busy-time eff. (run) "
            "| speed-up eff. | load balance | time/sample (s) | counter (us/op) | pieces | piece write (s) |")
    rows = [head, "|" + "---|" * (head.count("|") - 1)]
    wd_obj = None
    if a.keep:
        wd = a.keep
        os.makedirs(wd, exist_ok=True)
    else:
        wd_obj = tempfile.TemporaryDirectory()
        wd = wd_obj.name
    model_txt = []
    for study in a.studies:
        runs = {}
        for np_ in a.ranks:
            s, js, db = run(study, np_, wd)
            runs[np_] = (s, js, db)
        t1 = runs[1][0]["wall_time"] if 1 in runs else None
        for np_ in a.ranks:
            s = runs[np_][0]
            sp = "%.3f" % (t1 / (np_ * s["wall_time"])) if t1 else "-"
            rows.append("| %s | %d | %.2f | %.2f | %.2f | %.3f | %.3f | %s | %.3f | %.4f | %.1f | %d | %.3f |" % (
                study, np_, s["wall_time"], s["wall_time_samples"], s["wall_time_assembly"],
                s["busy_time_efficiency_sample_loop"], s["busy_time_efficiency"], sp, s["load_balance"],
                s["time_per_sample_mean"], 1e6 * s["counter_latency_mean"], s["pieces_written"],
                s["piece_write_time"]))
            print(rows[-1], flush=True)
        # model validation: the machine's inputs from crowd_snapbench, measured after the runs
        if 1 in runs:
            rr = [(runs[p][1], runs[p][2]) for p in a.ranks]
            bench = [snapbench(p, wd) for p in a.ranks]
            res = snapshot_model.validate(rr, bench)
            model_txt.append("\n%s, model (inputs: each run's per-sample times, the 1-rank run's serial "
                             "parts, crowd_snapbench at P ranks):\n" % study)
            for f in bench:
                model_txt.append("    " + open(f).read().strip())
            model_txt.append("")
            model_txt.append("| ranks | measured wall (s) | model (s) | error | loop measured / model (s) "
                             "| end measured / model (s) |")
            model_txt.append("|---|---|---|---|---|---|")
            for r in res:
                model_txt.append("| %d | %.3f | %.3f | %+.1f%% | %.3f / %.3f | %.3f / %.3f |" % (
                    r["ranks"], r["measured"], r["model"], 100 * r["error"], r["loop_measured"],
                    r["loop_model"], r["asm_measured"], r["asm_model"]))
        if 2 in runs and a.keep:
            fig = os.path.join(wd, "%s_np2_timeline.png" % study)
            subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "plot_timeline.py"), runs[2][2], runs[2][1],
                            "--out", fig], check=False)
        if study == "congested150" and 1 in runs:
            model_txt.append("\nprediction, 1 000-agent study (congested150's samples x 64 per-sample time, "
                             "x 6.7 data; 250 samples):\n")
            for n_s in (None, 10000):
                pred = snapshot_model.predict(runs[1][2], runs[1][1], n_samples=n_s)
                model_txt.append("| ranks | samples | wall (s) | loop (s) | assembly (s) | efficiency | loop efficiency "
                                 "| counter busy |")
                model_txt.append("|---|---|---|---|---|---|---|---|")
                for r in pred:
                    model_txt.append("| %d | %d | %.1f | %.1f | %.2f | %.3f | %.3f | %.1e |" % (
                        r["ranks"], r["samples"], r["wall"], r["loop"], r["assembly"], r["efficiency"],
                        r["loop_efficiency"], r["counter_busy"]))
                model_txt.append("")
    table = "\n".join(rows) + "\n" + "\n".join(model_txt)
    print()
    print(table)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        open(a.out, "w").write(table + "\n")
    if wd_obj:
        wd_obj.cleanup()


if __name__ == "__main__":
    main()
