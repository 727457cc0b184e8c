"""The cost ledger: every CPU second an answer needs, from nothing.

An entry is (stage, model, runs, cpu_seconds). Stages: ``build`` (what a model needs before its
first query: the snapshot runs, the offline stage, the ML fitting; ``Builds``), ``pilot`` (joint
runs that fix an allocation), ``training`` (exact runs a surrogate is fitted on), ``fitting``
(surrogate fitting and sampling in this process), ``estimation`` (the runs of the estimator
itself). A method's total is the sum of its own entries and of the build items of the models it
uses, each item once however many of its models the method uses.
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


class Builds:
    """Build items: (name, the models that need it, runs, CPU seconds). Several low fidelities
    of one ROM file share its snapshot and offline stages; an ML-corrected one adds its own
    training. ``ledger(models)`` charges every item that any of ``models`` needs, once."""

    def __init__(self, items=()):
        self.items = []
        for it in items:
            self.add(*it)

    @classmethod
    def per_model(cls, ledger):
        """Items from a CostLedger's build entries, each needed by the model it names."""
        return cls((e[1], [e[1]], e[2], e[3]) for e in ledger.entries if e[0] == "build")

    def add(self, name, models, runs, cpu_seconds):
        models = [models] if isinstance(models, str) else list(models)
        for it in self.items:
            if it[0] == name:           # the same item named again: more models need it
                it[1].update(models)
                if (it[2], it[3]) != (int(runs), float(cpu_seconds)):
                    raise ValueError(f"build '{name}' given twice with different costs")
                return self
        CostLedger().add("build", name, runs, cpu_seconds)         # checks the cost
        self.items.append((str(name), set(models), int(runs), float(cpu_seconds)))
        return self

    def ledger(self, models):
        """A fresh ledger with the build items needed by any of ``models`` (names), each once."""
        models = set(models)
        return CostLedger(("build", n, r, c) for n, used, r, c in self.items if used & models)

    def models(self):
        return set().union(*(it[1] for it in self.items)) if self.items else set()
