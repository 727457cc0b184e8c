#!/usr/bin/env python3
"""The namelist groups and variables the code reads, from its own `namelist /group/ ...`
statements, and their check against the input reference (docs/input-reference.md).

    input_reference.py [--root DIR]                       print every group, its variables and file
    input_reference.py --check docs/input-reference.md    exit 1 listing every difference
    input_reference.py --skeleton GROUP                   the reference's table of a group, to fill in

The source of truth is the Fortran: every `namelist /group/ var, var, &` statement of
src/**/*.f90 (continuation lines and comments handled). The reference documents a group under a
heading naming it (`### `&group``) with one table row per variable whose first cell is the
variable in backticks. `--check` reports a group or a variable the code reads that the reference
does not list under that group, and one the reference lists that the code does not read.
Exit status: 0, 1 when the reference differs, 2 for bad input (one 'input_reference: error:' line).
"""
import argparse
import glob
import os
import re
import sys

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from crowdrom_io import EXIT_BAD_INPUT  # noqa: E402

PROG = "input_reference"
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_NAMELIST = re.compile(r"^\s*namelist\s*/\s*(\w+)\s*/\s*(.*)$", re.IGNORECASE)
_HEADING = re.compile(r"^#{2,4}\s+`&(\w+)`\s*$")
_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|")


def _strip_comment(line):
    """A Fortran source line without its trailing comment (no '!' inside strings here)."""
    return line.split("!", 1)[0]


def code_groups(root=ROOT):
    """{group: (variables in order, source file relative to root)} from src/**/*.f90."""
    groups = {}
    for path in sorted(glob.glob(os.path.join(root, "src", "**", "*.f90"), recursive=True)):
        lines = open(path, encoding="utf-8").read().split("\n")
        i = 0
        while i < len(lines):
            m = _NAMELIST.match(_strip_comment(lines[i]))
            i += 1
            if not m:
                continue
            group, text = m.group(1).lower(), m.group(2).strip()
            while text.endswith("&") and i < len(lines):
                text = text[:-1] + " " + _strip_comment(lines[i]).strip().lstrip("&")
                i += 1
            names = [v.strip().lower() for v in text.split(",") if v.strip()]
            rel = os.path.relpath(path, root)
            if group in groups and groups[group][0] != names:
                raise ValueError(f"namelist /{group}/ declared differently in {groups[group][1]} and {rel}")
            groups[group] = (names, rel)
    return groups


def doc_groups(path):
    """{group: [variables]} documented in the input reference (Markdown)."""
    groups, current, fence = {}, None, False
    for line in open(path, encoding="utf-8"):
        if line.startswith("```"):
            fence = not fence
            continue
        if fence:
            continue
        h = _HEADING.match(line)
        if h:
            current = h.group(1).lower()
            groups.setdefault(current, [])
            continue
        if line.startswith("#"):
            current = None
            continue
        r = _ROW.match(line)
        if current and r and r.group(1) != "variable":
            groups[current].append(r.group(1).lower())
    return groups


def differences(doc_path, root=ROOT):
    """Every difference between the code's namelists and the reference, as sentences."""
    code, doc = code_groups(root), doc_groups(doc_path)
    out = []
    for g, (names, src) in sorted(code.items()):
        if g not in doc:
            out.append(f"&{g} ({src}) is not documented (no heading `&{g}`)")
            continue
        out += [f"&{g}: {v} ({src}) is not documented" for v in names if v not in doc[g]]
        out += [f"&{g}: {v} is documented but the code does not read it" for v in doc[g] if v not in names]
        dup = sorted({v for v in doc[g] if doc[g].count(v) > 1})
        out += [f"&{g}: {v} is documented twice" for v in dup]
    out += [f"&{g} is documented but no namelist statement declares it" for g in sorted(doc) if g not in code]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(prog="input_reference.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", default=ROOT, help="repository root (default: this script's)")
    ap.add_argument("--check", metavar="MARKDOWN", help="compare with this input reference")
    ap.add_argument("--skeleton", metavar="GROUP", help="print the Markdown table of GROUP to fill in")
    args = ap.parse_args(argv)
    try:
        if args.skeleton:
            groups = code_groups(args.root)
            g = args.skeleton.lstrip("&").lower()
            if g not in groups:
                raise ValueError(f"no namelist group &{g} in the code (groups: {', '.join(sorted(groups))})")
            names, src = groups[g]
            print(f"### `&{g}`\n\nRead from {src}.\n")
            print("| variable | default | unit | valid range | meaning |\n|---|---|---|---|---|")
            for v in names:
                print(f"| `{v}` | | | | |")
            return 0
        if args.check:
            if not os.path.isfile(args.check):
                raise ValueError(f"input reference not found: '{args.check}'")
            diff = differences(args.check, args.root)
            for d in diff:
                print(d)
            print(f"{PROG}: {len(diff)} difference(s) between the code's namelists and {args.check}")
            return 1 if diff else 0
        for g, (names, src) in sorted(code_groups(args.root).items()):
            print(f"&{g} ({src}): {', '.join(names)}")
        return 0
    except ValueError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
