#!/usr/bin/env python3
"""Benchmark of the prediction for new parameters (not a test): crowd_predict's throughput in
queries per CPU second for reduced settings, the ML correction and the exact model on one study,
and the parallel efficiency of the query loop at 2 ranks; prints a Markdown table.

Usage: .venv/bin/python scripts/bench/bench_predict.py ROM [--queries 200] [--exact-queries 10]
       [--setting N R HYPER CONTACTS CORRECTION ...] [--costly-queries K] [--costly-serial] [--exact-serial]
       [--ml-output ML.h5 --ml-models DIR] [--ranks 2] [--seed 1] [--keep DIR] [--out FILE.md]

ROM is a ROM file of version 3 (crowd_offline; scripts/run_study.sh CASE writes
results/CASE_rom.h5). The queries are drawn uniformly in the study's training box (&predict
n_queries, seed): the same list for every model. Default settings: every pair of the ROM file
with 'eq' / 'cone' / no correction (--setting replaces them; repeatable). The costly settings (the
local exact correction, online contacts) answer the first --costly-queries queries of the same
rule (default --queries); --costly-serial skips their run at --ranks ranks, --exact-serial that
of the exact model.

Figures (all from one run of this script, side by side; the machine is shared, so compare the
ratios):
* queries per CPU second = n_queries / the sum of the per-query CPU seconds of the product
  (setup for the parameter, the trajectory, its QoIs), 1 rank; the reduced operators are loaded
  once per run, outside the queries;
* ML: the reduced setting of the training output (its pair, trajectories written), then
  ml_correct.py --predict: the per-query CPU seconds of its product are the reduced query's, the
  query's share of the batch correction and the QoIs of the corrected positions;
* parallel efficiency at P ranks = wall(1 rank) / (P wall(P ranks)) of the query loop (the
  product's wall_seconds: dynamic distribution, gather in query order), P = --ranks.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.environ.get("CROWDROM_BIN") or os.path.join(ROOT, "build", "bin")
PY = sys.executable
ENV = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1",
           OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMPI_MCA_rmaps_base_oversubscribe="1")


def predict(work, tag, rom, np_, **opts):
    """Run crowd_predict on np_ ranks; return (product dict, summary dict)."""
    out = os.path.join(work, f"{tag}_np{np_}.h5")
    opts = dict(rom_file=f"'{os.path.abspath(rom)}'", output=f"'{out}'", **opts)
    nml = os.path.join(work, f"{tag}_np{np_}.nml")
    with open(nml, "w") as f:
        f.write("&predict %s /\n" % ", ".join(f"{k} = {v}" for k, v in opts.items()))
    summ = os.path.join(work, f"{tag}_np{np_}.json")
    cmd = [os.path.join(BIN, "crowd_predict"), nml, "--summary", summ]
    if np_ > 1:
        cmd = ["mpirun", "-np", str(np_)] + cmd
    p = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=work)
    if p.returncode != 0:
        sys.exit(f"bench_predict: crowd_predict ({tag}, {np_} ranks) failed: {p.stderr.strip()[-400:]}")
    return cio.read_prediction(out), json.load(open(summ)), out


def row(name, d, wall_p=None, np_=2):
    cpu = float(d["cpu_seconds"].sum())
    nq = len(d["cpu_seconds"])
    eff = float(d["wall_seconds"]) / (np_ * wall_p) if wall_p else None
    return {"model": name, "queries": nq, "cpu_per_query": cpu / nq, "qps": nq / cpu, "eff": eff,
            "wall1": float(d["wall_seconds"]), "wallp": wall_p}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rom", help="ROM file (version 3)")
    ap.add_argument("--queries", type=int, default=200, help="queries of each reduced model (default 200)")
    ap.add_argument("--exact-queries", type=int, default=10, help="queries of the exact model (default 10)")
    ap.add_argument("--setting", nargs=5, action="append", metavar=("N", "R", "HYPER", "CONTACTS", "CORRECTION"),
                    help="a reduced setting (repeatable; default: every pair, eq / cone / none)")
    ap.add_argument("--costly-queries", type=int, help="queries of the settings with the local correction or "
                    "online contacts (default: --queries)")
    ap.add_argument("--costly-serial", action="store_true", help="no parallel run of those settings")
    ap.add_argument("--exact-serial", action="store_true", help="no parallel run of the exact model")
    ap.add_argument("--ml-output", help="training output of ml_correct.py (its setting and best n)")
    ap.add_argument("--ml-models", help="the saved models of that training")
    ap.add_argument("--ml-config", help="the ML configuration of that training (JSON)")
    ap.add_argument("--ranks", type=int, default=2, help="ranks of the parallel run (default 2)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", help="keep the runs in this folder (default: a temporary one)")
    ap.add_argument("--out", help="also write the table to this Markdown file")
    args = ap.parse_args(argv)
    with cio.open_h5(args.rom, cio.ROM_SCHEMA, "ROM file") as f:
        pairs = [(cio.attr(f[f"pairs/{k}"], "n", int), cio.attr(f[f"pairs/{k}"], "r", int))
                 for k in cio.rom_pair_indices(f)]
        cio.read_rom_study(f)
    settings = args.setting or [(str(n), str(r), "eq", "cone", "none") for n, r in pairs]
    load0 = os.getloadavg()
    # absolute: crowd_predict runs in this folder and is given its input by path
    work = os.path.abspath(args.keep) if args.keep else tempfile.mkdtemp(prefix="bench_predict_")
    os.makedirs(work, exist_ok=True)
    rows = []
    sample = dict(n_queries=args.queries, seed=args.seed)
    for n, r, hyper, contacts, corr in settings:
        tag = f"rom_{n}_{r}_{hyper}_{contacts}_{corr}"
        s = dict(model="'rom'", n=n, r=r, hyper=f"'{hyper}'", contacts=f"'{contacts}'", correction=f"'{corr}'")
        costly = corr == "local" or contacts == "online"
        smp = dict(sample, n_queries=args.costly_queries) if costly and args.costly_queries else sample
        d1, _, _ = predict(work, tag, args.rom, 1, **s, **smp)
        wall_p = None
        if not (costly and args.costly_serial):
            dp, _, _ = predict(work, tag, args.rom, args.ranks, **s, **smp)
            wall_p = float(dp["wall_seconds"])
        rows.append(row(f"rom N={n} R={r} {hyper}/{contacts}" + ("" if corr == "none" else f"/{corr}"), d1,
                        wall_p, args.ranks))
        print(f"bench_predict: {rows[-1]['model']}: {rows[-1]['qps']:.3g} queries per CPU second", flush=True)
    if args.ml_output:
        with cio.open_h5(args.ml_output, cio.ML_SCHEMA, "ML output") as f:
            pn, pr, hyper = cio.attr(f, "pair_n", int), cio.attr(f, "pair_r", int), cio.attr(f, "hyper", str)
        s = dict(model="'rom'", n=pn, r=pr, hyper=f"'{hyper}'", trajectories=".true.")
        _, _, pred = predict(work, "ml_base", args.rom, 1, **s, **sample)
        ml_out = os.path.join(work, "ml.h5")
        cmd = [PY, os.path.join(ROOT, "scripts", "pipeline", "ml_correct.py"), "--predict", pred, "--ml-output", args.ml_output,
               "--models-dir", args.ml_models, "-o", ml_out, "--quiet"]
        if args.ml_config:
            cmd += ["--config", args.ml_config]
        p = subprocess.run(cmd, capture_output=True, text=True, env=dict(ENV, CROWDROM_BIN=BIN))
        if p.returncode != 0:
            sys.exit(f"bench_predict: ml_correct.py --predict failed: {p.stderr.strip()[-400:]}")
        for fn in sorted(os.listdir(work)):
            if fn.startswith("ml") and fn.endswith(".h5") and fn not in ("ml_base_np1.h5",):
                d = cio.read_prediction(os.path.join(work, fn))
                rows.append(row(d["model"], d))
                print(f"bench_predict: {rows[-1]['model']}: {rows[-1]['qps']:.3g} queries per CPU second", flush=True)
    ex = dict(model="'exact'", n_queries=args.exact_queries, seed=args.seed)
    d1, _, _ = predict(work, "exact", args.rom, 1, **ex)
    wall_p = None
    if not args.exact_serial:
        dp, _, _ = predict(work, "exact", args.rom, args.ranks, **ex)
        wall_p = float(dp["wall_seconds"])
    rows.append(row("exact (" + d1["model"].split(" ", 1)[1] + ")", d1, wall_p, args.ranks))
    print(f"bench_predict: exact: {rows[-1]['qps']:.3g} queries per CPU second", flush=True)
    q_ex = rows[-1]["qps"]
    lines = [f"| model | queries | CPU s per query | queries per CPU s | vs exact | parallel efficiency "
             f"({args.ranks} ranks) |", "|---|---|---|---|---|---|"]
    for r in rows:
        eff = f"{r['eff']:.2f}" if r["eff"] is not None else "-"
        lines.append(f"| {r['model']} | {r['queries']} | {r['cpu_per_query']:.3e} | {r['qps']:.3g} | "
                     f"{r['qps'] / q_ex:.3g} | {eff} |")
    load = os.getloadavg()
    lines.append("")
    lines.append(f"1-minute load average at the start / end: {load0[0]:.1f} / {load[0]:.1f} on {os.cpu_count()} "
                 f"cores; {args.queries} reduced / {args.exact_queries} exact queries drawn uniformly in the box, "
                 f"seed {args.seed}")
    table = "\n".join(lines)
    print(table)
    if args.out:
        with open(args.out, "w") as f:
            f.write(table + "\n")
    if not args.keep:
        import shutil
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors("bench_predict", main))
