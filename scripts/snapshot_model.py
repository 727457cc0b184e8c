#!/usr/bin/env python3
"""Scaling model of the snapshot stage (crowd_snapshots), validated against measured runs and
used to predict the 1 000-agent study on many ranks.

Model of the wall time at P ranks:

    T(P) = T_setup + T_loop(P) + T_asm(P)

* T_loop: the dynamic schedule simulated sample by sample, events in time order. Each rank takes
  a ticket from the shared counter (one-sided fetch-and-add on rank 0: the rank waits L, the
  counter is busy for its service time o and serves one operation at a time), computes the sample (a time drawn from the per-sample time distribution of a
  database), and records it (a second counter operation). A rank writes a piece when its time
  slice S is over, and at the end: c_w per byte of sample data. The loop ends when the last rank
  has written its last piece.
* T_asm: reading the pieces (every rank its own, at r_read bytes/s each, at most B_fs in
  total), the contact dictionary (measured, kept), the parallel data phase (the database bytes at
  r_write per rank, at most B_fs in total, plus n_coll collective HDF5/MPI operations of c(P)
  each) and the serial header / checksum phase on rank 0 (measured, kept).

Inputs come from the run's database (per-sample times `stats/time`) and its `--summary` JSON
(setup time, counter latency, piece bytes and write time, assembly phase times and bytes,
collective latency). `validate` rebuilds T(P) of measured runs; `predict` extrapolates.

Usage:
    snapshot_model.py validate --runs RUN.json[:DB.h5] ... [--calibrate-collectives RUN.json]
    snapshot_model.py predict  --db congested150.h5 --summary congested150_np1.json
                               [--agents 1000] [--ranks 16 128 1024]
"""
import argparse
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import crowdrom_io as cio  # noqa: E402

# collective operations of the assembly's parallel data phase: per set 16 datasets, each
# created (1 metadata collective + 1 error agreement) and written (2 error agreements + the
# MPI-IO transfer), plus file create, close, the digest reduction and the multiplier counts
N_COLL = 2 * 16 * 5 + 6


def sample_times(db):
    """Per-sample model-run times (s) of a database, train then valid."""
    with cio.open_h5(db, cio.DB_SCHEMA, "snapshot database") as f:
        return np.concatenate([cio.dataset(f, s + "/stats/time").reshape(-1) for s in ("train", "valid")
                               if s + "/stats/time" in f])


def inputs_from_run(summary, db=None):
    """Model inputs measured in one run (its summary JSON and, if given, its database)."""
    s = json.load(open(summary))
    n = s["samples_total"]
    p = s["ranks"]
    t = sample_times(db) if db else None
    bytes_per_sample = s["piece_bytes_written"] / max(s["samples_computed"], 1)
    return dict(
        ranks=p, n=n, times=t, setup=s["wall_time_setup"],
        latency=s["counter_latency_mean"], slice=s.get("batch_seconds", 2.0),
        bytes_per_sample=bytes_per_sample,
        write_per_byte=s["piece_write_time"] / max(s["piece_bytes_written"], 1.0),
        read_rate=s["assembly_read_bytes"] / max(s["assembly_read_time"], 1e-9) / p,
        read_bytes=s["assembly_read_bytes"], t_dict=s["assembly_dictionary_time"],
        db_bytes=s["database_bytes"], t_write=s["assembly_write_time"], t_header=s["assembly_header_time"],
        collective=s["collective_latency"], wall=s["wall_time"], loop=s["wall_time_samples"],
        assembly=s["wall_time_assembly"], busy=s["busy_time_per_rank"])


def simulate_loop(times, p, latency, slice_s, bytes_per_sample, write_per_byte, occupancy=None):
    """Wall time of the sample loop: dynamic schedule, events in time order. A ticket costs the
    rank `latency` and occupies the counter for `occupancy` (default: min(latency, 2 us); the
    counter serves one operation at a time); marking a sample done costs `latency`."""
    occ = min(latency, 2e-6) if occupancy is None else occupancy
    clock = [0.0] * p          # each rank's time
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
        clock[r] += times[k]
        k += 1
        batch_bytes[r] += bytes_per_sample
        if clock[r] - batch_start[r] >= slice_s:
            clock[r] += batch_bytes[r] * write_per_byte
            batch_bytes[r] = 0.0
            batch_start[r] = None
        clock[r] += latency    # mark_done (progress counter)
    return max(clock)


def assembly_time(p, inp, collective, fs_bandwidth=math.inf):
    """Assembly wall time at p ranks from rates measured at one rank."""
    read = inp["read_bytes"] / min(p * inp["read_rate"], fs_bandwidth)
    write_rate = inp["db_bytes"] / max(inp["t_write1"], 1e-9)
    write = inp["db_bytes"] / min(p * write_rate, fs_bandwidth)
    coll = 0.0 if p == 1 else N_COLL * collective(p)
    return read + inp["t_dict"] + write + coll + inp["t_header"]


def model_wall(p, inp, collective, fs_bandwidth=math.inf):
    loop = simulate_loop(inp["times"], p, inp["latency"], inp["slice"], inp["bytes_per_sample"],
                         inp["write_per_byte"])
    asm = assembly_time(p, inp, collective, fs_bandwidth)
    return inp["setup"] + loop + asm, loop, asm


def validate(runs, calibrate=None):
    """Model vs measured wall time of each run. Rates are those of the 1-rank run; the
    per-collective cost of the parallel data phase is taken from `calibrate` (a 2-rank run of the
    same study) when given, else from each run's measured MPI_Allreduce latency."""
    ins = [inputs_from_run(s, d) for s, d in runs]
    one = next((i for i in ins if i["ranks"] == 1), None)
    if one is None:
        raise SystemExit("snapshot_model: validate needs a 1-rank run")
    c_eff = None
    if calibrate is not None:
        cal = inputs_from_run(*calibrate)
        rate = one["db_bytes"] / max(one["t_write"], 1e-9)
        c_eff = max(cal["t_write"] - cal["db_bytes"] / (cal["ranks"] * rate), 0.0) / N_COLL
    rows = []
    for inp in ins:
        inp["read_rate"] = one["read_rate"]
        inp["t_write1"] = one["t_write"]
        coll = (lambda p: c_eff) if c_eff is not None else (lambda p, c=inp["collective"]: c)
        wall, loop, asm = model_wall(inp["ranks"], inp, coll)
        rows.append(dict(ranks=inp["ranks"], measured=inp["wall"], model=wall, loop_measured=inp["loop"],
                         loop_model=loop, asm_measured=inp["assembly"], asm_model=asm,
                         error=(wall - inp["wall"]) / inp["wall"]))
    return rows, c_eff


def predict(db, summary, agents=1000, agents_ref=150, step_ratio=194.385 / 3.036, ranks=(16, 128, 1024),
            n_samples=None, latency=5e-6, fs_bandwidth=10e9, write_rate=1e9, read_rate=2e9, alpha=5e-6):
    """Efficiency of a study like `db`'s with `agents` agents on many ranks.

    Per-sample times: the database's distribution times `step_ratio` (full-order time per step at
    `agents` over `agents_ref` agents, README "Full-order model: scaling"); data per sample x
    agents / agents_ref. Machine (assumed, not measured here): counter latency `latency` (s, one
    RDMA atomic), per-rank write / read rates, aggregate file-system bandwidth, collective cost
    alpha log2(P). Returns one row per rank count."""
    inp = inputs_from_run(summary, db)
    times = inp["times"] * step_ratio
    if n_samples is not None:
        rng = np.random.default_rng(1)
        times = rng.choice(times, n_samples)
    scale = agents / agents_ref
    inp.update(times=times, latency=latency, bytes_per_sample=inp["bytes_per_sample"] * scale,
               write_per_byte=1.0 / write_rate, read_rate=read_rate, read_bytes=inp["read_bytes"] * scale,
               db_bytes=inp["db_bytes"] * scale, t_write1=inp["db_bytes"] * scale / write_rate,
               setup=1.0, t_dict=0.05, t_header=0.05 * scale)
    work = float(np.sum(times))
    rows = []
    for p in ranks:
        wall, loop, asm = model_wall(p, inp, lambda q: alpha * math.log2(max(q, 2)), fs_bandwidth)
        rows.append(dict(ranks=p, samples=len(times), wall=wall, loop=loop, assembly=asm,
                         efficiency=work / (p * wall), loop_efficiency=work / (p * loop),
                         counter_busy=2 * len(times) * latency / loop, work=work))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("validate")
    v.add_argument("--runs", nargs="+", required=True, help="SUMMARY.json:DATABASE.h5 of each run")
    v.add_argument("--calibrate-collectives", default=None, help="SUMMARY.json:DATABASE.h5 of a 2-rank run")
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
            cal = tuple(a.calibrate_collectives.split(":", 1)) if a.calibrate_collectives else None
            rows, c = validate(runs, cal)
            print("| ranks | measured wall (s) | model (s) | error | loop measured / model (s) | assembly measured / model (s) |")
            print("|---|---|---|---|---|---|")
            for r in rows:
                print("| %d | %.3f | %.3f | %+.1f%% | %.3f / %.3f | %.3f / %.3f |" % (
                    r["ranks"], r["measured"], r["model"], 100 * r["error"], r["loop_measured"], r["loop_model"],
                    r["asm_measured"], r["asm_model"]))
            if c is not None:
                print("\ncost per collective of the parallel data phase (calibrated): %.2f ms" % (1e3 * c))
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
