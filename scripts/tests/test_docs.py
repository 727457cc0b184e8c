"""The documentation cannot drift from the code or point nowhere:
- every relative link of README.md and docs/*.md resolves (the file, and for a link with an
  #anchor the heading it names), and so does every `docs/...` reference in the README, the docs
  pages and the comments of src/, drivers/, scripts/, tests/ and inputs/;
- every namelist variable the code reads (the `namelist /group/ ...` statements of src/**/*.f90)
  is listed in docs/input-reference.md under its group, and nothing else is (the check of
  scripts/dev/input_reference.py; scripts/dev/nml_groups.py's map agrees with the same statements:
  scripts/tests/test_agreement.py);
- the project speaks of itself only: no word about how it was developed in the README, the docs,
  the sources, the scripts, the tests or the inputs.
"""
import glob
import os
import re
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
ROOT = os.path.dirname(SCRIPTS)
sys.path.insert(0, SCRIPTS)
import input_reference  # noqa: E402

#: pages other parts of the project write; a link to one of them is accepted while the page does
#: not exist yet, and checked like any other once it does (remove a name when its page is in)
PENDING = set()

DOCS = sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))
PAGES = [os.path.join(ROOT, "README.md")] + DOCS
#: files whose text may cite docs pages (comments, help texts, docstrings)
SOURCE_GLOBS = ["src/**/*.f90", "src/**/*.c", "drivers/**/*.f90", "scripts/**/*.py", "scripts/**/*.sh",
                "tests/**/*.f90", "tests/**/*.cmake", "tests/**/*.sh", "tests/**/*.py", "tests/CMakeLists.txt",
                "inputs/*.nml", "inputs/*.json", "CMakeLists.txt"]
SOURCES = sorted({p for g in SOURCE_GLOBS for p in glob.glob(os.path.join(ROOT, g), recursive=True)})

_LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_DOCREF = re.compile(r"(?<![\w./-])(docs/[\w./-]*\w)(#[\w-]+)?")
# the words of a development history, assembled so that this file does not match itself
_ORDINALS = "second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth"
HISTORY = re.compile(r"\b(" + "sess" + r"ions?|iss" + r"ues? \d+|(?:" + _ORDINALS + r") pa" + r"ss|\d+(?:st|nd|rd|th) pa"
                     + r"ss|work peri" + r"ods?|new " + r"in v?\d)\b", re.IGNORECASE)


def rel(path):
    return os.path.relpath(path, ROOT)


def slug(heading):
    """The anchor GitHub gives a Markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def anchors(path):
    """Every anchor of a Markdown file (its headings outside code blocks; duplicates get -1, -2)."""
    seen, out, fence = {}, set(), False
    for line in open(path, encoding="utf-8"):
        if line.startswith("```"):
            fence = not fence
            continue
        m = None if fence else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            base = slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def check_target(target, base_dir):
    """None if ``target`` (a relative path with an optional #anchor) resolves from ``base_dir``,
    else what is wrong."""
    path, _, anchor = target.partition("#")
    full = os.path.normpath(os.path.join(base_dir, path)) if path else None
    if full is not None and not os.path.exists(full):
        if rel(full) in PENDING:
            return None
        return f"no file '{rel(full)}'"
    if anchor and (full is None or full.endswith(".md")):
        if anchor not in anchors(full):
            return f"no heading for #{anchor} in '{rel(full)}'"
    return None


def code_free_text(path):
    """The text of a Markdown file without its fenced code blocks (links in examples are not links)."""
    out, fence = [], False
    for line in open(path, encoding="utf-8"):
        if line.startswith("```"):
            fence = not fence
            continue
        out.append("" if fence else line)
    return "".join(out)


def test_pages_exist_and_stay_short():
    names = {os.path.basename(p) for p in DOCS}
    for page in ("user-guide.md", "input-reference.md", "file-formats.md", "model.md", "results.md",
                 "benchmarks.md", "testing.md", "design.md"):
        assert page in names, page
    assert sum(1 for _ in open(os.path.join(ROOT, "README.md"))) <= 400
    for p in DOCS:
        assert sum(1 for _ in open(p, encoding="utf-8")) < 800, rel(p)


@pytest.mark.parametrize("page", PAGES, ids=rel)
def test_every_relative_link_resolves(page):
    bad = []
    for target in _LINK.findall(code_free_text(page)):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):          # http:, https:, mailto: ...
            continue
        if target.startswith("#"):
            problem = None if target[1:] in anchors(page) else f"no heading for {target}"
        else:
            problem = check_target(target, os.path.dirname(page))
        if problem:
            bad.append(f"({target}): {problem}")
    assert not bad, f"{rel(page)}: " + "; ".join(bad)


def test_every_docs_reference_resolves():
    bad = []
    for path in PAGES + SOURCES:
        text = open(path, encoding="utf-8", errors="replace").read()
        for ref, anchor in _DOCREF.findall(text):
            problem = check_target(ref + anchor, ROOT)
            if problem:
                bad.append(f"{rel(path)}: {ref}{anchor}: {problem}")
    assert not bad, "\n".join(bad)


def test_input_reference_lists_every_namelist_variable():
    code = input_reference.code_groups(ROOT)
    assert len(code) >= 20 and "scene" in code and "n_agents" in code["agents"][0]
    diff = input_reference.differences(os.path.join(ROOT, "docs", "input-reference.md"), ROOT)
    assert not diff, "\n".join(diff)


def test_input_reference_check_sees_a_missing_variable(tmp_path):
    """The check itself: a reference without one variable, or with one the code does not read,
    is reported."""
    text = open(os.path.join(ROOT, "docs", "input-reference.md"), encoding="utf-8").read()
    row = next(ln for ln in text.splitlines() if ln.startswith("| `cutoff_factor` |"))
    bad = tmp_path / "ref.md"
    bad.write_text(text.replace(row + "\n", "").replace("| `every` |", "| `everyother` |"))
    diff = input_reference.differences(str(bad), ROOT)
    assert "&contacts: cutoff_factor (src/config/cr_config.f90) is not documented" in diff
    assert "&output: every (src/config/cr_config.f90) is not documented" in diff
    assert "&output: everyother is documented but the code does not read it" in diff


def test_no_development_history():
    bad = []
    here = os.path.abspath(__file__)
    for path in PAGES + SOURCES:
        if os.path.abspath(path) == here:
            continue
        for i, line in enumerate(open(path, encoding="utf-8", errors="replace"), start=1):
            m = HISTORY.search(line)
            if m:
                bad.append(f"{rel(path)}:{i}: '{m.group(0)}'")
    # sources cite the docs pages, not the README's former sections
    for path in SOURCES:
        if os.path.abspath(path) == here:
            continue
        for i, line in enumerate(open(path, encoding="utf-8", errors="replace"), start=1):
            if re.search(r"README(?!\.md)", line):
                bad.append(f"{rel(path)}:{i}: README section reference")
    assert not bad, "\n".join(bad)
