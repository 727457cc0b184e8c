"""The honest reference of a case's questions: large exact samples (and the reduced models at the
same inputs), run in chunks through ``crowd_predict``, stored with their command; the truth of
every statistic with its own Monte Carlo error, and a disjoint pool that serves the coverage
repetitions (``coverage``).

* ``Batch``: the QoIs (t50, t90, t100, their censoring flags, per-query CPU seconds) of one
  model on a list of parameters, run in chunks of ``chunk`` queries, each chunk kept as an
  ``.npz`` file in a work folder (a run that stops resumes at the first missing chunk; a chunk
  whose parameters differ is refused), with progress and ETA.
* ``plan``: the samples a questions file needs: one per distinct distribution (the first
  ``n_pool`` rows the pool, the next ``n_truth`` the truth, so a larger ``n_truth`` only adds
  rows; a question that shares another's distribution shares its runs) drawn from the stream ``REFERENCE`` of the questions' seed, and
  one per map (its grid points).
* ``truth_table``: every statistic of the truth rows with its standard error and 95% interval
  (the M0 intervals of ``intervals``: t for the mean, chi-square with kurtosis-matched degrees
  of freedom for the std, order statistics for a percentile, Clopper-Pearson for an exceedance),
  the same statistic on the pool, and the map values.
"""
import json
import os
import sys
import time

import numpy as np

from . import backend
from .intervals import sample_statistic, z_value
from .sampling import stream

REFERENCE = 7
COLUMNS = {"t50": 0, "t90": 1, "t100": 2}


class ProductBackend(backend.Backend):
    """A model (a PredictBackend or PredictModel) run for its whole product: after each call,
    ``last`` holds the rows' t_evac [n, 3], censored [n, 3] and the product's per-query CPU
    seconds, ``last_cpu`` the call's process CPU seconds (start-up and reading included)."""

    def __init__(self, model):
        m = getattr(model, "model", model)
        self.name = m.name
        self.model = backend.PredictModel(
            m.name, m.rom_file, m.param_names, kind=m.kind, setting=m.setting, ml=m.ml or None,
            program=m.program, ranks=m.ranks, launcher=m.launcher, cpu="queries",
            workdir=m.workdir, seed_params=m.seed_params, python=m.python)

    def evaluate(self, params, seeds=None):
        t0 = backend.children_cpu()
        prod, cpu = self.model.products(params, seeds)
        self.last_cpu = backend.children_cpu() - t0
        self.last = {"t_evac": prod["t_evac"], "censored": prod["censored"], "cpu_seconds": cpu}
        return backend.Evaluation(prod["t_evac"][:, 1], float(np.sum(cpu)), prod["censored"][:, 1])


class Batch:
    """One model's QoIs on params [n, d]: ``t_evac`` [n, 3], ``censored`` [n, 3], ``cpu`` [n]
    (per query, the product's) and ``process_cpu`` (every call's CPU seconds, start-up and
    reading included), ``calls`` (crowd_predict runs)."""

    def __init__(self, model, params, workdir, tag, chunk=250, log=sys.stdout):
        self.model, self.params = model, np.asarray(params, float)
        n = len(self.params)
        self.t_evac, self.censored = np.empty((n, 3)), np.empty((n, 3), bool)
        self.cpu, self.process_cpu, self.calls = np.empty(n), 0.0, 0
        os.makedirs(workdir, exist_ok=True)
        t0, done_new = time.time(), 0
        for i in range(0, n, chunk):
            part = self.params[i:i + chunk]
            path = os.path.join(workdir, f"{tag}_{model.name}_{i:06d}.npz")
            if os.path.exists(path):
                d = np.load(path)
                if not np.array_equal(d["params"], part):
                    raise ValueError(f"{path}: its parameters are not this chunk's (another plan?)")
            else:
                model.evaluate(part)
                p = model.last
                d = {"params": part, "t_evac": p["t_evac"], "censored": p["censored"].astype(bool),
                     "cpu": p["cpu_seconds"], "process_cpu": np.array(model.last_cpu)}
                tmp = path + ".tmp.npz"
                np.savez(tmp, **d)
                os.replace(tmp, path)
                done_new += len(part)
                el = time.time() - t0
                left = (n - i - len(part)) * el / done_new
                print(f"  {tag} {model.name}: {i + len(part)} of {n}, {el:.0f} s, about {left:.0f} s left",
                      file=log, flush=True)
            j = slice(i, i + len(part))
            self.t_evac[j], self.censored[j], self.cpu[j] = d["t_evac"], d["censored"], d["cpu"]
            self.process_cpu += float(d["process_cpu"])
            self.calls += 1

    def values(self, qoi):
        """(values [n], censored [n]) of t50 / t90 / t100 (the horizon where censored)."""
        k = COLUMNS[qoi]
        return self.t_evac[:, k], self.censored[:, k]

    @property
    def overhead(self):
        """CPU seconds per call beyond its queries' (MPI start-up, reading the ROM file)."""
        return max(self.process_cpu - float(np.sum(self.cpu)), 0.0) / max(self.calls, 1)


def dist_key(question):
    return json.dumps([d.as_dict() for d in question.distribution.dists], sort_keys=True)


def plan(questions, n_truth, n_pool):
    """{sample name: params [n, d]} and {question id: sample name}: one sample per distinct
    distribution (the pool's rows first, then the truth's) and one per map (its grid points)."""
    samples, of, keys = {}, {}, {}
    box = questions.box
    for q in questions.questions:
        if q.kind == "map":
            name = f"map_{q.id}"
            samples[name] = q.grid_points(box)[0]
        else:
            k = dist_key(q)
            if k not in keys:
                keys[k] = f"dist_{q.id}"
                rng = stream(questions.seed, REFERENCE + 100 * len(keys))
                samples[keys[k]] = q.distribution.sample(rng, n_pool + n_truth)
            name = keys[k]
        of[q.id] = name
    return samples, of


def truth_table(questions, of, batches, exact, n_pool, confidence=0.95):
    """{question id: {statistic: {value, se, lo, hi, n, censored, pool_value, pool_n}}} from the
    exact model's truth rows (after the first ``n_pool``; maps: the values at the grid points,
    se 0)."""
    z = z_value(confidence)
    out = {}
    for q in questions.questions:
        y, cens = batches[of[q.id]][exact].values(q.qoi)
        if q.kind == "map":
            out[q.id] = {"map": {"value": y.tolist(), "se": 0.0, "censored": cens.astype(int).tolist()}}
            continue
        p, t = slice(0, n_pool), slice(n_pool, None)
        row = {}
        for s in q.statistics():
            kw = {"percentile": q.percentile, "threshold": q.threshold}
            v, lo, hi = sample_statistic(y[t], s, confidence, **kw)
            row[s] = {"value": float(v), "lo": float(lo), "hi": float(hi),
                      "se": float(max(hi - v, v - lo) / z), "n": int(len(y[t])),
                      "censored": int(np.sum(cens[t])),
                      "pool_value": float(sample_statistic(y[p], s, confidence, **kw)[0]),
                      "pool_n": int(len(y[p]))}
        out[q.id] = row
    return out
