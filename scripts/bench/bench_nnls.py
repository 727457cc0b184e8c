#!/usr/bin/env python3
"""Time per call of crowdrom's nnls_solve against SciPy's NNLS on small dense problems.

Usage: scripts/bench/bench_nnls.py [--bin build/bin/crowd_nnlsbench] [--baseline OTHER_BIN] [--rounds 3]
                             [--seconds 0.2] [--seed 1]

The problems are seeded random: A standard normal [m, n], b standard normal (about half of
the columns active at the optimum), at the sizes of the online reduced problems (the LDP of
a reduced step is an NNLS of size (N + 1) x R: (5, 10), (10, 15), (39, 65) on hall20) and a
few square and tall ones. Both solvers see the same data; crowd_nnlsbench times nnls_solve
in Fortran (one reusable work space, as the online model calls it), this script times
scipy.optimize.nnls from Python (timeit, best of 5 runs). Each binary runs --rounds times,
interleaved, and the best time per problem is kept (the machine may be shared). Prints a
Markdown table with the ratio SciPy / crowdrom per size and its geometric mean, and checks the
residuals agree. --baseline times a second build of crowd_nnlsbench (e.g. of an older commit)
on the same problems, for before/after comparisons. --callgrind (with --baseline) instead
counts the instructions per solve of both builds under valgrind's callgrind (11 solves per
problem, start-up subtracted): a comparison that the load of a shared machine does not blur.
"""
import argparse
import os
import struct
import subprocess
import sys
import tempfile
import timeit

SIZES = [(6, 10), (11, 15), (20, 20), (40, 65), (30, 20), (60, 40)]


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=os.path.join(root, "build", "bin", "crowd_nnlsbench"))
    ap.add_argument("--baseline", help="a second crowd_nnlsbench to compare with (before/after)")
    ap.add_argument("--callgrind", action="store_true", help="instructions per solve (valgrind) instead of times")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved runs of each binary (best kept)")
    ap.add_argument("--seconds", type=float, default=0.2, help="minimum timing per problem and solver")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--per-size", type=int, default=3, help="problems per size")
    args = ap.parse_args()
    try:
        import numpy as np
        import scipy
        from scipy.optimize import nnls
    except ImportError as e:
        sys.exit("error: bench_nnls.py: %s (run scripts/setup.sh)" % e)
    if not os.access(args.bin, os.X_OK):
        sys.exit("error: bench_nnls.py: %s is not an executable (build first: scripts/setup.sh)" % args.bin)
    rng = np.random.default_rng(args.seed)
    probs = []
    for m, n in SIZES:
        for _ in range(args.per_size):
            probs.append((rng.standard_normal((m, n)), rng.standard_normal(m)))
    if args.callgrind:
        return callgrind(args, probs, np)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "problems.bin")
        write_problems(path, probs, np)
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        bins = [args.bin] + ([args.baseline] if args.baseline else [])
        best = {b: None for b in bins}
        for _ in range(max(args.rounds, 1)):
            for b in bins:
                out = subprocess.run([b, path, str(args.seconds)], capture_output=True, text=True, env=env)
                if out.returncode != 0:
                    sys.exit("error: bench_nnls.py: %s failed: %s" % (b, out.stderr.strip().splitlines()[-1:]))
                lines = [line.split() for line in out.stdout.strip().splitlines()]
                if best[b] is None:
                    best[b] = lines
                else:
                    for old, new in zip(best[b], lines):
                        old[3] = str(min(float(old[3]), float(new[3])))
    ours = best[args.bin]
    base = best[args.baseline] if args.baseline else ours
    rows = {}
    worst_res = 0.0
    for (a, b), line, bline in zip(probs, ours, base):
        t_ours, res_ours, conv = float(line[3]), float(line[4]), int(line[5])
        timer = timeit.Timer(lambda: nnls(a, b))
        number, _ = timer.autorange()
        number = max(number, int(number * args.seconds / 0.2))
        t_scipy = min(timer.repeat(5, number)) / number * 1e6
        x, res_scipy = nnls(a, b)
        worst_res = max(worst_res, (res_ours - res_scipy) / max(np.linalg.norm(b), 1e-300))
        rows.setdefault(a.shape, []).append((t_ours, t_scipy, conv, float(bline[3])))
    print("SciPy %s, numpy %s; times in microseconds per call (mean over a size's %d problems)"
          % (scipy.__version__, np.__version__, args.per_size))
    print()
    if args.baseline:
        print("| m x n | crowdrom nnls_solve | baseline | scipy.optimize.nnls | ratio SciPy / crowdrom |")
        print("|---|---:|---:|---:|---:|")
    else:
        print("| m x n | crowdrom nnls_solve | scipy.optimize.nnls | ratio SciPy / crowdrom |")
        print("|---|---:|---:|---:|")
    logs, blogs = [], []
    for (m, n), r in rows.items():
        to = sum(x[0] for x in r) / len(r)
        ts = sum(x[1] for x in r) / len(r)
        tb = sum(x[3] for x in r) / len(r)
        logs.append(np.log(ts / to))
        blogs.append(np.log(tb / to))
        if args.baseline:
            print("| %d x %d | %.2f | %.2f | %.2f | %.1fx |" % (m, n, to, tb, ts, ts / to))
        else:
            print("| %d x %d | %.2f | %.2f | %.1fx |" % (m, n, to, ts, ts / to))
    print()
    print("geometric mean ratio (SciPy / crowdrom): %.2fx" % float(np.exp(np.mean(logs))))
    if args.baseline:
        print("geometric mean ratio (baseline / crowdrom): %.2fx" % float(np.exp(np.mean(blogs))))
    print("all converged: %s; largest (residual_crowdrom - residual_scipy) / |b|: %.1e"
          % (all(x[2] == 1 for r in rows.values() for x in r), worst_res))


def write_problems(path, probs, np):
    with open(path, "wb") as f:
        f.write(struct.pack("<i", len(probs)))
        for a, b in probs:
            f.write(struct.pack("<ii", *a.shape))
            f.write(np.asfortranarray(a).tobytes(order="F"))
            f.write(b.astype("<f8").tobytes())


def callgrind(args, probs, np):
    """Instructions per solve of --bin and --baseline, per size, under valgrind's callgrind."""
    import re
    import shutil
    if not args.baseline or not shutil.which("valgrind"):
        sys.exit("error: bench_nnls.py: --callgrind needs --baseline and valgrind on PATH")
    bins = [args.bin, args.baseline]

    def count(b, path):
        out = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", b, path, "1e-9"],
                             capture_output=True, text=True)
        m = re.search(r"Collected : (\d+)", out.stderr)
        if out.returncode != 0 or not m:
            sys.exit("error: bench_nnls.py: valgrind %s failed: %s" % (b, out.stderr.strip().splitlines()[-1:]))
        return int(m.group(1))

    sizes = []
    for a, _ in probs:
        if a.shape not in sizes:
            sizes.append(a.shape)
    print("instructions per solve (valgrind callgrind, 11 solves per problem, start-up subtracted)")
    print()
    print("| m x n | crowdrom nnls_solve | baseline | change |")
    print("|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        empty = os.path.join(tmp, "empty.bin")
        write_problems(empty, [], np)
        start = {b: count(b, empty) for b in bins}
        for shape in sizes:
            sub = [p for p in probs if p[0].shape == shape]
            path = os.path.join(tmp, "p.bin")
            write_problems(path, sub, np)
            per = {b: (count(b, path) - start[b]) / (11.0 * len(sub)) for b in bins}
            print("| %d x %d | %.0f | %.0f | %+.1f%% |" % (shape[0], shape[1], per[args.bin], per[args.baseline],
                                                     100.0 * (per[args.bin] / per[args.baseline] - 1)))


if __name__ == "__main__":
    main()
