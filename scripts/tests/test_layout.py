"""The folders of src/ form a layered architecture: no folder-level import circle (a module of
folder A using a module of folder B while some module of B reaches A again), and every module
lives in exactly one file (docs/design.md#layers)."""
import collections
import glob
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def folder_uses():
    mod_dir, uses = {}, collections.defaultdict(set)
    files = glob.glob(os.path.join(ROOT, "src", "*", "*.f90"))
    for f in files:
        d = os.path.basename(os.path.dirname(f))
        for m in re.findall(r"^\s*module\s+(\w+)\s*$", open(f).read(), re.M | re.I):
            assert m.lower() not in mod_dir, f"module {m} defined twice"
            mod_dir[m.lower()] = d
    for f in files:
        d = os.path.basename(os.path.dirname(f))
        for m in re.findall(r"^\s*use\s+(\w+)", open(f).read(), re.M | re.I):
            t = mod_dir.get(m.lower())
            if t is not None and t != d:
                uses[d].add(t)
    return uses


def circles(uses):
    """Folders that reach themselves through the uses graph {folder: {folders it uses}}."""
    def reach(a):
        seen, todo = set(), [a]
        while todo:
            for y in uses.get(todo.pop(), ()):
                if y not in seen:
                    seen.add(y)
                    todo.append(y)
        return seen

    return sorted(d for d in list(uses) if d in reach(d))


def test_no_folder_import_circle():
    uses = folder_uses()
    assert len(uses) >= 10, "fewer folders with modules under src/ than expected"
    found = circles(uses)
    assert not found, f"folder-level import circle through {found}: {dict(uses)}"


def test_circle_detection_finds_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c"]
    assert circles({"a": {"b"}, "b": set()}) == []
