#!/usr/bin/env python3
"""Coverage of the stated intervals: every method repeated R times with different seeds on each
question statistic (distribution questions) of a questions file, against a known truth.

    answers_coverage.py QUESTIONS.json --models MODELS.json --reps 100 --out results/cov.json
        [--truth TRUTH.json] [--n-exact 32] [--eps 0.05] [--methods M0 M1 M2 M3]

The truth: TRUTH.json {"question id": {"mean": v, "std": v, "p95": v, "exceedance": v}} (e.g.
from a large exact sample), or, for a synthetic models file, the family's closed forms (valid for
distributions uniform on the whole box). Each method at a fixed size: M0 and M2 with --n-exact
exact runs (M2: 2 000 low-fidelity runs), M1 with a GP on --n-exact exact runs, M3 planned from
a 40-run pilot for the relative accuracy --eps. Writes JSON (one entry per question, statistic
and method: coverage with its Wilson interval, mean stated error, actual error RMS and 95th
percentile, mean cost) and prints a Markdown table.
"""
import argparse
import json
import os
import sys
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)

import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "answers_coverage.py"


def estimator(method, q, stat, exact, lows, box, n_exact, eps, conf):
    from answers import methods, sampling
    from answers.intervals import z_value
    from answers.ledger import CostLedger

    def run(seed):
        led = CostLedger()
        if method == "M0":
            return methods.m0(q, stat, exact, n_exact, seed, conf, led)
        if method == "M1":
            tr = sampling.TrainingSet(q, box, [exact], seed, led)
            return methods.m1(q, stat, tr, n_exact, seed, conf, led, restarts=1)
        if method == "M2":
            return methods.m2(q, stat, lows[0], exact, 2000, n_exact, seed, conf, led)
        models = [exact] + lows
        pilot = sampling.Pilot(q, models, 40, seed, led)
        tsd = sampling.target_sd(stat, pilot.Y[:, 0], eps, z_value(conf), q.threshold, q.percentile)
        return methods.m3(q, stat, models, pilot, methods.m3_plan(pilot, stat, tsd, q), seed, conf, led)
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("questions")
    ap.add_argument("--models", required=True)
    ap.add_argument("--truth", help="truth JSON (default: the synthetic family's closed forms)")
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--n-exact", type=int, default=32)
    ap.add_argument("--eps", type=float, default=0.05)
    ap.add_argument("--methods", nargs="+", default=["M0", "M1", "M2", "M3"],
                    choices=["M0", "M1", "M2", "M3"])
    ap.add_argument("--out", required=True, help="output JSON")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    from answers.coverage import coverage
    from answers.questions import load_questions
    from crowd_answers import load_models

    qs = load_questions(args.questions)
    exact, lows, _ = load_models(args.models, qs.box, sorted({q.qoi for q in qs.questions}))
    cio.check_outputs([("output", args.out)], [("questions", args.questions), ("models", args.models)])
    truths = _truths(args, qs, exact)
    results = []
    print("| question | statistic | method | coverage [Wilson 95%] | stated error | actual RMS | actual p95 | cost |")
    print("|---|---|---|---|---|---|---|---|")
    for q in qs.questions:
        if q.kind == "map":
            continue
        for stat in q.statistics():
            for m in args.methods:
                if m in ("M2", "M3") and not lows:
                    continue
                run = estimator(m, q, stat, exact, lows, qs.box, args.n_exact, args.eps, qs.confidence)
                c = coverage(run, truths[q.id][stat], range(args.reps))
                c.update(question=q.id, statistic=stat, method=m, truth=truths[q.id][stat])
                results.append(c)
                print(f"| {q.id} | {stat} | {m} | {c['coverage']:.3f} [{c['coverage_lo']:.3f}, "
                      f"{c['coverage_hi']:.3f}] | {_pc(c['stated_error_mean'])} | {_pc(c['actual_error_rms'])} | "
                      f"{_pc(c['actual_error_p95'])} | {c['cost_mean']:.4g} |", flush=True)
    with cio.OutputSet() as out:
        with open(out.tmp(args.out), "w", encoding="utf-8") as f:
            json.dump({"questions_file": qs.path, "reps": args.reps, "n_exact": args.n_exact,
                       "eps_m3": args.eps, "results": results}, f, indent=1)
        out.commit()
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
            for s in q.statistics() if q.kind != "map" else []:
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
