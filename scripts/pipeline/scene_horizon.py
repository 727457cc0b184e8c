"""Evacuation times of a study's scene at the corners of its parameter box, to choose a horizon.

    scene_horizon.py inputs/CASE_study.nml [--corner NAME=lo|hi ...] [--grid K] [--bin build/bin]
                     [--max-steps M] [--json OUT]

For every corner of the &study box (each scalar parameter 'l_exit', 'l_exit2', 'speed' at its
param_min or param_max; 'speed_mean' sets every agent's speed to the mean, the narrowest case of
a population at a given mean; 'speeds' sets every agent to the bound), runs crowd_fom on the
study's scene with &time until_empty = .true. (the run stops when every agent has left) and
reports the steps at which 50%, 90% and 100% of the agents are out (the rule "first frame with
at least ceil(p N / 100) agents out", like cr_rom_metrics), the times, and the cost: CPU seconds
per step and in total (crowd_fom's summary). --corner restricts the run to the corners with the
given bounds (e.g. --corner l_exit=lo --corner speed=lo: the narrowest, slowest corner); --grid K
runs a tensor grid of K values per parameter instead (a scan for clogging: a run still not empty
after --max-steps steps has an arch blocking the exit, its times are reported as None).

The runs are serial (crowd_fom) and written to a temporary folder that is removed at the end.
"""
import argparse
import itertools
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402

#: the &study parameters the corners vary, and where each one goes in the model's groups
TARGET = {"l_exit": ("scene", "l_exit"), "l_exit2": ("scene", "l_exit2"), "speed": ("agents", "speed"),
          "speeds": ("agents", "speed"), "speed_mean": ("agents", "speed")}
#: groups the full model does not read (the study's stages)
STAGE_GROUPS = ("study", "offline", "pod", "cone", "pga", "infsup", "pairs", "hyper")


def study_box(text, path):
    """[(name, lo, hi)] of the &study group (names lower case)."""
    m = re.search(r"&study\b(.*?)\n\s*/", text, re.S | re.I)
    if m is None:
        raise cio.InputError(f"'{path}': no &study group")
    body = m.group(1)

    def values(key):
        mm = re.search(key + r"\s*=\s*(.*?)(?=,\s*[A-Za-z_]\w*\s*=|$)", body, re.S | re.I)
        if mm is None:
            raise cio.InputError(f"'{path}': &study has no {key}")
        return [v.strip().strip("'\"") for v in mm.group(1).replace("\n", " ").split(",") if v.strip()]

    names = [v.lower() for v in values("param_name")]
    lo = [float(v.replace("d", "e")) for v in values("param_min")]
    hi = [float(v.replace("d", "e")) for v in values("param_max")]
    return list(zip(names, lo, hi))


def model_text(text, overrides):
    """The study file's model groups with {group: {var: value}} appended inside each group."""
    out = []
    for m in re.finditer(r"&(\w+)\b(.*?)\n\s*/", text, re.S):
        g = m.group(1).lower()
        if g in STAGE_GROUPS:
            continue
        body = m.group(2).rstrip().rstrip(",")
        extra = ", ".join(f"{k} = {v}" for k, v in overrides.get(g, {}).items())
        out.append(f"&{g}{body}{', ' + extra if extra else ''}\n/\n")
    for g, kv in overrides.items():
        if not re.search(r"&" + g + r"\b", text, re.I):
            out.append(f"&{g} " + ", ".join(f"{k} = {v}" for k, v in kv.items()) + "\n/\n")
    return "".join(out)


def frames_out(curve, n_agents, percent):
    """First frame with at least ceil(percent n_agents / 100) agents out (None: never)."""
    idx = np.nonzero(curve >= math.ceil(percent * n_agents / 100))[0]
    return int(idx[0]) if idx.size else None


def run_point(exe, text, point, workdir, max_steps):
    """One crowd_fom run until empty at the parameter values {name: value}; its times and cost."""
    over = {"time": {"until_empty": ".true.", "max_steps": str(max_steps)},
            "output": {"file": "'%s'" % os.path.join(workdir, "fom.h5"), "every": "1",
                       "store_multipliers": ".false.", "log_level": "'warn'"}}
    for name, value in point.items():
        g, v = TARGET[name]
        over.setdefault(g, {})[v] = repr(value)
    nml = os.path.join(workdir, "corner.nml")
    with open(nml, "w") as fh:
        fh.write(model_text(text, over))
    summ = os.path.join(workdir, "summary.json")
    t0 = time.time()
    res = subprocess.run([exe, nml, "--summary", summ], capture_output=True, text=True)
    wall = time.time() - t0
    if res.returncode != 0:
        raise cio.InputError(f"crowd_fom failed at {point}: {res.stderr.strip() or res.stdout[-400:]}")
    with open(summ) as fh:
        s = json.load(fh)
    d = cio.read_fom(os.path.join(workdir, "fom.h5"))
    curve = (~d["inside"]).sum(axis=1)
    steps = d["step"]
    na, h = d["n_agents"], d["dt"]
    row = {"point": dict(point),
           "steps_run": int(s["steps"]), "agents_inside_at_end": int(s["agents_inside"]),
           "cpu_per_step": s.get("time_per_step", float("nan")), "wall_total": wall, "dt": h}
    for p in (50, 90, 100):
        f = frames_out(curve, na, p)
        row[f"step_t{p}"] = None if f is None else int(steps[f])
        row[f"t{p}"] = None if f is None else float(steps[f] * h)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("study")
    ap.add_argument("--corner", action="append", default=[], metavar="NAME=lo|hi")
    ap.add_argument("--bin", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "build", "bin"))
    ap.add_argument("--grid", type=int, default=2, metavar="K",
                    help="K equispaced values per parameter instead of the two bounds (K >= 2)")
    ap.add_argument("--max-steps", type=int, default=5000,
                    help="cap of each run (a run that reaches it has a clogged exit)")
    ap.add_argument("--json", default="")
    args = ap.parse_args(argv)
    with open(args.study) as fh:
        text = fh.read()
    box = study_box(text, args.study)
    want = {}
    for c in args.corner:
        name, _, side = c.partition("=")
        if name not in [b[0] for b in box] or side not in ("lo", "hi"):
            raise cio.InputError(f"--corner {c}: expected NAME=lo|hi with NAME one of {[b[0] for b in box]}")
        want[name] = side
    if args.grid < 2:
        raise cio.InputError(f"--grid {args.grid}: expected at least 2 values per parameter")
    varied = [b for b in box if b[0] in TARGET]
    axes = []
    for name, lo, hi in varied:
        vals = [lo + (hi - lo) * i / (args.grid - 1) for i in range(args.grid)]
        if name in want:
            vals = [lo if want[name] == "lo" else hi]
        axes.append(vals)
    rows = []
    exe = os.path.join(args.bin, "crowd_fom")
    with tempfile.TemporaryDirectory(prefix="scene_horizon_") as wd:
        for values in itertools.product(*axes):
            point = {b[0]: v for b, v in zip(varied, values)}
            row = run_point(exe, text, point, wd, args.max_steps)
            rows.append(row)
            cs = ", ".join(f"{k} = {v:g}" for k, v in row["point"].items())
            ts = ", ".join(f"t{p} = {row[f't{p}']} s (step {row[f'step_t{p}']})" for p in (50, 90, 100))
            print(f"{cs}: {ts}; {row['steps_run']} steps, {row['cpu_per_step']:.3g} s per step, "
                  f"{row['wall_total']:.1f} s wall", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors("scene_horizon", main))
