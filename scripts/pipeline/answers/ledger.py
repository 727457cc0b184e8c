"""The cost ledger: every CPU second an answer needs, from nothing.

An entry is (stage, model, runs, cpu_seconds). Stages: ``build`` (what a model needs before its
first query: the snapshot runs, the offline stage, the ML fitting; passed in by the caller),
``pilot`` (joint runs that fix an allocation), ``training`` (exact runs a surrogate is fitted on),
``fitting`` (surrogate fitting and sampling in this process), ``estimation`` (the runs of the
estimator itself). A method's total is the sum of its own entries and of the build entries of the
models it uses.
"""

STAGES = ("build", "pilot", "training", "fitting", "estimation")


class CostLedger:
    """A list of cost entries; ``total()`` in CPU seconds."""

    def __init__(self, entries=()):
        self.entries = []
        for e in entries:
            self.add(*e)

    def add(self, stage, model, runs, cpu_seconds):
        if stage not in STAGES:
            raise ValueError(f"unknown cost stage {stage!r} (known: {', '.join(STAGES)})")
        if not cpu_seconds >= 0:
            raise ValueError(f"cost of {stage}/{model} must be >= 0 CPU seconds, got {cpu_seconds}")
        self.entries.append((stage, str(model), int(runs), float(cpu_seconds)))
        return self

    def extend(self, other):
        for e in other.entries:
            self.add(*e)
        return self

    def builds_of(self, models):
        """A ledger with the build entries of ``models`` only."""
        return CostLedger(e for e in self.entries if e[0] == "build" and e[1] in models)

    def total(self):
        return sum(e[3] for e in self.entries)

    def by_stage(self):
        out = {}
        for s, _, _, c in self.entries:
            out[s] = out.get(s, 0.0) + c
        return out

    def as_list(self):
        return [{"stage": s, "model": m, "runs": r, "cpu_seconds": c} for s, m, r, c in self.entries]

    def copy(self):
        return CostLedger(self.entries)
