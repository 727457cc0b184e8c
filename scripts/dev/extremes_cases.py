"""The stability campaign at the extremes (docs/testing.md#the-extremes-campaign): one record per case.

A case is a run of one program (crowd_fom, crowd_snapshots, crowd_offline) on an input built
from a namelist file in tests/inputs/extremes/ with some groups replaced, in one of two sizes:
'small' (the ctest label `extremes`, Debug build, seconds) and 'full' (the report,
scripts/dev/extremes_report.py, Release build, bigger scenes). Each record says what is expected
and checks it:

  * completed runs: the program exits 0, no NaN or Inf in any output (HDF5 datasets and
    attributes, JSON), never a step claimed converged with a KKT residual above tol, every
    non-converged step counted in the summary, agents stay in the building, and the case's
    own bounds (overlap, agents left, POD rank, cone error, ...);
  * refused or stopped runs: a non-zero exit status, exactly one `error:` line matching the
    expected message, and no result file (HDF5, .partial, JSON summary) left behind.

A parser turns each run into one row of the report: outcome, KKT residual or error,
iterations, time. To add a case (e.g. the online reduced model), append a Case to CASES
(or to the list returned by all_cases) with its stage, program, input and check function.
"""
import json
import math
import os
import re
import shutil
import subprocess
import time
from dataclasses import dataclass, field

import sys

import h5py
import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402
import nml_groups  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
INPUTS = os.path.join(ROOT, "tests", "inputs", "extremes")
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")


# ----------------------------------------------------------------------------- namelists

def strip_groups(text, groups):
    """Remove the given namelist groups (one or several lines each) from a namelist text."""
    out, skip = [], False
    for line in text.splitlines():
        t = line.strip().lower()
        if any(re.match(r"&%s\b" % g, t) for g in groups):
            skip = True
        if not skip:
            out.append(line)
        if skip and t.endswith("/"):
            skip = False
    return "\n".join(out) + "\n"


def build_input(base, groups):
    """The namelist file `base` (in tests/inputs/extremes) with `groups` {name: text} replaced
    or added (a text of None removes the group). "offline" and "rom" name the options of
    crowd_offline / crowd_rom as one flat list, spread over their groups (nml_groups)."""
    expanded = {}
    for g, t in groups.items():
        if g in ("offline", "rom") and t is not None:
            expanded.update((nml_groups.offline_groups if g == "offline" else nml_groups.rom_groups)(t))
        else:
            expanded[g] = t
    with open(os.path.join(INPUTS, base)) as f:
        text = strip_groups(f.read(), list(expanded))
    for g, t in expanded.items():
        if t is not None:
            text += "&%s %s /\n" % (g, t)
    return text


def config_values(text, group):
    """{variable: value} of one group of an effective configuration (numbers and strings)."""
    m = re.search(r"&%s\b(.*?)/\s*$" % group, text, re.S | re.M)
    if not m:
        return {}
    vals = {}
    number = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[EeDd][-+]?\d+)?"
    for k, v in re.findall(r"(\w+)\s*=\s*('[^']*'|%s)" % number, m.group(1)):
        vals[k] = v.strip("'") if v.startswith("'") else float(v.replace("D", "E").replace("d", "e"))
    return vals


# ----------------------------------------------------------------------------- running

@dataclass
class Run:
    """One program run: exit status, output, wall time, summary JSON, error lines."""
    rc: int
    out: str
    wall: float
    workdir: str
    summary: dict = None
    errors: list = field(default_factory=list)
    timed_out: bool = False


def run_program(ctx, prog, nml_name, np_=1, summary="summary.json", timeout=600, args=()):
    """Run bin/prog on workdir/nml_name (under mpiexec when np_ > 1)."""
    exe = os.path.join(ctx.bin, prog)
    cmd = [exe, nml_name]
    if np_ > 1:
        cmd = ["mpiexec", "-n", str(np_), "--oversubscribe"] + cmd
    if summary:
        cmd += ["--summary", summary]
    cmd += list(args)
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=ctx.workdir, capture_output=True, text=True, env=ENV, timeout=timeout)
        rc, out, timed_out = p.returncode, p.stdout + p.stderr, False
    except subprocess.TimeoutExpired as e:
        rc, timed_out = -9, True
        out = (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
    r = Run(rc, out, time.perf_counter() - t0, ctx.workdir, timed_out=timed_out)
    r.errors = [l for l in out.splitlines() if l.startswith("error:")]
    if summary and os.path.exists(os.path.join(ctx.workdir, summary)):
        with open(os.path.join(ctx.workdir, summary)) as f:
            r.summary = json.load(f)
    return r


# ----------------------------------------------------------------------------- checks

def nonfinite_in_h5(path):
    """Names of the floating-point datasets and attributes of an HDF5 file holding NaN/Inf."""
    bad = []

    def attrs(name, obj):
        for k, v in obj.attrs.items():
            a = np.asarray(v)
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                bad.append("%s@%s" % (name, k))

    def visit(name, obj):
        attrs(name, obj)
        if isinstance(obj, h5py.Dataset) and obj.dtype.kind == "f" and obj.size:
            if not np.all(np.isfinite(obj[...])):
                bad.append(name)

    with cio.open_h5(path) as f:
        attrs("/", f)
        f.visititems(visit)
    return bad


def nonfinite_in_json(obj, prefix=""):
    bad = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            bad += nonfinite_in_json(v, prefix + "/" + k)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            bad += nonfinite_in_json(v, "%s[%d]" % (prefix, i))
    elif isinstance(obj, float) and not math.isfinite(obj):
        bad.append(prefix)
    return bad


class Checker:
    """Collects failed expectations."""

    def __init__(self):
        self.failures = []

    def need(self, ok, text):
        if not ok:
            self.failures.append(text)
        return ok


def check_refused(c, r, regex, files=("out.h5", "summary.json")):
    """Refusal or stop: non-zero status, one `error:` line matching regex, no result left."""
    c.need(not r.timed_out, "no answer within the time limit (hang)")
    c.need(r.rc not in (0, -9), "exit status %d, expected a failure" % r.rc)
    c.need(len(r.errors) == 1, "expected exactly one 'error:' line, got %d" % len(r.errors))
    c.need(any(re.search(regex, e) for e in r.errors), "no error line matching /%s/: %s" % (regex, r.errors))
    c.need(not any(s in r.out for s in ("Backtrace", "SIGFPE", "Floating-point exception", "Segmentation")),
           "the program crashed")
    for f in files:
        for g in (f, f + ".partial"):
            c.need(not os.path.exists(os.path.join(r.workdir, g)), "a failed run left %s" % g)


def check_completed(c, r):
    """Exit status 0 within the time limit, no NaN/Inf in the JSON summary."""
    c.need(not r.timed_out, "no answer within the time limit (hang)")
    if not c.need(r.rc == 0, "exit status %d: %s" % (r.rc, r.errors or r.out[-400:])):
        return False
    if c.need(r.summary is not None, "no JSON summary"):
        c.need(not nonfinite_in_json(r.summary), "NaN/Inf in the summary: %s" % nonfinite_in_json(r.summary))
    return True


def attr_str(a):
    """An HDF5 string attribute as str (h5py gives bytes or str depending on the type)."""
    return a.decode() if isinstance(a, (bytes, np.bytes_)) else str(a)


class FomResult:
    """The crowd_fom output read back (positions, stats, multipliers, scene, tolerance)."""

    def __init__(self, path):
        with cio.open_h5(path, cio.FOM_SCHEMA, "full-order output") as f:
            self.config = attr_str(f.attrs["config"])
            self.radius = float(f.attrs["agent_radius"])
            self.q = f["traj/positions"][...]            # [T, 2N]
            self.stats = {k: f["stats"][k][...] for k in f["stats"]}
            off = f["traj/contacts/offset"][...]
            lam = f["traj/contacts/lambda"][...]
            self.lambda_sum = np.array([lam[off[t]:off[t + 1]].sum() for t in range(len(off) - 1)])
            self.lambda_max = np.array([lam[off[t]:off[t + 1]].max() if off[t + 1] > off[t] else 0.0
                                        for t in range(len(off) - 1)])
        sc = config_values(self.config, "scene")
        self.length, self.width = sc["hall_length"], sc["hall_width"]
        self.l_exit, self.wall = sc["l_exit"], sc["wall_thickness"]
        self.tol = config_values(self.config, "solver")["tol"]


def check_fom_output(c, r, out="out.h5", gap_bound=1.0e-6, converged=True):
    """Checks of every completed crowd_fom run; returns the FomResult (or None).

    gap_bound: largest overlap allowed, relative to the radius (None: not checked);
    converged: True = every step must converge, False = at least one step must not,
    None = either (but always honestly flagged)."""
    path = os.path.join(r.workdir, out)
    if not c.need(os.path.exists(path), "no output file %s" % out):
        return None
    bad = nonfinite_in_h5(path)
    c.need(not bad, "NaN/Inf in the output: %s" % bad[:5])
    f = FomResult(path)
    st, s = f.stats, r.summary or {}
    conv = st["converged"].astype(bool)
    # never claimed converged with a residual above tol; every failure counted
    c.need(not np.any(conv & (st["kkt"] > f.tol)),
           "steps flagged converged with KKT > tol: %s" % np.nonzero(conv & (st["kkt"] > f.tol))[0][:5])
    c.need(s.get("failed_steps") == int(np.sum(~conv)),
           "summary failed_steps = %s but %d steps are not converged" % (s.get("failed_steps"), np.sum(~conv)))
    if len(conv):
        c.need(abs(s.get("largest_kkt_residual", -1) - float(st["kkt"].max())) <= 1e-12 * max(1.0, st["kkt"].max()),
               "summary largest_kkt_residual differs from stats/kkt")
    if converged is True:
        c.need(bool(np.all(conv)), "%d steps did not converge" % np.sum(~conv))
    elif converged is False:
        c.need(not np.all(conv), "every step converged although the case must hit a cap")
        c.need("not converged" in r.out, "no warning about non-converged steps in the log")
    if gap_bound is not None and len(st["min_gap"]):
        c.need(float(st["min_gap"].min()) >= -gap_bound * f.radius,
               "overlap %.3e (> %.0e r)" % (-st["min_gap"].min(), gap_bound))
    # agents stay in the building: below the top of the walls only inside [0, L] x [0, W + t]
    x, y = f.q[:, 0::2], f.q[:, 1::2]
    below = y < f.width + f.wall
    eps = 1e-9 * f.radius
    out_of_hall = below & ((x < -eps) | (x > f.length + eps) | (y < -eps))
    c.need(not np.any(out_of_hall), "%d agent positions outside the building" % np.sum(out_of_hall))
    return f


# ----------------------------------------------------------------------------- cases

@dataclass
class Case:
    """One case of the campaign.

    name, stage ('fom', 'snapshots', 'offline'; later 'online'), expected (one line for the
    report); program and input: base namelist file in tests/inputs/extremes and the groups
    to replace for each size ({'small': {...}, 'full': {...}}); files: extra files to write
    into the working directory ({name: text or function(size) -> text}); before: programs to
    run first ([(program, np)], e.g. crowd_snapshots for an offline case); check(c, r, ctx):
    the case's expectations; parse(r, ctx): the report row; np: MPI ranks; timeout (s) per
    size."""
    name: str
    stage: str
    expected: str
    program: str
    base: str
    groups: dict
    check: object
    parse: object = None
    files: dict = field(default_factory=dict)
    before: list = field(default_factory=list)
    np: int = 1
    timeout: dict = field(default_factory=lambda: {"small": 240, "full": 1800})  # hang guards, not speed checks: a shared machine can be 6x slower


class Context:
    def __init__(self, bin_dir, workdir, size):
        self.bin, self.workdir, self.size = bin_dir, workdir, size


def run_case(case, bin_dir, workroot, size):
    """Run one case; returns (Run, failures, row)."""
    ctx = Context(bin_dir, os.path.join(workroot, case.name), size)
    shutil.rmtree(ctx.workdir, ignore_errors=True)
    os.makedirs(ctx.workdir)
    groups = case.groups.get(size, case.groups.get("small", {}))
    with open(os.path.join(ctx.workdir, "input.nml"), "w") as f:
        f.write(build_input(case.base, groups))
    for name, text in case.files.items():
        with open(os.path.join(ctx.workdir, name), "w") as f:
            f.write(text(size) if callable(text) else text)
    c = Checker()
    t0 = time.perf_counter()
    for prog, np_ in case.before:
        pre = run_program(ctx, prog, "input.nml", np_=np_, summary="before.json", timeout=case.timeout[size])
        if pre.rc != 0:
            c.need(False, "%s before the case failed: %s" % (prog, pre.errors or pre.out[-400:]))
            r = pre
            break
    else:
        r = run_program(ctx, case.program, "input.nml", np_=case.np, timeout=case.timeout[size])
        try:
            case.check(c, r, ctx)
        except Exception as e:  # a check that cannot read what it expects is a failure
            c.need(False, "check raised %s: %s" % (type(e).__name__, e))
    r.total_wall = time.perf_counter() - t0
    try:
        row = (case.parse or parse_default)(r, ctx)
    except (KeyError, TypeError, ValueError, OSError) as e:
        row = parse_default(r, ctx)
        c.need(False, "unexpected summary (%s: %s)" % (type(e).__name__, e))
    return r, c.failures, row


# ----------------------------------------------------------------------------- report rows

def fmt(x, spec=".1e"):
    return "-" if x is None else format(x, spec)


def short_error(r):
    e = r.errors[0][len("error: "):] if r.errors else ("timed out" if r.timed_out else "exit %d" % r.rc)
    return e if len(e) <= 150 else e[:147] + "..."


def parse_default(r, ctx):
    if r.rc != 0:
        return {"outcome": "stopped: " + short_error(r), "measure": "-", "iterations": "-", "time": r.wall}
    return {"outcome": "completed", "measure": "-", "iterations": "-", "time": r.wall}


def parse_fom(r, ctx):
    if r.rc != 0 or not r.summary:
        return parse_default(r, ctx)
    s = r.summary
    gap = s.get("smallest_gap")
    gap_txt = "no contact" if gap is None else "%.1e r" % (gap / max(fom_radius(ctx), 1e-300))
    out = "completed: %d steps, %d of %d left, %d non-converged, min gap %s" % (
        s["steps"], s["agents_left"], s["agents"], s["failed_steps"], gap_txt)
    it = "-" if "iterations_mean" not in s else "%.0f / %d" % (s["iterations_mean"], s["iterations_max"])
    return {"outcome": out, "measure": "KKT " + fmt(s.get("largest_kkt_residual")), "iterations": it,
            "time": r.wall}


def fom_radius(ctx):
    try:
        with cio.open_h5(os.path.join(ctx.workdir, "out.h5"), cio.FOM_SCHEMA, "full-order output") as f:
            return float(f.attrs["agent_radius"])
    except (OSError, KeyError, cio.InputError):
        return 1.0


def parse_snapshots(r, ctx):
    if r.rc != 0 or not r.summary:
        return parse_default(r, ctx)
    s = r.summary
    out = "completed: %d samples, %d non-converged steps in %d samples" % (
        s.get("samples_total", 0), s.get("nonconverged_steps", 0), s.get("nonconverged_samples", 0))
    return {"outcome": out, "measure": "KKT " + fmt(s.get("largest_kkt_residual")), "iterations": "-",
            "time": r.wall}


def parse_offline(r, ctx):
    if r.rc != 0 or not r.summary:
        return parse_default(r, ctx)
    s = r.summary
    notes = [n for n in (s.get("cone_note"), s.get("pga_note")) if n]
    out = "completed: N_pod = %s (rank %s), N = %s, R = %s" % (s.get("n_pod"), s.get("pod_numerical_rank"),
                                                               s.get("n_total"), s.get("r"))
    if notes:
        out += "; " + "; ".join(notes)
    return {"outcome": out, "measure": "e_R %s, PGA %s" % (fmt(s.get("cone_error")), fmt(s.get("pga_error"))),
            "iterations": "R = %s, +%s supremizers" % (s.get("r"), s.get("pga_added")), "time": r.wall}


# ----------------------------------------------------------------------------- the cases

# the paper's congested scene (inputs/congested150.nml), the base of most full-size FOM cases
CONGESTED = {"scene": "hall_length = 2.0, hall_width = 1.25, l_exit = 0.32, wall_thickness = 0.1",
             "obstacles": "n_disks = 1, disk_x = 1.0, disk_y = 0.6, disk_r = 0.15",
             "agents": "n_agents = 150, radius = 0.05, speed = 5.0, seed = 150",
             "time": "dt = 0.005, n_steps = 50"}


def congested(**changes):
    """CONGESTED with some groups replaced ({group: text})."""
    return dict(CONGESTED, **changes)


def positions(rows):
    return "".join("%r %r\n" % (x, y) for x, y in rows)


def touching_grid(size):
    """Agents of radius 1/16 on a square grid of spacing 2r (gap exactly 0 between
    neighbours, the first row and column touching the bottom and left walls); all values are
    exact in binary."""
    r = 0.0625
    nx, ny = (6, 3) if size == "small" else (14, 6)
    return positions([(r + 2 * r * i, r + 2 * r * j) for j in range(ny) for i in range(nx)])


def fom_case(name, expected, base, groups, check, **kw):
    return Case(name, "fom", expected, "crowd_fom", base, groups, check, parse=parse_fom, **kw)


def refused(regex, files=("out.h5", "summary.json")):
    def check(c, r, ctx):
        check_refused(c, r, regex, files)
    return check


def completes(gap_bound=1.0e-6, converged=True, extra=None):
    def check(c, r, ctx):
        if check_completed(c, r):
            f = check_fom_output(c, r, gap_bound=gap_bound, converged=converged)
            if f is not None and extra is not None:
                extra(c, r, ctx, f)
    return check


def exit_narrow_extra(c, r, ctx, f):
    s = r.summary
    c.need(s["agents_left"] == 0, "%d agents left through an exit narrower than a diameter" % s["agents_left"])
    # no centre passes between the door corners: y <= W - sqrt(r^2 - (l/2)^2)
    ymax = f.width - math.sqrt(f.radius ** 2 - (f.l_exit / 2) ** 2)
    c.need(f.q[:, 1::2].max() <= ymax + 1e-9 * f.radius, "an agent went past the door corners")
    # the crowd jams: the total multiplier of the last tenth of the run exceeds the first tenth's
    n = max(len(f.lambda_sum) // 10, 1)
    c.need(f.lambda_sum[-n:].mean() > f.lambda_sum[1:n + 1].mean(), "the multipliers do not grow in the jam")


def clogging_extra(c, r, ctx, f):
    s = r.summary
    c.need(s["agents_left"] < s["agents"], "everybody left: no clogging at an exit of about one diameter")


def packing_extra(c, r, ctx, f):
    s = r.summary
    n = s["agents"]
    c.need(s["placement_iterations"] >= 1, "the random placement needed no overlap removal")
    c.need(f.stats["n_rows"].max() > 2 * n, "only %d contact rows for %d agents (expected more rows than "
           "velocity dofs: redundant contacts)" % (f.stats["n_rows"].max(), n))


def packing_either(c, r, ctx):
    """Placement near the limit: it either succeeds (then everything is checked) or says
    it cannot, with the reason."""
    if r.rc == 0:
        completes(converged=None, extra=kkt_within(1e-8))(c, r, ctx)
    else:
        check_refused(c, r, r"cannot make the initial configuration feasible: .*\((no progress|placement_max_iter)")


def kkt_within(bound):
    """Extra check: the largest KKT residual is below `bound` (steps above tol are allowed,
    and checked to be flagged, by check_fom_output)."""
    def extra(c, r, ctx, f):
        c.need(r.summary.get("largest_kkt_residual", 0) <= bound, "largest KKT residual %.2e > %.0e"
               % (r.summary.get("largest_kkt_residual", 0), bound))
    return extra


def at_rest_extra(c, r, ctx, f):
    c.need(np.all(f.q == f.q[0]), "a crowd at rest moved")
    c.need(r.summary["largest_kkt_residual"] == 0.0, "KKT residual of a crowd at rest is not 0")


def touching_extra(c, r, ctx, f):
    with open(os.path.join(ctx.workdir, "positions.txt")) as fh:
        q0 = np.array([float(v) for v in fh.read().split()])
    c.need(np.array_equal(f.q[0], q0), "the touching initial positions were changed")


def one_agent_extra(c, r, ctx, f):
    s = r.summary
    c.need(s["agents_left"] == 1 and s["steps"] >= 1, "the single agent did not leave")


def all_outside_extra(c, r, ctx, f):
    s = r.summary
    c.need(s["steps"] == 0 and s["agents_left"] == s["agents"], "a crowd already outside took steps")
    c.need(f.q.shape[0] == 1, "expected only the initial state in the output")


def uzawa_above_extra(c, r, ctx, f):
    c.need("exceeds the convergence bound" in r.out, "no warning that rho exceeds the convergence bound")
    c.need(r.summary["largest_kkt_residual"] <= 1e-8, "Uzawa did not converge (KKT %.2e)"
           % r.summary["largest_kkt_residual"])


def check_snapshot_db(c, r, ctx):
    if not check_completed(c, r):
        return
    path = os.path.join(ctx.workdir, "db.h5")
    if not c.need(os.path.exists(path), "no database"):
        return
    bad = nonfinite_in_h5(path)
    c.need(not bad, "NaN/Inf in the database: %s" % bad[:5])
    with cio.open_h5(path, cio.DB_SCHEMA, "database") as f:
        tol = config_values(attr_str(f.attrs["config"]), "solver")["tol"]
        nc = sum(int(np.sum(f[s]["stats/converged"][...] == 0)) for s in ("train", "valid"))
        kkt_bad = sum(int(np.sum((f[s]["stats/converged"][...] == 1) & (f[s]["stats/kkt"][...] > tol)))
                      for s in ("train", "valid"))
    s = r.summary
    c.need(s.get("nonconverged_steps") == nc, "summary nonconverged_steps = %s, database has %d"
           % (s.get("nonconverged_steps"), nc))
    c.need(nc > 0, "the iteration cap was never reached")
    c.need(kkt_bad == 0, "%d steps stored as converged with KKT > tol" % kkt_bad)


class Rom:
    """The crowd_offline ROM file read back."""

    def __init__(self, path):
        with cio.open_h5(path, cio.ROM_SCHEMA, "ROM file") as f:
            self.v = f["basis/v"][...].T                       # [n_dof, N]
            self.n_pod = int(f["basis"].attrs["n_pod"])
            self.rank = int(f["pod"].attrs["numerical_rank"])
            self.sigma = f["pod/sigma"][...]
            self.cone = {g: {"r": int(f[g].attrs["r"]), "err": f[g + "/err_max"][...],
                             "acc": f[g + "/err_acc"][...] if "err_acc" in f[g] else None,
                             "note": attr_str(f[g].attrs.get("note", ""))}
                         for g in f if g.startswith("cone")}
            self.pga_err = f["pga/err"][...]
            self.n_dict = f["contacts/ia"].shape[0]
            self.has_indices = "indices" in f["cone"]
            self.n_dof = 2 * int(f.attrs["n_agents"])


def offline_completes(extra=None):
    def check(c, r, ctx):
        if not check_completed(c, r):
            return
        path = os.path.join(ctx.workdir, "rom.h5")
        if not c.need(os.path.exists(path), "no ROM file"):
            return
        bad = nonfinite_in_h5(path)
        c.need(not bad, "NaN/Inf in the ROM file: %s" % bad[:5])
        rom = Rom(path)
        n = rom.v.shape[1]
        c.need(rom.v.shape[0] == rom.n_dof or n == 0, "basis has %d rows for %d dofs" % (rom.v.shape[0], rom.n_dof))
        c.need(n <= rom.n_dof, "the basis has %d vectors in a %d-dimensional space" % (n, rom.n_dof))
        if n:
            c.need(np.abs(rom.v.T @ rom.v - np.eye(n)).max() <= 1e-10, "the basis is not orthonormal")
        for g, cone in rom.cone.items():
            err = cone["err"]
            c.need(len(err) == cone["r"] + 1, "%s: %d errors for R = %d" % (g, len(err), cone["r"]))
            acc = cone["acc"]
            if acc is None:
                # gIS: errors are sums of squares of the uncovered coordinates (exact to rounding)
                c.need(np.all(np.diff(err) <= 1e-12), "%s: the error history increases" % g)
            elif c.need(len(acc) == len(err) and np.all(np.isfinite(acc)) and np.all(acc >= 0),
                        "%s: %d accuracies for %d errors, or not finite and >= 0" % (g, len(acc), len(err))):
                # mCPG: the exact worst error cannot grow with the cone; the computed one is within
                # a_r of it at every r (cr_cone's stated accuracy), so e_{r+1} <= e_r + a_r + a_{r+1}
                bad = np.nonzero(err[1:] > err[:-1] + acc[:-1] + acc[1:])[0]
                c.need(bad.size == 0, "%s: the error history increases by more than the projection accuracy "
                       "at r = %s" % (g, (bad + 1).tolist()[:5]))
                if "accuracy of the inner cone projections" in cone["note"]:
                    c.need(err[-1] <= acc[-1], "%s: stopped at the projection accuracy with e_R = %.3e > a_R = %.3e"
                           % (g, err[-1], acc[-1]))
        c.need(r.summary["n_total"] == n and r.summary["n_pod"] == rom.n_pod, "summary and ROM file disagree")
        if extra is not None:
            extra(c, r, ctx, rom)
    return check


def completes_or_refuses(check, regex):
    """Completion checked by `check`, or a refusal whose one error line matches regex (for
    requests such as N_pod = 0 that a later stage may legitimately refuse)."""
    def f(c, r, ctx):
        if r.rc == 0:
            check(c, r, ctx)
        else:
            check_refused(c, r, regex, files=("rom.h5", "summary.json"))
    return f


def off_case(name, expected, study, offline, check, full_study=None, full_offline=None,
             before=(("crowd_snapshots", 1),), **kw):
    """crowd_snapshots (at 1 rank unless before says otherwise) then crowd_offline on study
    (base file) + &offline text."""
    common = "database = 'db.h5', rom_file = 'rom.h5', infsup_samples = 4"
    groups = {"small": {"offline": common + ", " + offline}}
    groups["full"] = dict(full_study or {})
    groups["full"]["offline"] = common + ", " + (full_offline or offline)
    return Case(name, "offline", expected, "crowd_offline", study, groups, check, parse=parse_offline,
                before=list(before), **kw)


# full-size offline study: the hall20 scene, l_exit and each agent's speed within +-10%
HALL20_STUDY = {"scene": "hall_length = 1.3, hall_width = 1.0, l_exit = 0.3, wall_thickness = 0.1",
                "obstacles": None,
                "agents": "n_agents = 20, radius = 0.05, speed = 1.0, seed = 20",
                "time": "dt = 0.05, n_steps = 40",
                "study": "n_params = 2, param_name = 'l_exit', 'speeds', param_min = 0.27, 0.9, "
                         "param_max = 0.33, 1.1, n_train = 40, n_valid = 5, seed = 7, database = 'db.h5'"}


def all_cases():
    """The campaign (FOM, snapshots, offline). The lead appends the online cases."""
    cases = []
    add = cases.append
    narrow = lambda l, steps: {"scene": "hall_length = 1.0, hall_width = 0.8, l_exit = %g, wall_thickness = 0.1" % l,
                               "time": "dt = 0.02, n_steps = %d" % steps}
    # -- exits of one diameter and less
    add(fom_case("fom_exit_narrower", "completes: nobody leaves, the crowd jams (multipliers grow), no overlap, "
                 "every step converged", "exit_narrow.nml",
                 {"small": narrow(0.08, 60), "full": congested(scene="hall_length = 2.0, hall_width = 1.25, "
                                                              "l_exit = 0.08, wall_thickness = 0.1",
                                                              time="dt = 0.005, n_steps = 300")},
                 completes(extra=exit_narrow_extra)))
    add(fom_case("fom_exit_one_diameter", "completes: clogging, no overlap; steps whose KKT residual exceeds tol "
                 "(multipliers ~ 1/gap of an agent wedged between the door corners) counted as non-converged",
                 "exit_narrow.nml",
                 {"small": narrow(0.1, 100), "full": congested(scene="hall_length = 2.0, hall_width = 1.25, "
                                                              "l_exit = 0.1, wall_thickness = 0.1",
                                                              time="dt = 0.005, n_steps = 300")},
                 completes(converged=None, extra=clogging_extra)))
    add(fom_case("fom_exit_1_05_diameter", "completes: arching (few leave), no overlap, every step converged",
                 "exit_narrow.nml",
                 {"small": narrow(0.105, 100), "full": congested(scene="hall_length = 2.0, hall_width = 1.25, "
                                                                "l_exit = 0.105, wall_thickness = 0.1",
                                                                time="dt = 0.005, n_steps = 300")},
                 completes(extra=clogging_extra)))
    # -- dense packing
    big = lambda n, steps: {"scene": "hall_length = 3.5, hall_width = 3.5, l_exit = 0.08, wall_thickness = 0.1",
                            "agents": "n_agents = %d, radius = 0.05, speed = 1.0, seed = 8" % n,
                            "time": "dt = 0.01, n_steps = %d" % steps}
    add(fom_case("fom_packing_080", "placement succeeds; jammed projections with more contact rows than "
                 "dofs all converge, no overlap", "packing.nml",
                 {"small": {}, "full": big(1248, 5)}, completes(extra=packing_extra)))
    add(fom_case("fom_packing_085", "placement succeeds (then no overlap, KKT <= 1e-8, steps above tol "
                 "flagged) or stops saying it cannot, in bounded time", "packing.nml",
                 {"small": {"agents": "n_agents = 300, radius = 0.03, speed = 1.0, seed = 5"},
                  "full": big(1326, 3)}, packing_either))
    add(fom_case("fom_packing_090", "refused: placement stalls and says it cannot (no agent pushed out of "
                 "the hall), in bounded time", "packing.nml",
                 {"small": {"agents": "n_agents = 320, radius = 0.03, speed = 1.0, seed = 5"},
                  "full": big(1404, 5)},
                 refused(r"cannot make the initial configuration feasible: .*\(no progress")))
    add(fom_case("fom_packing_above_limit", "refused before placement: more agents than the densest packing",
                 "packing.nml", {"small": {"agents": "n_agents = 340, radius = 0.03, seed = 5"}},
                 refused(r"more agents than fit")))
    # -- time steps and speeds
    add(fom_case("fom_dt_tiny", "completes: agents move 1e-4 r per step, every step converged, no overlap",
                 "small_hall.nml", {"small": {"time": "dt = 4.0e-6, n_steps = 50"},
                                    "full": congested(time="dt = 1.0e-6, n_steps = 200")},
                 completes()))
    add(fom_case("fom_dt_large", "completes: agents move 2 r per step, no tunnelling through walls, no overlap",
                 "small_hall.nml", {"small": {"time": "dt = 0.08, n_steps = 30"},
                                    "full": congested(time="dt = 0.02, n_steps = 100")},
                 completes()))
    add(fom_case("fom_speed_tiny", "completes: speed 1e-9, every step converged", "small_hall.nml",
                 {"small": {"agents": "n_agents = 30, radius = 0.04, speed = 1.0e-9, seed = 3"},
                  "full": congested(agents="n_agents = 150, radius = 0.05, speed = 1.0e-9, seed = 150")},
                 completes()))
    add(fom_case("fom_speed_huge", "completes: speed 1e4 (thousands of radii per step), no overlap, nobody "
                 "leaves the building except through the exit", "small_hall.nml",
                 {"small": {"agents": "n_agents = 30, radius = 0.04, speed = 1.0e4, seed = 3"},
                  "full": congested(agents="n_agents = 150, radius = 0.05, speed = 1.0e4, seed = 150")},
                 completes()))
    add(fom_case("fom_speed_zero", "completes: a crowd at rest stays put, KKT residual 0 (no 0/0)",
                 "small_hall.nml", {"small": {"agents": "n_agents = 30, radius = 0.04, speed = 0.0, seed = 3"},
                                    "full": congested(agents="n_agents = 150, radius = 0.05, speed = 0.0, "
                                                             "seed = 150")},
                 completes(extra=at_rest_extra)))
    # -- initial states
    add(fom_case("fom_touching", "completes: agents exactly touching (gap 0) each other and the walls are "
                 "accepted, no overlap", "from_file.nml",
                 {"small": {}, "full": {"scene": "hall_length = 2.0, hall_width = 1.0, l_exit = 0.3, "
                                                 "wall_thickness = 0.1",
                                        "agents": "n_agents = 84, radius = 0.0625, init = 'file', "
                                                  "init_file = 'positions.txt'"}},
                 completes(extra=touching_extra), files={"positions.txt": touching_grid}))
    file_agents = lambda n, r=0.05: {"agents": "n_agents = %d, radius = %g, init = 'file', init_file = "
                                               "'positions.txt'" % (n, r)}
    add(fom_case("fom_same_position", "refused: two agents at the same position", "from_file.nml",
                 {"small": file_agents(4)}, refused(r"agents 1 and 3 are at the same position"),
                 files={"positions.txt": positions([(0.2, 0.2), (0.5, 0.5), (0.2, 0.2), (0.8, 0.3)])}))
    add(fom_case("fom_one_agent", "completes: the agent walks out (run until empty)", "from_file.nml",
                 {"small": dict(file_agents(1), time="dt = 0.01, until_empty = .true., max_steps = 1000")},
                 completes(extra=one_agent_extra), files={"positions.txt": positions([(0.5, 0.5)])}))
    add(fom_case("fom_zero_agents", "refused: n_agents must be >= 1", "from_file.nml",
                 {"small": {"agents": "n_agents = 0"}}, refused(r"n_agents must be >= 1 \(got 0\)")))
    add(fom_case("fom_inside_obstacle", "refused: an agent starts inside an obstacle", "from_file.nml",
                 {"small": dict(file_agents(2), obstacles="n_disks = 1, disk_x = 0.5, disk_y = 0.5, disk_r = 0.1")},
                 refused(r"agent 2 starts inside obstacle '&obstacles disk 1'"),
                 files={"positions.txt": positions([(0.2, 0.2), (0.5, 0.52)])}))
    add(fom_case("fom_outside_hall", "refused: an agent starts outside the building (beside the hall)",
                 "from_file.nml", {"small": file_agents(2)}, refused(r"agent 2 at .* starts outside the hall"),
                 files={"positions.txt": positions([(0.2, 0.2), (-0.5, 0.5)])}))
    add(fom_case("fom_all_outside", "completes with 0 steps: everybody is already beyond the exit (run "
                 "until empty), valid output", "from_file.nml",
                 {"small": dict(file_agents(3), time="dt = 0.01, until_empty = .true.")},
                 completes(extra=all_outside_extra),
                 files={"positions.txt": positions([(0.35, 1.3), (0.5, 1.3), (0.65, 1.3)])}))
    # -- Uzawa and iteration caps
    uz = lambda extra: {"solver": "name = 'uzawa', " + extra}
    add(fom_case("fom_uzawa_rho_above_bound", "completes with a warning: rho above the Gershgorin bound "
                 "2/L still converges here (KKT <= 1e-8); steps meeting the paper's test with KKT > tol are "
                 "flagged", "small_hall.nml",
                 {"small": dict(uz("uzawa_rho_factor = 0.3"), time="dt = 0.02, n_steps = 10"),
                  "full": dict(HALL20_STUDY, study=None, solver="name = 'uzawa', uzawa_rho_factor = 0.3")},
                 completes(converged=None, extra=uzawa_above_extra)))
    add(fom_case("fom_uzawa_diverges", "stops: Uzawa diverges (rho far above the bound), the message names rho "
                 "and the bound (no overflow, no NaN)", "small_hall.nml",
                 {"small": dict(uz("uzawa_rho_factor = 5.0"), time="dt = 0.02, n_steps = 10"),
                  "full": congested(solver="name = 'uzawa', uzawa_rho_factor = 5.0")},
                 refused(r"uzawa: diverged at iteration \d+ .* exceeds the convergence bound")))
    caps = [("uzawa", "name = 'uzawa', uzawa_max_iter = 20"), ("apgd", "name = 'apgd', max_iter = 50"),
            ("active_set", "name = 'active_set', max_iter = 1"), ("gpcg", "name = 'gpcg', max_iter = 5")]
    for solver, text in caps:
        add(fom_case("fom_cap_" + solver, "completes: iteration cap reached, non-converged steps counted and "
                     "flagged (never claimed converged), no NaN", "exit_narrow.nml",
                     {"small": dict(narrow(0.08, 30), solver=text),
                      "full": congested(solver=text, time="dt = 0.005, n_steps = 50")},
                     completes(gap_bound=None, converged=False)))
    # -- snapshots
    add(Case("snapshots_cap", "snapshots", "completes: non-converged steps counted in the summary, stored "
             "with converged = 0, never as converged", "crowd_snapshots", "study_tiny.nml",
             {"small": {"solver": "name = 'uzawa', uzawa_max_iter = 10"},
              "full": congested(solver="name = 'uzawa', uzawa_max_iter = 200",
                                study="n_params = 2, param_name = 'l_exit', 'speed', param_min = 0.28, 4.5, "
                                      "param_max = 0.36, 5.5, n_train = 8, n_valid = 2, seed = 5, "
                                      "database = 'db.h5'")},
             check_snapshot_db, parse=parse_snapshots, np=2))
    add(Case("snapshots_uzawa_diverges", "snapshots", "stops: the message names the sample and Uzawa's "
             "divergence; no database", "crowd_snapshots", "study_tiny.nml",
             {"small": {"solver": "name = 'uzawa', uzawa_rho_factor = 5.0"}},
             refused(r"sample \d+ .*uzawa: diverged", files=("db.h5", "summary.json")),
             parse=parse_snapshots, np=2))
    add(Case("snapshots_speed_without_effect", "snapshots", "refused: a study varying the speeds of prescribed "
             "desired velocities (&desired mode = 'file') would give identical samples", "crowd_snapshots",
             "study_tiny.nml", {"small": {"desired": "mode = 'file', file = 'vectors.txt'"}},
             refused(r"parameter 'speeds' has no effect with &desired mode = 'file'", files=("db.h5", "summary.json")),
             parse=parse_snapshots, files={"vectors.txt": "0.0 1.0\n" * 8}))
    # -- offline
    def rank_one(c, r, ctx, rom):
        c.need(rom.rank == 1 and rom.n_pod == 1, "numerical rank %d, N_pod %d (expected 1, 1)" % (rom.rank, rom.n_pod))
        c.need("exceeds the numerical rank" in r.out, "no warning that pod_n exceeds the numerical rank")

    def empty_cone(c, r, ctx, rom):
        for g, cone in rom.cone.items():
            c.need(cone["r"] == 0 and "empty cone" in cone["note"], "%s: R = %d, note '%s'" % (g, cone["r"],
                                                                                             cone["note"]))
            c.need(np.all(cone["err"] == 0), "%s: non-zero error of an empty cone" % g)
        c.need(rom.has_indices, "no cone/indices dataset for an empty gIS cone")
        c.need("PGA skipped" in r.out, "no message that PGA is skipped")

    def at_rest(c, r, ctx, rom):
        c.need(rom.n_pod == 0 and rom.v.shape[1] == 0, "a crowd at rest gave %d modes" % rom.v.shape[1])
        c.need("all zero" in r.out and "basis is empty" in r.out, "no warning about the zero snapshots")
        empty_cone(c, r, ctx, rom)

    def energy0(c, r, ctx, rom):
        c.need(rom.n_pod == rom.rank, "pod_energy = 0 kept %d modes, numerical rank %d" % (rom.n_pod, rom.rank))
        c.need(abs(r.summary["pod_energy_retained"] - 1) <= 1e-12, "retained energy not 1")

    def energy1(c, r, ctx, rom):
        c.need(rom.n_pod == 0, "pod_energy = 1 kept %d POD modes" % rom.n_pod)
        c.need("keeps no POD mode" in r.out, "no warning that no POD mode is kept")
        c.need(rom.v.shape[1] > 0, "no supremizer either")

    def cone_delta0(c, r, ctx, rom):
        gis = rom.cone["cone"]
        c.need(gis["err"][-1] == 0.0, "gIS with delta = 0 ends at e_R = %.3e, not 0" % gis["err"][-1])
        c.need(gis["r"] <= rom.n_dict, "gIS chose %d > %d dictionary indices" % (gis["r"], rom.n_dict))
        other = rom.cone.get("cone_mcpg")
        if c.need(other is not None, "no mCPG comparison"):
            c.need(other["note"] != "" or other["r"] == 100, "mCPG stopped without reaching 0 and without a note")
            c.need(r.summary.get("cone_comparison_note") == other["note"],
                   "summary cone_comparison_note %r differs from the ROM file's mCPG note %r"
                   % (r.summary.get("cone_comparison_note"), other["note"]))

    def cone_delta_above(c, r, ctx, rom):
        for g, cone in rom.cone.items():
            c.need(cone["r"] == 1, "%s: R = %d for delta above every error (expected 1)" % (g, cone["r"]))

    def pga_tiny(c, r, ctx, rom):
        c.need(r.summary["pga_note"] != "", "PGA stopped below delta without saying why")
        c.need(rom.v.shape[1] <= rom.n_dof, "more basis vectors than dofs")

    def pga_above(c, r, ctx, rom):
        c.need(r.summary["pga_added"] == 0, "%d supremizers added for delta above every error"
               % r.summary["pga_added"])

    column = lambda size: positions([(0.3, 0.08), (0.3, 0.22), (0.3, 0.36)] if size == "small" else
                                    [(0.65, 0.07 + 0.13 * k) for k in range(7)])
    column_full = {"scene": "hall_length = 1.3, hall_width = 1.0, l_exit = 0.3, wall_thickness = 0.1",
                   "agents": "n_agents = 7, radius = 0.05, speed = 1.0, init = 'file', init_file = 'positions.txt'",
                   "time": "dt = 0.01, n_steps = 10",
                   "study": "n_params = 1, param_name = 'l_exit', param_min = 0.27, param_max = 0.4, n_train = 40, "
                            "n_valid = 5, seed = 3, database = 'db.h5'"}
    add(off_case("offline_rank_one", "completes: rank-one snapshot set, pod_n = 4 gives N = 1 with a "
                 "warning; empty cone", "study_column.nml", "pod_n = 4, cone_compare = .true.",
                 offline_completes(rank_one), full_study=column_full, files={"positions.txt": column}))
    add(off_case("offline_pod_n_above_dofs", "refused: pod_n larger than the number of velocity dofs",
                 "study_tiny.nml", "pod_n = 100", refused(r"&pod: n = 100 is larger than the number of velocity dofs",
                                                         files=("rom.h5", "summary.json")),
                 full_study=HALL20_STUDY))
    add(off_case("offline_at_rest", "completes: zero snapshots give N = 0 (warning: empty basis), an empty "
                 "cone, PGA skipped, no 0/0 (or a clear refusal of N = 0 by a later stage)", "study_rest.nml",
                 "cone_compare = .true.",
                 completes_or_refuses(offline_completes(at_rest), r"\b0 (POD )?modes|no POD mode|all zero"),
                 full_study=dict(HALL20_STUDY, agents="n_agents = 20, radius = 0.05, speed = 0.0, seed = 20",
                                 study="n_params = 1, param_name = 'l_exit', param_min = 0.27, param_max = 0.33, "
                                       "n_train = 40, n_valid = 5, seed = 7, database = 'db.h5'")))
    add(off_case("offline_no_contact", "completes: no multiplier is ever non-zero: empty cone (said so, no "
                 "division by zero), PGA skipped", "study_sparse.nml", "cone_compare = .true.",
                 offline_completes(empty_cone), full_study=column_full, files={"positions.txt": column}))
    add(off_case("offline_no_contact_2ranks", "completes at 2 ranks (snapshots and offline): the empty "
                 "multiplier datasets are read collectively without a transfer; empty cone",
                 "study_sparse.nml", "cone_compare = .true.", offline_completes(empty_cone), full_study=column_full,
                 files={"positions.txt": column}, np=2, before=[("crowd_snapshots", 2)]))
    add(off_case("offline_pod_energy_0", "completes: every mode up to the numerical rank, retained energy 1",
                 "study_tiny.nml", "pod_energy = 0.0", offline_completes(energy0), full_study=HALL20_STUDY))
    add(off_case("offline_pod_energy_1", "completes: no POD mode (warning), the basis is made of supremizers "
                 "(or a clear refusal of N_pod = 0 by a later stage)",
                 "study_tiny.nml", "pod_energy = 1.0",
                 completes_or_refuses(offline_completes(energy1), r"\b0 (POD )?modes|no POD mode"),
                 full_study=HALL20_STUDY))
    add(off_case("offline_cone_delta_0", "completes: gIS covers every active contact, e_R = 0 exactly; mCPG "
                 "stops with a note", "study_tiny.nml", "cone_delta = 0.0, cone_compare = .true., mcpg_r_max = 60",
                 offline_completes(cone_delta0), full_study=HALL20_STUDY,
                 full_offline="cone_delta = 0.0, cone_compare = .true., cone_r_max = 2000, mcpg_r_max = 100"))
    add(off_case("offline_cone_delta_above", "completes: delta above every error keeps one cone vector (R = 1)",
                 "study_tiny.nml", "cone_delta = 10.0, cone_compare = .true.", offline_completes(cone_delta_above),
                 full_study=HALL20_STUDY))
    add(off_case("offline_pga_delta_0", "refused: pga_delta must be > 0", "study_tiny.nml", "pga_delta = 0.0",
                 refused(r"&pga: delta must be > 0", files=("rom.h5", "summary.json")), full_study=HALL20_STUDY))
    add(off_case("offline_pga_delta_tiny", "completes: PGA stops at the whole space or the round-off level "
                 "with a note (never adds noise directions), basis orthonormal", "study_tiny.nml",
                 "pga_delta = 1.0e-300, pod_n = 3", offline_completes(pga_tiny), full_study=HALL20_STUDY,
                 full_offline="pga_delta = 1.0e-300, pod_n = 5, pga_max_add = 400"))
    add(off_case("offline_pga_delta_above", "completes: delta above every error adds no supremizer",
                 "study_tiny.nml", "pga_delta = 10.0", offline_completes(pga_above), full_study=HALL20_STUDY))
    cases += online_cases()
    return cases


# ----------------------------------------------------------------------------- online (crowd_rom)

def parse_rom(r, ctx):
    if r.rc != 0 or not r.summary:
        return parse_default(r, ctx)
    s = r.summary
    if s["e_avg_max"] < 0:
        out = "completed (no full-order reference): deepest overlap %s" % fmt(s["max_overlap"])
    else:
        out = "completed: E_avg <= %s, deepest overlap %s, mobility %s..%s" % (
            fmt(s["e_avg_max"]), fmt(s["max_overlap"]), fmt(s["mobility_min"], ".2f"), fmt(s["mobility_max"], ".2f"))
    if s["infeasible_steps"]:
        out += ", %d infeasible steps" % s["infeasible_steps"]
    if s["extrapolating_samples"]:
        out += ", %d extrapolating samples (flagged)" % s["extrapolating_samples"]
    return {"outcome": out, "measure": "E_avg %s" % (fmt(s["e_avg_max"]) if s["e_avg_max"] >= 0 else "-"),
            "iterations": "capped steps %d" % s["capped_steps"], "time": r.wall}


def rom_output_ok(c, r, ctx, extra=None):
    """crowd_rom completed: result file and CSV written, no NaN/Inf, errors in [0, 2]."""
    if not check_completed(c, r):
        return
    path = os.path.join(ctx.workdir, "run.h5")
    if not c.need(os.path.exists(path), "no result file"):
        return
    c.need(os.path.exists(os.path.join(ctx.workdir, "run.csv")), "no CSV table")
    bad = nonfinite_in_h5(path)
    c.need(not bad, "NaN/Inf in the result file: %s" % bad[:5])
    with cio.open_h5(path, cio.ROMRUN_SCHEMA, "ROM run file") as f:
        for k in range(1, int(f.attrs["n_settings"]) + 1):
            for sname in f["setting_%d" % k]:
                g = f["setting_%d/%s" % (k, sname)]
                e = g["E_mu"][...]
                c.need(np.all((e == -1) | ((e >= 0) & (e <= 2))), "setting %d: E_mu out of [0, 2]: %s" % (k, e))
                c.need(np.all(g["max_overlap"][...] >= 0), "negative overlap")
        if extra is not None:
            extra(c, r, ctx, f)


def rom_case(name, expected, offline, rom, check, full_offline=None, full_rom=None, study="study_tiny.nml",
             full_study=None, **kw):
    """crowd_snapshots, crowd_offline, then crowd_rom on one input (study + &offline + &rom)."""
    off = "database = 'db.h5', rom_file = 'rom.h5', infsup_samples = 2, infsup_n = 2, infsup_r = 2, "
    ro = "rom_file = 'rom.h5', output = 'run.h5', table = 'run.csv', fom_timing_samples = 1, timing_repeats = 1, "
    groups = {"small": {"offline": off + offline, "rom": ro + rom}}
    groups["full"] = dict(full_study or {})
    groups["full"]["offline"] = off + (full_offline or offline)
    groups["full"]["rom"] = ro + (full_rom or rom)
    return Case(name, "online", expected, "crowd_rom", study, groups, check, parse=parse_rom,
                before=[("crowd_snapshots", 1), ("crowd_offline", 1)], **kw)


def online_cases():
    """The reduced model at its extremes (tiny study; the full size runs the hall20 study)."""
    cases = []
    add = cases.append

    def locking(c, r, ctx, f):
        # too many constraints on too small a velocity space: the crowd is slowed down
        mob = f["setting_1/valid/mobility"][...]
        c.need(np.all(mob >= 0), "no mobility figure")
        c.need(mob.mean() < 0.95, "no locking measured (mobility %s)" % mob)

    add(rom_case("online_locking", "completes: R >> N without supremizers; locking is measured (mobility < 1: "
                 "the reduced crowd moves less than the full-order one), never a NaN",
                 "pga = .false., pod_energy = 0.0, cone_delta = 0.0, rom_n = 1, rom_r = 9",
                 "sets = 'valid', n = 1, r = 9, hyper = 'none'",
                 lambda c, r, ctx: rom_output_ok(c, r, ctx, locking),
                 full_study=HALL20_STUDY, full_offline="pga = .false., pod_energy = 0.0, cone_delta = 0.0, "
                 "rom_n = 2, rom_r = 60", full_rom="sets = 'valid', n = 2, r = 60, hyper = 'none'"))

    def no_constraint(c, r, ctx, f):
        c.need(f["setting_1"].attrs["r"] == 0, "R is not 0")
        c.need("beta" not in f["setting_1/valid"] or f["setting_1/valid/beta"].shape[-1] == 0, "multipliers for R = 0")

    add(rom_case("online_r0", "completes: R = 0 (no constraint): the reduced velocity is the projected desired "
                 "velocity; overlaps (agents passing through each other) are reported, not hidden",
                 "pod_energy = 0.0, rom_n = 4, rom_r = 0", "sets = 'valid', n = 4, r = 0, hyper = 'eq'",
                 lambda c, r, ctx: rom_output_ok(c, r, ctx, no_constraint),
                 full_study=HALL20_STUDY, full_offline="pod_energy = 0.0, rom_n = 10, rom_r = 0",
                 full_rom="sets = 'valid', n = 10, r = 0, hyper = 'eq'"))
    add(rom_case("online_n1", "completes: N = 1 with the supremizers of R = 3 cone vectors, finite errors",
                 "pod_energy = 0.0, rom_n = 1, rom_r = 3", "sets = 'both', n = 1, 1, r = 3, 3, hyper = 'eq', 'none'",
                 lambda c, r, ctx: rom_output_ok(c, r, ctx), full_study=HALL20_STUDY))

    def extrapolates(c, r, ctx, f):
        c.need(f["setting_1/given/extrapolating"][...].tolist() == [1], "extrapolation not flagged")
        c.need("outside the training box" in r.out, "no extrapolation warning")

    add(rom_case("online_extrapolation", "completes: a parameter outside the training box runs and is flagged "
                 "as extrapolating (warning and output flag)",
                 "pod_energy = 0.0, rom_n = 4, rom_r = 3", "sets = 'given', mu = 0.3, 8*1.5, n = 4, r = 3",
                 lambda c, r, ctx: rom_output_ok(c, r, ctx, extrapolates),
                 full_study=HALL20_STUDY, full_offline="pod_energy = 1e-4, rom_n = 10, rom_r = 15",
                 full_rom="sets = 'given', mu = 0.45, 20*1.6, n = 10, r = 15"))
    add(rom_case("online_m_above_candidates", "refused: m_b larger than the EQ candidates of the pair",
                 "pod_energy = 0.0, rom_n = 4, rom_r = 3", "sets = 'valid', n = 4, r = 3, hyper = 'eq', m_b = 1000",
                 refused(r"m_b = 1000 is larger than the \d+ EQ candidates", files=("run.h5", "summary.json")),
                 full_study=HALL20_STUDY, full_offline="rom_n = 10, rom_r = 15",
                 full_rom="sets = 'valid', n = 10, r = 15, hyper = 'eq', m_b = 1000"))

    def eim_clamped(c, r, ctx, f):
        with cio.open_h5(os.path.join(ctx.workdir, "rom.h5"), cio.ROM_SCHEMA, "ROM file") as rom:
            g = rom["pairs/1/eim"]
            notes = [attr_str(g[t].attrs.get("note", b"")) for t in ("s1", "s2", "s3")]
            ms = [int(g[t].attrs["m"]) for t in ("s1", "s2", "s3")]
            ps = [int(g[t].attrs["p"]) for t in ("s1", "s2", "s3")]
        c.need(all(m <= p for m, p in zip(ms, ps)), "EIM kept more points than candidates")
        c.need(any("rank" in n for n in notes), "no note on the EIM rank clamp: %s" % notes)

    add(rom_case("online_eim_above_rank", "completes: EIM asked for more points than the numerical rank of a term "
                 "keeps the rank (note in the ROM file); the ROM runs with them",
                 "pod_energy = 0.0, rom_n = 4, rom_r = 3, hyper_m_factor = 50.0",
                 "sets = 'valid', n = 4, r = 3, hyper = 'eim'",
                 lambda c, r, ctx: rom_output_ok(c, r, ctx, eim_clamped),
                 full_study=HALL20_STUDY, full_offline="pod_energy = 1e-4, rom_n = 10, rom_r = 15, hyper_m_factor = 50.0",
                 full_rom="sets = 'valid', n = 10, r = 15, hyper = 'eim'"))
    return cases
