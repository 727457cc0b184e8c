#!/usr/bin/env python3
"""The honest reference of a questions file: a large exact sample for every distribution (the
first --n-pool rows the pool the coverage repetitions draw from, the next --n-truth rows the
truth, disjoint), the exact model at every map point, and every low fidelity of the models
file at the same inputs (a joint sample), run by crowd_predict (docs/answers-reference.md#honest-reference-congested150_evac).

    answers_reference.py QUESTIONS.json --models MODELS.json --n-truth 3000 --n-pool 1000 \\
        --work results/ref_chunks --out results/case_reference.h5 --truth results/case_truth.json

Chunks of --chunk queries are kept in --work (a stopped run resumes). Writes the HDF5 reference
(samples, QoIs, censoring, CPU seconds, the command, machine and load) and the truth JSON
({question id: {statistic: value}} plus "details": value, standard error, 95% interval, censored
count, the pool's value), both or neither.
"""
import argparse
import json
import os
import platform
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)

import crowdrom_io as cio  # noqa: E402

PROG = "answers_reference.py"


def backends(models_path, box, qoi):
    """(exact, lows) as ProductBackends from a crowd_predict models file."""
    from answers.reference import ProductBackend
    from crowd_answers import load_models
    exact, lows, _ = load_models(models_path, box, [qoi])

    return ProductBackend(exact), [ProductBackend(m) for m in lows]


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("questions")
    ap.add_argument("--models", required=True)
    ap.add_argument("--n-truth", type=int, default=3000)
    ap.add_argument("--n-pool", type=int, default=1000)
    ap.add_argument("--chunk", type=int, default=250)
    ap.add_argument("--work", required=True, help="folder of the chunks (resume)")
    ap.add_argument("--out", required=True, help="reference HDF5")
    ap.add_argument("--truth", required=True, help="truth JSON")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import h5py
    import numpy as np
    from answers import reference
    from answers.questions import load_questions

    qs = load_questions(args.questions)
    qois = sorted({q.qoi for q in qs.questions})
    exact, lows = backends(args.models, qs.box, qois[0])
    cio.check_outputs([("output", args.out), ("truth", args.truth)],
                      [("questions", args.questions), ("models", args.models)])
    load0, t0 = os.getloadavg(), time.time()
    samples, of = reference.plan(qs, args.n_truth, args.n_pool)
    batches = {}
    for name, params in samples.items():
        batches[name] = {m.name: reference.Batch(m, params, args.work, name, args.chunk)
                         for m in [exact] + lows}
    truth = reference.truth_table(qs, of, batches, exact.name, args.n_pool, qs.confidence)
    meta = {"command": " ".join([PROG] + (argv if argv is not None else sys.argv[1:])),
            "questions_file": qs.path, "models_file": args.models, "rom_file": exact.model.rom_file,
            "program": exact.model.program, "ranks": exact.model.ranks, "seed": qs.seed,
            "n_truth": args.n_truth, "n_pool": args.n_pool,
            "machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cores",
            "load_average_start": list(load0), "load_average_end": list(os.getloadavg()),
            "wall_seconds": time.time() - t0}
    with cio.OutputSet() as out:
        with h5py.File(out.tmp(args.out), "w") as f:
            for k, v in meta.items():
                f.attrs[k] = v
            f.attrs["param_names"] = ",".join(qs.box.names)
            f.attrs["sample_of"] = json.dumps(of)
            for name, params in samples.items():
                g = f.create_group(f"samples/{name}")
                g["params"] = params
                g.attrs["n_pool"] = args.n_pool if name.startswith("dist_") else 0
                for mname, b in batches[name].items():
                    h = g.create_group(mname)
                    h["t_evac"], h["censored"], h["cpu_seconds"] = b.t_evac, b.censored.astype(np.int8), b.cpu
                    h.attrs["process_cpu_seconds"], h.attrs["calls"] = b.process_cpu, b.calls
        doc = {q.id: {s: v["value"] for s, v in truth[q.id].items()} for q in qs.questions}
        doc["details"] = truth
        doc["reference"] = meta
        with open(out.tmp(args.truth), "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
        out.commit()
    for q in qs.questions:
        for s, v in truth[q.id].items():
            if s != "map":
                print(f"{q.id} {s}: {v['value']:.6g} +- {v['se']:.3g} (se, {100 * v['se'] / abs(v['value']):.2g}%), "
                      f"pool {v['pool_value']:.6g}, censored {v['censored']} of {v['n']}")
            else:
                print(f"{q.id}: {np.round(v['value'], 4).tolist()} censored {v['censored']}")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
