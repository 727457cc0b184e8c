"""Where each crowd_offline / crowd_rom / crowd_predict variable lives: one namelist group per concern.

The groups (docs/input-reference.md): crowd_offline reads &offline (files), &pod, &cone, &pga,
&infsup, &pairs, &hyper; crowd_rom reads &rom (files, samples), &sweep (settings), &reduced
(reduced solver), &fom_timing; crowd_predict reads &predict (docs/queries.md). The tests and the extremes campaign describe a stage's options
as one flat list of ``stage_variable = value`` assignments (the names of the former single
groups); ``offline_groups`` / ``rom_groups`` turn such a list into the groups' text.

The groups and their variables are the Fortran's (`namelist /group/` statements, read by
scripts/dev/input_reference.py): crowd_predict's one group is taken from there, and the flat names
of crowd_offline and crowd_rom below are checked against them (scripts/tests/test_agreement.py:
every variable of a group they name has a flat name, and every flat name is a variable).
"""
import os
import re
import sys

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from input_reference import code_groups  # noqa: E402

#: flat name -> (group, variable) for crowd_offline
OFFLINE = {
    "database": ("offline", "database"), "rom_file": ("offline", "rom_file"),
    "pod_method": ("pod", "method"), "pod_n": ("pod", "n"), "pod_energy": ("pod", "energy"),
    "rsvd_rank": ("pod", "rsvd_rank"), "rsvd_oversampling": ("pod", "rsvd_oversampling"),
    "rsvd_power": ("pod", "rsvd_power"), "rsvd_sketch": ("pod", "rsvd_sketch"),
    "rsvd_seed": ("pod", "rsvd_seed"), "pod_compare_n": ("pod", "compare_n"),
    "cone_method": ("cone", "method"), "cone_compare": ("cone", "compare"),
    "cone_delta": ("cone", "delta"), "cone_r_max": ("cone", "r_max"),
    "mcpg_r_max": ("cone", "mcpg_r_max"),
    "pga": ("pga", "enabled"), "pga_delta": ("pga", "delta"), "pga_max_add": ("pga", "max_add"),
    "infsup_n": ("infsup", "n"), "infsup_r": ("infsup", "r"), "infsup_samples": ("infsup", "samples"),
    "rom_n": ("pairs", "n"), "rom_r": ("pairs", "r"),
    "hyper": ("hyper", "enabled"), "hyper_m_factor": ("hyper", "m_factor"), "eq_tol": ("hyper", "eq_tol"),
}
#: flat name -> (group, variable) for crowd_rom
ROM = {
    "rom_file": ("rom", "rom_file"), "database": ("rom", "database"), "output": ("rom", "output"),
    "table": ("rom", "table"), "sets": ("rom", "sets"), "n_samples": ("rom", "n_samples"),
    "mu": ("rom", "mu"), "timing_repeats": ("rom", "timing_repeats"),
    "n": ("sweep", "n"), "r": ("sweep", "r"), "hyper": ("sweep", "hyper"),
    "contacts": ("sweep", "contacts"), "m_v": ("sweep", "m_v"), "m_b": ("sweep", "m_b"),
    "m_d": ("sweep", "m_d"), "correction": ("sweep", "correction"),
    "setting_sets": ("sweep", "sets"),
    "solver": ("reduced", "solver"), "nnls_max_iter": ("reduced", "nnls_max_iter"),
    "uzawa_rho_factor": ("reduced", "uzawa_rho_factor"), "uzawa_eps": ("reduced", "uzawa_eps"),
    "uzawa_max_iter": ("reduced", "uzawa_max_iter"),
    "fom_timing_samples": ("fom_timing", "samples"), "fom_tol": ("fom_timing", "tol"),
    "fom_uzawa_eps": ("fom_timing", "uzawa_eps"), "fom_uzawa_steps": ("fom_timing", "uzawa_steps"),
    "fom_uzawa_rows": ("fom_timing", "uzawa_rows"), "fom_exact_solver": ("fom_timing", "exact_solver"),
}

#: flat name -> (group, variable) for crowd_predict (one group: every variable of &predict)
PREDICT = {name: ("predict", name) for name in code_groups()["predict"][0]}

_ASSIGN = re.compile(r"(?:^|,)\s*([A-Za-z_]\w*)(\(\s*\d+\s*\))?\s*=")


def _split(text):
    """'a = 1, 2, b(3) = 'x'' -> [(name, index, value)] (values keep their commas)."""
    text = text.strip().rstrip(",")
    marks = [(m.start(), m.end(), m.group(1), m.group(2) or "") for m in _ASSIGN.finditer(text)]
    out = []
    for i, (s, e, name, idx) in enumerate(marks):
        end = marks[i + 1][0] if i + 1 < len(marks) else len(text)
        out.append((name, idx, text[e:end].strip().rstrip(",").strip()))
    return out


def _groups(flat, table):
    groups = {}
    for name, idx, value in _split(flat):
        # an unknown name stays in the first group, where the program reports it
        g, v = table.get(name, (next(iter(table.values()))[0], name))
        groups.setdefault(g, []).append("%s%s = %s" % (v, idx, value))
    return {g: ", ".join(a) for g, a in groups.items()}


def offline_groups(flat):
    """{group: text} of crowd_offline's groups for a flat assignment list."""
    return _groups(flat, OFFLINE)


def rom_groups(flat):
    """{group: text} of crowd_rom's groups for a flat assignment list."""
    return _groups(flat, ROM)


def predict_groups(flat):
    """{group: text} of crowd_predict's group for a flat assignment list."""
    return _groups(flat, PREDICT)


def as_text(groups):
    """Namelist text of {group: assignments}."""
    return "".join("&%s %s /\n" % (g, t) for g, t in groups.items())
