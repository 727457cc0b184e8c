#!/usr/bin/env python3
"""Calibration and validation of crowd_fom's flows against the published experimental ranges
and against JuPedSim's collision-free speed model on the same scenes (docs/calibration.md).

Parts (any subset, in this order):
  bottleneck   specific flow against exit width (0.8 to 3 m) in a bottleneck scene
  corridor     the fundamental diagram (speed against density) measured in a corridor
  crowd1000    the calibrated crowd1000 scene from the same start as JuPedSim: t50, t90, flows
               and CPU per simulated second, measured back to back
  convergence  t50, t90 and the exit flows of the calibrated crowd1000 scene at h, h/2, h/4
  cpu          CPU per simulated second over the first 20 s of crowd1000, crowd_fom calibrated
               and JuPedSim, back to back
  variants     the calibration table: specific flow of each behaviour variant (social distance,
               diagram, look-ahead, kernel width) on the bottleneck scene at w = 1.2 m

Each part writes <out>/<part>.json and a figure <out>/calibration_<part>.png. JuPedSim is an
OPTIONAL dependency (scripts/requirements-validation.txt): without it the script says so and
measures crowd_fom alone (--no-jupedsim does the same on purpose).

Quantities of interest: crowd_fom's are read from the group `qoi` of its output (the one
definition, src/model/cr_qoi.f90, computed from every step's positions; docs/queries.md), read
through crowdrom_io. JuPedSim's, from its exit curves (agents counted when its exit stages remove
them), follow the same definitions in `qois_of_curves`: specific flow of an exit = least-squares
slope of its cumulative count against time between the frames at which it first reaches 10% and
80% of its final count, divided by its width; t_p = first frame time at which ceil(p n / 100)
agents are out (censored at the horizon).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FOM = os.path.join(ROOT, "build", "bin", "crowd_fom")

# experimental range of the specific flow through wide bottlenecks (Seyfried et al. 2009,
# Kretz et al. 2006, Liao et al. 2014) [1/(m s)]
EXP_FLOW = (1.3, 2.0)
# Weidmann (1993): free speed [m/s], gamma [1/m2], jam density [1/m2]
WEIDMANN = (1.34, 1.913, 5.4)

# the calibrated behaviour (inputs/crowd1000_calibrated.nml; docs/calibration.md)
CALIBRATED = {"social_distance": 0.1, "speed_model": "weidmann", "density_sigma": 0.7, "look_ahead": 1.0}
PAPER = {"social_distance": 0.0, "speed_model": "constant", "density_sigma": 0.7}


# JuPedSim's obstacles: every HOLE_STRIDE-th vertex of crowd_fom's 32-gons (--jps-hole-stride)
HOLE_STRIDE = 1


class MissingOptional(Exception):
    """An optional dependency of the validation is not installed."""


# ------------------------------------------------------------------------------ scenes

def scene_text(sc):
    """&scene and &obstacles of a scene dict (L, W, t, l_exit, exit_center[, l_exit2,
    exit2_center][, disks: [(x, y, r)]])."""
    s = ("&scene hall_length = %r, hall_width = %r, l_exit = %r, exit_center = %r, wall_thickness = %r"
         % (sc["L"], sc["W"], sc["l_exit"], sc["exit_center"], sc["t"]))
    if sc.get("l_exit2", 0) > 0:
        s += ", l_exit2 = %r, exit2_center = %r" % (sc["l_exit2"], sc["exit2_center"])
    s += " /\n"
    disks = sc.get("disks", [])
    if disks:
        s += "&obstacles n_disks = %d, disk_x = %s, disk_y = %s, disk_r = %s /\n" % (
            len(disks), ", ".join(repr(d[0]) for d in disks), ", ".join(repr(d[1]) for d in disks),
            ", ".join(repr(d[2]) for d in disks))
    return s


def exits_of(sc):
    """[(width, axis, inner face)] of every exit: axis 1 = y (top wall), 0 = x (right wall)."""
    ex = [(sc["l_exit"], 1, sc["W"])]
    if sc.get("l_exit2", 0) > 0:
        ex.append((sc["l_exit2"], 0, sc["L"]))
    return ex


def behaviour_text(model):
    """The behaviour variables of &agents and &desired for a model dict."""
    a = ", social_distance = %r" % model["social_distance"] if model["social_distance"] > 0 else ""
    d = ""
    if model["speed_model"] != "constant":
        d = "&desired speed_model = '%s', density_sigma = %r, density_anisotropy = %r /\n" % (
            model["speed_model"], model["density_sigma"], model.get("look_ahead", 0.0))
    return a, d


def run_fom(text, workdir, tag, pdda=True, fom=None):
    """crowd_fom on namelist `text` (its &output is added); returns positions [T, N, 2], frame
    times [T], radius, dt, the run's QoIs (its group `qoi`, crowdrom_io.read_qoi_group), the
    PDDA file and the run's wall seconds."""
    import h5py
    out = os.path.join(workdir, tag + ".h5")
    pd = os.path.join(workdir, tag + "_pdda.h5")
    nml = os.path.join(workdir, tag + ".nml")
    with open(nml, "w") as f:
        f.write(text + "&output file = '%s', store_multipliers = .false., log_level = 'warn'%s /\n"
                % (out, ", pdda_file = '%s'" % pd if pdda else ""))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    p = subprocess.Popen([fom or FOM, nml], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env, text=True)
    log, _ = p.communicate()
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError("crowd_fom failed on %s:\n%s" % (nml, log))
    with h5py.File(out, "r") as f:
        pos = np.asarray(f["traj/positions"], dtype=float)
        res = {"time": np.asarray(f["traj/time"], dtype=float).ravel(),
               "radius": float(f.attrs["agent_radius"]), "dt": float(f.attrs["dt"]),
               "n_agents": int(f.attrs["n_agents"]), "speed": np.asarray(f["agents/speed"], dtype=float),
               "q0": np.asarray(f["agents/initial_positions"], dtype=float).reshape(-1, 2),
               "qoi": cio.read_qoi_group(f, "qoi")}
    res["pos"] = pos.reshape(pos.shape[0], -1, 2)
    res["pdda"] = pd if pdda else None
    res["wall"] = wall
    return res


def run_fom_timed(text, workdir, tag, fom=None, pdda=False):
    """run_fom plus the child's CPU seconds (user + sys) from the resource usage."""
    before = os.times()
    r = run_fom(text, workdir, tag, pdda=pdda, fom=fom)
    after = os.times()
    r["cpu"] = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return r


# ------------------------------------------------------------------------------ QoIs

def ceil_pct(p, n):
    """ceil(p n / 100) in integers (no rounding of p n / 100 in floating point)."""
    return -(-int(p) * int(n) // 100)


def flow_rate(curve, times):
    """Least-squares slope of a cumulative count between the frames at which it first reaches
    10% and 80% of its final count [1/s]; None when fewer than 3 frames or nobody out."""
    final = int(curve[-1])
    if final <= 0:
        return None
    i10 = int(np.argmax(curve >= ceil_pct(10, final)))
    i80 = int(np.argmax(curve >= ceil_pct(80, final)))
    if i80 - i10 + 1 < 3:
        return None
    t = times[i10:i80 + 1]
    c = curve[i10:i80 + 1].astype(float)
    return float(np.polyfit(t, c, 1)[0])


def t_percent(total, times, p, n_agents):
    """(first frame time at which ceil(p n / 100) agents are out, censored)."""
    hit = np.nonzero(total >= ceil_pct(p, n_agents))[0]
    if hit.size == 0:
        return float(times[-1]), True
    return float(times[hit[0]]), False


def exit_boxes(sc, depth=1.0):
    """The area in front of each exit: the opening's width, `depth` m deep into the hall, as
    coordinate lists (the measurement areas of the density at the exits)."""
    boxes = []
    for (w, axis, face) in exits_of(sc):
        c = sc["exit_center"] if axis == 1 else sc["exit2_center"]
        if axis == 1:
            boxes.append([(c - w / 2, face - depth), (c + w / 2, face - depth), (c + w / 2, face), (c - w / 2, face)])
        else:
            boxes.append([(face - depth, c - w / 2), (face, c - w / 2), (face, c + w / 2), (face - depth, c + w / 2)])
    return boxes


def exit_densities(pos, sc, radius, depth=1.0):
    """Classic density in front of each exit at each frame [T, n_exits]: agents whose centre is
    in the exit's box (exit_boxes) divided by its area [1/m2]."""
    out = np.zeros((pos.shape[0], len(exits_of(sc))))
    for e, b in enumerate(exit_boxes(sc, depth)):
        b = np.asarray(b)
        lo, hi = b.min(axis=0), b.max(axis=0)
        m = ((pos[:, :, 0] >= lo[0]) & (pos[:, :, 0] <= hi[0]) & (pos[:, :, 1] >= lo[1]) & (pos[:, :, 1] <= hi[1]))
        out[:, e] = m.sum(axis=1) / float(np.prod(hi - lo))
    return out


def fom_qois(r):
    """t50, t90, t100 (with censoring), the steady and specific flow of each exit (None where
    not defined) and the agents out at the end, from crowd_fom's QoI group of run_fom's result."""
    g = r["qoi"]
    q = {}
    for k, p in enumerate((50, 90, 100)):
        q["t%d" % p], q["t%d_censored" % p] = float(g["t_evac"][0, k]), bool(g["censored"][0, k])
    ok = g["flow_defined"][0]
    q["flow_rate"] = [float(x) if d else None for x, d in zip(g["flow_rate"][0], ok)]
    q["flow"] = [float(x) if d else None for x, d in zip(g["flow"][0], ok)]
    q["out"] = int(g["curve_total"][0, -1])
    return q


def qois_of_curves(curves, times, sc, n_agents):
    """JuPedSim's t50, t90, t100 (with censoring) and the specific flow of each exit from its
    exit curves [T, n_exits] at the frame times [T] (the definitions of fom_qois')."""
    total = curves.sum(axis=1)
    q = {}
    for p in (50, 90, 100):
        q["t%d" % p], q["t%d_censored" % p] = t_percent(total, times, p, n_agents)
    q["flow"], q["flow_rate"] = [], []
    for e, (w, _, _) in enumerate(exits_of(sc)):
        r = flow_rate(curves[:, e], times)
        q["flow_rate"].append(r)
        q["flow"].append(None if r is None else r / w)
    q["out"] = int(total[-1])
    return q


# ------------------------------------------------------------------------------ JuPedSim

def need_jupedsim():
    try:
        import jupedsim  # noqa: F401
        import shapely  # noqa: F401
    except ImportError as e:
        raise MissingOptional("jupedsim is not installed (optional: pip install -r "
                              "scripts/requirements-validation.txt); measuring crowd_fom alone (%s)" % e)


def exit_polygons(sc, radius):
    """The part of each exit's outside strip beyond its 'has left' line (JuPedSim removes an
    agent there, where crowd_fom counts it out), as coordinate lists."""
    polys = []
    L, W, t = sc["L"], sc["W"], sc["t"]
    for (w, axis, face) in exits_of(sc):
        if axis == 1:
            c = sc["exit_center"]
            wd = max(0.0, min(1.0, c - w / 2 + t, L + t - (c + w / 2)))
            y0 = W + t + radius
            polys.append([(c - w / 2 - wd, y0), (c + w / 2 + wd, y0), (c + w / 2 + wd, W + t + 2.0),
                          (c - w / 2 - wd, W + t + 2.0)])
        else:
            c = sc["exit2_center"]
            wd = max(0.0, min(1.0, c - w / 2 + t, W + t - (c + w / 2)))
            x0 = L + t + radius
            polys.append([(x0, c - w / 2 - wd), (L + t + 2.0, c - w / 2 - wd), (L + t + 2.0, c + w / 2 + wd),
                          (x0, c + w / 2 + wd)])
    return polys


def nearest_exit(sc, radius, p):
    """Index of the exit whose narrowed opening is nearest in a straight line."""
    best, arg = None, 0
    for e, (w, axis, face) in enumerate(exits_of(sc)):
        c = sc["exit_center"] if axis == 1 else sc["exit2_center"]
        lo, hi = c - w / 2 + radius, c + w / 2 - radius
        if axis == 1:
            d = math.hypot(min(max(p[0], lo), hi) - p[0], face - p[1])
        else:
            d = math.hypot(face - p[0], min(max(p[1], lo), hi) - p[1])
        if best is None or d < best:
            best, arg = d, e
    return arg


def run_jupedsim(sc, wkt, q0, radius, speeds, t_max, dt=0.01, frame_dt=0.1, sample=False):
    """JuPedSim's collision-free speed model (default parameters, time gap 1 s) on the walkable
    area `wkt` from positions q0 [N, 2]: exit curves at frames every frame_dt [T, n_exits], the
    frame times, the CPU seconds of the iterations and, with `sample`, the agents' positions
    at every frame after the first ({id: (x, y)} per frame)."""
    need_jupedsim()
    import jupedsim as jps
    if HOLE_STRIDE > 1:
        # coarser obstacle polygons (every k-th vertex of each hole: JuPedSim's cost per
        # iteration grows with the vertices)
        import shapely
        poly = shapely.from_wkt(wkt)
        wkt = shapely.Polygon(poly.exterior.coords,
                              [list(r.coords)[:-1][::HOLE_STRIDE] for r in poly.interiors]).wkt
    sim = jps.Simulation(model=jps.CollisionFreeSpeedModel(), geometry=wkt, dt=dt)
    journeys = []
    for poly in exit_polygons(sc, radius):
        st = sim.add_exit_stage(poly)
        journeys.append((sim.add_journey(jps.JourneyDescription([st])), st))
    exit_of = {}
    for i, p in enumerate(q0):
        e = nearest_exit(sc, radius, p)
        j, st = journeys[e]
        aid = sim.add_agent(jps.CollisionFreeSpeedModelAgentParameters(
            position=(float(p[0]), float(p[1])), journey_id=j, stage_id=st, desired_speed=float(speeds[i]),
            radius=radius))
        exit_of[aid] = e
    every = int(round(frame_dt / dt))
    n_frames = int(round(t_max / frame_dt)) + 1
    curves = np.zeros((n_frames, len(journeys)), dtype=int)
    out = np.zeros(len(journeys), dtype=int)
    samples = []
    cpu = 0.0
    for k in range(1, n_frames):
        c0 = time.process_time()
        for _ in range(every):
            sim.iterate()
            for aid in sim.removed_agents():
                out[exit_of[aid]] += 1
        cpu += time.process_time() - c0
        curves[k] = out
        if sample:
            samples.append({a.id: a.position for a in sim.agents()})
        if sim.agent_count() == 0:
            curves[k + 1:] = out
            break
    times = frame_dt * np.arange(n_frames)
    return {"curves": curves, "time": times, "cpu": cpu, "samples": samples, "t_end": sim.elapsed_time()}


# ------------------------------------------------------------------------------ parts

def model_text(model, sc, n, speed, dt, radius=0.2, region=None, seed=1, init_file=None, until_empty=True,
               max_steps=200000, n_steps=None):
    a, d = behaviour_text(model)
    s = scene_text(sc)
    if init_file:
        s += "&agents n_agents = %d, radius = %r, speed = %r, init = 'file', init_file = '%s'%s /\n" % (
            n, radius, speed, init_file, a)
    else:
        s += "&agents n_agents = %d, radius = %r, speed = %r, seed = %d, region = %s%s /\n" % (
            n, radius, speed, seed, ", ".join(repr(x) for x in region), a)
    s += d
    if n_steps is None:
        s += "&time dt = %r, until_empty = .true., max_steps = %d /\n" % (dt, max_steps)
    else:
        s += "&time dt = %r, n_steps = %d /\n" % (dt, n_steps)
    s += "&solver name = 'sparse_active_set', tol = 1.0e-10 /\n"
    return s


def bottleneck_scene(w):
    """An 8 m x 8 m room with one exit of width w centred in the top wall (0.3 m thick)."""
    return {"L": 8.0, "W": 8.0, "t": 0.3, "l_exit": w, "exit_center": 4.0}


def part_bottleneck(args, work):
    widths = [0.8, 1.2, 1.6, 2.0, 2.5, 3.0] if not args.quick else [1.2, 2.4]
    n, v0 = args.bottleneck_agents, WEIDMANN[0]
    region = (0.3, 0.3, 7.7, 6.5)
    rows = []
    for w in widths:
        sc = bottleneck_scene(w)
        row = {"width": w}
        for name, model in (("calibrated", CALIBRATED), ("paper", PAPER)):
            if name not in args.models.split(",") and name != "calibrated":
                continue
            r = run_fom_timed(model_text(model, sc, n, v0, args.dt, region=region, seed=7,
                                         max_steps=int(round(args.t_max_bottleneck / args.dt))), work,
                              "bn_%s_%g" % (name, w), pdda=False)
            q = fom_qois(r)
            row[name] = q
            if name == "calibrated":
                q0, rad = r["q0"], r["radius"]
                wkt = walkable_wkt_of(sc, work, "bn_%g" % w)
        if args.jupedsim:
            j = run_jupedsim(sc, wkt, q0, rad, np.full(n, v0), t_max=args.t_max_bottleneck)
            row["jupedsim"] = qois_of_curves(j["curves"], j["time"], sc, n)
        rows.append(row)
        log("bottleneck w = %.1f m: specific flow calibrated %s, paper %s, JuPedSim %s" % (
            w, fmt(row["calibrated"]["flow"][0]), fmt(row["paper"]["flow"][0]),
            fmt(row.get("jupedsim", {}).get("flow", [None])[0])))
    return {"agents": n, "free_speed": v0, "dt": args.dt, "rows": rows}


def part_variants(args, work):
    """The calibration table: the specific flow of each behaviour variant on the bottleneck
    scene at w = 1.2 m (the scene, start and step of part_bottleneck)."""
    w, n, v0 = 1.2, args.bottleneck_agents, WEIDMANN[0]
    sc = bottleneck_scene(w)
    weid = {"speed_model": "weidmann", "density_sigma": 0.7}
    variants = [("paper model", PAPER),
                ("d_s = 0.1 m only", dict(PAPER, social_distance=0.1)),
                ("Weidmann only (isotropic, sigma 0.7)", dict(weid, social_distance=0.0)),
                ("Weidmann + d_s = 0.1 m", dict(weid, social_distance=0.1)),
                ("Weidmann + d_s = 0.1 m + look-ahead 1 (chosen)", CALIBRATED),
                ("the same with sigma = 0.5 m", dict(CALIBRATED, density_sigma=0.5))]
    rows = []
    for k, (name, model) in enumerate(variants):
        r = run_fom_timed(model_text(model, sc, n, v0, args.dt, region=(0.3, 0.3, 7.7, 6.5), seed=7,
                                     max_steps=int(round(args.t_max_bottleneck / args.dt))), work,
                          "var_%d" % k, pdda=False)
        q = fom_qois(r)
        rows.append({"variant": name, "model": model, "flow": q["flow"][0], "t90": q["t90"]})
        log("variant %s: specific flow %s, t90 %s" % (name, fmt(q["flow"][0]), fmt(q["t90"])))
    return {"width": w, "agents": n, "free_speed": v0, "dt": args.dt, "rows": rows}


def walkable_wkt_of(sc, work, tag):
    """The walkable area crowd_fom writes for scene `sc` (one step of a one-agent run)."""
    import h5py
    text = scene_text(sc) + "&agents n_agents = 1, radius = 0.2, region = %r, %r, %r, %r /\n" % (
        sc["L"] / 2 - 0.3, 0.3, sc["L"] / 2 + 0.3, 0.9) + "&time dt = 0.1, n_steps = 1 /\n"
    r = run_fom(text, work, "wkt_" + tag, pdda=True)
    with h5py.File(r["pdda"], "r") as f:
        w = f.attrs["wkt_geometry"]
    return w.decode() if isinstance(w, bytes) else str(w)


def corridor_scene():
    """A corridor 4 m wide and 40 m long (the hall), open at its far end (3.6 m exit)."""
    return {"L": 4.0, "W": 40.0, "t": 0.3, "l_exit": 3.6, "exit_center": 2.0}


def part_corridor(args, work):
    """Crowds of uniform initial density in the first 24 m of the corridor walk towards its
    end; density and mean speed in the measurement area [0.4, 3.6] x [10, 14] m over 2-6 s."""
    densities = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0] if not args.quick else [1.0, 3.0]
    sc = corridor_scene()
    region = (0.2, 0.2, 3.8, 24.0)
    area = (3.6 * 23.8)
    box = (0.4, 3.6, 10.0, 14.0)
    box_area = (box[1] - box[0]) * (box[3] - box[2])
    v0 = WEIDMANN[0]
    t_window = (2.0, 6.0)

    rows = []
    for rho in densities:
        n = int(round(rho * area))
        row = {"density0": rho, "agents": n}
        for name, model in (("calibrated", CALIBRATED), ("paper", PAPER)):
            steps = int(round(t_window[1] / args.dt))
            r = run_fom_timed(model_text(model, sc, n, v0, args.dt, region=region, seed=11, until_empty=False,
                                         n_steps=steps), work, "cor_%s_%g" % (name, rho), pdda=False)
            pos, tt = r["pos"], r["time"]
            vel = np.diff(pos, axis=0) / r["dt"]
            dens, spd = [], []
            for k in range(1, len(tt)):
                if t_window[0] <= tt[k] <= t_window[1]:
                    p = pos[k]
                    m = (p[:, 0] >= box[0]) & (p[:, 0] <= box[1]) & (p[:, 1] >= box[2]) & (p[:, 1] <= box[3])
                    dens.append(m.sum() / box_area)
                    spd.append(np.linalg.norm(vel[k - 1][m], axis=1).mean() if m.any() else np.nan)
            row[name] = {"density": float(np.mean(dens)), "speed": float(np.nanmean(spd))}
            if name == "calibrated":
                q0, rad = r["q0"], r["radius"]
        if args.jupedsim:
            wkt = walkable_wkt_of(sc, work, "corridor")
            j = run_jupedsim(sc, wkt, q0, rad, np.full(n, v0), t_max=t_window[1], sample=True)
            dens, spd = [], []
            fdt = j["time"][1]
            for k in range(1, len(j["samples"])):
                t = (k + 1) * fdt
                if not (t_window[0] <= t <= t_window[1]):
                    continue
                prev, cur = j["samples"][k - 1], j["samples"][k]
                inb = [i for i, p in cur.items() if box[0] <= p[0] <= box[1] and box[2] <= p[1] <= box[3]]
                dens.append(len(inb) / box_area)
                v = [math.hypot(cur[i][0] - prev[i][0], cur[i][1] - prev[i][1]) / fdt for i in inb if i in prev]
                spd.append(np.mean(v) if v else np.nan)
            row["jupedsim"] = {"density": float(np.mean(dens)), "speed": float(np.nanmean(spd))}
        rows.append(row)
        log("corridor rho0 = %.1f: calibrated rho %.2f v %.2f; paper rho %.2f v %.2f; JuPedSim %s" % (
            rho, row["calibrated"]["density"], row["calibrated"]["speed"], row["paper"]["density"],
            row["paper"]["speed"], "rho %.2f v %.2f" % (row["jupedsim"]["density"], row["jupedsim"]["speed"])
            if "jupedsim" in row else "-"))
    return {"box": box, "window": t_window, "free_speed": v0, "dt": args.dt, "rows": rows}


def crowd1000_scene():
    return {"L": 20.0, "W": 14.0, "t": 0.3, "l_exit": 2.4, "exit_center": 14.0, "l_exit2": 2.4,
            "exit2_center": 5.0, "disks": [(12.0, 10.0, 0.5), (17.0, 6.0, 0.5)]}


def crowd1000_text(dt, model, until_empty=True, max_steps=200000):
    """crowd1000 at the study's reference parameters (inputs/crowd1000_study.nml), the
    behaviour of `model`, step dt, until everybody is out."""
    a, d = behaviour_text(model)
    s = scene_text(crowd1000_scene())
    s += "&agents n_agents = 1000, radius = 0.2, speed = 1.2, seed = 1000%s /\n" % a + d
    s += "&time dt = %r, until_empty = .true., max_steps = %d /\n" % (dt, max_steps)
    s += "&solver name = 'sparse_active_set', tol = 1.0e-10 /\n"
    return s


def part_crowd1000(args, work):
    sc = crowd1000_scene()
    res = {}
    for name, model in (("calibrated", CALIBRATED), ("paper", PAPER)):
        if name not in args.models.split(","):
            continue
        r = run_fom_timed(crowd1000_text(args.h1000, model), work, "c1000_" + name, pdda=(name == "calibrated"))
        q = fom_qois(r)
        q["cpu"] = r["cpu"]
        q["cpu_per_s"] = r["cpu"] / r["time"][-1]
        q["dt"] = args.h1000
        res[name] = q
        log("crowd1000 %s h = %g: t50 %.1f t90 %.1f flows %s, CPU %.1f s (%.3f per simulated s)" % (
            name, args.h1000, q["t50"], q["t90"], [fmt(x) for x in q["flow"]], q["cpu"], q["cpu_per_s"]))
        if name == "calibrated":
            q0, rad, speeds, pdda = r["q0"], r["radius"], r["speed"], r["pdda"]
    if args.jupedsim:
        import h5py
        with h5py.File(pdda, "r") as f:
            w = f.attrs["wkt_geometry"]
        wkt = w.decode() if isinstance(w, bytes) else str(w)
        j = run_jupedsim(sc, wkt, q0, rad, speeds, t_max=args.t_max_1000, dt=args.jps_dt)
        q = qois_of_curves(j["curves"], j["time"], sc, len(q0))
        q["cpu"] = j["cpu"]
        q["cpu_per_s"] = j["cpu"] / j["t_end"]
        q["dt"] = args.jps_dt
        q["hole_stride"] = HOLE_STRIDE
        res["jupedsim"] = q
        log("crowd1000 JuPedSim CFSM dt = %g: t50 %.1f t90 %.1f flows %s, CPU %.1f s (%.3f per simulated s)" % (
            args.jps_dt, q["t50"], q["t90"], [fmt(x) for x in q["flow"]], q["cpu"], q["cpu_per_s"]))
    return res


def part_cpu(args, work):
    """CPU per simulated second over the first `cpu_window` seconds of crowd1000 (nearly all
    agents inside for both models), crowd_fom calibrated at its default step and JuPedSim's
    collision-free speed model at its default dt = 0.01 s, measured back to back."""
    sc = crowd1000_scene()
    T = args.cpu_window
    res = {"window": T}
    text = crowd1000_text(args.h1000, CALIBRATED).replace(
        "until_empty = .true., max_steps = 200000", "n_steps = %d" % int(round(T / args.h1000)))
    r = run_fom_timed(text, work, "cpu_fom", pdda=True)
    res["crowd_fom"] = {"cpu": r["cpu"], "cpu_per_s": r["cpu"] / T, "dt": args.h1000,
                        "inside_at_end": int(r["n_agents"] - fom_qois(r)["out"])}
    log("CPU crowd_fom calibrated h = %g over %g s: %.1f s (%.3f per simulated s)" % (
        args.h1000, T, r["cpu"], r["cpu"] / T))
    if args.jupedsim:
        import h5py
        with h5py.File(r["pdda"], "r") as f:
            w = f.attrs["wkt_geometry"]
        wkt = w.decode() if isinstance(w, bytes) else str(w)
        j = run_jupedsim(sc, wkt, r["q0"], r["radius"], r["speed"], t_max=T)
        res["jupedsim"] = {"cpu": j["cpu"], "cpu_per_s": j["cpu"] / T, "dt": 0.01,
                           "inside_at_end": int(len(r["q0"]) - j["curves"][-1].sum())}
        res["ratio"] = res["jupedsim"]["cpu_per_s"] / res["crowd_fom"]["cpu_per_s"]
        log("CPU JuPedSim CFSM dt = 0.01 over %g s: %.1f s (%.3f per simulated s); ratio %.1f" % (
            T, j["cpu"], j["cpu"] / T, res["ratio"]))
    return res


def part_convergence(args, work):
    rows = []
    for h in args.steps:
        r = run_fom_timed(crowd1000_text(h, CALIBRATED), work, "conv_%g" % h)
        q = fom_qois(r)
        q["dt"] = h
        q["cpu"] = r["cpu"]
        rows.append(q)
        log("convergence h = %g: t50 %.2f t90 %.2f flows %s CPU %.0f s" % (h, q["t50"], q["t90"],
                                                                          [fmt(x) for x in q["flow"]], q["cpu"]))
    for a, b in zip(rows[:-1], rows[1:]):
        ch = {"t50": rel(a["t50"], b["t50"]), "t90": rel(a["t90"], b["t90"]),
              "flow": [rel(x, y) for x, y in zip(a["flow"], b["flow"])]}
        a["change_when_halved"] = ch
    return {"rows": rows}


def rel(a, b):
    if a is None or b is None or b == 0:
        return None
    return abs(a - b) / abs(b)


def fmt(x):
    return "-" if x is None else "%.2f" % x


def log(msg):
    print(msg, flush=True)


# ------------------------------------------------------------------------------ figures

def figures(results, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    if "bottleneck" in results:
        rows = results["bottleneck"]["rows"]
        fig, ax = plt.subplots(figsize=(6, 4))
        w = [r["width"] for r in rows]
        ax.axhspan(*EXP_FLOW, color="0.85", label="experiments (Seyfried 2009, Kretz 2006, Liao 2014)")
        for key, style, lab in (("calibrated", "o-", "crowd_fom calibrated"), ("paper", "s--", "crowd_fom paper model"),
                                ("jupedsim", "^-", "JuPedSim CFSM")):
            if all(key in r for r in rows):
                ax.plot(w, [r[key]["flow"][0] or np.nan for r in rows], style, label=lab)
        ax.set_xlabel("exit width [m]")
        ax.set_ylabel("specific flow [1/(m s)]")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(os.path.join(out, "calibration_bottleneck.png"), dpi=110)
        plt.close(fig)
    if "corridor" in results:
        rows = results["corridor"]["rows"]
        fig, ax = plt.subplots(figsize=(6, 4))
        rho = np.linspace(0.2, 5.4, 200)
        v0, g, rm = WEIDMANN
        ax.plot(rho, v0 * (1 - np.exp(-g * (1 / rho - 1 / rm))), "k-", label="Weidmann 1993")
        for key, style, lab in (("calibrated", "o", "crowd_fom calibrated"), ("paper", "s", "crowd_fom paper model"),
                                ("jupedsim", "^", "JuPedSim CFSM")):
            if all(key in r for r in rows):
                ax.plot([r[key]["density"] for r in rows], [r[key]["speed"] for r in rows], style, label=lab)
        ax.set_xlabel("density [1/m2]")
        ax.set_ylabel("speed [m/s]")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(os.path.join(out, "calibration_corridor.png"), dpi=110)
        plt.close(fig)


def main(argv=None):
    global FOM, HOLE_STRIDE
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("parts", nargs="*", default=["bottleneck", "corridor", "crowd1000", "convergence"])
    ap.add_argument("--out", default=os.path.join(ROOT, "results", "calibration"))
    ap.add_argument("--fom", default=FOM)
    ap.add_argument("--no-jupedsim", dest="jupedsim", action="store_false")
    ap.add_argument("--quick", action="store_true", help="two widths and two densities")
    ap.add_argument("--dt", type=float, default=0.05, help="crowd_fom step of the bottleneck and corridor")
    ap.add_argument("--h1000", type=float, default=0.05, help="crowd_fom step of crowd1000")
    ap.add_argument("--steps", type=float, nargs="+", default=[0.1, 0.05, 0.025], help="convergence steps")
    ap.add_argument("--bottleneck-agents", type=int, default=150)
    ap.add_argument("--t-max-bottleneck", type=float, default=200.0)
    ap.add_argument("--t-max-1000", type=float, default=400.0)
    ap.add_argument("--jps-hole-stride", type=int, default=1,
                    help="JuPedSim obstacles: every k-th vertex of the 32-gons (2: 16-gons)")
    ap.add_argument("--jps-dt", type=float, default=0.01,
                    help="JuPedSim's step in the crowd1000 part (its default 0.01 s; the cpu part always uses 0.01)")
    ap.add_argument("--cpu-window", type=float, default=20.0, help="simulated seconds of the CPU comparison")
    ap.add_argument("--models", default="calibrated,paper", help="crowd_fom models of crowd1000 and bottleneck")
    args = ap.parse_args(argv)
    FOM = args.fom
    HOLE_STRIDE = args.jps_hole_stride
    if args.jupedsim:
        try:
            need_jupedsim()
        except MissingOptional as e:
            log("note: " + str(e))
            args.jupedsim = False
    os.makedirs(args.out, exist_ok=True)
    results = {}
    with tempfile.TemporaryDirectory() as work:
        for part in args.parts:
            fn = {"bottleneck": part_bottleneck, "corridor": part_corridor, "crowd1000": part_crowd1000,
                  "convergence": part_convergence, "cpu": part_cpu, "variants": part_variants}.get(part)
            if fn is None:
                ap.error("unknown part '%s'" % part)
            results[part] = fn(args, work)
            with open(os.path.join(args.out, part + ".json"), "w") as f:
                json.dump(results[part], f, indent=1)
    figures(results, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
