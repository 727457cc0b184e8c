#!/usr/bin/env python3
"""Summarise valgrind memcheck XML logs: the errors raised in crowdrom's own code.

    memcheck_report.py ROOT LOG.xml [LOG.xml ...]

An error is *ours* when, walking its stack from the innermost frame outwards, a frame whose
source file belongs to ROOT's src/, drivers/ or tests/ comes before any frame in the MPI stack
(Open MPI, PMIx, hwloc, libevent, UCX): a read of uninitialised memory inside our code, or a
value of ours handed to a library (a BLAS/LAPACK/HDF5 call, a write) with undefined bytes.
An error whose stack reaches our code only through an MPI call is listed apart ("through MPI":
judge by hand; Open MPI's own start-up and transports are noisy), and an error with no frame of
ours is only counted. Each error of ours is printed with its frames of ours and the origin of
the undefined value (--track-origins=yes). Exit status: 1 if any error of ours, else 0; 2 on an
unreadable log. A log left open (a forked child's copy, cut at its exec) is read up to its end.
Uses the Python standard library only.
"""
import os
import re
import sys
import xml.etree.ElementTree as ET

MPI_OBJ = re.compile(r"(libmpi|libopen-(pal|rte)|mca_|libpmix|libhwloc|libevent|libucp|libucs|libuct|"
                     r"libfabric|libpsm|openmpi)")


def our_sources(root):
    """basenames of our Fortran/C sources (gfortran records the basename in the debug info)"""
    names = set()
    for sub in ("src", "drivers", "tests"):
        for d, _, files in os.walk(os.path.join(root, sub)):
            for f in files:
                if f.endswith((".f90", ".F90", ".c", ".h")):
                    names.add(f)
    return names


def frames(stack):
    out = []
    if stack is None:
        return out
    for fr in stack.findall("frame"):
        out.append({"fn": fr.findtext("fn", "?"), "file": fr.findtext("file"), "line": fr.findtext("line"),
                    "obj": fr.findtext("obj", "")})
    return out


def fmt(fr):
    where = f"{fr['file']}:{fr['line']}" if fr["file"] else os.path.basename(fr["obj"] or "?")
    return f"{fr['fn']} ({where})"


def classify(stack, ours):
    for fr in stack:
        if fr["file"] in ours:
            return "ours"
        if MPI_OBJ.search(fr["obj"] or ""):
            return "mpi" if any(f["file"] in ours for f in stack) else "foreign"
    return "foreign"


def main():
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    ours = our_sources(sys.argv[1])
    n = {"ours": 0, "mpi": 0, "foreign": 0}
    seen = set()
    status = 0
    for path in sys.argv[2:]:
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                text = f.read()
        except OSError as e:
            print(f"memcheck: cannot read {path}: {e}")
            status = 2
            continue
        try:
            root = ET.fromstring(text)
        except ET.ParseError:
            # a log left open: the program forked a child that then ran another program (the
            # child's copy of the log stops at its exec), or valgrind was killed
            try:
                root = ET.fromstring(text + "\n</valgrindoutput>\n")
            except ET.ParseError as e:
                print(f"memcheck: cannot parse {path}: {e}")
                status = 2
                continue
        argv = " ".join(x.text or "" for x in root.findall("./args/argv/*"))
        for err in root.findall("error"):
            kind = err.findtext("kind", "?")
            if kind.startswith("Leak"):
                continue
            what = err.findtext("what") or err.findtext("xwhat/text") or kind
            stack = frames(err.find("stack"))
            cls = classify(stack, ours)
            n[cls] += 1
            if cls == "foreign":
                continue
            mine = [fr for fr in stack if fr["file"] in ours]
            key = (kind, tuple(fmt(fr) for fr in mine[:3]))
            if key in seen:
                continue
            seen.add(key)
            tag = "ERROR" if cls == "ours" else "through MPI (check by hand)"
            print(f"memcheck: {tag}: {kind}: {what}")
            print(f"  in: {argv}")
            for fr in mine[:6]:
                print(f"  at {fmt(fr)}")
            if stack and stack[0]["file"] not in ours:
                print(f"  (innermost: {fmt(stack[0])})")
            stacks = err.findall("stack")
            if len(stacks) > 1:
                aux = err.findtext("auxwhat", "origin")
                print(f"  {aux}:")
                for fr in frames(stacks[1])[:4]:
                    print(f"    {fmt(fr)}")
    print(f"memcheck: {n['ours']} error(s) in our code, {n['mpi']} through MPI, "
          f"{n['foreign']} in libraries only ({len(sys.argv) - 2} log(s))")
    if n["ours"]:
        return 1
    return status


if __name__ == "__main__":
    sys.exit(main())
