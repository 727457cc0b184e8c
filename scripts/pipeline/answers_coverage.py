#!/usr/bin/env python3
"""Coverage of the stated intervals: every method repeated R times with different seeds on each
question statistic of a questions file, against a known truth.

    answers_coverage.py QUESTIONS.json --models MODELS.json --reps 100 --out results/cov.json
        [--truth TRUTH.json] [--reference REF.h5 --work DIR] [--n-exact 32] [--n-train 16]
        [--n-low 2000] [--eps 0.05 | --m3-target m0] [--methods M0 M1 M2 M3] [--maps]

The truth: TRUTH.json {"question id": {"mean": v, "std": v, "p95": v, "exceedance": v,
"map": [v, ...]}} (answers_reference.py writes one from a large exact sample), or, for a
synthetic models file, the family's closed forms (distributions uniform on the whole box).

With --reference (answers_reference.py's HDF5 file, whose pool rows are disjoint from the truth
rows) the real models are served from runs made beforehand: M0, M2 and M3 draw their inputs from
the pool of joint runs (without replacement; answers/pool.py says why this is sound), M1 and the
map methods train on their own design points, which are run first through crowd_predict (in
chunks kept in --work) and then looked up; each looked-up run is charged its measured CPU
seconds, each call the measured start-up of one crowd_predict run.

Each method at a fixed size: M0 with --n-exact exact runs; M1 a GP on --n-train exact runs;
M2 --n-low low-fidelity runs and --n-exact held-out pairs; M3 planned from a 40-run pilot for
the relative accuracy --eps, or (--m3-target m0) for the variance of M0 with --n-exact runs (so
M3's cost compares with M0's at equal precision); maps (--maps): M0 at every point, M1, M2, M3
(the autoregressive GP) on --n-train training runs. Writes JSON (one entry per question,
statistic and method: coverage with its Wilson interval, for maps pointwise too, for pool runs
against the pool's own value too, mean stated error, actual error RMS and 95th percentile, mean
cost) and prints a Markdown table.
"""
import argparse
import json
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)

import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "answers_coverage.py"


class Models:
    """The models the repetitions use: exact, lows, builds; ``pool_q(q)`` the question they
    draw from (the pool's with --reference, else q itself)."""

    def __init__(self, exact, lows, builds, pools=None, pool_truth=None):
        self.exact, self.lows, self.builds = exact, lows, builds
        self.pools, self.pool_truth = pools or {}, pool_truth or {}

    def pool_q(self, q):
        from answers.pool import pool_question
        return pool_question(q, self.pools[q.id]) if q.id in self.pools else q


def estimator(method, q, stat, models, box, args, conf):
    from answers import methods, sampling
    from answers.intervals import z_value
    from answers.ledger import CostLedger
    exact, lows, builds = models.exact, models.lows, models.builds
    pq = models.pool_q(q)
    names = [m.name for m in lows]

    def run(seed):
        led = CostLedger()
        if stat == "map":
            return _map(method, q, exact, lows, box, args, conf, seed, builds)
        if method == "M0":
            return methods.m0(pq, stat, exact, args.n_exact, seed, conf, led)
        if method == "M1":
            tr = sampling.TrainingSet(q, box, [exact], seed, led)
            n_large, n_draws, n_sub = args.m1_propagation
            return methods.m1(q, stat, tr, args.n_train, seed, conf, led, restarts=1,
                              n_large=n_large, n_draws=n_draws, n_sub=n_sub)
        if method == "M2":
            led = builds.ledger([names[0]])
            return methods.m2(pq, stat, lows[0], exact, args.n_low, args.n_exact, seed, conf, led)
        led = builds.ledger(names)
        pilot = sampling.Pilot(pq, [exact] + lows, 40, seed, led)
        if args.m3_target == "m0":
            tsd = _m0_sd(pilot, stat, pq, args.n_exact)
        else:
            tsd = sampling.target_sd(stat, pilot.Y[:, 0], args.eps, z_value(conf), q.threshold, q.percentile)
        plan = methods.m3_plan(pilot, stat, tsd, pq)
        return methods.m3(pq, stat, [exact] + lows, pilot, plan, seed, conf, led)
    return run


def _m0_sd(pilot, stat, q, n):
    """The standard deviation of plain Monte Carlo's per-sample mean with n runs, from the pilot."""
    import numpy as np
    from answers.sampling import per_sample
    y = pilot.Y[:, 0]
    if stat in ("mean", "std"):
        return float(np.std(per_sample(stat, [y])[0], ddof=1) / np.sqrt(n))
    p = (np.mean(y > q.threshold) if stat == "exceedance" else np.mean(y >= q.horizon) if stat == "censored"
         else q.percentile / 100)
    p = float(np.clip(p, 0.5 / len(y), 1 - 0.5 / len(y)))
    return float(np.sqrt(p * (1 - p) / n))


def _map(method, q, exact, lows, box, args, conf, seed, builds):
    from answers import methods, sampling
    from answers.ledger import CostLedger
    if method == "M0":
        return methods.m0_map(q, box, exact, seed, conf, CostLedger())
    if method == "M1":
        led = CostLedger()
        tr = sampling.TrainingSet(q, box, [exact], seed, led)
        return methods.m1_map(q, box, tr, args.n_train, seed, conf, led, restarts=1)
    led = builds.ledger([lows[0].name])
    tr = sampling.TrainingSet(q, box, [exact, lows[0]], seed, led)
    if method == "M2":
        return methods.m2_map(q, box, lows[0], exact, tr, args.n_train, seed, conf, led)
    return methods.m3_map(q, box, lows[0], tr, args.n_train, seed, conf, led, restarts=1)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("questions")
    ap.add_argument("--models", required=True)
    ap.add_argument("--truth", help="truth JSON (default: the synthetic family's closed forms)")
    ap.add_argument("--reference", help="answers_reference.py's HDF5: serve the runs from its pool")
    ap.add_argument("--work", help="folder of the design runs' chunks (with --reference)")
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--n-exact", type=int, default=32)
    ap.add_argument("--n-train", type=int, help="M1 and map training runs (default --n-exact)")
    ap.add_argument("--n-low", type=int, default=2000, help="M2's low-fidelity runs")
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--m3-target", choices=["eps", "m0"], default="eps")
    ap.add_argument("--m1-propagation", type=int, nargs=3, default=[20000, 200, 300],
                    metavar=("N_LARGE", "N_DRAWS", "N_SUB"), help="M1's propagation sample sizes")
    ap.add_argument("--methods", nargs="+", default=["M0", "M1", "M2", "M3"],
                    choices=["M0", "M1", "M2", "M3"])
    ap.add_argument("--questions-only", nargs="+", help="question ids (default: all)")
    ap.add_argument("--maps", action="store_true", help="the map questions too")
    ap.add_argument("--designs-only", action="store_true",
                    help="with --reference's models: only run the design points into --work, then stop")
    ap.add_argument("--rescore", help="an earlier output JSON: score its answers against --truth")
    ap.add_argument("--out", required=True, help="output JSON")
    args = ap.parse_args(argv)
    args.n_train = args.n_train or args.n_exact
    warnings.simplefilter("ignore")
    from answers.coverage import coverage
    from answers.methods import conditional
    from answers.questions import load_questions
    from crowd_answers import load_models

    qs = load_questions(args.questions)
    if args.rescore:
        return rescore(args, qs)
    exact, lows, builds = load_models(args.models, qs.box, sorted({q.qoi for q in qs.questions}))
    cio.check_outputs([("output", args.out)], [("questions", args.questions), ("models", args.models)])
    seeds = range(args.first_seed, args.first_seed + args.reps)
    chosen = [q for q in qs.questions if (args.questions_only is None or q.id in args.questions_only)
              and (q.kind != "map" or args.maps)]
    if args.designs_only:
        from answers import pool
        pool.design_runs(qs, chosen, pool.sample_names(qs), exact, lows, seeds, args.n_train,
                         args.methods, args.work)
        return 0
    truths = _truths(args, qs, exact)
    models = Models(exact, lows, builds)
    if args.reference:
        if not args.work:
            raise InputError("--work is needed with --reference (the design runs' chunks)")
        from answers import pool
        ex, lo, pools, pool_truth = pool.served_models(args.reference, qs, chosen, exact, lows, builds,
                                                       seeds, args.n_train, args.methods, args.work)
        models = Models(ex, lo, builds, pools, pool_truth)
    results, t0 = [], time.time()
    print("| question | statistic | method | coverage [Wilson 95%] | stated error | actual RMS | actual p95 | cost |")
    print("|---|---|---|---|---|---|---|---|")
    for q in chosen:
        for stat in q.statistics():
            for m in args.methods:
                if m in ("M2", "M3") and not lows or m == "M3" and conditional(q, stat):
                    continue
                run = estimator(m, q, stat, models, qs.box, args, qs.confidence)
                pt = models.pool_truth.get(q.id, {}).get(stat)
                c = coverage(run, truths[q.id][stat], seeds, pool_truth=pt)
                c.update(question=q.id, statistic=stat, method=m, truth=truths[q.id][stat],
                         pool_truth=pt, seconds=time.time() - t0)
                results.append(c)
                _row(c)
    _write(args.out, {"questions_file": qs.path, "command": " ".join([PROG] + (argv or sys.argv[1:])),
                      "reps": args.reps, "n_exact": args.n_exact, "n_train": args.n_train,
                      "n_low": args.n_low, "eps_m3": args.eps, "m3_target": args.m3_target,
                      "load_average_end": list(os.getloadavg()), "results": results})
    return 0


def _row(c):
    cov = f"{c['coverage']:.3f} [{c['coverage_lo']:.3f}, {c['coverage_hi']:.3f}]"
    if "coverage_points" in c:
        cov += f" (points {c['coverage_points']:.3f})"
    print(f"| {c['question']} | {c['statistic']} | {c['method']} | {cov} | {_pc(c['stated_error_mean'])} | "
          f"{_pc(c['actual_error_rms'])} | {_pc(c['actual_error_p95'])} | {c['cost_mean']:.4g} |", flush=True)


def _write(path, doc):
    with cio.OutputSet() as out:
        with open(out.tmp(path), "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
        out.commit()


def rescore(args, qs):
    """Score the answers of earlier output JSONs (--rescore, several joined by commas) against
    --truth: the same table for another (e.g. a larger) truth sample."""
    from answers.coverage import score
    if not args.truth:
        raise InputError("--rescore needs --truth")
    args.maps = True
    truths = _truths(args, qs, None)
    results = []
    for path in args.rescore.split(","):
        try:
            with open(path, encoding="utf-8") as f:
                doc = json.load(f)
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: cannot read: {exc}") from None
        for c in doc["results"]:
            t = truths[c["question"]][c["statistic"]]
            new = {**c, **score(c["answers"], t, c.get("pool_truth")), "truth": t}
            results.append(new)
            _row(new)
    _write(args.out, {"questions_file": qs.path, "truth_file": args.truth, "rescored": args.rescore,
                      "results": results})
    return 0


def _pc(x):
    return "-" if x is None else f"{100 * x:.3g}%"


def _truths(args, qs, exact):
    if args.truth:
        try:
            with open(args.truth, encoding="utf-8") as f:
                t = json.load(f)
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"{args.truth}: cannot read the truth: {exc}") from None
        for q in qs.questions:
            for s in q.statistics() if (q.kind != "map" or args.maps) else []:
                if s not in t.get(q.id, {}):
                    raise InputError(f"{args.truth}: {q.id}.{s}: missing truth")
        return t
    fam = getattr(exact, "family", None)
    if fam is None:
        raise InputError("--truth is needed with command models (no closed forms)")
    return {q.id: {s: float(fam.truth(s, q.percentile, q.threshold)) for s in q.statistics()}
            for q in qs.questions if q.kind != "map"}


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
