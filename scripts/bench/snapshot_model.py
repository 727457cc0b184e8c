#!/usr/bin/env python3
"""Scaling model of the snapshot stage (crowd_snapshots), validated against measured runs and
used to predict the 1 000-agent study on many ranks.

Model of the wall time at P ranks:

    T(P) = T_setup(P) + T_loop(P) + T_end(P)

* T_loop: the dynamic schedule simulated sample by sample, events in time order. Each rank takes
  a ticket from the shared counter (one-sided fetch-and-add on rank 0: the rank waits L, the
  counter is busy for its service time o and serves one operation at a time), computes the
  sample (its time from the per-sample time distribution of a database), hands it on (copy into
  the batch, scene mapping, checksum parts: the 1-rank run's busy time minus its model runs and
  piece writes, per sample), puts it into the database (its bytes at the per-rank block-write
  bandwidth W). A rank writes a piece when its time slice S is over, and at the end (c_w per
  byte of sample data). The loop ends when the last rank has written its last piece.
* T_setup and T_end: the 1-rank run's setup and end of the database (dictionary, multiplier
  datasets, checksums, complete = 1), which do not shrink with P except the end's work on each
  rank's own samples' multipliers (unique contacts, CSR places, checksum parts, block writes:
  `end_block_time_per_rank`, divided by P), plus N_SETUP and N_END light collective operations
  of cost c(P) each, the counter window's creation (setup) and release (end) at their measured
  costs at P ranks. Rank 0's HDF5 layout of the database (`database_layout_time` of the 1-rank
  run) is not in T_setup: the other ranks start their samples meanwhile, so rank 0 enters the
  simulated loop that much later.
* Machine speed f: the 1-rank run's work other than the model runs (handling, pieces, serial
  setup and end) is scaled by f = mean per-sample time of the run / mean per-sample time of the
  1-rank run (both from the databases): on a shared machine the ranks of a P-rank run each get a
  share of a core, for all their work, not only for the model runs.

Inputs, none fitted (no constant is adjusted to make a row agree):
* from the run a row predicts: its database's per-sample times (`stats/time`, the work and how
  fast this machine did it in that run) and, by default (`--latency run`), its summary's counter
  latency L(P) (`counter_latency_mean`: the mean wait of every fetch-and-add of every rank in
  that run); with `--latency bench`, L(P) is crowd_snapbench's instead (both models are reported);
* from the same round's 1-rank run: setup and end-of-database times, per-sample handling, piece
  bytes and write time, bytes per sample, mean per-sample time;
* from the micro-benchmark `crowd_snapbench` at P ranks: cost c of a collective and of a window
  created and freed for ranks arriving from computation, per-rank block-write bandwidth W (and
  its own L(P), the only source of L for a run that has not been made).
`validate` rebuilds T(P) of measured runs; `predict` extrapolates to an assumed cluster, whose
L(P) is an assumption stated there (one RDMA atomic), not a measured run's.

Usage:
    snapshot_model.py validate --runs RUN.json:DB.h5 ... --bench BENCH_P1.json BENCH_P2.json ...
                               [--latency run|bench]
    snapshot_model.py predict  --db congested150.h5 --summary congested150_np1.json
                               [--agents 1000] [--ranks 16 128 1024]
"""
import argparse
import json
import math
import os
import sys

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402

# light collective operations outside the sample loop (src/study/cr_study_run.f90 and the
# writer of src/products/cr_snapshot_file.f90, a fresh run):
# setup: initial positions with the database probe (one broadcast), the pieces found (one
# broadcast); the places of the database follow by a nonblocking broadcast while the ranks
# compute (not counted); end: one reduction (every rank's figures, the writer's counts and
# checksum parts), the dictionary with the places of the multiplier datasets (MPI_Allgatherv),
# every rank's report that its blocks are in, with the multipliers' checksums (MPI_Reduce to
# rank 0), and the commit's status (one broadcast). The heavy one (the counter window,
# created and freed) is measured by crowd_snapbench as a pair and counted apart.
N_SETUP = 2
N_END = 4


def sample_times(db):
    """Per-sample model-run times (s) of a database, train then valid."""
    with cio.open_h5(db, cio.DB_SCHEMA, "snapshot database") as f:
        return np.concatenate([cio.dataset(f, s + "/stats/time").reshape(-1) for s in ("train", "valid")
                               if s + "/stats/time" in f])


def inputs_from_run(summary, db=None):
    """Figures measured in one run (its summary JSON and, if given, its database)."""
    s = json.load(open(summary))
    n = s["samples_total"]
    t = sample_times(db) if db else None
    # per-sample handling outside the model run (copy into the batch, scene mapping, checksum
    # parts, database blocks): busy time in the loop minus model runs and piece writes, per sample
    handling = None
    if t is not None and s["samples_computed"] == len(t):
        handling = max(sum(s["busy_time_per_rank"]) - sum(s.get("end_block_time_per_rank", [0.0]))
                       - sum(s.get("serial_database_time_per_rank", [0.0])) - float(np.sum(t))
                       - s["piece_write_time"], 0.0) / max(len(t), 1)
    return dict(
        handling=handling, ranks=s["ranks"], n=n, times=t, setup=s["wall_time_setup"],
        layout=s.get("database_layout_time", 0.0),
        mean_time=float(np.mean(t)) if t is not None and len(t) else None,
        latency=s["counter_latency_mean"], slice=s.get("batch_seconds", 2.0),
        bytes_per_sample=s["piece_bytes_written"] / max(s["samples_computed"], 1),
        db_bytes_per_sample=s["assembly_bytes_written"] / max(n, 1),
        write_per_byte=s["piece_write_time"] / max(s["piece_bytes_written"], 1.0),
        end=s["wall_time_assembly"], wall=s["wall_time"], loop=s["wall_time_samples"],
        # the end's work on each rank's own samples' multipliers (shrinks with P); the rest of
        # the end is rank 0's serial work and the collectives
        end_parallel=float(np.mean(s.get("end_block_time_per_rank", [0.0]))) * s["ranks"],
        busy=s["busy_time_per_rank"])


def bench_inputs(path):
    """Machine figures of crowd_snapbench at one rank count (JSON line)."""
    b = json.loads(open(path).read().strip().splitlines()[-1])
    return dict(ranks=b["ranks"], latency=b["counter_latency"], collective=b["collective_cost"],
                bandwidth=b["write_bandwidth_per_rank"], window_create=b.get("window_create_cost", 0.0),
                window_free=b.get("window_free_cost", 0.0))


def simulate_loop(times, p, latency, slice_s, bytes_per_sample, write_per_byte, occupancy=None, put=0.0,
                  start0=0.0):
    """Wall time of the sample loop: dynamic schedule, events in time order. A ticket costs the
    rank `latency` and occupies the counter for `occupancy` (default: min(latency, 2 us); the
    counter serves one operation at a time); putting a sample into the database costs `put`.
    Rank 0 starts at `start0` (its layout of the database), the others at 0."""
    occ = min(latency, 2e-6) if occupancy is None else occupancy
    clock = [0.0] * p          # each rank's time
    clock[0] = start0
    batch_start = [None] * p   # start of the rank's open piece
    batch_bytes = [0.0] * p
    counter_free = 0.0
    k = 0
    active = list(range(p))
    while active:
        # the next ticket goes to the rank that asks first
        r = min(active, key=lambda q: clock[q])
        t0 = max(clock[r], counter_free)
        counter_free = t0 + occ
        clock[r] = t0 + latency
        if k >= len(times):
            if batch_bytes[r] > 0:
                clock[r] += batch_bytes[r] * write_per_byte
            active.remove(r)
            continue
        if batch_start[r] is None:
            batch_start[r] = clock[r]
        clock[r] += times[k] + put
        k += 1
        batch_bytes[r] += bytes_per_sample
        if clock[r] - batch_start[r] >= slice_s:
            clock[r] += batch_bytes[r] * write_per_byte
            batch_bytes[r] = 0.0
            batch_start[r] = None
    return max(clock)


def model_wall(p, inp, one, bench, speed=None):
    """Wall time at p ranks: inp = the run's figures (per-sample times), one = the 1-rank run's,
    bench = crowd_snapbench at p ranks and at 1 rank ({p: figures}).

    `speed`: how much slower this machine ran every rank's own work in the run than in the
    1-rank run; by default the ratio of the mean per-sample times of the two databases (the same
    measured input as the per-sample times). The 1-rank run's other work (per-sample handling,
    piece files, serial setup and end of the database) is scaled by it: on a shared machine the
    ranks of a 2-rank run each get less of a core, and not only for the model runs."""
    b, b1 = bench[p], bench[1]
    f = speed
    if f is None:
        f = inp["mean_time"] / one["mean_time"] if inp.get("mean_time") and one.get("mean_time") else 1.0
    # the 1-rank run's per-sample handling, its database blocks at the bandwidth of p ranks
    put = (f * max((one.get("handling") or 0.0) - one["db_bytes_per_sample"] / b1["bandwidth"], 0.0)
           + one["db_bytes_per_sample"] / b["bandwidth"])
    layout = f * min(one.get("layout", 0.0), one["setup"])
    loop = simulate_loop(inp["times"], p, b["latency"], one["slice"], one["bytes_per_sample"],
                         f * one["write_per_byte"], put=put, start0=layout)
    par = min(one.get("end_parallel", 0.0), one["end"])
    setup = (f * one["setup"] - layout + N_SETUP * (b["collective"] - b1["collective"])
             + b.get("window_create", 0.0) - b1.get("window_create", 0.0))
    end = (f * (one["end"] - par + par / p) + N_END * (b["collective"] - b1["collective"])
           + b.get("window_free", 0.0) - b1.get("window_free", 0.0))
    return setup + loop + end, loop, end


def validate(runs, bench_files, latency="run"):
    """Model vs measured wall time of each run (runs: (summary, database) pairs, one at 1 rank;
    bench_files: crowd_snapbench JSON at each rank count of the runs).

    latency = "run": the counter latency L(P) is the one the run itself measured (its summary's
    `counter_latency_mean`, every ticket of every rank), an input of the same kind as its
    per-sample times; "bench": crowd_snapbench's at P ranks. Each row carries both models
    (`model` with the chosen L, `model_bench` / `model_run` with each)."""
    if latency not in ("run", "bench"):
        raise SystemExit("snapshot_model: --latency must be 'run' or 'bench'")
    ins = [inputs_from_run(s, d) for s, d in runs]
    one = next((i for i in ins if i["ranks"] == 1), None)
    if one is None:
        raise SystemExit("snapshot_model: validate needs a 1-rank run")
    bench = {}
    for f in bench_files:
        b = bench_inputs(f)
        bench[b["ranks"]] = b
    rows = []
    for inp in ins:
        if inp["ranks"] not in bench or 1 not in bench:
            raise SystemExit("snapshot_model: no crowd_snapbench figures at %d (and 1) ranks" % inp["ranks"])
        p = inp["ranks"]
        wall_b, loop_b, end_b = model_wall(p, inp, one, bench)
        # the same model with the run's own counter latency in place of crowd_snapbench's
        own = dict(bench)
        own[p] = dict(bench[p], latency=inp["latency"])
        wall_r, loop_r, end_r = model_wall(p, inp, one, own)
        wall, loop, end = (wall_r, loop_r, end_r) if latency == "run" else (wall_b, loop_b, end_b)
        rows.append(dict(ranks=p, measured=inp["wall"], model=wall, loop_measured=inp["loop"],
                         loop_model=loop, asm_measured=inp["end"], asm_model=end,
                         error=(wall - inp["wall"]) / inp["wall"], latency_source=latency,
                         latency_run=inp["latency"], latency_bench=bench[p]["latency"],
                         model_run=wall_r, error_run=(wall_r - inp["wall"]) / inp["wall"],
                         model_bench=wall_b, error_bench=(wall_b - inp["wall"]) / inp["wall"]))
    return rows


def predict(db, summary, agents=1000, agents_ref=150, step_ratio=194.385 / 3.036, ranks=(16, 128, 1024),
            n_samples=None, latency=5e-6, write_rate=1e9, alpha=5e-6, fs_bandwidth=10e9):
    """Efficiency of a study like `db`'s with `agents` agents on many ranks.

    Per-sample times: the database's distribution times `step_ratio` (full-order time per step at
    `agents` over `agents_ref` agents, docs/benchmarks.md#full-order-model); data per sample x
    agents / agents_ref. Machine (assumed, not measured here): counter latency `latency` (s, one
    RDMA atomic), per-rank write rate (the aggregate capped by the file system's bandwidth),
    collective cost alpha log2(P) (creating or freeing the window: 2 collectives each).
    The serial end of the database (dictionary, multiplier layout, checksums) and the per-sample
    handling (copies, checksum parts) are the 1-rank run's, scaled with the data. Returns one
    row per rank count."""
    inp = inputs_from_run(summary, db)
    times = inp["times"] * step_ratio
    if n_samples is not None:
        rng = np.random.default_rng(1)
        times = rng.choice(times, n_samples)
    scale = agents / agents_ref
    one = dict(inp, setup=1.0, end=inp["end"] * scale, bytes_per_sample=inp["bytes_per_sample"] * scale,
               db_bytes_per_sample=inp["db_bytes_per_sample"] * scale, write_per_byte=1.0 / write_rate,
               handling=(inp.get("handling") or 0.0) * scale)
    work = float(np.sum(times))
    rows = []
    for p in ranks:
        w = min(write_rate, fs_bandwidth / p)
        c = alpha * math.log2(max(p, 2))
        bench = {1: dict(latency=latency, collective=0.0, bandwidth=write_rate, window_create=0.0, window_free=0.0),
                 p: dict(latency=latency, collective=c, bandwidth=w, window_create=2 * c, window_free=2 * c)}
        wall, loop, end = model_wall(p, dict(inp, times=times), one, bench, speed=1.0)
        rows.append(dict(ranks=p, samples=len(times), wall=wall, loop=loop, assembly=end,
                         efficiency=work / (p * wall), loop_efficiency=work / (p * loop),
                         counter_busy=len(times) * latency / loop, work=work))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("validate")
    v.add_argument("--runs", nargs="+", required=True, help="SUMMARY.json:DATABASE.h5 of each run")
    v.add_argument("--bench", nargs="+", required=True, help="crowd_snapbench JSON at each rank count")
    v.add_argument("--latency", choices=("run", "bench"), default="run",
                   help="counter latency L(P): the run's own (its summary) or crowd_snapbench's (default: run)")
    pr = sub.add_parser("predict")
    pr.add_argument("--db", required=True)
    pr.add_argument("--summary", required=True)
    pr.add_argument("--agents", type=int, default=1000)
    pr.add_argument("--ranks", type=int, nargs="+", default=[16, 128, 1024])
    pr.add_argument("--samples", type=int, default=None)
    a = ap.parse_args()
    try:
        if a.cmd == "validate":
            runs = [tuple(r.split(":", 1)) for r in a.runs]
            rows = validate(runs, a.bench, latency=a.latency)
            print("| ranks | measured wall (s) | model (s), L of the %s | error | loop measured / model (s) "
                  "| end measured / model (s) | L run / snapbench (us) | model, L of the run (s) | error "
                  "| model, L of snapbench (s) | error |" % a.latency)
            print("|---|---|---|---|---|---|---|---|---|---|---|")
            for r in rows:
                print("| %d | %.3f | %.3f | %+.1f%% | %.3f / %.3f | %.3f / %.3f | %.1f / %.1f | %.3f | %+.1f%% "
                      "| %.3f | %+.1f%% |" % (
                          r["ranks"], r["measured"], r["model"], 100 * r["error"], r["loop_measured"], r["loop_model"],
                          r["asm_measured"], r["asm_model"], 1e6 * r["latency_run"], 1e6 * r["latency_bench"],
                          r["model_run"], 100 * r["error_run"], r["model_bench"], 100 * r["error_bench"]))
        else:
            rows = predict(a.db, a.summary, agents=a.agents, ranks=a.ranks, n_samples=a.samples)
            print("| ranks | samples | wall (s) | loop (s) | assembly (s) | efficiency | loop efficiency | counter busy |")
            print("|---|---|---|---|---|---|---|---|")
            for r in rows:
                print("| %d | %d | %.1f | %.1f | %.2f | %.3f | %.3f | %.2e |" % (
                    r["ranks"], r["samples"], r["wall"], r["loop"], r["assembly"], r["efficiency"],
                    r["loop_efficiency"], r["counter_busy"]))
    except cio.InputError as exc:
        raise SystemExit("snapshot_model.py: error: %s" % exc)


if __name__ == "__main__":
    main()
