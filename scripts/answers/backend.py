"""Models as backends: parameter vectors [n, d] and seeds [n] in, QoI values [n] and the CPU
seconds spent out.

* ``SyntheticFamily``: K correlated models on a parameter box with known means, standard
  deviations, correlations and (for the first, the "exact" one) quantiles and exceedance
  probabilities when the parameters are uniform on the box; declared costs per run.
* ``CommandBackend``: runs a program that reads a parameter list and writes the crowdrom-qoi
  product (``crowd_predict``), reads the product through ``crowdrom_io.read_qoi`` and charges the
  program's CPU seconds (all its processes, measured by the operating system).
"""
import os
import resource
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


# ------------------------------------------------------------------------------ external program

def write_param_list(path, names, params, seeds):
    """The parameter list a prediction program reads: a header line '# name ... seed', then one
    line per query (values with 17 significant digits, then the integer seed)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write("# " + " ".join(list(names) + ["seed"]) + "\n")
        for row, s in zip(params, seeds):
            f.write(" ".join(f"{v:.17g}" for v in row) + f" {int(s)}\n")


def children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


class CommandBackend(Backend):
    """A model run by an external program.

    ``command``: argument list with the placeholders ``{params}`` (the parameter list written by
    ``write_param_list``) and ``{output}`` (the QoI product to write), e.g.
    ``["mpirun", "-n", "2", "build/bin/crowd_predict", "predict.nml", "--params", "{params}",
    "--output", "{output}"]``; ``qoi`` the column of the product; ``reader`` turns a product path
    into a dict (default ``crowdrom_io.read_qoi``) holding ``params`` [n, d], the QoI [n] and
    optionally ``<qoi>_censored`` [n]. Cost: the CPU seconds of the program and every process it
    waited for (user + system), as counted by the operating system."""

    def __init__(self, name, command, qoi, param_names, workdir=None, reader=None):
        self.name, self.command, self.qoi = name, list(command), qoi
        self.param_names, self.workdir, self.reader = list(param_names), workdir, reader

    def _reader(self):
        if self.reader is not None:
            return self.reader
        if not hasattr(crowdrom_io, "read_qoi"):
            raise InputError("crowdrom_io has no read_qoi: the QoI product cannot be read")
        return crowdrom_io.read_qoi

    def evaluate(self, params, seeds):
        params = np.atleast_2d(np.asarray(params, float))
        with tempfile.TemporaryDirectory(dir=self.workdir, prefix=f"answers-{self.name}-") as tmp:
            plist, out = os.path.join(tmp, "params.txt"), os.path.join(tmp, "qoi.h5")
            write_param_list(plist, self.param_names, params, seeds)
            cmd = [a.replace("{params}", plist).replace("{output}", out) for a in self.command]
            t0 = children_cpu()
            run = subprocess.run(cmd, capture_output=True, text=True)
            cpu = children_cpu() - t0
            if run.returncode != 0:
                last = (run.stderr.strip().splitlines() or ["(no message)"])[-1]
                raise InputError(f"model '{self.name}': {cmd[0]} exited with {run.returncode}: {last}")
            prod = self._reader()(out)
        return self._check(prod, params, cpu)

    def _check(self, prod, params, cpu):
        if self.qoi not in prod:
            raise InputError(f"model '{self.name}': the QoI product has no '{self.qoi}'")
        got = np.asarray(prod["params"], float)
        if got.shape != params.shape or not np.allclose(got, params, rtol=1e-12, atol=0.0):
            raise InputError(f"model '{self.name}': the product's parameters [{got.shape}] are not "
                             f"the {params.shape} queried")
        return Evaluation(prod[self.qoi], cpu, prod.get(f"{self.qoi}_censored"))
