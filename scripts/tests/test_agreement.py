"""The Fortran and the Python say the same about what they share; the Fortran is the source:
- the exit statuses: src/core/cr_exit_codes.f90 (EXIT_*) and crowdrom_io's EXIT_*;
- the products' schema names and versions: the `<P>_SCHEMA`, `<P>_SCHEMA_VERSION` (written) and
  `<P>_VERSIONS_READ` parameters of src/products and crowdrom_io's *_SCHEMA, SCHEMA_VERSIONS,
  SCRIPT_ONLY_VERSIONS and the versions the scripts write (ML_VERSION, PROJREQ_VERSION);
- the namelist groups: scripts/dev/nml_groups.py's maps and the `namelist /group/` statements.
Each check reads the sources at a root directory, so that the tests below also show that a
changed Fortran value is reported.
"""
import glob
import os
import re
import shutil
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPTS = os.path.dirname(HERE)
ROOT = os.path.dirname(SCRIPTS)
sys.path.insert(0, SCRIPTS)
import crowdrom_io as cio  # noqa: E402
import input_reference  # noqa: E402
import nml_groups  # noqa: E402

_INT = re.compile(r"^\s*integer\s*,\s*parameter\s*::\s*(\w+)\s*=\s*(-?\d+)\s*(?:!.*)?$", re.I | re.M)
_TEXT = re.compile(r"^\s*character\s*\(\s*len\s*=\s*\*\s*\)\s*,\s*parameter\s*::\s*(\w+)_SCHEMA\s*=\s*\"([^\"]*)\"",
                   re.I | re.M)
_LIST = re.compile(r"^\s*integer\s*,\s*parameter\s*::\s*(\w+)_VERSIONS_READ\s*\(\s*\d+\s*\)\s*=\s*\[([\d,\s]*)\]",
                   re.I | re.M)


def fortran_exit_codes(root):
    """{name: value} of src/core/cr_exit_codes.f90."""
    text = open(os.path.join(root, "src", "core", "cr_exit_codes.f90"), encoding="utf-8").read()
    return {name.upper(): int(v) for name, v in _INT.findall(text) if name.upper().startswith("EXIT_")}


def fortran_products(root):
    """{schema name: {"written": version or None, "read": [versions] or None}} of src/products."""
    out = {}
    for path in sorted(glob.glob(os.path.join(root, "src", "products", "*.f90"))):
        text = open(path, encoding="utf-8").read()
        ints = {k.upper(): int(v) for k, v in _INT.findall(text)}
        lists = {k.upper(): [int(x) for x in v.split(",") if x.strip()] for k, v in _LIST.findall(text)}
        for prefix, name in _TEXT.findall(text):
            p = prefix.upper()
            out[name] = {"written": ints.get(p + "_SCHEMA_VERSION"), "read": lists.get(p),
                         "file": os.path.relpath(path, root)}
    return out


def exit_code_differences(root, io=cio):
    fortran = fortran_exit_codes(root)
    python = {k: v for k, v in vars(io).items() if k.startswith("EXIT_")}
    diff = [f"exit status {k}: Fortran {fortran.get(k)}, crowdrom_io {python.get(k)}"
            for k in sorted(set(fortran) | set(python)) if fortran.get(k) != python.get(k)]
    return diff


def schema_differences(root, io=cio):
    """Every disagreement between src/products and crowdrom_io, one line each."""
    fortran = fortran_products(root)
    python = {v: k for k, v in vars(io).items() if k.endswith("_SCHEMA") and isinstance(v, str)}
    #: the products the scripts write, with the version they write
    script_written = {io.ML_SCHEMA: io.ML_VERSION, io.PROJREQ_SCHEMA: io.PROJREQ_VERSION}
    diff = []
    for name, f in sorted(fortran.items()):
        if name not in python:
            diff.append(f"schema '{name}' ({f['file']}) has no crowdrom_io constant")
            continue
        if f["written"] is not None and name not in io.SCHEMA_VERSIONS:
            diff.append(f"schema '{name}' is written by the programs but crowdrom_io has no reader for it")
        if name in io.SCHEMA_VERSIONS:
            fortran_set = set(f["read"] if f["read"] is not None else [f["written"]])
            want = fortran_set | set(io.SCRIPT_ONLY_VERSIONS.get(name, ()))
            got = set(io.SCHEMA_VERSIONS[name])
            if got != want:
                diff.append(f"schema '{name}': crowdrom_io reads versions {sorted(got)}, the Fortran "
                            f"({f['file']}) {sorted(fortran_set)} plus the scripts' own "
                            f"{sorted(io.SCRIPT_ONLY_VERSIONS.get(name, ()))}")
            if f["written"] is not None and f["written"] not in got:
                diff.append(f"schema '{name}': the programs write version {f['written']}, crowdrom_io "
                            f"reads {sorted(got)}")
        if name in script_written and f["read"] is not None and script_written[name] not in f["read"]:
            diff.append(f"schema '{name}': the scripts write version {script_written[name]}, the programs "
                        f"read {f['read']}")
    for name in sorted(set(python) - set(fortran)):
        if name not in script_written:
            diff.append(f"crowdrom_io's {python[name]} = '{name}' is no product of the programs or the scripts")
    return diff


def namelist_differences(root, groups=nml_groups):
    """Every flat name of nml_groups that is no variable, and every variable of a group the maps
    use that has no flat name."""
    code = input_reference.code_groups(root)
    diff = []
    for label, table in (("OFFLINE", groups.OFFLINE), ("ROM", groups.ROM), ("PREDICT", groups.PREDICT)):
        for flat, (group, var) in sorted(table.items()):
            if group not in code or var not in code[group][0]:
                diff.append(f"nml_groups.{label}['{flat}'] = &{group} {var}: no such variable in the code")
        for group in sorted({g for g, _ in table.values()} & set(code)):
            missing = [v for v in code[group][0] if (group, v) not in set(table.values())]
            if missing:
                diff.append(f"nml_groups.{label}: &{group} {', '.join(missing)} ({code[group][1]}) not mapped")
    return diff


#: a literal status where a name of cr_exit_codes belongs: an assignment or comparison of an
#: error's code, a stop code (the code argument of set_error: _set_error_code)
_LITERAL_CODE = re.compile(r"%code\s*(?:=|==|/=)\s*\d\b|\bstop\s+\d\b", re.I)


def _set_error_code(stmt):
    """The last top-level argument of a set_error call in stmt, or None."""
    m = re.search(r"\bset_error\s*\(", stmt, re.I)
    if not m:
        return None
    depth, quote, start = 0, None, m.end()
    for j in range(m.end() - 1, len(stmt)):
        ch = stmt[j]
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
            if depth == 0:
                return stmt[start:j].strip()
        elif ch == "," and depth == 1:
            start = j + 1
    return None


def _is_literal_code(stmt):
    code = _set_error_code(stmt) if "set_error" in stmt else None
    if code is not None and re.fullmatch(r"\d|merge\s*\(\s*\d\s*,.*|merge\s*\(.*,\s*\d\s*,.*", code):
        return True
    return bool(_LITERAL_CODE.search(stmt))


def _statements(line_text):
    """The statements of one joined line, split at semicolons outside strings."""
    if ";" not in line_text:
        return [line_text]
    parts, cur, quote = [], "", None
    for ch in line_text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == ";":
            parts.append(cur)
            cur = ""
            continue
        cur += ch
    return parts + [cur]


def literal_codes(root):
    """'file:line: statement' of every literal exit status in src/, drivers/ and tests/."""
    found = []
    paths = [p for d in ("src", "drivers", "tests")
             for p in glob.glob(os.path.join(root, d, "**", "*.f90"), recursive=True)]
    for path in sorted(paths):
        rel = os.path.relpath(path, root)
        if rel.endswith("cr_exit_codes.f90") or rel.endswith("test_env_error.f90"):
            continue
        lines = open(path, encoding="utf-8").read().split("\n")
        i = 0
        while i < len(lines):
            start, stmt = i, input_reference._strip_comment(lines[i]).rstrip()
            while stmt.endswith("&") and i + 1 < len(lines):
                i += 1
                stmt = stmt[:-1] + " " + input_reference._strip_comment(lines[i]).strip().lstrip("&")
            i += 1
            found += [f"{rel}:{start + 1}: {part.strip()}" for part in _statements(stmt) if _is_literal_code(part)]
    return found


def test_exit_codes_are_named():
    """Every exit status in the Fortran is a name of cr_exit_codes (test_env_error uses a few
    arbitrary codes whose propagation over the ranks it checks)."""
    assert literal_codes(ROOT) == []


def test_exit_codes_agree():
    assert exit_code_differences(ROOT) == []
    assert cio.EXIT_BAD_INPUT == 2


def test_schemas_agree():
    assert schema_differences(ROOT) == []
    # the check saw every product of src/products
    assert {cio.FOM_SCHEMA, cio.DB_SCHEMA, cio.ROM_SCHEMA, cio.ROMRUN_SCHEMA, cio.QOI_SCHEMA,
            cio.PROJREQ_SCHEMA, cio.PROJ_SCHEMA} <= set(fortran_products(ROOT))


def test_namelist_groups_agree():
    assert namelist_differences(ROOT) == []


def _copy_sources(root, tmp_path):
    """src/ of root under tmp_path (the part the checks read)."""
    shutil.copytree(os.path.join(root, "src"), tmp_path / "src")
    return tmp_path


def _edit(path, old, new):
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, 1))


def test_a_changed_fortran_value_is_reported(tmp_path):
    """The checks themselves: a schema version, a read version list, a schema name, an exit status
    and a namelist variable changed in a copy of the Fortran are each reported."""
    root = _copy_sources(ROOT, tmp_path)
    prod = root / "src" / "products"
    _edit(prod / "cr_rom_file.f90", "ROM_SCHEMA_VERSION = 3", "ROM_SCHEMA_VERSION = 4")
    _edit(prod / "cr_fom_file.f90", "FOM_VERSIONS_READ(1) = [1]", "FOM_VERSIONS_READ(2) = [1, 2]")
    _edit(prod / "cr_qoi_file.f90", 'QOI_SCHEMA = "crowdrom-qoi"', 'QOI_SCHEMA = "crowdrom-qois"')
    _edit(prod / "cr_projection_file.f90", "PROJREQ_VERSIONS_READ(1) = [1]", "PROJREQ_VERSIONS_READ(1) = [2]")
    diff = "\n".join(schema_differences(str(root)))
    assert "schema 'crowdrom-rom': the programs write version 4" in diff
    assert "schema 'crowdrom-fom': crowdrom_io reads versions [1], the Fortran" in diff
    assert "schema 'crowdrom-qois' (src/products/cr_qoi_file.f90) has no crowdrom_io constant" in diff
    assert "QOI_SCHEMA = 'crowdrom-qoi' is no product" in diff
    assert "schema 'crowdrom-projreq': the scripts write version 1, the programs read [2]" in diff

    _edit(root / "src" / "core" / "cr_exit_codes.f90", "EXIT_BAD_INPUT = 2", "EXIT_BAD_INPUT = 5")
    assert exit_code_differences(str(root)) == ["exit status EXIT_BAD_INPUT: Fortran 5, crowdrom_io 2"]

    nml = root / "src" / "rom" / "cr_rom_config.f90"
    text = nml.read_text()
    m = re.search(r"namelist\s*/\s*reduced\s*/\s*(\w+)", text)
    assert m, "no namelist /reduced/ in src/rom/cr_rom_config.f90"
    nml.write_text(text.replace(m.group(0), m.group(0) + ", extra_knob", 1))
    diff = "\n".join(namelist_differences(str(root)))
    assert "nml_groups.ROM: &reduced extra_knob (src/rom/cr_rom_config.f90) not mapped" in diff


def test_predict_map_is_the_fortran_group():
    """crowd_predict's map is read from the code: every variable of &predict, nothing else."""
    code = input_reference.code_groups(ROOT)
    assert sorted(nml_groups.PREDICT) == sorted(code["predict"][0])
