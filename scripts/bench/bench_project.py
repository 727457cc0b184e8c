#!/usr/bin/env python3
"""Benchmark of the exact position projection (crowd_project) on ML-like positions of the
crowd1000 scene, without the crowd1000 pipeline.

1. A one-sample snapshot database of the crowd1000 scene (inputs/crowd1000_study.nml without
   its &study and later groups, a one-sample &study) is made once by crowd_snapshots in the
   work directory (about 15-40 s of CPU; reused when present).
2. Its full-order trajectory is perturbed the way an ML regression of the positions errs: a
   smooth displacement field (a few Fourier modes in space, slowly drifting in time, amplitude
   --smooth, a few agent radii) plus a per-agent error that is smooth in time (AR(1), standard
   deviation --noise); every configuration after the first overlaps (in the jams by up to a
   diameter).
3. The first --configs configurations are projected as ml_correct.py does (one request through
   crowdrom_io.run_projection: the first configuration on its own, each later one from the
   projection of the one before; --refine projections of refinement, default 0 as ml_correct.py)
   and the figures printed: time per configuration and per query, solves, iterations, free set,
   depth before / deepest overlap after, KKT residual.

    .venv/bin/python scripts/bench/bench_project.py [--workdir build/bench_project] [--configs 300]
        [--steps 300] [--smooth 0.3] [--noise 0.05] [--seed 1] [--refine 0] [--exe build/bin/crowd_project]

The request file stays in the work directory (projection_request.h5), so a profile is one more
command: valgrind --tool=callgrind build/bin/crowd_project <workdir>/projection_request.h5.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path[:0] = [HERE, os.path.dirname(HERE)]  # this folder and scripts/ (crowdrom_io)
import crowdrom_io as cio  # noqa: E402


def scene_text(steps, db):
    """inputs/crowd1000_study.nml up to its &study group, n_steps = steps, and a one-sample
    &study writing `db`."""
    text = open(os.path.join(ROOT, "inputs", "crowd1000_study.nml")).read()
    text = text[:text.index("&study")]
    text = re.sub(r"n_steps\s*=\s*\d+", f"n_steps = {steps}", text)
    text = text.replace("results/crowd1000_fom.h5", os.path.join(os.path.dirname(db), "fom.h5"))
    # (about) the reference parameters of the full-order measurement of docs/results.md#crowd1000
    # (exits 2.4 m, 1.2 m/s)
    text += ("&study\n  n_params = 3, param_name = 'l_exit', 'l_exit2', 'speed', "
             "param_min = 2.4, 2.4, 1.2,\n  param_max = 2.4001, 2.4001, 1.2001, sampling = 'random', "
             f"n_train = 1, n_valid = 0, seed = 1000,\n  database = '{db}'\n/\n")
    return text


def make_database(workdir, steps, bindir):
    db = os.path.join(workdir, f"crowd1000_bench_{steps}.h5")
    if os.path.exists(db):
        return db
    exe = os.path.join(bindir, "crowd_snapshots")
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        raise cio.InputError(f"no crowd_snapshots in --bindir '{bindir}' (build first: scripts/setup.sh)")
    nml = os.path.join(workdir, f"crowd1000_bench_{steps}.nml")
    with open(nml, "w") as f:
        f.write(scene_text(steps, db))
    print(f"making the database: {exe} {nml}", flush=True)
    t0 = time.time()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    p = subprocess.run([exe, nml], cwd=workdir,
                       capture_output=True, text=True, env=env)
    if p.returncode != 0:
        last = (p.stderr.strip() or p.stdout.strip() or "(no message)").splitlines()[-1]
        raise RuntimeError(f"crowd_snapshots failed (exit status {p.returncode}): {last}")
    print(f"  done in {time.time() - t0:.1f} s", flush=True)
    return db


def perturb(q, smooth, noise, seed):
    """ML-like positions [n_conf, n_dof] from the full-order trajectory q [n_conf, n_dof]: a
    smooth field of amplitude `smooth` (6 modes per component, wavelengths 3-10 m, phases
    drifting over the trajectory) and a per-agent AR(1) error (correlation 0.95 per step) of
    standard deviation `noise`; configuration 0 is left as it is (the ROM starts exact)."""
    rng = np.random.default_rng(seed)
    n_conf, n_dof = q.shape
    n_a = n_dof // 2
    out = q.copy()
    k = rng.uniform(2 * np.pi / 10, 2 * np.pi / 3, size=(2, 6)) * rng.choice([-1, 1], size=(2, 6))
    ang = rng.uniform(0, 2 * np.pi, size=(2, 6))
    om = rng.uniform(0.5, 2.0, size=(2, 6)) * 2 * np.pi / max(n_conf, 1)
    ph = rng.uniform(0, 2 * np.pi, size=(2, 6))
    e = np.zeros((n_a, 2))
    rho = 0.95
    for c in range(1, n_conf):
        x = q[c].reshape(n_a, 2)
        d = np.zeros((n_a, 2))
        for comp in range(2):
            for m in range(6):
                kx, ky = k[comp, m] * np.cos(ang[comp, m]), k[comp, m] * np.sin(ang[comp, m])
                d[:, comp] += np.sin(kx * x[:, 0] + ky * x[:, 1] + ph[comp, m] + om[comp, m] * c)
        d *= smooth / np.sqrt(3.0)                     # rms `smooth` per component
        e = rho * e + np.sqrt(1 - rho ** 2) * rng.normal(scale=noise, size=(n_a, 2))
        out[c] = (x + d * min(1.0, c / 10) + e).ravel()
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", default=os.path.join(ROOT, "build", "bench_project"))
    ap.add_argument("--bindir", default=os.path.join(ROOT, "build", "bin"))
    ap.add_argument("--exe", default=None, help="crowd_project (default: <bindir>/crowd_project)")
    ap.add_argument("--steps", type=int, default=300, help="full-order steps of the database")
    ap.add_argument("--configs", type=int, default=300, help="configurations projected (from 0)")
    ap.add_argument("--smooth", type=float, default=0.3, help="smooth error amplitude [m]")
    ap.add_argument("--noise", type=float, default=0.05, help="per-agent error [m]")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--refine", type=int, default=0, help="refinement projections (ml_correct: 0)")
    ap.add_argument("--json", default=None, help="also write the figures as JSON")
    ap.add_argument("--per-config", action="store_true", help="print one line per configuration")
    args = ap.parse_args(argv)
    if args.configs < 1 or args.steps < 1 or args.refine < 0 or args.smooth < 0 or args.noise < 0:
        ap.error("--configs and --steps must be >= 1, --refine, --smooth and --noise >= 0")
    os.makedirs(args.workdir, exist_ok=True)
    workdir = os.path.abspath(args.workdir)
    db = make_database(workdir, args.steps, args.bindir)
    import h5py
    with h5py.File(db, "r") as f:
        tr = cio.read_database_set(f, "train", velocities=False)
    q = tr["positions"][0]                                           # [N_T + 1, n_dof]
    n_conf = min(args.configs, q.shape[0])
    qml = perturb(q[:n_conf], args.smooth, args.noise, args.seed)
    exe = args.exe or os.path.join(args.bindir, "crowd_project")
    t0 = time.time()
    r = cio.run_projection(exe, db, tr["params"][:1], qml[None], workdir, refine_max=args.refine)
    wall = time.time() - t0
    t = r["time"][0]
    fig = {
        "configurations": int(n_conf), "agents": int(q.shape[1] // 2), "smooth": args.smooth,
        "noise": args.noise, "seed": args.seed, "refine_max": args.refine,
        "with_overlap": int((r["n_overlaps"][0] > 0).sum()),
        "overlapping_pairs_mean": float(r["n_overlaps"][0].mean()),
        "depth_in_max": float(r["depth_in"][0].max()),
        "overlap_after_max": float(max(r["overlap_agents_after"].max(), r["overlap_walls_after"].max())),
        "kkt_max": float(r["kkt"][0].max()),
        "time_per_config_mean": float(t.mean()), "time_per_config_median": float(np.median(t)),
        "time_per_config_max": float(t.max()), "time_query": float(r["t_total"]),
        "wall_program": wall,
        "solves_mean": float(r["solves"][0].mean()), "iterations_mean": float(r["iterations"][0].mean()),
        "restarts_mean": float(r["restarts"][0].mean()),
        "n_free_mean": float(r["n_free"][0].mean()), "n_moved_mean": float(r["n_moved"][0].mean()),
        "refined_short": int((r["refined"][0] == 0).sum()),
        "displacement_rel": float(np.linalg.norm(r["positions"][0] - qml) / np.linalg.norm(qml - q[:n_conf])),
    }
    print(f"crowd_project on {n_conf} ML-like configurations of {fig['agents']} agents "
          f"(smooth {args.smooth} m, noise {args.noise} m, seed {args.seed}, refine {args.refine})")
    print(f"  overlapping: {fig['with_overlap']} configurations, {fig['overlapping_pairs_mean']:.0f} pairs "
          f"each on average, deepest {fig['depth_in_max']:.3f} m; after: {fig['overlap_after_max']:.1e} m, "
          f"largest KKT residual {fig['kkt_max']:.1e}")
    print(f"  time per configuration: mean {fig['time_per_config_mean']:.4f} s, median "
          f"{fig['time_per_config_median']:.4f} s, max {fig['time_per_config_max']:.4f} s; per query "
          f"(projection loop) {fig['time_query']:.2f} s, program wall {wall:.2f} s")
    print(f"  per configuration: {fig['solves_mean']:.1f} solves, {fig['iterations_mean']:.0f} solver "
          f"iterations, {fig['restarts_mean']:.1f} restarts, "
          f"{fig['n_free_mean']:.0f} agents free, {fig['n_moved_mean']:.0f} moved")
    print(f"  |q_out - q_ml| / |q_fom - q_ml| = {fig['displacement_rel']:.3f}; request: "
          f"{os.path.join(workdir, 'projection_request.h5')}")
    if args.per_config:
        print("  config  time[s]  pairs  depth_in  solves  iterations  restarts  free")
        for c in range(n_conf):
            print(f"  {c:6d} {t[c]:8.4f} {int(r['n_overlaps'][0][c]):6d} {r['depth_in'][0][c]:9.3f} "
                  f"{int(r['solves'][0][c]):7d} {int(r['iterations'][0][c]):11d} "
                  f"{int(r['restarts'][0][c]):9d} {int(r['n_free'][0][c]):5d}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(fig, f, indent=1)


if __name__ == "__main__":
    sys.exit(cio.one_line_errors("bench_project.py", main))
