"""Models as backends: parameter vectors [n, d] and seeds [n] in, QoI values [n] and the CPU
seconds spent out.

* ``SyntheticFamily``: K correlated models on a parameter box with known means, standard
  deviations, correlations and (for the first, the "exact" one) quantiles and exceedance
  probabilities when the parameters are uniform on the box; declared costs per run.
* ``PredictModel``: the real models (the exact model, a reduced setting of a ROM file, or a
  reduced setting corrected by the saved ML models). The rows not run yet are written as a
  ``crowd_predict`` parameter list with a ``&predict`` group, ``crowd_predict`` runs (optionally
  under ``mpirun -np N``; for the ML model with trajectories, then ``ml_correct.py --predict``),
  and every QoI of every row is kept with the row's CPU seconds (those of the programs and every
  process they waited for, ``getrusage`` of the children, or on request the product's per-query
  ``cpu_seconds``). ``PredictBackend`` is one QoI of a model (``qoi_values``): questions on t50
  and t90 run each row once.
"""
import hashlib
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time

import numpy as np
from scipy import stats

import crowdrom_io
from crowdrom_io import InputError

#: the scripts folder (pipeline/ml_correct.py)
SCRIPTS = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class Evaluation:
    """Values [n] of one QoI, right-censored flags [n] (the QoI hit the horizon) and the CPU
    seconds the runs cost in total."""

    def __init__(self, values, cpu_seconds, censored=None):
        self.values = np.asarray(values, dtype=float)
        self.cpu_seconds = float(cpu_seconds)
        self.censored = (np.zeros(self.values.shape, bool) if censored is None
                         else np.asarray(censored, bool))


class Backend:
    """A model: ``name``, ``evaluate(params [n, d], seeds [n]) -> Evaluation``."""

    name = "model"

    def evaluate(self, params, seeds):
        raise NotImplementedError


# ------------------------------------------------------------------------------ synthetic family

class SyntheticModel(Backend):
    def __init__(self, family, k):
        self.family, self.k = family, k
        self.name = family.names[k]

    def evaluate(self, params, seeds=None):
        params = np.atleast_2d(np.asarray(params, float))
        return Evaluation(self.family.values(self.k, params), len(params) * self.family.costs[self.k])


class SyntheticFamily:
    """K models y_k(x) = m_k + s_k (L z(x))_k on a box, z(x) [d] the box point's standardised
    coordinates and L the Cholesky factor of the correlation matrix C [K, K] (padded to d >= K
    columns). ``kind`` 'gauss': z = Phi^-1(u) with u the position in the box (so y is jointly
    Gaussian when x is uniform on the box); 'uniform': z = sqrt(12) (u - 1/2) (model 0 is then
    uniform). Either way, for x uniform on the box: E y_k = m_k, sd y_k = s_k, corr = C."""

    def __init__(self, box, means, stds, corr, costs, kind="gauss", names=None):
        self.box, self.kind = box, kind
        self.means, self.stds = np.asarray(means, float), np.asarray(stds, float)
        self.corr, self.costs = np.asarray(corr, float), np.asarray(costs, float)
        K = len(self.means)
        if box.dim < K:
            raise ValueError(f"a family of {K} models needs a box of at least {K} parameters")
        self.L = np.zeros((K, box.dim))
        self.L[:, :K] = np.linalg.cholesky(self.corr)
        self.names = list(names) if names else ["exact"] + [f"low{k}" for k in range(1, K)]

    def z(self, params):
        u = (params - self.box.lo) / (self.box.hi - self.box.lo)
        if self.kind == "gauss":
            return stats.norm.ppf(np.clip(u, 1e-15, 1 - 1e-15))
        return np.sqrt(12.0) * (u - 0.5)

    def values(self, k, params):
        return self.means[k] + self.stds[k] * (self.z(params) @ self.L[k])

    def model(self, k):
        return SyntheticModel(self, k)

    # the truth for x uniform on the box (model 0 unless k is given)
    def mean(self, k=0):
        return self.means[k]

    def std(self, k=0):
        return self.stds[k]

    def quantile(self, p, k=0):
        if self.kind == "gauss":
            return self.means[k] + self.stds[k] * stats.norm.ppf(p)
        if k != 0:
            raise ValueError("closed-form quantiles of kind 'uniform' exist for model 0 only")
        return self.means[0] + self.stds[0] * np.sqrt(12.0) * (p - 0.5)

    def exceedance(self, c, k=0):
        if self.kind == "gauss":
            return stats.norm.sf((c - self.means[k]) / self.stds[k])
        if k != 0:
            raise ValueError("closed-form probabilities of kind 'uniform' exist for model 0 only")
        u = (c - self.means[0]) / (self.stds[0] * np.sqrt(12.0)) + 0.5
        return float(np.clip(1.0 - u, 0.0, 1.0))

    def truth(self, statistic, percentile=95.0, threshold=None):
        """The exact model's value of a question's statistic (x uniform on the box)."""
        if statistic == "mean":
            return self.mean()
        if statistic == "std":
            return self.std()
        if statistic == "exceedance":
            return self.exceedance(threshold)
        if statistic.startswith("p"):
            return self.quantile(percentile / 100.0)
        raise ValueError(f"no closed form for statistic {statistic!r}")


# ------------------------------------------------------------------------------ crowd_predict

#: the evacuation times of the product's ``qoi/t_evac`` columns
EVAC_COLUMNS = {"t50": 0, "t90": 1, "t100": 2}
#: per-exit QoIs: ``<name>_<exit>`` is column exit - 1 of the product's ``qoi/<name>``
EXIT_QOIS = ("flow_rate", "flow")
#: per-trajectory scalars: the product's ``qoi/<name>`` [n]
SCALAR_QOIS = ("displacement",)
#: the &predict variables a reduced setting may set (docs/queries.md, "The group &predict")
SETTING_KEYS = ("n", "r", "hyper", "contacts", "m_v", "m_b", "m_d", "correction", "solver")
CPU_SOURCES = ("process", "queries")


def qoi_values(prod, qoi, where):
    """(values [n], censored [n]) of a question's QoI in a read QoI product.

    t50 / t90 / t100: ``t_evac[:, j]`` and ``censored[:, j]`` (a censored time is the horizon and
    flagged); ``flow_<e>`` / ``flow_rate_<e>``: exit e's column of ``flow`` / ``flow_rate`` (0 where
    ``flow_defined`` is 0, never censored); ``displacement``: ``qoi/displacement``. Anything else, or an exit the scene lacks: InputError
    naming ``where`` (the product) and the QoI."""
    n = len(prod["params"])
    if qoi in EVAC_COLUMNS:
        j = EVAC_COLUMNS[qoi]
        return prod["t_evac"][:, j].astype(float), prod["censored"][:, j].astype(bool)
    if qoi in SCALAR_QOIS:
        return prod[qoi].astype(float), np.zeros(n, bool)
    for name in sorted(EXIT_QOIS, key=len, reverse=True):
        tail = qoi[len(name) + 1:] if qoi.startswith(name + "_") else ""
        if tail.isdigit():
            e, n_exits = int(tail), prod["n_exits"]
            if not 1 <= e <= n_exits:
                raise InputError(f"{where}: QoI '{qoi}': the product's scene has {n_exits} exit"
                                 f"{'s' if n_exits != 1 else ''} (dataset 'qoi/{name}' [n, {n_exits}])")
            return prod[name][:, e - 1].astype(float), np.zeros(n, bool)
    known = ", ".join(list(EVAC_COLUMNS) + [f"{x}_<exit>" for x in EXIT_QOIS] + list(SCALAR_QOIS))
    raise InputError(f"{where}: QoI '{qoi}': not a QoI of the product (known: {known})")


def write_param_list(path, names, params):
    """crowd_predict's text parameter list: a comment, the header (the study's component names,
    comma-separated), then one query per line with 17 significant digits (exact round trip)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write("# queries written by answers.backend\n")
        f.write(", ".join(names) + "\n")
        for row in params:
            f.write(" ".join(f"{v:.17g}" for v in row) + "\n")


def nml_value(v):
    if isinstance(v, bool):
        return ".true." if v else ".false."
    if isinstance(v, str):
        return "'" + v.replace("'", "''") + "'"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


def write_predict_group(path, values):
    """A namelist file with one ``&predict`` group of ``values`` (name -> Python value)."""
    body = ",\n  ".join(f"{k} = {nml_value(v)}" for k, v in values.items())
    with open(path, "w", encoding="utf-8") as f:
        f.write(f"&predict\n  {body}\n/\n")


def children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def last_error_line(run):
    """The program's error line (the last line saying 'error', else the last line of stderr)."""
    lines = [l.strip() for l in (run.stderr + "\n" + run.stdout).splitlines() if l.strip()]
    errs = [l for l in lines if "error" in l.lower()]
    return (errs or lines or ["(no message)"])[-1]


#: the per-row datasets of a product kept in the cache (everything ``qoi_values`` reads)
ROW_KEYS = ("t_evac", "censored", "flow", "flow_rate", "displacement")
#: models a PredictModel runs: crowd_predict's 'exact' and 'rom', and 'ml' (a reduced setting
#: with trajectories, corrected by ``ml_correct.py --predict``)
KINDS = ("exact", "rom", "ml")
#: keys of an 'ml' model's specification (``ml``): the saved models and how to pick the truncation
ML_KEYS = ("models_dir", "config", "ml_output", "n", "regressor", "batch")
#: the integer range of a seed component (e.g. ``speed_seed``,
#: docs/scenes.md#hetero1000-a-heterogeneous-population)
SEED_RANGE = 1_000_000


class PredictModel:
    """One model of a ROM file: the exact model, a reduced setting, or a reduced setting
    ML-corrected, run on parameter rows; every QoI of every row is kept, so a row asked again
    (for another QoI, another question or statistic) is not run again.

    ``kind`` 'exact' or 'rom' (``setting``: the &predict variables of SETTING_KEYS): one
    ``crowd_predict`` run per call on the rows not yet run; 'ml': ``crowd_predict`` with
    ``model = 'rom'``, the setting and ``trajectories = .true.``, then ``ml_correct.py --predict``
    with ``ml`` = {models_dir, config, ml_output or n, regressor, batch} (the rows in batches of
    ``batch``, default 25, as the trajectories are held in memory); the QoIs are those of the
    corrected positions (measured by crowd_predict, model 'positions').

    ``param_names``: the questions' box names; ``seed_params``: components filled from the
    engine's seeds (modulo SEED_RANGE), e.g. ``speed_seed`` of a heterogeneous population, so
    two models given the same row and seed run the same population. ``cpu`` 'process' charges the
    CPU seconds (user + system) of every process run for the rows (``getrusage`` of the
    children: start-up, reading the ROM file, the ML correction and its QoIs included), shared
    equally by the rows of the run; 'queries' the product's per-query ``cpu_seconds``.
    Each row's CPU seconds are kept with it: a row served from the cache is charged what it
    cost when run (each answer's ledger stays what it needs from nothing)."""

    def __init__(self, name, rom_file, param_names, kind="rom", setting=None, ml=None,
                 program="crowd_predict", ranks=0, launcher="mpirun", cpu="process",
                 workdir=None, seed_params=(), progress=None, python=None, cache_dir=None):
        if kind not in KINDS:
            raise InputError(f"model '{name}': model must be one of {', '.join(KINDS)}, not {kind!r}")
        if cpu not in CPU_SOURCES:
            raise InputError(f"model '{name}': cpu must be one of {', '.join(CPU_SOURCES)}, not {cpu!r}")
        setting = dict(setting or {})
        bad = [k for k in setting if k not in SETTING_KEYS]
        if bad:
            raise InputError(f"model '{name}': {bad[0]}: not a setting variable of &predict "
                             f"(known: {', '.join(SETTING_KEYS)})")
        if kind == "exact" and setting:
            raise InputError(f"model '{name}': the exact model takes no setting ({', '.join(setting)})")
        self.ml = dict(ml or {})
        if kind == "ml":
            bad = [k for k in self.ml if k not in ML_KEYS]
            if bad or "models_dir" not in self.ml or ("ml_output" in self.ml) == ("n" in self.ml):
                what = (f"{bad[0]}: unknown key (known: {', '.join(ML_KEYS)})" if bad else
                        "needs models_dir and one of ml_output (each regressor's best n) or n")
                raise InputError(f"model '{name}': ml: {what}")
        elif self.ml:
            raise InputError(f"model '{name}': ml: only a model of kind 'ml' takes it")
        self.name, self.rom_file, self.kind, self.setting = name, rom_file, kind, setting
        self.param_names, self.seed_params = list(param_names), list(seed_params)
        self.program, self.ranks, self.launcher = program, int(ranks), launcher
        self.cpu, self.workdir = cpu, workdir
        self.progress = progress or (lambda msg: None)
        self.python = python or sys.executable
        self.rows, self.n_runs, self.wall_per_row = {}, 0, None
        self.cache_file = self._cache_file(cache_dir) if cache_dir else None
        if self.cache_file and os.path.exists(self.cache_file):
            self._load_cache()

    # -------------------------------------------------------------------------- file cache
    def _cache_file(self, cache_dir):
        """The cache file of this model: named by a digest of everything a row's result depends
        on (the ROM file's path, size and modification time, the model, its setting, the ML
        models, the programs, the parameter and seed components)."""
        st = os.stat(self.rom_file)
        key = json.dumps([os.path.abspath(self.rom_file), st.st_size, st.st_mtime_ns, self.kind,
                          self.setting, self.ml, os.path.abspath(self.program) if os.sep in self.program
                          else self.program, self.param_names, self.seed_params, self.cpu], sort_keys=True)
        digest = hashlib.sha256(key.encode()).hexdigest()[:16]
        return os.path.join(cache_dir, f"{self.name}-{digest}.npz")

    def _load_cache(self):
        with np.load(self.cache_file) as z:
            for j, r in enumerate(z["rows"]):
                rec = {k: z[k][j] for k in ROW_KEYS}
                rec.update(n_exits=int(z["n_exits"]), cpu=float(z["cpu"][j]))
                self.rows[r.tobytes()] = rec
        self.progress(f"model '{self.name}': {len(self.rows)} rows from {self.cache_file}")

    def _save_cache(self):
        keys = list(self.rows)
        width = len(self.param_names) + len(self.seed_params)
        data = {"rows": np.array([np.frombuffer(k, float) for k in keys]).reshape(len(keys), width),
                "cpu": np.array([self.rows[k]["cpu"] for k in keys]),
                "n_exits": np.array(self.rows[keys[0]]["n_exits"])}
        for k in ROW_KEYS:
            data[k] = np.array([self.rows[x][k] for x in keys])
        os.makedirs(os.path.dirname(os.path.abspath(self.cache_file)), exist_ok=True)
        tmp = self.cache_file + ".tmp.npz"
        np.savez(tmp, **data)
        os.replace(tmp, self.cache_file)

    def for_qoi(self, qoi):
        """The Backend giving this model's values of one QoI."""
        return PredictBackend.of(self, qoi)

    # -------------------------------------------------------------------------- rows and cache
    def columns(self, params, seeds):
        """The query rows [n, d + s]: the box's columns, then the seed components."""
        params = np.atleast_2d(np.asarray(params, float))
        if not self.seed_params:
            return params
        seeds = np.zeros(len(params), np.int64) if seeds is None else np.asarray(seeds, np.int64)
        s = (seeds % SEED_RANGE).astype(float)
        return np.column_stack([params] + [s] * len(self.seed_params))

    def products(self, params, seeds=None):
        """(a product-like dict of the rows' QoIs, CPU seconds per row [n]) for params [n, d];
        runs only the rows not in the cache."""
        rows = self.columns(params, seeds)
        keys = [r.tobytes() for r in rows]
        new, seen = [], set()
        for k, r in zip(keys, rows):
            if k not in self.rows and k not in seen:
                seen.add(k)
                new.append(r)
        if new:
            self._run_rows(np.array(new))
        recs = [self.rows[k] for k in keys]
        prod = {k: np.array([r[k] for r in recs]) for k in ROW_KEYS}
        prod.update(params=rows, n_exits=recs[0]["n_exits"] if recs else 0,
                    param_names=self.param_names + self.seed_params)
        return prod, np.array([r["cpu"] for r in recs], float)

    def _run_rows(self, rows):
        n = len(rows)
        batch = int(self.ml.get("batch", 25)) if self.kind == "ml" else n
        eta = f", about {self.wall_per_row * n:.0f} s" if self.wall_per_row else ""
        self.progress(f"model '{self.name}': {n} new queries{eta}")
        t0 = time.time()
        for b in range(0, n, batch):
            chunk = rows[b:b + batch]
            prod, cpu = self._run(chunk)
            per = (np.asarray(prod["cpu_seconds"], float) if self.cpu == "queries"
                   else np.full(len(chunk), cpu / len(chunk)))
            for j, r in enumerate(chunk):
                rec = {k: prod[k][j] for k in ROW_KEYS}
                rec.update(n_exits=prod["n_exits"], cpu=float(per[j]))
                self.rows[r.tobytes()] = rec
            if b + batch < n:
                done = b + batch
                self.progress(f"model '{self.name}': {done} of {n} queries, {time.time() - t0:.0f} s, "
                              f"remaining about {(time.time() - t0) / done * (n - done):.0f} s")
            if self.cache_file:
                self._save_cache()
        wall = time.time() - t0
        self.wall_per_row = wall / n
        self.n_runs += n
        self.progress(f"model '{self.name}': {n} queries in {wall:.1f} s wall "
                      f"({self.n_runs} run in all, {len(self.rows)} distinct)")

    # -------------------------------------------------------------------------- one run
    def _run(self, rows):
        """One crowd_predict run (and the ML correction) on rows [n, d + s]: (product, CPU s)."""
        where = f"model '{self.name}' ({self.kind}, {self.rom_file})"
        names = self.param_names + self.seed_params
        with tempfile.TemporaryDirectory(dir=self.workdir, prefix=f"answers-{self.name}-") as tmp:
            plist, nml, out = (os.path.join(tmp, f) for f in ("params.txt", "predict.nml", "qoi.h5"))
            write_param_list(plist, names, rows)
            group = {"rom_file": self.rom_file, "output": out,
                     "model": "exact" if self.kind == "exact" else "rom",
                     "label": self.name, "params_file": plist, **self.setting}
            if self.kind == "ml":
                group["trajectories"] = True
            write_predict_group(nml, group)
            t0 = children_cpu()
            self._call(self.command(nml), tmp, os.path.basename(self.program))
            if self.kind == "ml":
                ml_out = os.path.join(tmp, "ml.h5")
                self._call(self.ml_command(out, ml_out), tmp, "ml_correct.py --predict")
                prod = crowdrom_io.read_qoi(ml_out)
            else:
                prod = crowdrom_io.read_prediction(out)
            cpu = children_cpu() - t0
        return self._check(prod, rows, names, where), cpu

    def command(self, nml):
        cmd = [self.program, nml]
        if self.ranks > 0:
            cmd = shlex.split(self.launcher) + ["-np", str(self.ranks)] + cmd
        return cmd

    def ml_command(self, pred, out):
        m = self.ml
        cmd = [self.python, os.path.join(SCRIPTS, "pipeline", "ml_correct.py"), "--predict", pred,
               "--models-dir", m["models_dir"], "-o", out, "--quiet"]
        cmd += ["--ml-output", m["ml_output"]] if "ml_output" in m else ["--n", str(int(m["n"]))]
        if "config" in m:
            cmd += ["--config", m["config"]]
        if "regressor" in m:
            cmd += ["--regressors", m["regressor"]]
        return cmd

    def _call(self, cmd, cwd, what):
        env = dict(os.environ)
        for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
            env.setdefault(k, "1")
        if os.sep in self.program:      # ml_correct.py measures with the same crowd_predict
            env["CROWDROM_BIN"] = os.path.dirname(os.path.abspath(self.program))
        try:
            run = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
        except OSError as exc:
            raise InputError(f"model '{self.name}': cannot run {cmd[0]}: {exc.strerror or exc}") from None
        if run.returncode != 0:
            raise InputError(f"model '{self.name}': {what} exited with {run.returncode}: "
                             f"{last_error_line(run)}")

    def _check(self, prod, rows, names, where):
        got_names = prod["param_names"]
        if sorted(got_names) != sorted(names):
            raise InputError(f"{where}: the product's parameters ({', '.join(got_names)}) are not the "
                             f"questions' box ({', '.join(names)})")
        got = np.asarray(prod["params"], float)[:, [got_names.index(x) for x in names]]
        if got.shape != rows.shape or not np.array_equal(got, rows):
            raise InputError(f"{where}: the product's parameters {got.shape} are not the "
                             f"{rows.shape} queried")
        return prod


class PredictBackend(Backend):
    """One QoI of a PredictModel: ``evaluate(params [n, d], seeds [n])`` gives the QoI's values,
    censoring flags and the CPU seconds of the rows (run now or earlier).

    ``PredictBackend(name, qoi, rom_file, param_names, model='rom' | 'exact', setting=...,
    program=..., ranks=..., launcher=..., cpu=..., workdir=...)`` makes its own model;
    ``PredictBackend.of(model, qoi)`` (or ``model.for_qoi(qoi)``) shares one, so questions on
    several QoIs run each parameter row once. Seeds are ignored unless the model has seed
    components: the models are deterministic."""

    def __init__(self, name, qoi, rom_file, param_names, model="rom", setting=None, **kw):
        self.model = PredictModel(name, rom_file, param_names, kind=model, setting=setting, **kw)
        self.name, self.qoi = name, qoi

    @classmethod
    def of(cls, model, qoi):
        b = cls.__new__(cls)
        b.model, b.name, b.qoi = model, model.name, qoi
        return b

    def for_qoi(self, qoi):
        return PredictBackend.of(self.model, qoi)

    def evaluate(self, params, seeds=None):
        prod, cpu = self.model.products(params, seeds)
        where = f"model '{self.name}' ({self.model.kind}, {self.model.rom_file})"
        values, censored = qoi_values(prod, self.qoi, where)
        return Evaluation(values, float(np.sum(cpu)), censored)
