"""The questions file (JSON): what a user asks of a case's parameter space.

    {"case": "crowd1000",
     "box": {"l_exit": [2.0, 3.0], "l_exit2": [2.0, 3.0], "speed": [1.0, 1.4]},
     "accuracy": {"relative": [0.01, 0.02, 0.05], "confidence": 0.95},
     "seed": 35,
     "questions": [
       {"id": "t90_map", "kind": "map", "qoi": "t90",
        "grid": {"l_exit": [2.0, 2.5, 3.0], "l_exit2": [2.0, 2.5, 3.0]}, "nominal": {"speed": 1.2}},
       {"id": "t90_spread", "kind": "moments", "qoi": "t90", "percentile": 95,
        "distributions": {"l_exit": {"kind": "fixed", "value": 2.4}, ...}},
       {"id": "t90_late", "kind": "exceedance", "qoi": "t90", "threshold": 25.0,
        "distributions": {...}}]}

Every key is checked (unknown keys refused); each problem raises ``QuestionsError`` with one line
naming the file, the key (``questions[1].distributions.speed.low``) and the problem.
"""
import json
import math
import os
import re

import numpy as np
from scipy import stats

from crowdrom_io import InputError

#: parameter components the engine fills from its seeds, not from the box
#: (docs/scenes.md#hetero1000-a-heterogeneous-population)
SEED_COMPONENTS = ("speed_seed",)
#: relative tolerance of "the questions file's box is the ROM file's"
BOX_RTOL = 1e-9
#: quantities of interest a question may name (the scalar QoIs of the crowdrom-qoi product)
QOI_NAMES = ("t50", "t90", "t100", "flow_1", "flow_2", "flow_rate_1", "flow_rate_2", "displacement")
KINDS = ("map", "moments", "exceedance")
#: how a moments question with a ``horizon`` treats the runs censored there
CENSORING = ("bound", "condition")
DIST_KEYS = {"fixed": ("value",), "uniform": ("low", "high"),
             "truncnormal": ("mean", "std", "low", "high"), "triangular": ("low", "mode", "high")}


class QuestionsError(InputError):
    """Bad content in a questions file (exit status 2)."""


class ParamBox:
    """The trained parameter box: names [d], lower and upper bounds [d]."""

    def __init__(self, names, lo, hi):
        self.names = list(names)
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)

    @property
    def dim(self):
        return len(self.names)

    def index(self, name):
        return self.names.index(name)


def _nml_list(text, key):
    """The values of ``key = v1, v2, ...`` in one namelist group's text (strings unquoted)."""
    m = re.search(r"\b" + key + r"\s*=\s*(.*?)(?=,?\s*\b[a-z_]+\s*=|\s*/)", text, re.S | re.I)
    if not m:
        return None
    return [v.strip().strip("'\"") for v in re.split(r",\s*", m.group(1).strip().rstrip(",")) if v.strip()]


def rom_box(rom_file):
    """(ParamBox, seed components) of a ROM file (version 3): the study's component names (group
    ``study``, attribute ``param_names``) with the bounds of their parameter (``&study param_min``
    / ``param_max`` of the stored configuration; ``speed_<i>`` take those of ``speeds``); the seed
    components (``speed_seed``) are not in the box: the engine fills them from its seeds."""
    import crowdrom_io as cio
    with cio.open_h5(rom_file, cio.ROM_SCHEMA, "ROM file") as f:
        study = cio.read_rom_study(f)
    m = re.search(r"&study\b(.*?)/\s*$", study["config"], re.S | re.M | re.I)
    names, lo, hi = (_nml_list(m.group(1), k) if m else None for k in ("param_name", "param_min", "param_max"))
    if not names or not lo or not hi or not len(names) == len(lo) == len(hi):
        raise QuestionsError(f"{rom_file}: study/config: no &study param_name, param_min, param_max")
    bounds = {n: (float(a.replace("d", "e").replace("D", "e")), float(b.replace("d", "e").replace("D", "e")))
              for n, a, b in zip(names, lo, hi)}
    comps, seeds, blo, bhi = [], [], [], []
    for c in study["param_names"]:
        c = c.strip()
        if c in SEED_COMPONENTS:
            seeds.append(c)
            continue
        p = c if c in bounds else ("speeds" if re.fullmatch(r"speed_\d+", c) and "speeds" in bounds else None)
        if p is None:
            raise QuestionsError(f"{rom_file}: study/param_names: component '{c}' has no &study bounds")
        comps.append(c)
        blo.append(bounds[p][0])
        bhi.append(bounds[p][1])
    return ParamBox(comps, blo, bhi), seeds


class Distribution:
    """One parameter's distribution: ``kind`` in DIST_KEYS and its numbers."""

    def __init__(self, kind, **p):
        self.kind, self.p = kind, p
        if kind == "uniform":
            self._rv = stats.uniform(p["low"], p["high"] - p["low"])
        elif kind == "truncnormal":
            a, b = (p["low"] - p["mean"]) / p["std"], (p["high"] - p["mean"]) / p["std"]
            self._rv = stats.truncnorm(a, b, loc=p["mean"], scale=p["std"])
        elif kind == "triangular":
            w = p["high"] - p["low"]
            self._rv = stats.triang((p["mode"] - p["low"]) / w, loc=p["low"], scale=w)
        else:
            self._rv = None

    def support(self):
        if self.kind == "fixed":
            return self.p["value"], self.p["value"]
        return self.p["low"], self.p["high"]

    def ppf(self, u):
        """Quantile function at u in (0, 1) [n]."""
        u = np.asarray(u, dtype=float)
        if self._rv is None:
            return np.full(u.shape, float(self.p["value"]))
        return self._rv.ppf(u)

    def as_dict(self):
        return {"kind": self.kind, **self.p}


class JointDistribution:
    """Independent distributions of every box parameter (in the box's order)."""

    def __init__(self, box, dists):
        self.box, self.dists = box, [dists[n] for n in box.names]

    def from_unit(self, u):
        """Map points of the unit cube [n, d] to parameters [n, d] (component-wise quantiles)."""
        u = np.atleast_2d(u)
        return np.column_stack([d.ppf(u[:, j]) for j, d in enumerate(self.dists)])

    def sample(self, rng, n):
        """n independent parameter vectors [n, d]."""
        return self.from_unit(rng.random((n, self.box.dim)))

    def varying(self):
        """Indices of the parameters that are not fixed."""
        return [j for j, d in enumerate(self.dists) if d.kind != "fixed"]


class Question:
    """One question: ``kind`` (map / moments / exceedance), ``qoi`` and its specification."""

    def __init__(self, qid, kind, qoi, **spec):
        self.id, self.kind, self.qoi = qid, kind, qoi
        self.grid = spec.get("grid")            # map: {name: values}
        self.nominal = spec.get("nominal")      # map: {name: value}
        self.distribution = spec.get("distribution")   # moments / exceedance: JointDistribution
        self.percentile = spec.get("percentile", 95.0)
        self.threshold = spec.get("threshold")
        self.replicates = spec.get("replicates", 1)
        self.horizon = spec.get("horizon")          # moments: the value of a censored run
        self.censoring = spec.get("censoring", "bound" if self.horizon is not None else None)

    def region_key(self):
        """The question's region as canonical text (grid and nominal values, or distributions):
        equal for two questions that draw their parameters alike."""
        if self.kind == "map":
            spec = {"grid": self.grid, "nominal": self.nominal, "replicates": self.replicates}
        else:
            spec = {"distributions": [[n, d.as_dict()] for n, d in
                                      zip(self.distribution.box.names, self.distribution.dists)]}
        return json.dumps(spec, sort_keys=True)

    def statistics(self):
        """The statistics this question asks for (one answer each)."""
        if self.kind == "moments":
            first = ["censored"] if self.censoring == "condition" else []
            return first + ["mean", "std", f"p{self.percentile:g}"]
        if self.kind == "exceedance":
            return ["exceedance"]
        return ["map"]

    def grid_points(self, box):
        """Map questions: the grid's points [n_points, d] (first grid parameter varying slowest)
        and the grid's shape."""
        names = list(self.grid)
        mesh = np.meshgrid(*[np.asarray(self.grid[n], float) for n in names], indexing="ij")
        pts = np.empty((mesh[0].size, box.dim))
        for j, n in enumerate(box.names):
            pts[:, j] = mesh[names.index(n)].ravel() if n in names else self.nominal[n]
        return pts, mesh[0].shape


class Questions:
    """A parsed, checked questions file."""

    def __init__(self, path, case, box, relative, confidence, seed, questions):
        self.path, self.case, self.box = path, case, box
        self.relative, self.confidence, self.seed = relative, confidence, seed
        self.questions = questions


def load_questions(path, box=None, box_source=None):
    """Read and check a questions file. ``box`` (a ParamBox, e.g. ``rom_box`` of the ROM file
    ``box_source``) is the trained box; without it the file's ``box`` key is used, with it the
    file's box (optional) must be the same box: every component, the same bounds. Raises
    QuestionsError (one line: file, key, problem)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise QuestionsError(f"questions file not found: '{path}'") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise QuestionsError(f"{path}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise QuestionsError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None
    return _Checker(path, box_source).document(doc, box)


class _Checker:
    def __init__(self, path, box_source=None):
        self.path, self.source = path, box_source or "the caller's trained box"

    def fail(self, key, problem):
        raise QuestionsError(f"{self.path}: {key}: {problem}")

    def keys(self, obj, key, required, optional=()):
        if not isinstance(obj, dict):
            self.fail(key, f"expected an object, got {type(obj).__name__}")
        for k in obj:
            if k not in required and k not in optional:
                known = ", ".join(list(required) + list(optional))
                self.fail(f"{key}.{k}" if key else k, f"unknown key (known: {known})")
        for k in required:
            if k not in obj:
                self.fail(key or "(top level)", f"missing key '{k}'")

    def number(self, v, key, positive=False, nonneg=False):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(key, f"expected a finite number, got {v!r}")
        if positive and v <= 0:
            self.fail(key, f"must be > 0, got {v!r}")
        if nonneg and v < 0:
            self.fail(key, f"must be >= 0, got {v!r}")
        return float(v)

    def document(self, doc, box):
        self.keys(doc, "", ("questions", "accuracy"), ("case", "box", "seed", "comment"))
        box = self.box(doc.get("box"), box)
        acc = doc["accuracy"]
        self.keys(acc, "accuracy", ("relative",), ("confidence",))
        rel = acc["relative"]
        if not isinstance(rel, list) or not rel:
            self.fail("accuracy.relative", "expected a non-empty list of relative accuracies")
        rel = [self.number(v, f"accuracy.relative[{i}]", positive=True) for i, v in enumerate(rel)]
        conf = self.number(acc.get("confidence", 0.95), "accuracy.confidence")
        if not 0.5 <= conf < 1.0:
            self.fail("accuracy.confidence", f"must lie in [0.5, 1), got {conf}")
        seed = doc.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            self.fail("seed", f"expected a non-negative integer, got {seed!r}")
        qs = doc["questions"]
        if not isinstance(qs, list) or not qs:
            self.fail("questions", "expected a non-empty list of questions")
        questions = [self.question(q, f"questions[{i}]", box) for i, q in enumerate(qs)]
        ids = [q.id for q in questions]
        for i, qid in enumerate(ids):
            if qid in ids[:i]:
                self.fail(f"questions[{i}].id", f"duplicate id '{qid}'")
        return Questions(self.path, str(doc.get("case", "")), box, sorted(rel), conf, seed, questions)

    def box(self, given, trained):
        if given is None:
            if trained is None:
                self.fail("box", "missing (no trained box given by the caller either)")
            return trained
        if not isinstance(given, dict) or not given:
            self.fail("box", "expected an object {parameter: [min, max]}")
        lo, hi = [], []
        for n, v in given.items():
            if not isinstance(v, list) or len(v) != 2:
                self.fail(f"box.{n}", f"expected [min, max], got {v!r}")
            a, b = (self.number(x, f"box.{n}") for x in v)
            if not a < b:
                self.fail(f"box.{n}", f"min {a} must be below max {b}")
            lo.append(a)
            hi.append(b)
        if trained is not None:
            for j, n in enumerate(given):
                if n not in trained.names:
                    self.fail(f"box.{n}", f"not a parameter of {self.source} ({', '.join(trained.names)})")
                k = trained.index(n)
                for end, mine, theirs in (("min", lo[j], trained.lo[k]), ("max", hi[j], trained.hi[k])):
                    if abs(mine - theirs) > BOX_RTOL * max(abs(theirs), 1e-300):
                        self.fail(f"box.{n}", f"[{lo[j]}, {hi[j]}] disagrees with the trained box "
                                  f"[{trained.lo[k]}, {trained.hi[k]}] of {self.source} ({end})")
            missing = [n for n in trained.names if n not in given]
            if missing:
                self.fail(f"box.{missing[0]}", f"missing: {self.source} has the parameters "
                          f"{', '.join(trained.names)}")
            return trained
        return ParamBox(list(given), lo, hi)

    def question(self, q, key, box):
        if not isinstance(q, dict):
            self.fail(key, "expected an object")
        kind = q.get("kind")
        if kind not in KINDS:
            self.fail(f"{key}.kind", f"unknown kind {kind!r} (known: {', '.join(KINDS)})")
        extra = {"map": (("grid", "nominal"), ("replicates",)),
                 "moments": (("distributions",), ("percentile", "horizon", "censoring")),
                 "exceedance": (("distributions", "threshold"), ())}[kind]
        self.keys(q, key, ("id", "kind", "qoi") + extra[0], extra[1] + ("comment",))
        if not isinstance(q["id"], str) or not q["id"]:
            self.fail(f"{key}.id", f"expected a non-empty string, got {q['id']!r}")
        if q["qoi"] not in QOI_NAMES:
            self.fail(f"{key}.qoi", f"unknown QoI {q['qoi']!r} (known: {', '.join(QOI_NAMES)})")
        spec = {}
        if kind == "map":
            spec.update(self.grid(q, key, box))
        else:
            spec["distribution"] = self.distributions(q["distributions"], f"{key}.distributions", box)
        if kind == "moments" and "percentile" in q:
            p = self.number(q["percentile"], f"{key}.percentile")
            if not 0 < p < 100:
                self.fail(f"{key}.percentile", f"must lie in (0, 100), got {p}")
            spec["percentile"] = p
        if kind == "moments":
            spec.update(self.censoring(q, key))
        if kind == "exceedance":
            spec["threshold"] = self.number(q["threshold"], f"{key}.threshold")
        return Question(q["id"], kind, q["qoi"], **spec)

    def censoring(self, q, key):
        """``horizon`` (> 0) and ``censoring`` ('bound' or 'condition', needs a horizon)."""
        out = {}
        if "horizon" in q:
            out["horizon"] = self.number(q["horizon"], f"{key}.horizon")
            if not out["horizon"] > 0:
                self.fail(f"{key}.horizon", f"must be > 0, got {out['horizon']}")
        if "censoring" in q:
            if q["censoring"] not in CENSORING:
                self.fail(f"{key}.censoring", f"unknown {q['censoring']!r} (known: {', '.join(CENSORING)})")
            if "horizon" not in q:
                self.fail(f"{key}.censoring", "needs a horizon (the value of a censored run)")
            out["censoring"] = q["censoring"]
        return out

    def inside(self, v, name, key, box):
        k = box.index(name)
        if not box.lo[k] <= v <= box.hi[k]:
            self.fail(key, f"{v} lies outside the trained box [{box.lo[k]}, {box.hi[k]}] of '{name}'")

    def grid(self, q, key, box):
        grid, nominal = q["grid"], q["nominal"]
        if not isinstance(grid, dict) or not grid:
            self.fail(f"{key}.grid", "empty grid (expected {parameter: [values]})")
        out_grid = {}
        for n, vals in grid.items():
            if n not in box.names:
                self.fail(f"{key}.grid.{n}", f"unknown parameter (known: {', '.join(box.names)})")
            if not isinstance(vals, list) or not vals:
                self.fail(f"{key}.grid.{n}", "empty grid (expected a non-empty list of values)")
            vs = [self.number(v, f"{key}.grid.{n}[{i}]") for i, v in enumerate(vals)]
            for i, v in enumerate(vs):
                self.inside(v, n, f"{key}.grid.{n}[{i}]", box)
            if any(b <= a for a, b in zip(vs, vs[1:])):
                self.fail(f"{key}.grid.{n}", "values must increase strictly")
            out_grid[n] = vs
        self.keys(nominal, f"{key}.nominal", [n for n in box.names if n not in grid])
        out_nom = {}
        for n, v in nominal.items():
            out_nom[n] = self.number(v, f"{key}.nominal.{n}")
            self.inside(out_nom[n], n, f"{key}.nominal.{n}", box)
        reps = q.get("replicates", 1)
        if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
            self.fail(f"{key}.replicates", f"expected a positive integer, got {reps!r}")
        return {"grid": out_grid, "nominal": out_nom, "replicates": reps}

    def distributions(self, ds, key, box):
        self.keys(ds, key, box.names)
        out = {}
        for n in box.names:
            d, k = ds[n], f"{key}.{n}"
            if not isinstance(d, dict) or d.get("kind") not in DIST_KEYS:
                got = d.get("kind") if isinstance(d, dict) else d
                self.fail(f"{k}.kind", f"unknown distribution {got!r} (known: {', '.join(DIST_KEYS)})")
            names = DIST_KEYS[d["kind"]]
            self.keys(d, k, ("kind",) + names)
            p = {m: self.number(d[m], f"{k}.{m}") for m in names}
            self.check_dist(d["kind"], p, k)
            for m in ("value", "low", "high"):
                if m in p:
                    self.inside(p[m], n, f"{k}.{m}", box)
            out[n] = Distribution(d["kind"], **p)
        return JointDistribution(box, out)

    def check_dist(self, kind, p, k):
        if kind != "fixed" and not p["low"] < p["high"]:
            self.fail(f"{k}.low", f"low {p['low']} must be below high {p['high']}")
        if kind == "truncnormal" and p["std"] <= 0:
            self.fail(f"{k}.std", f"must be > 0, got {p['std']}")
        if kind == "triangular" and not p["low"] <= p["mode"] <= p["high"]:
            self.fail(f"{k}.mode", f"{p['mode']} must lie in [low, high]")
