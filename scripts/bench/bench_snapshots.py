#!/usr/bin/env python3
"""Benchmark of crowd_snapshots (not a test): the hall20 and congested150 studies at 1, 2 and 4
ranks (4 oversubscribed on this 2-core machine) with the Release build; prints Markdown tables
(efficiencies, load balance, overheads), measures the machine's inputs of the scaling model with
the micro-benchmark crowd_snapbench at each rank count, validates the model
(scripts/bench/snapshot_model.py) against the measured wall times (no constant fitted on them; the
counter latency of each run's own summary, crowd_snapbench's reported beside it), predicts the 1 000-agent study on 16, 128 and 1 024 ranks and
draws the timeline of each 2-rank run.

Usage: .venv/bin/python scripts/bench/bench_snapshots.py [--ranks 1 2 4] [--studies hall20 congested150]
       [--repeats N] [--out results/bench_snapshots.md] [--keep DIR]

With --repeats N the rank counts are run in turn N times (1, 2, 4, 1, 2, 4, ...: the machine's
load drifts alike over all of them); the tables give, per rank count, the run of median wall
time (its own figures) with the range of the 1-minute load average at the start of the runs,
and every run's busy-time efficiency; the model is validated round by round.

Efficiencies (all from the same run; the machine is shared, so compare ratios within it):
* busy-time efficiency = sum over ranks of busy time (samples, their piece files and their
  database blocks, and rank 0's serial work on the database: its HDF5 layout, dictionary,
  checksums, close and rename) / (P x wall time), for the sample loop and for the whole run;
  waiting (collectives, the counter, another rank's serial work) is never busy. The column
  "without serial" leaves rank 0's serial database work out of the busy time (the definition
  before it was counted);
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

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import snapshot_model  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
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


def snapbench(np_, workdir, tag=""):
    """crowd_snapbench at np_ ranks: its JSON file."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    p = subprocess.run(["mpiexec", "-np", str(np_), os.path.join(ROOT, "build", "bin", "crowd_snapbench"),
                        os.path.join(workdir, "snapbench.tmp"), "20", "65536"], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise SystemExit("crowd_snapbench failed:\n" + p.stdout + p.stderr)
    out = os.path.join(workdir, "snapbench%s_np%d.json" % (tag, np_))
    open(out, "w").write(p.stdout)
    return out


def loadavg():
    """The 1-minute load average (as `uptime` prints it)."""
    try:
        return float(open("/proc/loadavg").read().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def median_run(rows):
    """The run of median wall time among repeats (its own figures, not a mix)."""
    rows = sorted(rows, key=lambda r: r[0]["wall_time"])
    return rows[(len(rows) - 1) // 2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--studies", nargs="+", default=["hall20", "congested150"])
    ap.add_argument("--repeats", type=int, default=1,
                    help="rounds; each round runs every rank count once, in turn (1, 2, 4, 1, 2, 4, ...)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--keep", default=None, help="keep databases, summaries and figures in DIR")
    a = ap.parse_args()
    head = ("| study | ranks | runs | load (1 min) | wall (s) | loop (s) | end of database (s) | busy-time eff. (loop) "
            "| busy-time eff. (run) | without serial | speed-up eff. | load balance | time/sample (s) | counter (us/op) "
            "| pieces | piece write (s) |")
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
        runs = {p: [] for p in a.ranks}      # per rank count: (summary, json, db, load) of each round
        rounds = []                          # per round: {p: (json, db)} and its crowd_snapbench files
        for rep in range(a.repeats):
            this_round = {}
            for np_ in a.ranks:
                load = loadavg()
                s, js, db = run(study, np_, wd, tag="_r%d" % rep)
                s["load"] = load
                runs[np_].append((s, js, db))
                this_round[np_] = (js, db)
                print("%s np%d round %d: wall %.3f s, busy-time efficiency %.3f, load %.2f" % (
                    study, np_, rep, s["wall_time"], s["busy_time_efficiency"], load), flush=True)
            bench = [snapbench(p, wd, tag="_%s_r%d" % (study, rep)) for p in a.ranks] if 1 in a.ranks else []
            rounds.append((this_round, bench))
        t1 = median_run(runs[1])[0]["wall_time"] if 1 in runs else None
        for np_ in a.ranks:
            s = median_run(runs[np_])[0]
            loads = [r[0]["load"] for r in runs[np_]]
            sp = "%.3f" % (t1 / (np_ * s["wall_time"])) if t1 else "-"
            rows.append("| %s | %d | %d | %.1f-%.1f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %s | %.3f | %.4f | %.1f "
                        "| %d | %.3f |" % (
                            study, np_, len(runs[np_]), min(loads), max(loads), s["wall_time"], s["wall_time_samples"],
                            s["wall_time_assembly"], s["busy_time_efficiency_sample_loop"], s["busy_time_efficiency"],
                            s.get("busy_time_efficiency_without_serial", s["busy_time_efficiency"]),
                            sp, s["load_balance"], s["time_per_sample_mean"], 1e6 * s["counter_latency_mean"],
                            s["pieces_written"], s["piece_write_time"]))
            print(rows[-1], flush=True)
            effs = sorted(r[0]["busy_time_efficiency"] for r in runs[np_])
            effs0 = sorted(r[0].get("busy_time_efficiency_without_serial", r[0]["busy_time_efficiency"])
                           for r in runs[np_])
            rows.append("|  | | | every run: busy-time eff. %s (without serial %s); wall %s |" % (
                ", ".join("%.3f" % e for e in effs), ", ".join("%.3f" % e for e in effs0),
                ", ".join("%.3f" % w for w in sorted(r[0]["wall_time"] for r in runs[np_]))))
        # model validation, round by round: the machine's inputs from crowd_snapbench right after
        # the round, the 1-rank run of the same round
        if 1 in a.ranks:
            model_txt.append("\n%s, model (inputs: each run's per-sample times and counter latency L, the same "
                             "round's 1-rank run, crowd_snapbench at P ranks right after the round for c, W and "
                             "the window; last columns: the same model with crowd_snapbench's L):\n" % study)
            model_txt.append("| round | ranks | measured wall (s) | model (s) | error | loop measured / model (s) "
                             "| end measured / model (s) | L run / snapbench (us) | model, L of snapbench (s) "
                             "| error |")
            model_txt.append("|---|---|---|---|---|---|---|---|---|---|")
            errs = {p: [] for p in a.ranks}
            errs_b = {p: [] for p in a.ranks}
            for k, (rr, bench) in enumerate(rounds):
                res = snapshot_model.validate([rr[p] for p in a.ranks], bench, latency="run")
                for r in res:
                    errs[r["ranks"]].append(r["error"])
                    errs_b[r["ranks"]].append(r["error_bench"])
                    model_txt.append("| %d | %d | %.3f | %.3f | %+.1f%% | %.3f / %.3f | %.3f / %.3f | %.1f / %.1f "
                                     "| %.3f | %+.1f%% |" % (
                                         k, r["ranks"], r["measured"], r["model"], 100 * r["error"],
                                         r["loop_measured"], r["loop_model"], r["asm_measured"], r["asm_model"],
                                         1e6 * r["latency_run"], 1e6 * r["latency_bench"], r["model_bench"],
                                         100 * r["error_bench"]))
            model_txt.append("")
            for name, ee in (("L of the run", errs), ("L of snapbench", errs_b)):
                model_txt.append("largest |error|, %s: " % name + ", ".join(
                    "%d ranks %+.1f%%" % (p, 100 * max(e, key=abs)) for p, e in ee.items()))
            for f in rounds[-1][1]:
                model_txt.append("    " + open(f).read().strip())
        if 2 in runs and a.keep:
            s, js, db = median_run(runs[2])
            fig = os.path.join(wd, "%s_np2_timeline.png" % study)
            subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "post", "plot_timeline.py"), db, js,
                            "--out", fig], check=False)
        if study == "congested150" and 1 in runs:
            s, js, db = median_run(runs[1])
            model_txt.append("\nprediction, 1 000-agent study (congested150's samples x 64 per-sample time, "
                             "x 6.7 data; from %s):\n" % os.path.basename(js))
            for n_s in (None, 10000):
                pred = snapshot_model.predict(db, js, n_samples=n_s)
                model_txt.append("| ranks | samples | wall (s) | loop (s) | end (s) | efficiency | loop efficiency "
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
