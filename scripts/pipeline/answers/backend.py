"""Models as backends: parameter vectors [n, d] and seeds [n] in, QoI values [n] and the CPU
seconds spent out.

* ``SyntheticFamily``: K correlated models on a parameter box with known means, standard
  deviations, correlations and (for the first, the "exact" one) quantiles and exceedance
  probabilities when the parameters are uniform on the box; declared costs per run.
* ``PredictBackend``: the real models. Each call writes the queries as a ``crowd_predict``
  parameter list and a ``&predict`` group (a reduced setting of a ROM file, or the exact model),
  runs ``crowd_predict`` (optionally under ``mpirun -np N``), reads the product through
  ``crowdrom_io.read_prediction`` and picks the question's QoI (``qoi_values``); the CPU seconds
  charged are those of the program and every process it waited for (``getrusage`` of the
  child), or on request the sum of the product's per-query ``cpu_seconds``.
"""
import os
import resource
import shlex
import subprocess
import tempfile

import numpy as np
from scipy import stats

import crowdrom_io
from crowdrom_io import InputError


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


class PredictBackend(Backend):
    """One model of a ROM file run through ``crowd_predict``, for one QoI.

    ``model``: 'exact' (the study's full model) or 'rom' with ``setting`` (the &predict variables
    of SETTING_KEYS, e.g. ``{"n": 4, "r": 3, "hyper": "eq"}``); ``param_names`` the study's
    component names in the questions' box order; ``program`` the crowd_predict executable;
    ``ranks`` > 0 runs it under ``mpirun -np ranks`` (``launcher``, default "mpirun"); ``cpu``
    'process' charges the CPU seconds (user + system) of the program and every process it waited
    for, as the operating system counts them (start-up and the ROM file's reading included),
    'queries' the sum of the product's per-query ``cpu_seconds`` (the query loop only). Seeds are
    ignored: both models are deterministic. Each call runs the program once on all its queries in
    a temporary directory under ``workdir`` that is removed afterwards."""

    def __init__(self, name, qoi, rom_file, param_names, model="rom", setting=None,
                 program="crowd_predict", ranks=0, launcher="mpirun", cpu="process", workdir=None):
        if model not in ("rom", "exact"):
            raise InputError(f"model '{name}': model must be 'rom' or 'exact', not {model!r}")
        if cpu not in CPU_SOURCES:
            raise InputError(f"model '{name}': cpu must be one of {', '.join(CPU_SOURCES)}, not {cpu!r}")
        setting = dict(setting or {})
        bad = [k for k in setting if k not in SETTING_KEYS]
        if bad:
            raise InputError(f"model '{name}': {bad[0]}: not a setting variable of &predict "
                             f"(known: {', '.join(SETTING_KEYS)})")
        if model == "exact" and setting:
            raise InputError(f"model '{name}': the exact model takes no setting ({', '.join(setting)})")
        self.name, self.qoi, self.rom_file, self.model = name, qoi, rom_file, model
        self.param_names, self.setting, self.program = list(param_names), setting, program
        self.ranks, self.launcher, self.cpu, self.workdir = int(ranks), launcher, cpu, workdir

    def command(self, nml):
        cmd = [self.program, nml]
        if self.ranks > 0:
            cmd = shlex.split(self.launcher) + ["-np", str(self.ranks)] + cmd
        return cmd

    def evaluate(self, params, seeds=None):
        params = np.atleast_2d(np.asarray(params, float))
        with tempfile.TemporaryDirectory(dir=self.workdir, prefix=f"answers-{self.name}-") as tmp:
            plist, nml, out = (os.path.join(tmp, f) for f in ("params.txt", "predict.nml", "qoi.h5"))
            write_param_list(plist, self.param_names, params)
            write_predict_group(nml, {"rom_file": self.rom_file, "output": out, "model": self.model,
                                      "label": self.name, "params_file": plist, **self.setting})
            env = dict(os.environ)
            for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
                env.setdefault(k, "1")
            cmd = self.command(nml)
            t0 = children_cpu()
            try:
                run = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp)
            except OSError as exc:
                raise InputError(f"model '{self.name}': cannot run {cmd[0]}: {exc.strerror or exc}") from None
            cpu = children_cpu() - t0
            if run.returncode != 0:
                raise InputError(f"model '{self.name}': {os.path.basename(self.program)} exited with "
                                 f"{run.returncode}: {last_error_line(run)}")
            prod = crowdrom_io.read_prediction(out)
        return self._evaluation(prod, params, cpu)

    def _evaluation(self, prod, params, cpu):
        where = f"model '{self.name}' ({self.model}, {self.rom_file})"
        names = prod["param_names"]
        if sorted(names) != sorted(self.param_names):
            raise InputError(f"{where}: the product's parameters ({', '.join(names)}) are not the "
                             f"questions' box ({', '.join(self.param_names)})")
        got = np.asarray(prod["params"], float)[:, [names.index(x) for x in self.param_names]]
        if got.shape != params.shape or not np.array_equal(got, params):
            raise InputError(f"{where}: the product's parameters {got.shape} are not the "
                             f"{params.shape} queried")
        values, censored = qoi_values(prod, self.qoi, where)
        if self.cpu == "queries":
            cpu = float(np.sum(prod["cpu_seconds"]))
        return Evaluation(values, cpu, censored)
