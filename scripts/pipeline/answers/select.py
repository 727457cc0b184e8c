"""The cheapest method per question and accuracy, with its answer, interval and total cost.

For each question statistic and relative accuracy eps (at the file's confidence):

* M0 and M3 are planned from one joint pilot of all models (``pilot`` runs, charged to both):
  M0 needs n = C_11 / v runs, M3 the MFMC plan reaching the variance v that gives eps (maps: M0
  is one run per point and replicate, exact when replicates = 1);
* M1 (GP on exact runs) and M2 / M3-map (per low fidelity) are run on a ladder of training sizes
  (nested designs, so a rung only adds runs), each rung an actual answer with its stated error;
* the cheapest candidate whose (predicted or actual) stated error reaches eps within
  ``max_cost`` is chosen; a planned one is then run on fresh samples (and planned once more
  from its own stated error if that misses eps, both runs charged).

The report holds one row per (question, statistic, accuracy) with the chosen answer and M0's
cost, every candidate (for the figure), and every answer in full.
"""
import hashlib
import math

import numpy as np

from . import acv, methods
from .intervals import quantile_ci, z_value
from .ledger import Builds, CostLedger
from .sampling import Pilot, RunCache, TrainingSet, per_sample, target_sd


class Setup:
    """The models and the knobs: ``exact`` and ``lows`` (Backends, or models with
    ``for_qoi(qoi)`` giving one: then each question gets its QoI's backends and the models'
    runs are shared between questions), ``builds`` (``ledger.Builds``, or a CostLedger whose
    build entries each belong to the model they name), pilot size, the ladders, the low
    fidelity's sample size in M2 (``m2_low_runs``), the CPU budget cap."""

    def __init__(self, exact, lows=(), builds=None, seed=0, n_pilot=40, m1_ladder=(8, 16, 32, 64),
                 m2_ladder=(8, 16, 32, 64), max_cost=math.inf, methods=("M0", "M1", "M2", "M3"),
                 gp_restarts=2, progress=None, m2_low_runs=2000):
        self.exact, self.lows = exact, list(lows)
        builds = builds if builds is not None else Builds()
        self.builds = builds if isinstance(builds, Builds) else Builds.per_model(builds)
        self.seed, self.n_pilot, self.max_cost = seed, n_pilot, max_cost
        self.m1_ladder, self.m2_ladder, self.methods = m1_ladder, m2_ladder, methods
        self.gp_restarts, self.m2_low_runs = gp_restarts, m2_low_runs
        self.progress = progress or (lambda msg: None)

    def ledger(self, models=()):
        """A fresh ledger holding the build items needed by ``models`` (names), each once."""
        return self.builds.ledger(models)

    def for_qoi(self, qoi):
        """This setup with the backends of one QoI (models without ``for_qoi`` are kept)."""
        out = Setup.__new__(Setup)
        out.__dict__.update(self.__dict__)
        pick = (lambda m: m.for_qoi(qoi) if hasattr(m, "for_qoi") else m)
        out.exact, out.lows = pick(self.exact), [pick(m) for m in self.lows]
        return out


def question_seed(seed, q):
    """The seed of a question's random streams: from the file's seed and the question's region
    (distributions, or grid and nominal values), not from its place in the file, so questions on
    several QoIs over one region draw the same parameter rows (and run them once)."""
    h = hashlib.sha256(f"{int(seed)}:{q.region_key()}".encode()).hexdigest()
    return int(h[:8], 16)       # < 2**32: a random_state scikit-learn accepts


class Candidate:
    def __init__(self, method, cost, error, answer=None, plan=None, label=None):
        self.method, self.cost, self.error = method, cost, error
        self.answer, self.plan, self.label = answer, plan, label or method


def answer_questions(questions, setup):
    """Answer every question at every accuracy; a dict report (rows, candidates, answers)."""
    rows, cands, answers, pilots = [], [], [], []
    for qi, q in enumerate(questions.questions):
        seed = question_seed(setup.seed, q)
        setup.progress(f"question {qi + 1} of {len(questions.questions)}: '{q.id}' ({q.kind}, {q.qoi})")
        qs = setup.for_qoi(q.qoi)
        if q.kind == "map":
            per_stat = {"map": _map_candidates(q, questions, qs, seed)}
        else:
            per_stat = _stat_candidates(q, questions, qs, seed, pilots)
        for stat, (cl, planner) in per_stat.items():
            for eps in questions.relative:
                row, extra = _choose(q, stat, eps, cl(eps), planner, questions.confidence, qs)
                rows.append(row)
                answers.extend(extra)
            cands.extend({"question": q.id, "statistic": stat, "method": c.label, "cost": c.cost,
                          "stated_error": _num(c.error), "planned": c.answer is None}
                         for c in cl(None))
    return {"case": questions.case, "questions_file": questions.path,
            "confidence": questions.confidence, "accuracy": questions.relative,
            "max_cost": setup.max_cost if math.isfinite(setup.max_cost) else None,
            "rows": rows, "candidates": cands, "answers": [a.as_dict() for a in answers],
            "pilots": pilots}


def _num(x):
    return float(x) if x is not None and np.isfinite(x) else None


def _choose(q, stat, eps, cands, planner, conf, setup):
    ok = [c for c in cands if c.error is not None and c.error <= eps and c.cost <= setup.max_cost]
    m0 = min((c for c in cands if c.method == "M0"), key=lambda c: c.cost, default=None)
    row = {"question": q.id, "qoi": q.qoi, "statistic": stat, "accuracy": eps,
           "m0_cost": m0.cost if m0 else None, "m0_cost_planned": bool(m0 and m0.answer is None)}
    if not ok:
        row.update(method=None, reached=False)
        return row, []
    best = min(ok, key=lambda c: c.cost)
    a = best.answer if best.answer is not None else planner(best, eps)
    if best.method == "M0" and a is not best.answer:
        row.update(m0_cost=a.cost, m0_cost_planned=False)
    row.update(method=best.label, value=a.value.tolist(), lo=a.lo.tolist(), hi=a.hi.tolist(),
               stated_error=_num(a.stated_error), reached=bool(a.stated_error <= eps),
               cost=a.cost, gain_vs_m0=(row["m0_cost"] / a.cost) if row["m0_cost"] else None)
    return row, [a]


# ------------------------------------------------------------------------------ distributions

def pilot_summary(q, pilot):
    """What decides between the methods, as the pilot measured it: per model the CPU seconds per
    run, the mean and standard deviation of the QoI, its Pearson and Spearman correlation with
    the exact model's and the mean difference exact - model (the bias M2 must state)."""
    from scipy import stats
    raw, out = pilot.raw, []
    for k, name in enumerate(pilot.names):
        y = raw[:, k]
        flat = np.std(y) == 0 or np.std(raw[:, 0]) == 0
        out.append({"model": name, "cpu_per_run": float(pilot.costs[k]), "mean": float(np.mean(y)),
                    "std": float(np.std(y, ddof=1)),
                    "corr": None if flat else float(np.corrcoef(raw[:, 0], y)[0, 1]),
                    "spearman": None if flat else float(stats.spearmanr(raw[:, 0], y).statistic),
                    "bias": float(np.mean(raw[:, 0] - y))})
    return {"question": q.id, "qoi": q.qoi, "runs": int(len(raw)), "models": out}


def _stat_candidates(q, questions, setup, seed, pilots=None):
    conf, z = questions.confidence, z_value(questions.confidence)
    models = [setup.exact] + setup.lows
    pilot_ledger = CostLedger()
    pilot = Pilot(q, models, setup.n_pilot, seed, pilot_ledger)
    if pilots is not None:
        pilots.append(pilot_summary(q, pilot))
    exact_pilot = CostLedger(e for e in pilot_ledger.entries if e[1] == setup.exact.name)
    training = TrainingSet(q, questions.box, [setup.exact], seed, CostLedger())
    out = {}
    for stat in q.statistics():
        fixed = _ladders(q, stat, setup, training, seed, conf)

        def cands(eps, stat=stat, fixed=fixed):
            found = list(fixed)
            for e in ([eps] if eps is not None else questions.relative):
                found += _planned(q, stat, e, pilot, pilot_ledger, exact_pilot, setup, z)
            return found

        def planner(c, eps, stat=stat):
            return _run_planned(q, stat, c, eps, pilot, pilot_ledger, exact_pilot, setup, conf, z)
        out[stat] = (cands, planner)
    return out


def _ladders(q, stat, setup, training, seed, conf):
    """M1 and M2 rungs: actual answers on growing numbers of exact runs."""
    found = []
    if "M1" in setup.methods:
        for n in setup.m1_ladder:
            led = CostLedger()
            a = methods.m1(q, stat, training, n, seed, conf, led, restarts=setup.gp_restarts)
            a.ledger = training.ledger.copy().extend(CostLedger(
                e for e in led.entries if e[0] == "fitting"))
            _trim(a.ledger, setup.exact.name, n)
            found.append(Candidate("M1", a.cost, a.stated_error, a, label=f"M1 gp n={n}"))
    if "M2" in setup.methods:
        for low in setup.lows:
            for n in setup.m2_ladder:
                a = methods.m2(q, stat, low, setup.exact, setup.m2_low_runs, n, seed, conf,
                               setup.ledger([low.name]))
                found.append(Candidate("M2", a.cost, a.stated_error, a, label=f"M2 {low.name} n={n}"))
    return found


def _trim(ledger, name, n):
    """Keep the training entries of the first n exact runs only (the nested design's rungs)."""
    runs, keep = 0, []
    for e in ledger.entries:
        if e[0] == "training" and e[1] == name:
            if runs >= n:
                continue
            take = min(e[2], n - runs)
            keep.append((e[0], e[1], take, e[3] * take / e[2]))
            runs += take
        else:
            keep.append(e)
    ledger.entries = keep


def _planned(q, stat, eps, pilot, pilot_ledger, exact_pilot, setup, z):
    tsd = target_sd(stat, pilot.Y[:, 0], eps, z, q.threshold, q.percentile)
    found = []
    if "M0" in setup.methods:
        G = per_sample(stat, [pilot.Y[:, 0]], _threshold(q, stat, pilot))[0]
        n = max(int(math.ceil(np.var(G, ddof=1) / tsd ** 2)), 10)
        if stat not in ("mean", "std", "exceedance"):       # a percentile: both ends bounded
            n = max(n, quantile_min_runs(q.percentile / 100, 2 * _norm_cdf(z) - 1))
        found.append(Candidate("M0", exact_pilot.total() + n * pilot.costs[0], eps, plan={"n": n},
                               label="M0 exact MC"))
    if "M3" in setup.methods and setup.lows and not methods.conditional(q, stat):
        plan = methods.m3_plan(pilot, stat, tsd, q)
        lows = [pilot.names[j] for j in plan["models"][1:]]
        # the pilot ran every model: the builds of all of them are needed
        cost = pilot_ledger.total() + plan["cost"] + setup.ledger(pilot.names).total()
        layout = acv.LABELS[plan["scheme"]]
        label = f"M3 {layout} " + "+".join(lows) if lows else "M3 MFMC (exact only)"
        found.append(Candidate("M3", cost, eps, plan=plan, label=label))
    return found


def _norm_cdf(z):
    return 0.5 * (1 + math.erf(z / math.sqrt(2)))


def quantile_min_runs(p, confidence):
    """The fewest runs whose order-statistic interval of the p-quantile (M0's) has both ends:
    below it one end is infinite and no accuracy is reached, however many runs the variance
    asks for (72 for the 95th percentile at 95% confidence)."""
    a = 1 - confidence
    n = max(int(math.ceil(math.log(a / 2) / math.log(max(p, 1 - p)))) - 1, 1)
    while not np.all(np.isfinite(quantile_ci(np.arange(n, dtype=float), p, confidence)[1:])):
        n += 1
    return n


def _threshold(q, stat, pilot):
    if stat == "exceedance":
        return q.threshold
    if stat in ("mean", "std"):
        return None
    return float(np.quantile(pilot.Y[:, 0], q.percentile / 100))


def _run_planned(q, stat, c, eps, pilot, pilot_ledger, exact_pilot, setup, conf, z):
    """Run a planned M0 / M3 candidate on fresh samples; if its stated error misses eps, extend
    the same sample once to the plan for the target scaled by (eps / stated error) (the runs
    made are kept and charged once), unless the extension's cost would exceed ``max_cost``: the
    answer then stands with its stated error, reported as not reaching eps."""
    models = [setup.exact] + setup.lows
    cache, spent, a = RunCache(), CostLedger(), None
    s = setup.seed * 1000 + 500
    for attempt in range(2):
        if c.method == "M0":
            if a is None:
                n = c.plan["n"]
            elif np.isfinite(a.stated_error):
                n = int(math.ceil(c.plan["n"] * (a.stated_error / eps) ** 2 * 1.1))
            else:       # an unbounded interval (too few runs for the quantile's order statistics)
                n = 4 * c.plan["n"]
            if a is not None and exact_pilot.total() + n * pilot.costs[0] > setup.max_cost:
                break   # the extension would leave the budget: the answer stands as it is
            a = methods.m0(q, stat, setup.exact, n, s, conf, spent, cache)
            a.ledger = exact_pilot.copy().extend(spent)
        else:
            if a is not None and not np.isfinite(a.stated_error):
                break
            plan = c.plan if a is None else methods.m3_plan(
                pilot, stat, target_sd(stat, pilot.Y[:, 0], eps, z, q.threshold, q.percentile)
                * eps / a.stated_error / 1.05, q)
            if a is not None and (plan["models"], plan["scheme"]) != (c.plan["models"], c.plan["scheme"]):
                break
            plan["m"] = np.maximum(plan["m"], c.plan["m"])
            if a is not None and (setup.ledger(pilot.names).total() + pilot_ledger.total()
                                  + float(np.dot(plan["m"], np.asarray(pilot.costs)[plan["models"]])) > setup.max_cost):
                break   # the extension would leave the budget
            a = methods.m3(q, stat, models, pilot, plan, s, conf, spent, cache)
            a.ledger = setup.ledger(pilot.names).extend(pilot_ledger).extend(spent)
        if a.stated_error <= eps:
            break
    return a


# ------------------------------------------------------------------------------ maps

def _map_candidates(q, questions, setup, seed):
    conf, box = questions.confidence, questions.box
    pts, _ = q.grid_points(box)
    found = []
    training = TrainingSet(q, box, [setup.exact] + setup.lows, seed, CostLedger())
    ladder = sorted(set(setup.m1_ladder) | set(setup.m2_ladder))
    for n in ladder:
        training.grow(n)
        if "M1" in setup.methods and n in setup.m1_ladder:
            led = _training_ledger(training, [setup.exact.name], n)
            a = methods.m1_map(q, box, training, n, seed, conf, led, restarts=setup.gp_restarts)
            found.append(Candidate("M1", a.cost, a.stated_error, a, label=f"M1 gp n={n}"))
        for k, low in enumerate(setup.lows):
            sub = _TrainingView(training, k + 1)
            if "M2" in setup.methods and n in setup.m2_ladder:
                led = setup.ledger([low.name]).extend(_training_ledger(training, [setup.exact.name, low.name], n))
                a = methods.m2_map(q, box, low, setup.exact, sub, n, seed, conf, led)
                found.append(Candidate("M2", a.cost, a.stated_error, a, label=f"M2 {low.name} n={n}"))
            if "M3" in setup.methods and n in setup.m1_ladder:
                led = setup.ledger([low.name]).extend(_training_ledger(training, [setup.exact.name, low.name], n))
                a = methods.m3_map(q, box, low, sub, n, seed, conf, led, restarts=setup.gp_restarts)
                found.append(Candidate("M3", a.cost, a.stated_error, a, label=f"M3 ar1-gp {low.name} n={n}"))
    w0 = _cost_per_run(training.ledger, setup.exact.name)
    if "M0" in setup.methods and q.replicates == 1:
        found.append(Candidate("M0", len(pts) * w0, 0.0, label="M0 exact per point"))
    elif "M0" in setup.methods:
        a = methods.m0_map(q, box, setup.exact, seed, conf, CostLedger())
        found.append(Candidate("M0", a.cost, a.stated_error, a, label="M0 exact per point"))

    def planner(c, eps):
        return methods.m0_map(q, box, setup.exact, seed, conf, CostLedger())

    return (lambda eps: found), planner


class _TrainingView:
    """The training set seen with the exact model in column 0 and one low fidelity in column 1."""

    def __init__(self, training, k):
        self.t, self.k, self.region = training, k, training.region

    def grow(self, n):
        self.t.grow(n)

    @property
    def Y(self):
        return self.t.Y[:, [0, self.k]]

    def inputs(self, n):
        return self.t.inputs(n)


def _training_ledger(training, names, n):
    led = CostLedger(e for e in training.ledger.entries if e[1] in names)
    out = CostLedger()
    for name in names:
        one = CostLedger(e for e in led.entries if e[1] == name)
        _trim(one, name, n)
        out.extend(one)
    return out


def _cost_per_run(ledger, name):
    runs = sum(e[2] for e in ledger.entries if e[1] == name)
    return sum(e[3] for e in ledger.entries if e[1] == name) / max(runs, 1)
