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
              "cpu", "engine", "comment")
LOW_KEYS = ("name", "setting", "ml", "comment")
BUILD_KEYS = ("name", "model", "models", "runs", "cpu_seconds", "summary", "ml_output", "regressor",
              "fit_threads", "comment")
#: the engine's knobs a models file may set (``engine``), with the Setup argument they fill
ENGINE_KEYS = {"pilot": "n_pilot", "m1_ladder": "m1_ladder", "m2_ladder": "m2_ladder",
               "m2_low_runs": "m2_low_runs", "max_cost": "max_cost"}


def _json(path, what):
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise InputError(f"{what} not found: '{path}'") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None


def build_cost(path, key, b):
    """(runs, CPU seconds) of a builds entry: given; from a stage's --summary JSON
    (crowd_snapshots': the sum of busy_time_per_rank, samples_total runs; crowd_offline's: ranks x
    the sum of its time_* stage times, wall seconds of every rank, an upper bound of the CPU); or
    from an ML training output (``ml_output``, schema crowdrom-ml): the reduced queries its
    training and validation sets needed (t_query_rom x (n_train + n_valid)) and the fits of
    ``regressor`` (every truncation, t_fit wall seconds x ``fit_threads``)."""
    if "ml_output" in b:
        return ml_build_cost(path, key, b)
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


def ml_build_cost(path, key, b):
    import numpy as np
    where = f"{path}: {key}.ml_output"
    try:
        with cio.open_h5(b["ml_output"], cio.ML_SCHEMA, "ML output") as f:
            runs = cio.attr(f, "n_train", int) + cio.attr(f, "n_valid", int)
            t_rom = cio.attr(f, "t_query_rom", float)
            reg = b.get("regressor", "random_forest")
            if reg not in f:
                raise InputError(f"'{b['ml_output']}' has no regressor '{reg}'")
            t_fit = float(np.sum(f[reg]["t_fit"][()]))
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    return runs, runs * max(t_rom, 0.0) + float(b.get("fit_threads", 1)) * t_fit


def load_builds(path, doc):
    """The build items of a models file (``ledger.Builds``). An entry names the models that need
    it (``models``, or one ``model``); entries with the same ``name``, or else the same
    ``summary`` / ``ml_output`` file, are one item (charged once to an answer using any of them)."""
    from answers.ledger import Builds
    builds = Builds()
    for i, b in enumerate(doc.get("builds", [])):
        key = f"builds[{i}]"
        if not isinstance(b, dict):
            raise InputError(f"{path}: {key}: expected an object")
        for k in b:
            if k not in BUILD_KEYS:
                raise InputError(f"{path}: {key}.{k}: unknown key (known: {', '.join(BUILD_KEYS[:-1])})")
        models = b.get("models", [b["model"]] if "model" in b else None)
        if not models or not isinstance(models, list):
            raise InputError(f"{path}: {key}: needs 'models' (a non-empty list) or 'model'")
        name = b.get("name") or b.get("summary") or b.get("ml_output") or str(models[0])
        try:
            runs, cpu = build_cost(path, key, b)
            builds.add(name, models, runs, cpu)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: {key}: {type(exc).__name__}: {exc}") from None
    return builds


def predict_models(path, doc, box, seed_params, program=None, progress=None, cache_dir=None):
    """(exact, lows) PredictModels of a models file naming a ROM file."""
    from answers.backend import PredictModel
    rom = os.path.abspath(doc["rom_file"])
    program = program or doc.get("program", os.path.join(ROOT, "build", "bin", "crowd_predict"))
    program = os.path.abspath(program) if os.sep in program else program
    common = dict(rom_file=rom, param_names=box.names, seed_params=seed_params, program=program,
                  ranks=doc.get("ranks", 0), launcher=doc.get("launcher", "mpirun"),
                  cpu=doc.get("cpu", "process"), progress=progress, cache_dir=cache_dir)

    def model(spec, key, kind):
        if not isinstance(spec, dict) or "name" not in spec:
            raise InputError(f"{path}: {key}: expected {{\"name\": ..., \"setting\": {{...}}}}")
        for k in spec:
            if k not in LOW_KEYS:
                raise InputError(f"{path}: {key}.{k}: unknown key (known: {', '.join(LOW_KEYS[:-1])})")
        ml = spec.get("ml")
        if ml is not None and isinstance(ml, dict):
            ml = {k: (os.path.abspath(v) if k in ("models_dir", "config", "ml_output") else v)
                  for k, v in ml.items()}
        try:
            return PredictModel(spec["name"], kind="ml" if ml is not None else kind,
                                setting=spec.get("setting"), ml=ml, **common)
        except InputError as exc:
            raise InputError(f"{path}: {key}: {exc}") from None
    lows = doc.get("lows", [])
    if not isinstance(lows, list):
        raise InputError(f"{path}: lows: expected a list")
    return model(doc["exact"], "exact", "exact"), [model(s, f"lows[{i}]", "rom") for i, s in enumerate(lows)]


def read_models_file(path):
    doc = _json(path, "models file")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected an object")
    for k in doc:
        if k not in MODEL_KEYS:
            raise InputError(f"{path}: {k}: unknown key (known: {', '.join(MODEL_KEYS[:-1])})")
    if "synthetic" not in doc:
        for k in ("rom_file", "exact"):
            if k not in doc:
                raise InputError(f"{path}: missing key '{k}' (or 'synthetic')")
        if not os.path.isfile(doc["rom_file"]):
            raise InputError(f"{path}: rom_file: not found: '{doc['rom_file']}'")
    eng = doc.get("engine", {})
    if not isinstance(eng, dict):
        raise InputError(f"{path}: engine: expected an object")
    for k in eng:
        if k not in ENGINE_KEYS:
            raise InputError(f"{path}: engine.{k}: unknown key (known: {', '.join(ENGINE_KEYS)})")
    return doc


def load_models(path, box, qoi_names=None, doc=None, seed_params=(), program=None, progress=None,
                cache_dir=None):
    """(exact, lows, builds) from a models file: Backends of the synthetic family, or
    PredictModels (one per model, serving every QoI; with ``qoi_names`` of one QoI, that QoI's
    Backends); InputError naming file and key."""
    from answers.backend import SyntheticFamily
    doc = doc if doc is not None else read_models_file(path)
    builds = load_builds(path, doc)
    if "synthetic" in doc:
        s = doc["synthetic"]
        try:
            fam = SyntheticFamily(box, s["means"], s["stds"], s["corr"], s["costs"],
                                  s.get("kind", "gauss"), s.get("names"))
        except (KeyError, TypeError, ValueError, IndexError, Exception) as exc:
            raise InputError(f"{path}: synthetic: {type(exc).__name__}: {exc}") from None
        models = [fam.model(k) for k in range(len(fam.means))]
        exact, lows = models[0], models[1:]
    else:
        exact, lows = predict_models(path, doc, box, list(seed_params), program, progress, cache_dir)
        if qoi_names is not None and len(qoi_names) == 1:
            exact, lows = exact.for_qoi(qoi_names[0]), [m.for_qoi(qoi_names[0]) for m in lows]
    names = [m.name for m in [exact] + lows]
    if len(set(names)) != len(names):
        raise InputError(f"{path}: model names must differ ({', '.join(names)})")
    unknown = sorted(builds.models() - set(names))
    if unknown:
        raise InputError(f"{path}: builds: model '{unknown[0]}' is not a model of the file "
                         f"({', '.join(names)})")
    return exact, lows, builds


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("questions", help="questions file (JSON, docs/answers.md)")
    ap.add_argument("--models", required=True, help="models file (JSON, see above)")
    ap.add_argument("--out-prefix", required=True, help="outputs <prefix>.md/.json/.png")
    ap.add_argument("--seed", type=int, help="seed (default: the questions file's)")
    ap.add_argument("--pilot", type=int, help="joint pilot runs (default: the models file's "
                    "engine.pilot, else 40)")
    ap.add_argument("--max-cost", type=float, help="CPU seconds a candidate may cost at most "
                    "(default: the models file's engine.max_cost, else unlimited)")
    ap.add_argument("--program", help="the crowd_predict executable (default: the models file's)")
    ap.add_argument("--cache", metavar="DIR", help="keep every model's runs (QoIs and CPU seconds per "
                    "parameter row) in DIR and reuse them in a later run (default: none)")
    ap.add_argument("--methods", nargs="+", default=["M0", "M1", "M2", "M3"],
                    choices=["M0", "M1", "M2", "M3"])
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    from answers import report as rep
    from answers.questions import load_questions, rom_box
    from answers.select import Setup, answer_questions

    t0 = time.time()

    def progress(msg):
        if not args.quiet:
            print(f"{PROG}: [{time.time() - t0:7.1f} s] {msg}", flush=True)
    doc = read_models_file(args.models)
    box, seed_params, source = None, [], None
    if "synthetic" not in doc:
        box, seed_params = rom_box(doc["rom_file"])
        source = f"ROM file '{doc['rom_file']}'"
    qs = load_questions(args.questions, box, source)
    exact, lows, builds = load_models(args.models, qs.box, None, doc, seed_params, args.program,
                                      progress, args.cache)
    outs = {ext: f"{args.out_prefix}.{ext}" for ext in ("md", "json", "png")}
    cio.check_outputs([(f"output .{e}", p) for e, p in outs.items()],
                      [("questions", args.questions), ("models", args.models)])
    knobs = {ENGINE_KEYS[k]: (tuple(v) if isinstance(v, list) else v)
             for k, v in doc.get("engine", {}).items()}
    if args.pilot is not None:
        knobs["n_pilot"] = args.pilot
    if args.max_cost is not None:
        knobs["max_cost"] = args.max_cost
    setup = Setup(exact, lows, builds, seed=qs.seed if args.seed is None else args.seed,
                  methods=args.methods, progress=progress, **knobs)
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
