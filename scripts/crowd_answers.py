#!/usr/bin/env python3
"""Answer a case's questions with a stated error by the cheapest method (docs/answers.md).

    crowd_answers.py QUESTIONS.json --models MODELS.json --out-prefix results/case_answers

writes <prefix>.md (the table), <prefix>.json (every answer, interval, cost ledger and
candidate) and <prefix>.png (stated error against total cost), all or none.

MODELS.json names the models:

    {"exact": {"name": "exact", "command": ["build/bin/crowd_predict", "exact.nml",
                                            "--params", "{params}", "--output", "{output}"]},
     "lows": [{"name": "rom3", "command": [...]}],
     "builds": [{"model": "rom3", "cpu_seconds": 812.0, "runs": 36}]}

or, for a synthetic family of correlated models with known moments on the questions' box:

    {"synthetic": {"means": [20, 15], "stds": [2, 1.5], "corr": [[1, 0.9], [0.9, 1]],
                   "costs": [6.0, 0.05], "kind": "gauss", "names": ["exact", "rom"]},
     "builds": [{"model": "rom", "cpu_seconds": 300.0}]}
"""
import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "crowd_answers.py"


def load_models(path, box, qoi_names):
    """(exact, lows, builds ledger) from a models file; InputError naming file and key."""
    from answers.backend import CommandBackend, SyntheticFamily
    from answers.ledger import CostLedger
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise InputError(f"models file not found: '{path}'") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected an object")
    for k in doc:
        if k not in ("exact", "lows", "builds", "synthetic", "comment"):
            raise InputError(f"{path}: {k}: unknown key (known: exact, lows, builds, synthetic)")
    builds = CostLedger()
    for i, b in enumerate(doc.get("builds", [])):
        try:
            builds.add("build", b["model"], b.get("runs", 0), float(b["cpu_seconds"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: builds[{i}]: {exc}") from None
    if "synthetic" in doc:
        s = doc["synthetic"]
        try:
            fam = SyntheticFamily(box, s["means"], s["stds"], s["corr"], s["costs"],
                                  s.get("kind", "gauss"), s.get("names"))
        except (KeyError, TypeError, ValueError, IndexError, Exception) as exc:
            raise InputError(f"{path}: synthetic: {type(exc).__name__}: {exc}") from None
        models = [fam.model(k) for k in range(len(fam.means))]
        return models[0], models[1:], builds
    if len(qoi_names) != 1:
        raise InputError(f"{path}: the questions name several QoIs ({', '.join(qoi_names)}): "
                         "one questions file per QoI with command models")

    def backend(spec, key):
        if not isinstance(spec, dict) or "command" not in spec or "name" not in spec:
            raise InputError(f"{path}: {key}: expected {{\"name\": ..., \"command\": [...]}}")
        return CommandBackend(spec["name"], spec["command"], qoi_names[0], box.names)
    if "exact" not in doc:
        raise InputError(f"{path}: missing key 'exact' (or 'synthetic')")
    return (backend(doc["exact"], "exact"),
            [backend(s, f"lows[{i}]") for i, s in enumerate(doc.get("lows", []))], builds)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("questions", help="questions file (JSON, docs/answers.md)")
    ap.add_argument("--models", required=True, help="models file (JSON, see above)")
    ap.add_argument("--out-prefix", required=True, help="outputs <prefix>.md/.json/.png")
    ap.add_argument("--seed", type=int, help="seed (default: the questions file's)")
    ap.add_argument("--pilot", type=int, default=40, help="joint pilot runs (default 40)")
    ap.add_argument("--max-cost", type=float, default=float("inf"),
                    help="CPU seconds a candidate may cost at most (default unlimited)")
    ap.add_argument("--methods", nargs="+", default=["M0", "M1", "M2", "M3"],
                    choices=["M0", "M1", "M2", "M3"])
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    from answers import report as rep
    from answers.questions import load_questions
    from answers.select import Setup, answer_questions

    qs = load_questions(args.questions)
    exact, lows, builds = load_models(args.models, qs.box, sorted({q.qoi for q in qs.questions}))
    outs = {ext: f"{args.out_prefix}.{ext}" for ext in ("md", "json", "png")}
    cio.check_outputs([(f"output .{e}", p) for e, p in outs.items()],
                      [("questions", args.questions), ("models", args.models)])
    t0 = time.time()

    def progress(msg):
        if not args.quiet:
            print(f"{PROG}: [{time.time() - t0:7.1f} s] {msg}", flush=True)
    setup = Setup(exact, lows, builds, seed=qs.seed if args.seed is None else args.seed,
                  n_pilot=args.pilot, max_cost=args.max_cost, methods=args.methods, progress=progress)
    report = answer_questions(qs, setup)
    with cio.OutputSet() as out:
        with open(out.tmp(outs["md"]), "w", encoding="utf-8") as f:
            f.write(rep.markdown(report))
        rep.write_json(report, out.tmp(outs["json"]))
        rep.figure(report, out.tmp(outs["png"]))
        out.commit()
    reached, n = rep.summary_numbers(report)
    progress(f"{reached} of {n} answers reach their accuracy; wrote {', '.join(outs.values())}")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
