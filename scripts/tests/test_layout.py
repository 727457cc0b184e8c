"""The folders of src/ form a layered architecture (docs/design.md#layers): LAYERS declares
their order from the bottom; a module may use modules of its own folder and of folders in
lower layers only, never of a folder in the same or a higher layer. Every module lives in
exactly one file, the HDF5 library is called through src/io/cr_h5file.f90 (HDF5_USERS), and
there is no folder-level import circle."""
import collections
import glob
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

#: the layers of src/, bottom first; folders of one layer do not use each other
LAYERS = [
    ["core"],
    ["io"],
    ["geometry"],
    ["config"],
    ["model"],
    ["parallel"],
    ["linalg"],
    ["solvers"],
    ["hyper"],
    ["products"],
    ["fom"],
    ["study", "offline"],
    ["rom"],
    ["predict"],
    ["app"],
]

#: the files that use the HDF5 library's own modules: the file handle, and the pedestrian
#: trajectory file, whose compound records (PedPy's layout) the handle does not offer
HDF5_USERS = {"src/io/cr_h5file.f90", "src/products/cr_pdda_file.f90"}

MODULE_RE = re.compile(r"^\s*module\s+(\w+)\s*(?:!.*)?$", re.M | re.I)
USE_RE = re.compile(r"^\s*use\s*(?:,\s*(?:non_)?intrinsic\s*::\s*|::\s*)?(\w+)", re.M | re.I)


def sources(root=ROOT):
    """{path relative to root: text} of every Fortran file under src/<folder>/."""
    return {os.path.relpath(f, root): open(f).read()
            for f in sorted(glob.glob(os.path.join(root, "src", "*", "*.f90")))}


def module_folders(files):
    """{module name: folder} of the modules the files define (each defined once)."""
    mod_dir = {}
    for path, text in files.items():
        for m in MODULE_RE.findall(text):
            assert m.lower() not in mod_dir, f"module {m} defined twice ({path})"
            mod_dir[m.lower()] = path.split(os.sep)[1]
    return mod_dir


def uses(files):
    """(path, folder, module used) for every `use` of a module."""
    for path, text in files.items():
        for m in USE_RE.findall(text):
            yield path, path.split(os.sep)[1], m.lower()


def layer_violations(files, layers=LAYERS):
    """Messages, one per `use` of a module of a folder not in a lower layer than the user's
    (or of a folder no layer declares)."""
    level = {d: k for k, group in enumerate(layers) for d in group}
    mod_dir = module_folders(files)
    found = []
    for path, d, m in uses(files):
        t = mod_dir.get(m)
        if t is None or t == d:
            continue
        if d not in level or t not in level:
            missing = d if d not in level else t
            found.append(f"{path}: folder src/{missing} is in no layer of LAYERS")
        elif level[t] >= level[d]:
            where = "a higher layer than" if level[t] > level[d] else "the same layer as"
            found.append(f"{path}: uses {m} of src/{t}, {where} src/{d}")
    return sorted(set(found))


def hdf5_violations(files, allowed=HDF5_USERS):
    """Messages, one per file outside `allowed` that uses the HDF5 library's modules."""
    return sorted(f"{path}: uses {m} (HDF5 goes through src/io/cr_h5file.f90)"
                  for path, _, m in uses(files)
                  if (m == "hdf5" or m.startswith("h5")) and path.replace(os.sep, "/") not in allowed)


def folder_uses(files=None):
    files = sources() if files is None else files
    mod_dir, graph = module_folders(files), collections.defaultdict(set)
    for _, d, m in uses(files):
        t = mod_dir.get(m)
        if t is not None and t != d:
            graph[d].add(t)
    return graph


def circles(graph):
    """Folders that reach themselves through the uses graph {folder: {folders it uses}}."""
    def reach(a):
        seen, todo = set(), [a]
        while todo:
            for y in graph.get(todo.pop(), ()):
                if y not in seen:
                    seen.add(y)
                    todo.append(y)
        return seen

    return sorted(d for d in list(graph) if d in reach(d))


def test_every_folder_in_a_layer():
    folders = {p.split(os.sep)[1] for p in sources()}
    declared = {d for group in LAYERS for d in group}
    assert folders == declared, f"folders of src/ without a layer: {sorted(folders - declared)}; " \
        f"layers without a folder: {sorted(declared - folders)}"


def test_layer_order():
    found = layer_violations(sources())
    assert not found, "uses against the layer order (docs/design.md#layers):\n" + "\n".join(found)


def test_hdf5_through_h5file():
    found = hdf5_violations(sources())
    assert not found, "\n".join(found)


def test_no_folder_import_circle():
    graph = folder_uses()
    assert len(graph) >= 10, "fewer folders with modules under src/ than expected"
    found = circles(graph)
    assert not found, f"folder-level import circle through {found}: {dict(graph)}"


def test_layer_check_finds_an_upward_use():
    files = {
        os.path.join("src", "core", "a.f90"): "module a\nend module a\n",
        os.path.join("src", "io", "b.f90"): "module b\n  use a, only: x\nend module b\n",
        os.path.join("src", "core", "c.f90"): "module c\n  use b\nend module c\n",
        os.path.join("src", "io", "d.f90"): "module d\n  use, intrinsic :: iso_fortran_env\n  use b\nend module d\n",
    }
    assert layer_violations(files) == [os.path.join("src", "core", "c.f90") + ": uses b of src/io, a higher layer "
                                       "than src/core"]
    same = {os.path.join("src", "study", "s.f90"): "module s\nend module s\n",
            os.path.join("src", "offline", "o.f90"): "module o\n  use s\nend module o\n"}
    assert layer_violations(same) == [os.path.join("src", "offline", "o.f90") + ": uses s of src/study, "
                                      "the same layer as src/offline"]
    assert hdf5_violations({os.path.join("src", "study", "r.f90"): "module r\n  use hdf5, only: h5open_f\n"}) \
        == [os.path.join("src", "study", "r.f90") + ": uses hdf5 (HDF5 goes through src/io/cr_h5file.f90)"]


def test_circle_detection_finds_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c"]
    assert circles({"a": {"b"}, "b": set()}) == []
