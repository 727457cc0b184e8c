#!/usr/bin/env python3
"""Compare two crowd_offline ROM files (or any two HDF5 files) entry by entry.

    scripts/dev/rom_diff.py A.h5 B.h5 [--ignore-attr NAME ...]

Every dataset and attribute present in either file is compared: bitwise equal, or the largest
absolute and relative difference (relative to the largest magnitude in A), or a shape/type/
presence mismatch. Timing attributes (`timing/*`, `time_*`) and the configuration echo
(`config`, which names the input and ROM files) are listed as ignored, not compared.
Exit status 0 when every compared entry is bitwise equal, 1 otherwise.
"""
import argparse
import sys

import h5py
import numpy as np

IGNORED_ATTRS = {"config"}


def ignored(path, name, extra):
    return (name in IGNORED_ATTRS or name in extra or name.startswith("time")
            or path.rstrip("/").endswith("timing"))


def collect(f):
    """{(kind, path, name): value} for every dataset ('d') and attribute ('a')."""
    out = {}

    def visit(path, obj):
        for k, v in obj.attrs.items():
            out[("a", "/" + path, k)] = v
        if isinstance(obj, h5py.Dataset):
            out[("d", "/" + path, "")] = obj[()]

    for k, v in f.attrs.items():
        out[("a", "/", k)] = v
    f.visititems(visit)
    return out


def compare(a, b):
    """(equal, description) of two values."""
    if isinstance(a, (bytes, str)) or isinstance(b, (bytes, str)):
        return a == b, "" if a == b else "%r != %r" % (a, b)
    x = np.asarray(a)
    y = np.asarray(b)
    if x.shape != y.shape:
        return False, "shape %s != %s" % (x.shape, y.shape)
    if x.dtype.kind not in "fiub" or y.dtype.kind not in "fiub":
        eq = bool(np.all(x == y))
        return eq, "" if eq else "differs"
    if x.size == 0 or np.array_equal(x, y):
        return True, ""
    d = np.abs(x.astype(np.float64) - y.astype(np.float64))
    scale = max(float(np.max(np.abs(x))), np.finfo(float).tiny)
    i = np.unravel_index(np.argmax(d), d.shape) if d.ndim else ()
    return False, "max |diff| %.3e (%.3e of max |A| = %.3e) at %s: %r vs %r; %d of %d entries differ" % (
        float(np.max(d)), float(np.max(d)) / scale, scale, tuple(int(k) for k in i), x[i] if d.ndim else x,
        y[i] if d.ndim else y, int(np.count_nonzero(d)), d.size)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--ignore-attr", action="append", default=[], help="attribute name not compared")
    args = ap.parse_args()
    with h5py.File(args.a, "r") as fa, h5py.File(args.b, "r") as fb:
        ea, eb = collect(fa), collect(fb)
    n_equal = 0
    n_diff = 0
    skipped = []
    for key in sorted(set(ea) | set(eb)):
        kind, path, name = key
        label = path if kind == "d" else "%s@%s" % (path, name)
        if kind == "a" and ignored(path, name, args.ignore_attr):
            skipped.append(label)
            continue
        if key not in ea or key not in eb:
            print("only in %s: %s" % (args.a if key in ea else args.b, label))
            n_diff += 1
            continue
        eq, why = compare(ea[key], eb[key])
        if eq:
            n_equal += 1
        else:
            n_diff += 1
            print("%s: %s" % (label, why))
    print("rom_diff: %d entries bitwise equal, %d differ, %d ignored (timings, config echo)" % (
        n_equal, n_diff, len(skipped)))
    return 0 if n_diff == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
