#!/usr/bin/env python3
"""Answer a case's questions with a stated error by the cheapest method (docs/answers.md).

    crowd_answers.py QUESTIONS.json --models MODELS.json --out-prefix results/case_answers

writes <prefix>.md (the table), <prefix>.json (every answer, interval, cost ledger and
candidate) and <prefix>.png (stated error against total cost), all or none.

MODELS.json names the models: the exact model and reduced settings of a ROM file, all run
through crowd_predict (paths relative to the working directory):

    {"rom_file": "results/hall20_rom.h5", "program": "build/bin/crowd_predict", "ranks": 2,
     "exact": {"name": "exact"},
     "lows": [{"name": "rom_39_65", "setting": {"n": 39, "r": 65, "hyper": "eq"}}],
     "builds": [{"model": "rom_39_65", "summary": "results/hall20_snapshots.json"},
                {"model": "rom_39_65", "cpu_seconds": 812.0, "runs": 36}]}

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
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)

import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "crowd_answers.py"
ROOT = os.path.dirname(os.path.dirname(HERE))
MODEL_KEYS = ("exact", "lows", "builds", "synthetic", "rom_file", "program", "ranks", "launcher",
              "cpu", "comment")


def _json(path, what):
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise InputError(f"{what} not found: '{path}'") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None


def build_cost(path, key, b):
    """(runs, CPU seconds) of a builds entry: given, or from a stage's --summary JSON:
    crowd_snapshots' (sum of busy_time_per_rank, samples_total runs) or crowd_offline's (ranks x
    the sum of its time_* stage times: wall seconds of every rank, an upper bound of the CPU)."""
    if "summary" not in b:
        return int(b.get("runs", 0)), float(b["cpu_seconds"])
    s = _json(b["summary"], f"{path}: {key}.summary: stage summary")
    if "busy_time_per_rank" in s:
        return int(s.get("samples_total", 0)), float(sum(s["busy_time_per_rank"]))
    times = [float(v) for k, v in s.items() if k.startswith("time_") and isinstance(v, (int, float))]
    if times and "ranks" in s:
        return 0, float(s["ranks"]) * sum(times)
    raise InputError(f"{path}: {key}.summary: '{b['summary']}' is neither a crowd_snapshots nor a "
                     "crowd_offline summary (no busy_time_per_rank, no time_* with ranks)")


def load_builds(path, doc):
    from answers.ledger import CostLedger
    builds = CostLedger()
    for i, b in enumerate(doc.get("builds", [])):
        key = f"builds[{i}]"
        try:
            runs, cpu = build_cost(path, key, b)
            builds.add("build", b["model"], runs, cpu)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: {key}: {type(exc).__name__}: {exc}") from None
    return builds


def predict_backends(path, doc, box, qoi):
    """(exact, lows) PredictBackends of a models file naming a ROM file."""
    from answers.backend import PredictBackend
    if "rom_file" not in doc or "exact" not in doc:
        raise InputError(f"{path}: missing key '{'rom_file' if 'rom_file' not in doc else 'exact'}' "
                         "(or 'synthetic')")
    rom = os.path.abspath(doc["rom_file"])
    if not os.path.isfile(rom):
        raise InputError(f"{path}: rom_file: not found: '{doc['rom_file']}'")
    program = doc.get("program", os.path.join(ROOT, "build", "bin", "crowd_predict"))
    program = os.path.abspath(program) if os.sep in program else program
    common = dict(rom_file=rom, param_names=box.names, program=program, ranks=doc.get("ranks", 0),
                  launcher=doc.get("launcher", "mpirun"), cpu=doc.get("cpu", "process"))

    def backend(spec, key, model):
        if not isinstance(spec, dict) or "name" not in spec:
            raise InputError(f"{path}: {key}: expected {{\"name\": ..., \"setting\": {{...}}}}")
        for k in spec:
            if k not in ("name", "setting"):
                raise InputError(f"{path}: {key}.{k}: unknown key (known: name, setting)")
        try:
            return PredictBackend(spec["name"], qoi, model=model, setting=spec.get("setting"), **common)
        except InputError as exc:
            raise InputError(f"{path}: {key}: {exc}") from None
    lows = doc.get("lows", [])
    if not isinstance(lows, list):
        raise InputError(f"{path}: lows: expected a list")
    return backend(doc["exact"], "exact", "exact"), [backend(s, f"lows[{i}]", "rom")
                                                     for i, s in enumerate(lows)]


def load_models(path, box, qoi_names):
    """(exact, lows, builds ledger) from a models file; InputError naming file and key."""
    from answers.backend import SyntheticFamily
    doc = _json(path, "models file")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected an object")
    for k in doc:
        if k not in MODEL_KEYS:
            raise InputError(f"{path}: {k}: unknown key (known: {', '.join(MODEL_KEYS[:-1])})")
    builds = load_builds(path, doc)
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
                         "one questions file per QoI with crowd_predict models")
    exact, lows = predict_backends(path, doc, box, qoi_names[0])
    names = [m.name for m in [exact] + lows]
    if len(set(names)) != len(names):
        raise InputError(f"{path}: model names must differ ({', '.join(names)})")
    return exact, lows, builds


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
