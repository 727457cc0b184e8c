#!/usr/bin/env python3
"""Numerical stability at the extremes (docs/testing.md): run the campaign and write its table.

  .venv/bin/python scripts/dev/extremes_report.py [--out results/extremes.md] [--bin build/bin]
        [--size full|small] [--cases NAME ...] [--workdir DIR]
  .venv/bin/python scripts/dev/extremes_report.py --check NAME --bin build-debug/bin --workdir DIR
  .venv/bin/python scripts/dev/extremes_report.py --list

Default: every case of scripts/dev/extremes_cases.py at full size on the Release build
(bigger scenes: the 150-agent congested scene, 1000+ agents near the densest packing, a
40-sample study), one Markdown row per case (case, stage, expected, outcome, KKT residual or
error, iterations, time, check) on stdout and in --out. Exit status 1 if a check failed.

--check NAME runs one case at small size and asserts its expectations (what ctest's label
`extremes` runs, tests/extremes/extremes.cmake); the last line is "1 passed, 0 failed" or the reverse.
"""
import argparse
import os
import sys
import tempfile

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from crowdrom_io import EXIT_BAD_INPUT  # noqa: E402
from extremes_cases import ROOT, all_cases, run_case  # noqa: E402


def table(rows):
    head = "| case | stage | expected | outcome | KKT residual / error | iterations | time (s) | check |\n" \
           "|---|---|---|---|---|---|---:|---|\n"
    body = ""
    for case, row, failures in rows:
        verdict = "ok" if not failures else "FAILED: " + "; ".join(failures)
        cells = [case.name, case.stage, case.expected, row["outcome"], row["measure"], row["iterations"],
                 "%.2f" % row["time"], verdict]
        body += "| " + " | ".join(str(c).replace("|", "\\|").replace("\n", " ") for c in cells) + " |\n"
    return head + body


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", metavar="NAME", help="run one case at small size and assert its expectations")
    ap.add_argument("--bin", default=None, help="directory of the programs (default build/bin, with --check "
                                                 "build-debug/bin)")
    ap.add_argument("--size", choices=["small", "full"], default=None)
    ap.add_argument("--cases", nargs="*", default=None, help="only these cases")
    ap.add_argument("--workdir", default=None, help="where the cases run (default: a temporary directory)")
    ap.add_argument("--out", default=None, help="also write the Markdown table here")
    ap.add_argument("--list", action="store_true", help="print 'name;ranks' of every case (for CMake)")
    a = ap.parse_args()
    cases = {c.name: c for c in all_cases()}
    if a.list:
        for c in cases.values():
            print("%s;%d" % (c.name, max([c.np] + [np_ for _, np_ in c.before])))
        return 0

    if a.check:
        if a.check not in cases:
            print("unknown case '%s'; known: %s" % (a.check, ", ".join(cases)))
            return EXIT_BAD_INPUT
        bin_dir = os.path.abspath(a.bin or os.path.join(ROOT, "build-debug", "bin"))
        work = a.workdir or tempfile.mkdtemp(prefix="extremes_")
        r, failures, row = run_case(cases[a.check], bin_dir, work, a.size or "small")
        print(r.out[-3000:])
        print("outcome: %s | %s | iterations %s | %.2f s" % (row["outcome"], row["measure"], row["iterations"],
                                                             row["time"]))
        for f in failures:
            print("FAIL: " + f)
        print("0 passed, 1 failed" if failures else "1 passed, 0 failed")
        return 1 if failures else 0

    bin_dir = os.path.abspath(a.bin or os.path.join(ROOT, "build", "bin"))
    size = a.size or "full"
    work = a.workdir or tempfile.mkdtemp(prefix="extremes_")
    names = a.cases or list(cases)
    rows = []
    for name in names:
        print("running %s (%s) ..." % (name, size), file=sys.stderr, flush=True)
        r, failures, row = run_case(cases[name], bin_dir, work, size)
        rows.append((cases[name], row, failures))
        print("   %s; %s; %.2f s; %s" % (row["outcome"], row["measure"], row["time"],
                                         "ok" if not failures else "FAILED: " + "; ".join(failures)),
              file=sys.stderr, flush=True)
    md = table(rows)
    print(md)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        with open(a.out, "w") as f:
            f.write(md)
    return 1 if any(f for _, _, f in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
