"""Models served from runs made beforehand: the coverage repetitions of a real case draw their
inputs from a pool of joint runs (exact and low fidelities on the same inputs, drawn from the
question's distribution) and look the values up, instead of running the models again.

* ``LookupBackend``: a Backend whose ``evaluate`` returns the stored values of the rows asked
  for (matched bit for bit), charging each row's measured CPU seconds and, per call, the
  measured start-up of one crowd_predict run; a row not stored is an error.
* ``PoolDistribution``: draws n rows of the pool without replacement (a random permutation, so
  the first rows do not depend on n, as ``sampling.draw`` requires); ``pool_question`` is a
  question whose distribution is the pool.

Drawing without replacement from a pool of N joint runs is drawing from the pool's empirical
distribution: an estimator on n << N rows has the law it has on the question's distribution, up
to the pool's own sampling error (sd / sqrt(N), the same for every repetition) and a finite
population correction 1 - n / N that makes its intervals slightly conservative. The truth is
taken from runs disjoint from the pool.
"""
import copy

import numpy as np

from .backend import Backend, Evaluation


class LookupBackend(Backend):
    """Stored values of one model: rows params [n, d], values [n], censored [n], cpu [n]
    (CPU seconds per row) and ``overhead`` (CPU seconds per call)."""

    def __init__(self, name, overhead=0.0):
        self.name, self.overhead = name, float(overhead)
        self.index, self.rows = {}, []

    def add(self, params, values, censored, cpu):
        for p, v, c, s in zip(np.asarray(params, float), values, censored, cpu):
            key = p.tobytes()
            if key not in self.index:
                self.index[key] = len(self.rows)
                self.rows.append((float(v), bool(c), float(s)))
        return self

    def evaluate(self, params, seeds=None):
        params = np.atleast_2d(np.asarray(params, float))
        try:
            rows = [self.rows[self.index[p.tobytes()]] for p in params]
        except KeyError:
            raise ValueError(f"model '{self.name}': a query was not run beforehand "
                             f"({len(self.rows)} rows stored)") from None
        v, c, s = (np.array(x) for x in zip(*rows)) if rows else (np.empty(0),) * 3
        return Evaluation(v, float(np.sum(s)) + self.overhead, c)


class PoolDistribution:
    """The empirical distribution of pool rows [N, d], drawn without replacement."""

    def __init__(self, params, varying):
        self.params, self._varying = np.asarray(params, float), list(varying)

    def sample(self, rng, n):
        if n > len(self.params):
            raise ValueError(f"{n} draws from a pool of {len(self.params)} runs")
        return self.params[rng.permutation(len(self.params))[:n]]

    def varying(self):
        return self._varying

    def from_unit(self, u):
        raise ValueError("a pool has no quantile function (surrogates train on their own runs)")


def pool_question(question, params):
    """A copy of a distribution question drawing its inputs from the pool rows params [N, d]."""
    q = copy.copy(question)
    q.distribution = PoolDistribution(params, question.distribution.varying())
    return q


def read_reference(path, qoi):
    """The reference file's samples: {name: {"params", "n_pool", model: (values, censored, cpu,
    overhead per call)}} and {question id: sample name}."""
    import json

    import h5py
    from .reference import COLUMNS
    out = {}
    with h5py.File(path, "r") as f:
        of = json.loads(f.attrs["sample_of"])
        for name, g in f["samples"].items():
            s = {"params": g["params"][()], "n_pool": int(g.attrs["n_pool"])}
            for m in g:
                if m == "params":
                    continue
                h = g[m]
                cpu = h["cpu_seconds"][()]
                over = max(float(h.attrs["process_cpu_seconds"]) - float(cpu.sum()), 0.0) / max(int(h.attrs["calls"]), 1)
                s[m] = (h["t_evac"][:, COLUMNS[qoi]], h["censored"][:, COLUMNS[qoi]].astype(bool), cpu, over)
            out[name] = s
    return out, of


def design_points(question, box, seeds, n):
    """The training inputs [n, d] of ``sampling.TrainingSet`` for each seed, in seed order."""
    from .sampling import TRAINING, Region, sobol
    reg = Region(question, box)
    return [reg.from_unit(sobol(len(reg.varying), n, [s, TRAINING])) for s in seeds]


def design_runs(questions, chosen, of, exact, lows, seeds, n_train, methods, work):
    """Run (or find in ``work``) the training points of M1 and of the maps' methods for every
    repetition; {model name: [(params, Batch)]}. Questions sharing a distribution (``of``: the
    same sample name) share their design."""
    from .reference import Batch, ProductBackend
    need = {}      # (sample name, model name) -> design rows
    for q in chosen:
        key = of[q.id]
        if q.kind == "map" and any(x in methods for x in ("M1", "M2", "M3")):
            pts = np.vstack(design_points(q, questions.box, seeds, n_train))
            need[(key, exact.name)] = pts
            if lows and ("M2" in methods or "M3" in methods):
                need[(key, lows[0].name)] = pts
        elif q.kind != "map" and "M1" in methods:
            need[(key, exact.name)] = np.vstack(design_points(q, questions.box, seeds, n_train))
    out = {}
    for (key, name), rows in need.items():
        m = next(x for x in [exact] + list(lows) if x.name == name)
        real = ProductBackend(m)
        tag = f"design_{key}_n{n_train}_s{min(seeds)}-{max(seeds)}"
        out.setdefault(name, []).append((rows, Batch(real, rows, work, tag, chunk=400)))
    return out


def sample_names(questions):
    """{question id: sample name} as ``reference.plan`` names them (without drawing)."""
    from .reference import dist_key
    of, keys = {}, {}
    for q in questions.questions:
        if q.kind == "map":
            of[q.id] = f"map_{q.id}"
        else:
            of[q.id] = keys.setdefault(dist_key(q), f"dist_{q.id}")
    return of


def served_models(ref_path, questions, chosen, exact, lows, builds, seeds, n_train, methods, work):
    """The coverage's models served from a reference file's pool and from design runs made
    here first (M1 and the maps' training points, through crowd_predict, chunks in ``work``):
    (exact, lows) LookupBackends, {question id: pool rows}, {question id: {statistic: the
    pool's value}}."""
    from .intervals import sample_statistic
    qoi = chosen[0].qoi
    ref, of = read_reference(ref_path, qoi)
    models = [exact] + list(lows)
    look = {}
    for m in models:
        over = [s[m.name][3] for s in ref.values() if m.name in s]
        look[m.name] = LookupBackend(m.name, max(over) if over else 0.0)
    pools, pool_truth = {}, {}
    for q in chosen:
        s = ref[of[q.id]]
        keep = slice(0, s["n_pool"]) if q.kind != "map" else slice(None)
        for m in models:
            v, c, cpu, _ = s[m.name]
            look[m.name].add(s["params"][keep], v[keep], c[keep], cpu[keep])
        if q.kind != "map":
            pools[q.id] = s["params"][keep]
            y = s[exact.name][0][keep]
            pool_truth[q.id] = {st: float(sample_statistic(y, st, questions.confidence, percentile=q.percentile,
                                                           threshold=q.threshold)[0])
                                for st in q.statistics()}
    for name, batches in design_runs(questions, chosen, of, exact, lows, seeds, n_train, methods, work).items():
        for rows, b in batches:
            v, c = b.values(qoi)
            look[name].add(rows, v, c, b.cpu)
    return look[exact.name], [look[m.name] for m in lows], pools, pool_truth
