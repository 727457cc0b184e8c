"""Readers of the crowdrom HDF5 files for the Python post-processing (ML correction, figures).

Fortran writes the files; h5py shows every dataset with its Fortran dimensions reversed. The
readers here return arrays in a "natural" numpy layout and say so in their docstrings:

* snapshot database (schema ``crowdrom-snapshots``): positions ``[n_S, N_T + 1, n_dof]``,
  velocities ``[n_S, N_T, n_dof]``, params ``[n_S, n_mu]``;
* ROM file (schema ``crowdrom-rom``): pair basis ``V`` ``[n_dof, n_basis]`` (columns are basis
  vectors, the first ``n`` the POD modes);
* ROM run file (schema ``crowdrom-romrun``): alpha ``[n_S, N_T, n_basis]``, positions
  ``[n_S, N_T + 1, n_dof]``, err_time ``[n_S, N_T + 1]``;
* QoI product (schema ``crowdrom-qoi``) and the QoI groups of the other products: one row per
  query or sample, curve ``[n, n_exits, N_T + 1]``, t_evac ``[n, 3]`` (``read_qoi``,
  ``read_qoi_group``); crowd_predict's product adds its own datasets (``read_prediction``):
  alpha ``[n_Q, N_T, n_basis]``, positions ``[n_Q, N_T + 1, n_dof]``.

One reader per product, mirroring the Fortran owners in ``src/products``: ``read_fom`` (schema
``crowdrom-fom``), ``read_database_*`` (``crowdrom-snapshots``), ``read_rom_pair`` (``crowdrom-rom``),
``romrun_*`` (``crowdrom-romrun``); ``open_h5`` checks the schema name and accepts only the schema
versions in ``SCHEMA_VERSIONS`` (the versions the Fortran readers accept). ``write_h5_atomic``
writes a product (the ML output) under a temporary name. No script opens h5py itself.

Every problem with an input raises ``InputError`` with a one-line message naming the file and the
missing object; the command-line scripts turn it into ``<script>: error: <message>`` and exit 2.
"""
import math
import os
import sys

import numpy as np

DB_SCHEMA = "crowdrom-snapshots"
ROM_SCHEMA = "crowdrom-rom"
ROMRUN_SCHEMA = "crowdrom-romrun"
ML_SCHEMA = "crowdrom-ml"
FOM_SCHEMA = "crowdrom-fom"
PROJREQ_SCHEMA = "crowdrom-projreq"
PROJ_SCHEMA = "crowdrom-projected"
QOI_SCHEMA = "crowdrom-qoi"
#: schema versions each reader accepts: those the Fortran readers accept (src/products:
#: <P>_VERSIONS_READ, or the version written, <P>_SCHEMA_VERSION, of a product no program reads)
#: plus SCRIPT_ONLY_VERSIONS; scripts/tests/test_agreement.py checks both sides agree
SCHEMA_VERSIONS = {FOM_SCHEMA: (1,), DB_SCHEMA: (1, 2), ROM_SCHEMA: (1, 2, 3), ROMRUN_SCHEMA: (1,),
                   ML_SCHEMA: (1, 2), PROJ_SCHEMA: (2,), QOI_SCHEMA: (1,)}
#: versions only the scripts read: the figures read the offline results of a version-1 ROM file
#: (written before the prepared pairs), which crowd_rom (pairs needed) refuses
SCRIPT_ONLY_VERSIONS = {ROM_SCHEMA: (1,)}
#: products whose every dataset carries a ``checksum`` attribute (from the given schema version
#: on; but those under the listed groups, e.g. the database's reference scene written by the
#: full-order writer): ``dataset`` refuses one without it, and verifies it wherever it is present
CHECKSUMMED = {DB_SCHEMA: (1, ("/scene/",)), ML_SCHEMA: (2, ())}
#: version of the ML output this package writes (2: every dataset with its checksum)
ML_VERSION = 2
#: version of the projection request this package writes (read by crowd_project)
PROJREQ_VERSION = 1
#: exit statuses of the scripts, the values of the programs' (src/core/cr_exit_codes.f90)
EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_STOPPED = 3
EXIT_MPI = 4


class InputError(Exception):
    """A missing, unreadable or inconsistent input file (exit status 2 in the scripts)."""


def text(value):
    """Attribute value as str (fixed-length strings come back as bytes)."""
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode("utf-8", errors="replace").rstrip("\x00 ")
    if isinstance(value, np.ndarray):
        if value.shape == () or value.size == 1:
            return text(value.reshape(-1)[0])
    return str(value)


def scalar(value):
    """Attribute value as a Python number (1-element arrays accepted)."""
    a = np.asarray(value)
    if a.size != 1:
        raise ValueError(f"expected a scalar, got shape {a.shape}")
    return a.reshape(-1)[0].item()


def open_h5(path, schema=None, what="file"):
    """Open an HDF5 file read-only and check its root attribute ``schema``."""
    import h5py

    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputError(f"{what} not found: '{path}'")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"cannot open {what} '{path}' as HDF5: {exc}") from None
    if schema is not None:
        got = text(f.attrs["schema"]) if "schema" in f.attrs else None
        if got != schema:
            f.close()
            raise InputError(f"'{path}' is not a {schema} file (root attribute schema = {got!r})")
        check_version(f, path, schema, what)
    return f


def check_version(f, path, schema, what="file"):
    """Root attribute ``schema_version`` must be one the readers know (InputError otherwise)."""
    known = SCHEMA_VERSIONS.get(schema)
    if known is None:
        return
    if "schema_version" not in f.attrs:
        f.close()
        raise InputError(f"'{path}': {what} without a schema_version attribute")
    try:
        v = int(scalar(f.attrs["schema_version"]))
    except (TypeError, ValueError):
        v = None
    if v not in known:
        f.close()
        raise InputError(f"'{path}': {what} schema version {v} is not supported (supported: "
                         f"{', '.join(str(k) for k in known)})")


def need_finite(path, name, arr):
    """InputError naming the file and dataset if ``arr`` holds NaN or Inf."""
    a = np.asarray(arr)
    if a.dtype.kind == "f" and a.size and not np.all(np.isfinite(a)):
        i = int(np.flatnonzero(~np.isfinite(a.ravel()))[0])
        raise InputError(f"'{path}': dataset '{name}': non-finite value at entry {i + 1}")
    return arr


def write_h5_atomic(path, write):
    """Write an HDF5 product: ``write(f)`` fills ``path + '.partial'``, renamed to ``path`` only
    when complete (a failure removes the temporary and leaves any previous ``path`` intact)."""
    import h5py

    tmp = os.fspath(path) + ".partial"
    try:
        with h5py.File(tmp, "w") as f:
            write(f)
            stamp_checksums(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def stamp_checksums(f):
    """Give every numeric dataset of an open writable file its ``checksum`` attribute."""
    def visit(name, obj):
        if hasattr(obj, "shape") and obj.dtype.kind in "fiub":
            obj.attrs["checksum"] = np.bytes_(digest(obj[()]))
    f.visititems(visit)


def attr(obj, name, kind=float):
    """Attribute ``name`` of a file/group/dataset converted by ``kind`` (InputError if missing)."""
    if name not in obj.attrs:
        raise InputError(f"'{obj.file.filename}': missing attribute '{name}' on '{obj.name}'")
    v = obj.attrs[name]
    if kind is str:
        return text(v)
    return kind(scalar(v))


def dataset(f, name, finite=False):
    """Dataset ``name`` of an open file or group as a numpy array, verified: its ``checksum``
    attribute (the digest below, as the Fortran readers compute it) when it has one, and it must
    have one in a product listed in CHECKSUMMED; ``finite``: no NaN or Inf. InputError naming the
    file, the dataset and the problem otherwise."""
    path = f.file.filename
    if name not in f:
        raise InputError(f"'{path}': missing dataset '{name}'")
    obj = f[name]
    if not hasattr(obj, "shape"):
        raise InputError(f"'{path}': '{name}' is a group, expected a dataset")
    try:
        data = np.asarray(obj[()])
    except (OSError, ValueError, TypeError) as exc:
        raise InputError(f"'{path}': dataset '{obj.name}' cannot be read ({' '.join(str(exc).split())})") from None
    if "checksum" in obj.attrs:
        _verify(path, obj.name, data, obj.attrs["checksum"])
    elif _needs_checksums(f.file, obj.name):
        raise InputError(f"'{path}': dataset '{obj.name}' has no checksum attribute (written by an older "
                         "crowdrom, or damaged)")
    if finite:
        need_finite(path, obj.name.lstrip("/"), data)
    return data


def _needs_checksums(f, name):
    """Does the open file's schema (and version) promise a checksum on dataset ``name``?"""
    schema = text(f.attrs["schema"]) if "schema" in f.attrs else None
    if schema not in CHECKSUMMED:
        return False
    since, exempt = CHECKSUMMED[schema]
    if any(name.startswith(g) for g in exempt):
        return False
    try:
        v = int(scalar(f.attrs["schema_version"]))
    except (KeyError, TypeError, ValueError):
        return True
    return v >= since


def _verify(path, name, data, stored):
    if data.dtype.kind not in "fiub":
        return
    got = digest(data)
    if text(stored) != got:
        raise InputError(f"'{path}': checksum mismatch in dataset '{name.lstrip('/')}' (stored {text(stored)}, "
                         f"data {got}): the file is corrupted")


def group(f, name):
    if name not in f:
        raise InputError(f"'{f.file.filename}': missing group '{name}'")
    return f[name]


# ------------------------------------------------------------------------------ full-order output

def read_fom(path):
    """A full-order output file (schema ``crowdrom-fom``): scene (as ``read_scene``), attributes,
    steps and times [n_out], positions [n_out, n_agents, 2], inside flags [n_out, n_agents] and
    the sparse multipliers (offset [n_out + 1], ia, ib, ob, lambda [nnz]) when stored."""
    with open_h5(path, FOM_SCHEMA, "full-order output") as f:
        d = read_scene(f)
        d.update({"radius": attr(f, "agent_radius", float), "n_agents": attr(f, "n_agents", int),
                  "dt": attr(f, "dt", float) if "dt" in f.attrs else None,
                  "step": dataset(f, "traj/step").astype(int).ravel(),
                  "time": dataset(f, "traj/time").astype(float).ravel(),
                  "pos": need_finite(f.filename, "traj/positions",
                                     dataset(f, "traj/positions").astype(float)),
                  "inside": dataset(f, "traj/inside").astype(bool)})
        if "traj/contacts/offset" in f:
            d["contacts"] = {k: dataset(f, f"traj/contacts/{k}").ravel()
                             for k in ("offset", "ia", "ib", "ob", "lambda")}
    n_out, na = d["pos"].shape[0], d["n_agents"]
    if d["pos"].shape != (n_out, 2 * na) or d["inside"].shape != (n_out, na):
        raise InputError(f"'{path}': 'traj/positions' / 'traj/inside' have h5py shapes "
                         f"{d['pos'].shape} / {d['inside'].shape}, expected ({n_out}, {2 * na}) / "
                         f"({n_out}, {na}) for n_agents = {na}")
    d["pos"] = d["pos"].reshape(n_out, na, 2)
    return d


# ------------------------------------------------------------------------------ database

def _blocks(arr, n_blocks, per_block, n_dof, path, name):
    """h5py array [(per_block * n_blocks), n_dof] -> [n_blocks, per_block, n_dof]."""
    if arr.shape != (per_block * n_blocks, n_dof):
        raise InputError(f"'{path}': '{name}' has h5py shape {arr.shape}, expected "
                         f"({per_block * n_blocks}, {n_dof})")
    return arr.reshape(n_blocks, per_block, n_dof)


def read_database_meta(f):
    """Root metadata of an open snapshot database, checked as the Fortran reader does: complete,
    n_agents and n_steps >= 1, n_train and n_valid >= 0, dt and agent_radius finite and > 0."""
    path = f.filename
    if "complete" in f.attrs and attr(f, "complete", int) != 1:
        raise InputError(f"'{path}': the snapshot database is not complete (attribute complete = "
                         f"{attr(f, 'complete', int)})")
    m = {
        "n_agents": attr(f, "n_agents", int),
        "n_steps": attr(f, "n_steps", int),
        "dt": attr(f, "dt", float),
        "agent_radius": attr(f, "agent_radius", float),
        "param_names": attr(f, "param_names", str).split(",") if "param_names" in f.attrs else [],
        "config_hash": attr(f, "config_hash", str) if "config_hash" in f.attrs else "",
    }
    for key in ("n_train", "n_valid"):
        m[key] = attr(f, key, int) if key in f.attrs else None
    bad = [f"{k} = {m[k]}" for k in ("n_agents", "n_steps") if m[k] < 1]
    bad += [f"{k} = {m[k]}" for k in ("n_train", "n_valid") if m[k] is not None and m[k] < 0]
    bad += [f"{k} = {m[k]}" for k in ("dt", "agent_radius") if not (np.isfinite(m[k]) and m[k] > 0)]
    if bad:
        raise InputError(f"'{path}': root attribute(s) out of range: {', '.join(bad)}")
    return m


#: datasets of a set in the order of the block table ``<set>/sample_checksums`` (schema 2): per
#: sample, the two residues of the digest of its block of each (src/products/cr_snapshot_file.f90)
SAMPLE_CHECKSUM_DATASETS = ("params", "positions", "velocities", "desired", "lambda_offset", "lambda_index",
                            "lambda_value", "stats/kkt", "stats/min_gap", "stats/iterations", "stats/converged",
                            "stats/n_active", "stats/time", "stats/rank", "stats/start", "scene_vertices",
                            "scene_exit")


def sample_block_table(f, s):
    """The block table of set S of an open database [n_S, 34] (schema version 2; None for version
    1), its own checksum verified by ``dataset``."""
    if int(scalar(f.attrs["schema_version"])) < 2:
        return None
    t = dataset(f, f"{s}/sample_checksums")
    n = params_count(f, s)
    if t.shape != (n, 2 * len(SAMPLE_CHECKSUM_DATASETS)):
        raise InputError(f"'{f.filename}': dataset '{s}/sample_checksums' has h5py shape {t.shape}, expected "
                         f"({n}, {2 * len(SAMPLE_CHECKSUM_DATASETS)})")
    return t


def params_count(f, s):
    d = f[f"{s}/params"] if f"{s}/params" in f else None
    if d is None:
        raise InputError(f"'{f.filename}': missing dataset '{s}/params'")
    return d.shape[0] if d.ndim > 1 else d.size


def verify_blocks(f, s, name, data, k0, k1, offset):
    """Samples k0..k1-1 (0-based) of dataset ``<s>/<name>`` were read as ``data`` (h5py layout),
    its first element at 0-based linear index ``offset``: compare its digest with the sum of those
    samples' entries in the block table (InputError on a mismatch)."""
    t = sample_block_table(f, s)
    q = SAMPLE_CHECKSUM_DATASETS.index(name)
    got = digest(data, offset)
    part = t[k0:k1, 2 * q:2 * q + 2].astype(np.int64)
    want = "%08x%08x" % tuple(int(x) % _M for x in part.sum(axis=0))
    if got != want:
        raise InputError(f"'{f.filename}': block checksum mismatch in dataset '{s}/{name}' (samples {k0 + 1}.."
                         f"{k1}: stored {want}, data {got}): the file is corrupted")


def read_database_samples(f, s, k0, k1, velocities=True):
    """Samples k0..k1-1 (0-based) of set S of an open database, read alone and verified against
    the block table as the Fortran reader does (a version 1 database has none: refused unless
    the range is the whole set). Returns what ``read_database_set`` returns, for those samples."""
    meta = read_database_meta(f)
    nt, n_dof = meta["n_steps"], 2 * meta["n_agents"]
    n = params_count(f, s)
    if not (0 <= k0 < k1 <= n):
        raise InputError(f"'{f.filename}': samples {k0 + 1}..{k1} of set '{s}' requested, the set has {n}")
    if k0 == 0 and k1 == n:
        return read_database_set(f, s, velocities)
    if sample_block_table(f, s) is None:
        raise InputError(f"'{f.filename}': snapshot database schema version 1 has no per-sample checksums: "
                         f"samples {k0 + 1}..{k1} of the {n} of set {s} cannot be verified (read the whole set, "
                         "or rerun crowd_snapshots)")
    out = {}
    for name, per, key in (("params", 1, "params"), ("positions", nt + 1, "positions"),
                           ("velocities", nt, "velocities")):
        if key == "velocities" and not velocities:
            continue
        d = f[f"{s}/{name}"]
        width = d.shape[1] if d.ndim > 1 else 1
        a = np.asarray(d[k0 * per:k1 * per])
        verify_blocks(f, s, name, a, k0, k1, k0 * per * width)
        need_finite(f.filename, f"{s}/{name}", a)
        out[key] = a if key == "params" else _blocks(a, k1 - k0, per, n_dof, f.filename, f"{s}/{name}")
    if out["params"].ndim == 1:
        out["params"] = out["params"].reshape(-1, 1)
    return out


def read_database_set(f, s, velocities=True):
    """One set S of an open database: params [n_S, n_mu], positions [n_S, N_T+1, n_dof],
    velocities [n_S, N_T, n_dof] (if asked); every dataset against its checksum."""
    meta = read_database_meta(f)
    nt, n_dof = meta["n_steps"], 2 * meta["n_agents"]
    group(f, s)
    params = dataset(f, f"{s}/params", finite=True)
    if params.ndim == 1:
        params = params.reshape(-1, 1)
    n_s = params.shape[0]
    n_attr = meta.get(f"n_{s}")
    if n_attr is not None and n_s != n_attr:
        raise InputError(f"'{f.filename}': dataset '{s}/params' holds {n_s} samples, but the root attribute "
                         f"n_{s} says {n_attr}")
    out = {"params": params,
           "positions": need_finite(f.filename, f"{s}/positions",
                                    _blocks(dataset(f, f"{s}/positions"), n_s, nt + 1, n_dof,
                                            f.filename, f"{s}/positions"))}
    if velocities:
        out["velocities"] = need_finite(f.filename, f"{s}/velocities",
                                        _blocks(dataset(f, f"{s}/velocities"), n_s, nt, n_dof,
                                                f.filename, f"{s}/velocities"))
    return out


def read_scene(f):
    """The reference scene stored under /scene (same layout as in crowdrom-fom files)."""
    g = group(f, "scene")
    d = {
        "kind": np.asarray(dataset(g, "obstacle_kind"), dtype=int).ravel(),
        "oradius": np.asarray(dataset(g, "obstacle_radius"), dtype=float).ravel(),
        "vstart": np.asarray(dataset(g, "obstacle_vertex_start"), dtype=int).ravel(),
        "verts": np.asarray(dataset(g, "obstacle_vertices"), dtype=float).reshape(-1, 2),
        "exit": np.asarray(dataset(g, "exit_segment"), dtype=float).reshape(2, 2),
        "domain": np.asarray(dataset(g, "domain"), dtype=float).ravel(),
        "n_walls": int(scalar(g.attrs["n_walls"])) if "n_walls" in g.attrs else None,
    }
    return d


def read_sample_scenes(f, s):
    """The scene of every sample of set S as the model mapped it (list of dicts as ``read_scene``):
    the stored ``<S>/scene_vertices`` (Fortran [2 n_vertices, n_S]) and ``<S>/scene_exit``
    ([4, n_S]: x_lo, y, x_hi, y). A database written before they were stored is accepted only when
    no parameter changes the geometry (then every sample has the reference scene)."""
    ref = read_scene(f)
    params = dataset(f, f"{s}/params")
    n_s = params.shape[0] if params.ndim > 1 else params.size
    if f"{s}/scene_vertices" not in f:
        if "l_exit" in read_database_meta(f)["param_names"]:
            raise InputError(f"'{f.filename}': no per-sample scenes ('{s}/scene_vertices'): the "
                             "database predates them; rerun crowd_snapshots")
        return [ref] * n_s
    v = need_finite(f.filename, f"{s}/scene_vertices", dataset(f, f"{s}/scene_vertices"))
    e = need_finite(f.filename, f"{s}/scene_exit", dataset(f, f"{s}/scene_exit"))
    if v.shape != (n_s, ref["verts"].size) or e.shape != (n_s, 4):
        raise InputError(f"'{f.filename}': '{s}/scene_vertices' / '{s}/scene_exit' have h5py shapes "
                         f"{v.shape} / {e.shape}, expected ({n_s}, {ref['verts'].size}) / ({n_s}, 4)")
    return [dict(ref, verts=v[i].reshape(-1, 2), exit=e[i].reshape(2, 2)) for i in range(n_s)]


def multipliers_csr(f, s):
    """Sparse multipliers of set S as scipy CSC [n_dict, N_T n_S] (column = velocity column)."""
    from scipy.sparse import csc_matrix

    off = dataset(f, f"{s}/lambda_offset").astype(np.int64).ravel()
    idx = dataset(f, f"{s}/lambda_index").astype(np.int64).ravel()
    val = dataset(f, f"{s}/lambda_value").astype(float).ravel()
    n_dict = dataset(f, "contacts/ia").size
    n_col = off.size - 1
    if off[0] != 0 or off[-1] != idx.size or idx.size != val.size:
        raise InputError(f"'{f.filename}': inconsistent multiplier CSR in set '{s}'")
    need_finite(f.filename, f"{s}/lambda_value", val)
    if idx.size and (idx.min() < 1 or idx.max() > n_dict):
        raise InputError(f"'{f.filename}': multiplier index outside 1..{n_dict} in set '{s}'")
    return csc_matrix((val, idx - 1, off), shape=(n_dict, n_col))


# ------------------------------------------------------------------------------ ROM file

def read_rom_pair(f, k):
    """Pair k (1-based) of an open ROM file: attrs and the basis V [n_dof, n_basis]."""
    name = f"pairs/{k}"
    if "pairs" not in f:
        raise InputError(f"'{f.filename}': no group 'pairs' (ROM schema_version < 2?)")
    g = group(f, name)
    p = {"index": k, "n": attr(g, "n", int), "r": attr(g, "r", int),
         "n_pga": attr(g, "n_pga", int), "n_basis": attr(g, "n_basis", int)}
    v = dataset(g, "v")
    if v.ndim != 2 or v.shape[0] != p["n_basis"]:
        raise InputError(f"'{f.filename}': '{name}/v' has h5py shape {v.shape}, expected "
                         f"(n_basis = {p['n_basis']}, n_dof)")
    need_finite(f.filename, f"{name}/v", v)
    p["V"] = np.ascontiguousarray(v.T)
    return p


def read_rom_pair_vdeim(f, k):
    """The DEIM of the desired velocity stored with pair k's 'eq' method (group
    pairs/<k>/eq/v_deim, hyper = 'eq_deim'): {"U": basis [n_dof, m], "indices": 1-based [m],
    "err": [m]}, or None when the file has none (written before it existed, or no hyper)."""
    name = f"pairs/{k}/eq/v_deim"
    if name not in f:
        return None
    g = group(f, name)
    m = attr(g, "m", int)
    if m == 0:
        return None
    u = dataset(g, "basis")
    idx = dataset(g, "indices")
    if u.ndim != 2 or u.shape[0] != m or idx.shape != (m,):
        raise InputError(f"'{f.filename}': '{name}': basis {u.shape} / indices {idx.shape} do not match m = {m}")
    need_finite(f.filename, f"{name}/basis", u)
    if idx.min() < 1 or idx.max() > u.shape[1]:
        raise InputError(f"'{f.filename}': '{name}/indices': index outside 1..{u.shape[1]}")
    return {"U": np.ascontiguousarray(u.T), "indices": idx.astype(int), "err": dataset(g, "err")}


def read_database_desired(f, s):
    """Desired velocities of set S of an open database at its configurations q^0..q^(N_T-1):
    [n_S, N_T, n_dof]."""
    meta = read_database_meta(f)
    n_s = dataset(f, f"{s}/params").shape[0]
    return need_finite(f.filename, f"{s}/desired",
                       _blocks(dataset(f, f"{s}/desired"), n_s, meta["n_steps"], 2 * meta["n_agents"],
                               f.filename, f"{s}/desired"))


def rom_pair_indices(f):
    """Sorted 1-based pair indices present in a ROM file."""
    if "pairs" not in f:
        return []
    return sorted(int(k) for k in f["pairs"].keys() if k.isdigit())


# ------------------------------------------------------------------------------ ROM run file

SETTING_ATTRS = {"n": int, "r": int, "n_basis": int, "pair": int, "hyper": str, "E_avg": float,
                 "t_step": float, "speedup_uzawa": float, "speedup_exact": float}
SETTING_ATTRS_OPTIONAL = {"contacts": str, "solver": str, "m_v": int, "m_b": int, "m_d": int,
                          "samples_diverged": int, "correction": str}


def romrun_meta(f):
    """Root metadata and FOM timing of an open ROM run file."""
    m = {"rom_file": attr(f, "rom_file", str), "database": attr(f, "database", str),
         "n_agents": attr(f, "n_agents", int), "n_steps": attr(f, "n_steps", int),
         "dt": attr(f, "dt", float), "agent_radius": attr(f, "agent_radius", float),
         "n_settings": attr(f, "n_settings", int),
         "param_names": attr(f, "param_names", str).split(",") if "param_names" in f.attrs else []}
    bad = [f"{k} = {m[k]}" for k in ("n_agents", "n_steps") if m[k] < 1]
    bad += [f"{k} = {m[k]}" for k in ("dt", "agent_radius") if not (np.isfinite(m[k]) and m[k] > 0)]
    bad += [f"n_settings = {m['n_settings']}"] if m["n_settings"] < 0 else []
    if bad:
        raise InputError(f"'{f.filename}': root attribute(s) out of range: {', '.join(bad)}")
    g = group(f, "fom_timing")
    m["t_step_uzawa"] = attr(g, "t_step_uzawa", float)
    m["t_step_exact"] = attr(g, "t_step_exact", float)
    for k in ("t_step_uzawa", "t_step_exact"):
        if not np.isfinite(m[k]):
            raise InputError(f"'{f.filename}': attribute 'fom_timing/{k}' = {m[k]} is not finite")
    m["exact_solver"] = attr(g, "exact_solver", str) if "exact_solver" in g.attrs else ""
    # the solver asked for ('fastest' or a name) and "name t_step t_query; ..." of every exact
    # solver timed (absent from files written before the 'fastest' reference)
    m["exact_solver_asked"] = attr(g, "exact_solver_asked", str) if "exact_solver_asked" in g.attrs \
        else m["exact_solver"]
    m["exact_solver_timings"] = attr(g, "exact_solver_timings", str) if "exact_solver_timings" in g.attrs else ""
    return m


def romrun_setting(f, k):
    """Attributes of setting k (1-based) of an open ROM run file."""
    name = f"setting_{k}"
    if name not in f:
        n = int(scalar(f.attrs["n_settings"])) if "n_settings" in f.attrs else "?"
        raise InputError(f"'{f.filename}': no setting {k} (group '/{name}'; the file has "
                         f"n_settings = {n})")
    g = f[name]
    s = {"index": k}
    for key, kind in SETTING_ATTRS.items():
        s[key] = attr(g, key, kind)
        if kind is float and not np.isfinite(s[key]):
            raise InputError(f"'{f.filename}': attribute '{name}/{key}' = {s[key]} is not finite")
    for key, kind in SETTING_ATTRS_OPTIONAL.items():
        s[key] = attr(g, key, kind) if key in g.attrs else None
    if s["correction"] is None:     # files written before the local correction
        s["correction"] = "none"
    s["sets"] = [x for x in ("train", "valid") if x in g]
    return s


def romrun_set(f, k, s, n_steps, n_dof):
    """Set S of setting k: params [n_S, n_mu], alpha [n_S, N_T, n_basis], positions
    [n_S, N_T+1, n_dof], err_time [n_S, N_T+1] and the per-sample vectors."""
    name = f"setting_{k}/{s}"
    if name not in f:
        raise InputError(f"'{f.filename}': setting {k} has no '{s}' set (group '/{name}')")
    g = f[name]
    params = dataset(g, "params", finite=True)
    if params.ndim == 1:
        params = params.reshape(-1, 1)
    n_s = params.shape[0]
    alpha = dataset(g, "alpha", finite=True)
    if alpha.ndim != 2 or alpha.shape[0] != n_steps * n_s:
        raise InputError(f"'{f.filename}': '{name}/alpha' has h5py shape {alpha.shape}, expected "
                         f"(N_T n_S = {n_steps * n_s}, n_basis)")
    out = {"params": params, "alpha": alpha.reshape(n_s, n_steps, alpha.shape[1]),
           "positions": _blocks(dataset(g, "positions", finite=True), n_s, n_steps + 1, n_dof, f.filename,
                                f"{name}/positions")}
    et = dataset(g, "err_time", finite=True)
    if et.shape != (n_s, n_steps + 1):
        raise InputError(f"'{f.filename}': '{name}/err_time' has h5py shape {et.shape}, expected "
                         f"({n_s}, {n_steps + 1})")
    out["err_time"] = et
    for key in ("E_mu", "E_proj", "max_overlap", "n_not_left", "time", "diverged_step", "E_disp",
                "max_overlap_agents", "max_overlap_walls", "mobility"):
        if key in g:
            out[key] = dataset(g, key, finite=True).ravel()
            if out[key].size != n_s:
                raise InputError(f"'{f.filename}': '{name}/{key}' has {out[key].size} entries, expected n_S = {n_s}")
    # evacuation curves [n_S, N_T + 1] and times of 50 % / 90 % out [n_S, 2] (-1: not reached)
    for key, width in (("evac_rom", n_steps + 1), ("evac_fom", n_steps + 1), ("t_out_rom", 2), ("t_out_fom", 2)):
        if key in g:
            x = dataset(g, key, finite=True)
            if x.shape != (n_s, width):
                raise InputError(f"'{f.filename}': '{name}/{key}' has h5py shape {x.shape}, expected "
                                 f"({n_s}, {width})")
            out[key] = x
    # the quantities of interest of the reduced trajectories (read_qoi_group), when stored
    if "qoi" in g:
        q = read_qoi_group(f, name + "/qoi")
        if q["n_rows"] != n_s or q["n_steps"] != n_steps:
            raise InputError(f"'{f.filename}': '{name}/qoi' has {q['n_rows']} rows of {q['n_steps']} steps, "
                             f"expected {n_s} of {n_steps}")
        out["qoi"] = q
    # local exact correction ('local' settings only): agents corrected per step [n_S, N_T] and
    # the correction's wall time per sample [n_S]; the positions are then the corrected ones,
    # carried in full (integrating alpha does not give them back)
    if "n_corrected" in g:
        x = dataset(g, "n_corrected")
        if x.shape != (n_s, n_steps):
            raise InputError(f"'{f.filename}': '{name}/n_corrected' has h5py shape {x.shape}, expected "
                             f"({n_s}, {n_steps})")
        out["n_corrected"] = x
        out["t_correct"] = dataset(g, "t_correct", finite=True).ravel()
    return out


# ------------------------------------------------------------------------------ CSV tables

#: columns of the tables holding text (every other column holds numbers)
CSV_TEXT_COLUMNS = {"set", "hyper", "contacts", "solver", "correction", "exact_solver", "fom_exact_solver",
                    "regressor", "label", "kind", "mode"}
#: columns holding wall times (s): >= 0, or -1 for "not measured"
CSV_TIME_COLUMNS = {"t_step_rom", "t_step_fom_exact", "t_step_fom_uzawa", "t_query_rom", "t_query_fom_exact",
                    "t_correct", "t_step", "t_query", "t_project_step", "t_project_query", "t_ml_step"}


def csv_number(v):
    """A CSV cell as int (written without '.' or exponent) or float; ValueError otherwise."""
    x = float(v)
    if math.isfinite(x) and x.is_integer() and "." not in v and "e" not in v.lower():
        return int(x)
    return x


def read_csv_table(path, needed, what, positive_times=()):
    """(header, rows) of a CSV table written by crowd_rom (the sweep table) or ml_correct.py (the
    ML table), checked: every column of ``needed`` in the header, every row as long as the header,
    no empty cell in a needed column, a finite number in every numeric column (all but
    CSV_TEXT_COLUMNS; a column neither needed nor known may hold text), times >= 0 or -1
    (unknown), and > 0 for ``positive_times``. Rows are dicts
    of converted values. InputError naming the file, the line and the column otherwise."""
    import csv

    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputError(f"{what} not found: '{path}'")
    if os.path.isdir(path):
        raise InputError(f"{what} '{path}' is a directory")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            lines = list(csv.reader(fh))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"'{path}': not a CSV {what} ({' '.join(str(exc).split())})") from None
    if not lines:
        raise InputError(f"'{path}': empty {what}")
    header = [c.strip() for c in lines[0]]
    missing = [c for c in needed if c not in header]
    if missing:
        raise InputError(f"'{path}': missing column(s) {missing} in the header of the {what}")
    rows = []
    for i, cells in enumerate(lines[1:], start=2):
        if not cells:
            continue
        if len(cells) != len(header):
            raise InputError(f"'{path}' line {i}: {len(cells)} cells, the header has {len(header)} columns")
        r = {}
        for c, v in zip(header, cells):
            v = v.strip()
            if v == "":
                if c in needed:
                    raise InputError(f"'{path}' line {i}: empty '{c}'")
                r[c] = v
                continue
            if c in CSV_TEXT_COLUMNS:
                r[c] = v
                continue
            try:
                x = csv_number(v)
            except ValueError:
                # a column this reader does not know may hold text (a solver's name, say)
                if c in needed or c in CSV_TIME_COLUMNS:
                    raise InputError(f"'{path}' line {i}: column '{c}' holds '{v}', not a number") from None
                r[c] = v
                continue
            if not math.isfinite(x):
                raise InputError(f"'{path}' line {i}: column '{c}' holds {v} (not a finite number)")
            if c in CSV_TIME_COLUMNS and x < 0 and x != -1:
                raise InputError(f"'{path}' line {i}: column '{c}' = {v}: a time must be >= 0 (or -1: not measured)")
            if c in positive_times and not x > 0:
                raise InputError(f"'{path}' line {i}: column '{c}' = {v}: must be > 0")
            r[c] = x
        rows.append(r)
    if not rows:
        raise InputError(f"'{path}': no rows in the {what}")
    return header, rows


# ------------------------------------------------------------------------------ errors, schemes

def read_rom_study(f):
    """The study a ROM file holds (version 3): ``q0`` [n_dof], ``param_names`` (list), ``config``."""
    if "study" not in f:
        raise InputError(f"'{f.filename}': no group 'study' (ROM file version < 3: rebuild it with crowd_offline)")
    g = f["study"]
    q0 = need_finite(f.filename, "study/q0", dataset(g, "q0").ravel())
    return {"q0": q0, "param_names": attr(g, "param_names", str).split(","), "config": attr(g, "config", str)}


def read_prediction(path):
    """A crowd_predict product: ``read_qoi``'s dict (the QoIs, params, outside_box, cpu_seconds,
    ...) plus the prediction's own data, checked: the root attributes rom_file, queries_from,
    param_min, param_max, n_agents, n_steps, n_ranks, wall_seconds, pair, pair_n, pair_r, n_basis;
    diverged_step, n_infeasible, n_capped [n_Q] and, when written (trajectories = .true.),
    positions [n_Q, N_T + 1, n_dof] and alpha [n_Q, N_T, n_basis] (reduced model only)."""
    d = read_qoi(path)
    with open_h5(path, QOI_SCHEMA, "QoI product") as f:
        if "pair" not in f.attrs or "diverged_step" not in f:
            raise InputError(f"'{path}': a QoI product without the prediction's datasets (not written by "
                             "crowd_predict)")
        for k in ("rom_file", "queries_from"):
            d[k] = attr(f, k, str)
        for k in ("n_agents", "n_steps", "n_ranks", "pair", "pair_n", "pair_r", "n_basis"):
            d[k] = attr(f, k, int)
        d["wall_seconds"] = attr(f, "wall_seconds", float)
        d["param_min"], d["param_max"] = np.asarray(f.attrs["param_min"]), np.asarray(f.attrs["param_max"])
        nq, nt, na = d["n_queries"], d["n_steps"], d["n_agents"]
        for k in ("diverged_step", "n_infeasible", "n_capped"):
            a = dataset(f, k)
            if a.shape != (nq,):
                raise InputError(f"'{path}': dataset '{k}' has shape {a.shape}, expected ({nq},)")
            verify_checksum(f, k)
            d[k] = a
        if "positions" in f:
            a = dataset(f, "positions")
            if a.shape != (nq * (nt + 1), 2 * na):
                raise InputError(f"'{path}': dataset 'positions' has shape {a.shape}, expected "
                                 f"({nq * (nt + 1)}, {2 * na})")
            verify_checksum(f, "positions")
            d["positions"] = need_finite(path, "positions", a).reshape(nq, nt + 1, 2 * na)
        if "alpha" in f:
            a = dataset(f, "alpha")
            if a.ndim != 2 or a.shape != (nq * nt, d["n_basis"]):
                raise InputError(f"'{path}': dataset 'alpha' has shape {a.shape}, expected "
                                 f"({nq * nt}, {d['n_basis']})")
            verify_checksum(f, "alpha")
            d["alpha"] = need_finite(path, "alpha", a).reshape(nq, nt, d["n_basis"])
    return d


def integrate_positions(q0, u, h):
    """Explicit scheme q(nu) = q(nu-1) + h u(nu) from q(0) = q0.

    q0 [n_dof], u [n_S, N_T, n_dof] -> positions [n_S, N_T + 1, n_dof]."""
    n_s, nt, n_dof = u.shape
    q = np.empty((n_s, nt + 1, n_dof))
    q[:, 0, :] = q0
    q[:, 1:, :] = q0 + h * np.cumsum(u, axis=1)
    return q


def time_integrated_error(q_ref, q, h):
    """The paper's E_mu per sample: sqrt(sum_nu h |q - q^|^2) / sqrt(sum_nu h |q|^2), nu = 1..N_T.

    q_ref, q [n_S, N_T + 1, n_dof] -> [n_S]."""
    num = np.sqrt(h * np.sum((q_ref[:, 1:] - q[:, 1:]) ** 2, axis=(1, 2)))
    den = np.sqrt(h * np.sum(q_ref[:, 1:] ** 2, axis=(1, 2)))
    return num / np.where(den > 0, den, 1.0)


def displacement_error(q_ref, q):
    """E_disp per sample: sqrt(sum_nu |q - q^|^2) / sqrt(sum_nu |q^ - q^0|^2), nu = 1..N_T (the
    error relative to how far the agents move; as src/rom/cr_rom_metrics).

    q_ref, q [n_S, N_T + 1, n_dof] -> [n_S] (-1 where the reference does not move)."""
    num = np.sqrt(np.sum((q_ref[:, 1:] - q[:, 1:]) ** 2, axis=(1, 2)))
    den = np.sqrt(np.sum((q_ref[:, 1:] - q_ref[:, :1]) ** 2, axis=(1, 2)))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), -1.0)


def mobility(q_ref, q):
    """|q^N_T - q^0| / |q_ref^N_T - q_ref^0| per sample (< 1: a locked crowd; -1 where the
    reference does not move). q_ref, q [n_S, N_T + 1, n_dof] -> [n_S]."""
    num = np.linalg.norm(q[:, -1] - q[:, 0], axis=1)
    den = np.linalg.norm(q_ref[:, -1] - q_ref[:, 0], axis=1)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), -1.0)


PROJ_PER_CONFIG = ("time", "displacement", "max_move", "depth_in", "overlap_agents_before",
                   "overlap_walls_before", "overlap_agents_after", "overlap_walls_after", "kkt",
                   "n_overlaps", "n_moved", "n_free", "solves", "iterations", "restarts",
                   "refines", "refined")


def run_projection(exe, database, params, positions, workdir, solver="", tol=0.0, refine_max=50,
                   timeout=None, show_progress=False):
    """Exact position projection of ``positions`` [n_S, n_conf, n_dof] (sample s has the
    parameters ``params`` [n_S, n_mu] of ``database``) by the Fortran program ``crowd_project``:
    writes the request (schema crowdrom-projreq) in ``workdir``, runs the program and reads its
    result (schema crowdrom-projected). Returns a dict: ``positions`` [n_S, n_conf, n_dof], each
    of PROJ_PER_CONFIG [n_S, n_conf], and the root attributes ``solver``, ``tol``, ``t_total``.
    ``refine_max``: refinement projections per configuration at most (0: the first-order
    projection from the start only). The program's bad-input errors (exit 2) become InputError, other failures RuntimeError, with
    its one ``error:`` line. ``show_progress``: the program's progress lines (stage, sample k of n,
    ETA) go to this process's standard output instead of being captured."""
    import subprocess

    import h5py

    exe = os.fspath(exe)
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        raise InputError(f"crowd_project not found or not executable: '{exe}' (build it with "
                         "scripts/setup.sh, name it with --crowd-project, or skip the projection "
                         "with --no-project)")
    positions = np.asarray(positions, dtype=float)
    params = np.asarray(params, dtype=float).reshape(positions.shape[0], -1)
    n_s, n_conf, n_dof = positions.shape
    req = os.path.join(os.fspath(workdir), "projection_request.h5")
    out = os.path.join(os.fspath(workdir), "projection_result.h5")
    with h5py.File(req, "w") as f:
        a = f.attrs
        a["schema"], a["schema_version"] = np.bytes_(PROJREQ_SCHEMA), np.int32(PROJREQ_VERSION)
        a["database"] = np.bytes_(os.path.abspath(database))
        a["output"] = np.bytes_(os.path.abspath(out))
        a["solver"] = np.bytes_(solver)
        a["tol"] = float(tol)
        a["refine_max"] = np.int32(refine_max)
        a["n_agents"], a["configs_per_sample"] = np.int32(n_dof // 2), np.int32(n_conf)
        f["positions"] = positions.reshape(n_s * n_conf, n_dof)
        f["params"] = params
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    if show_progress:
        sys.stdout.flush()
    p = subprocess.run([exe, req], stdout=None if show_progress else subprocess.PIPE,
                       stderr=subprocess.PIPE, text=True, env=env, timeout=timeout)
    out_text = p.stdout or ""
    if p.returncode != 0:
        lines = [ln.strip() for ln in (out_text + "\n" + p.stderr).splitlines() if "error:" in ln]
        msg = lines[-1] if lines else (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        if p.returncode == EXIT_BAD_INPUT:
            raise InputError(f"crowd_project: {msg}")
        raise RuntimeError(f"crowd_project failed (exit status {p.returncode}): {msg}")
    res = {"log": out_text}
    with open_h5(out, PROJ_SCHEMA, "projection result") as f:
        q = dataset(f, "positions")
        if q.shape != (n_s * n_conf, n_dof):
            raise InputError(f"'{out}': 'positions' has h5py shape {q.shape}, expected "
                             f"({n_s * n_conf}, {n_dof})")
        res["positions"] = need_finite(out, "positions", q).reshape(n_s, n_conf, n_dof)
        for key in PROJ_PER_CONFIG:
            x = np.asarray(dataset(f, key)).ravel()
            if x.size != n_s * n_conf:
                raise InputError(f"'{out}': '{key}' has {x.size} entries, expected {n_s * n_conf}")
            res[key] = x.reshape(n_s, n_conf)
        res["solver"] = attr(f, "solver", str)
        res["tol"] = attr(f, "tol", float)
        res["t_total"] = attr(f, "t_total", float)
    return res


def error_in_time(q_ref, q):
    """Relative position error per step |q - q^| / |q|: [n_S, N_T + 1]."""
    num = np.linalg.norm(q_ref - q, axis=2)
    den = np.linalg.norm(q_ref, axis=2)
    return num / np.where(den > 0, den, 1.0)


def match_samples(ref_params, params, path, what):
    """Index into ref_params [n_ref, n_mu] of each row of params [n_S, n_mu] (exact up to 1e-10
    relative); InputError if a sample is not in the reference set."""
    if ref_params.shape[1] != params.shape[1]:
        raise InputError(f"{what}: {params.shape[1]} parameter components, the database has "
                         f"{ref_params.shape[1]}")
    scale = np.maximum(np.abs(ref_params).max(axis=0), 1e-300)
    out = np.empty(params.shape[0], dtype=int)
    for i, p in enumerate(params):
        d = np.max(np.abs(ref_params - p) / scale, axis=1)
        j = int(np.argmin(d))
        if d[j] > 1e-10:
            raise InputError(f"{what}: sample {i + 1} (params {np.array2string(p, precision=6)}) "
                             f"is not in the database '{path}'")
        out[i] = j
    return out


def resolve_path(path, relative_to):
    """Path stored in a file: absolute, or relative to the cwd, else to the storing file's folder."""
    if os.path.isabs(path) or os.path.exists(path):
        return path
    cand = os.path.join(os.path.dirname(os.path.abspath(os.fspath(relative_to))), path)
    return cand if os.path.exists(cand) else path


_M = 2147483647  # 2^31 - 1


def _fold(y, t):
    """y mod 2^31-1 in place for 0 <= y < 2^63 (int64 arrays; t a scratch array of the same
    size), as cr_digest's fold: two folds of the high bits, one subtraction."""
    np.right_shift(y, 31, out=t)
    np.bitwise_and(y, _M, out=y)
    y += t
    np.right_shift(y, 31, out=t)
    np.bitwise_and(y, _M, out=y)
    y += t
    y -= _M * (y >= _M)
    return y


_LANES = ((1103515245, 69069, 1664525, 12345, 977), (214013, 1812433253, 22695477, 2531011, 1013))


def digest(arr, offset=0, chunk=1 << 16):
    """Checksum of a dataset as crowdrom writes it (attribute ``checksum``, 16 hex digits; the
    algorithm of src/io/cr_digest.f90): two sums over the elements, in file order, of a mix of
    the element's 64 bits (integers sign-extended to 64 bits) and its 0-based linear index
    (the first element's is ``offset``), modulo 2^31 - 1. ``arr`` is the array as h5py reads it
    (C order = Fortran linear order). Computed in chunks of ``chunk`` elements (in cache); every
    intermediate stays below 2^63."""
    a = np.ascontiguousarray(arr)
    w = (a.astype("<f8") if a.dtype.kind == "f" else a.astype("<i8")).reshape(-1).view("<u8")
    s = [0, 0]
    for i0 in range(0, w.size, chunk):
        ww = w[i0:i0 + chunk]
        lo = (ww & np.uint64(0xFFFFFFFF)).view(np.int64)
        hi = (ww >> np.uint64(32)).view(np.int64)
        t = np.empty(ww.size, np.int64)
        g = _fold(np.arange(offset + i0, offset + i0 + ww.size, dtype=np.int64), t)
        for lane, (a1, a2, a3, a4, a5) in enumerate(_LANES):
            x = _fold(lo * a1, t)
            x += _fold(hi * a2, t)
            x += _fold(g * a3, t)
            x += a4
            _fold(x, t)
            x *= x + a5
            _fold(x, t)
            s[lane] = (s[lane] + int(x.sum()) % _M) % _M
    return "%08x%08x" % tuple(s)


def verify_checksum(f, name):
    """Raise InputError if dataset ``name`` of the open file does not match its ``checksum``."""
    data = dataset(f, name)
    d = f[name]
    if "checksum" not in d.attrs:
        raise InputError("%s: dataset '%s' has no checksum attribute" % (f.filename, name))
    stored = text(d.attrs["checksum"])
    got = digest(data)
    if stored != got:
        raise InputError("%s: checksum mismatch in dataset '%s' (stored %s, data %s): the file is corrupted"
                         % (f.filename, name, stored, got))


# ------------------------------------------------------------------------------ quantities of interest

#: the QoI group's datasets (src/products/cr_qoi_file.f90): name -> shape in rows (n), exits (e),
#: frames (t = n_steps + 1); flags (integers 0/1) come back as bool
_QOI_SHAPES = {"curve": "net", "curve_total": "nt", "t_evac": "n3", "censored": "n3", "exit_width": "ne",
               "flow_rate": "ne", "flow": "ne", "flow_defined": "ne", "overlap_agents": "n",
               "overlap_obstacles": "n", "n_through": "n", "displacement": "n"}
_QOI_FLAGS = ("censored", "flow_defined")


def read_qoi_group(f, name="qoi"):
    """The QoI group ``name`` of an open crowdrom file (the QoI product's ``qoi``, a snapshot
    database's ``train/qoi``, a ROM run's ``setting_k/<set>/qoi``, a full-order output's ``qoi``):
    a dict of numpy arrays, one row per trajectory (curve [n, n_exits, N_T + 1], curve_total
    [n, N_T + 1], t_evac and censored [n, 3] for t50, t90, t100, exit_width, flow_rate, flow,
    flow_defined [n, n_exits], overlap_agents, overlap_obstacles, n_through, displacement [n])
    and the group's attributes (n_rows, n_agents, n_steps, n_exits, dt, evac_pct,
    flow_window_pct). Shapes, finiteness, flags and checksums are checked (InputError)."""
    g = group(f, name)
    path = f.file.filename
    d = {k: attr(g, k, int) for k in ("n_rows", "n_agents", "n_steps", "n_exits")}
    d["dt"] = attr(g, "dt", float)
    d["evac_pct"] = np.asarray(g.attrs.get("evac_pct", (50, 90, 100)))
    d["flow_window_pct"] = np.asarray(g.attrs.get("flow_window_pct", (10, 80)))
    dims = {"n": d["n_rows"], "e": d["n_exits"], "t": d["n_steps"] + 1, "3": 3}
    for key, shape in _QOI_SHAPES.items():
        full = name + "/" + key
        arr = dataset(f, full)
        want = tuple(dims[c] for c in shape)
        if arr.shape != want:
            raise InputError(f"'{path}': dataset '{full}' has shape {arr.shape}, expected {want} "
                             f"(n_rows, n_exits, n_steps + 1 of the group's attributes)")
        verify_checksum(f, full)
        need_finite(path, full, arr)
        if key in _QOI_FLAGS:
            if arr.size and (arr.min() < 0 or arr.max() > 1):
                raise InputError(f"'{path}': dataset '{full}': flags must be 0 or 1")
            arr = arr.astype(bool)
        d[key] = arr
    if d["curve"].size and (d["curve"].min() < 0 or d["curve"].max() > d["n_agents"]):
        raise InputError(f"'{path}': dataset '{name}/curve': counts outside 0..n_agents = {d['n_agents']}")
    return d


def read_qoi(path):
    """A QoI product (schema ``crowdrom-qoi``, version 1; docs/queries.md): ``read_qoi_group``'s
    dict of the group ``qoi`` plus params [n, n_params], param_names (list), outside_box [n]
    (bool), cpu_seconds [n] and the root attributes program, model, config, agent_radius, dt,
    n_queries, n_params. Verifies schema, version, shapes, finiteness and checksums."""
    with open_h5(path, QOI_SCHEMA, "QoI product") as f:
        n, npar = attr(f, "n_queries", int), attr(f, "n_params", int)
        d = read_qoi_group(f, "qoi")
        if d["n_rows"] != n:
            raise InputError(f"'{path}': group 'qoi' has {d['n_rows']} rows, n_queries is {n}")
        for key, want in (("params", (n, npar)), ("outside_box", (n,)), ("cpu_seconds", (n,))):
            arr = dataset(f, key)
            if arr.shape != want:
                raise InputError(f"'{path}': dataset '{key}' has shape {arr.shape}, expected {want}")
            verify_checksum(f, key)
            d[key] = need_finite(path, key, arr)
        if n and (d["outside_box"].min() < 0 or d["outside_box"].max() > 1):
            raise InputError(f"'{path}': dataset 'outside_box': flags must be 0 or 1")
        d["outside_box"] = d["outside_box"].astype(bool)
        for key in ("program", "model", "config"):
            d[key] = attr(f, key, str)
        names = attr(f, "param_names", str)
        d["param_names"] = [x.strip() for x in names.split(",")] if names else []
        d["agent_radius"], d["dt"] = attr(f, "agent_radius", float), attr(f, "dt", float)
        d["n_queries"], d["n_params"] = n, npar
    return d


# ------------------------------------------------------------------------------ outputs

def check_outputs(outputs, inputs=()):
    """Refuse, before any work, outputs that would destroy an input or each other.

    ``outputs`` and ``inputs`` are ``(what, path)`` pairs (paths may be None). Paths are compared
    resolved (``./x``, ``dir/../x``, symbolic links; hard links by inode). Also refused: an output that is
    a directory, or whose directory does not exist or is not writable. Raises ``InputError``.
    """
    seen = []
    ins = [(w, p, os.path.realpath(p)) for w, p in inputs if p and os.path.exists(p)]
    for what, path in outputs:
        if not path:
            continue
        path = os.fspath(path)
        if os.path.isdir(path):
            raise InputError(f"{what} '{path}' is a directory")
        d = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(d):
            raise InputError(f"{what} '{path}': the directory '{d}' does not exist")
        if not os.access(d, os.W_OK | os.X_OK):
            raise InputError(f"{what} '{path}': cannot write in the directory '{d}'")
        real = os.path.realpath(path)
        for w, p, r in ins:
            # the same file also through a hard link (same device and inode)
            if r == real or (os.path.exists(path) and os.path.samefile(path, p)):
                raise InputError(f"{what} '{path}' is the input {w} '{p}' (both are {r}): "
                                 "refusing to overwrite an input")
        for w, p, r in seen:
            if r == real:
                raise InputError(f"{what} '{path}' and {w} '{p}' are the same file ({r})")
        seen.append((what, path, real))


def partial_name(path):
    """Temporary name next to ``path`` keeping its extension (matplotlib picks the format
    from it): ``dir/name.partial.png`` for ``dir/name.png``."""
    stem, ext = os.path.splitext(os.fspath(path))
    return f"{stem}.partial{ext}"


class OutputSet:
    """Files written together or not at all: ``tmp(final)`` names a temporary to write;
    ``commit()`` renames every temporary to its final name; leaving the ``with`` block by an
    exception (or ``abort()``) removes the temporaries and leaves earlier outputs untouched."""

    def __init__(self):
        self.items = []

    def tmp(self, final):
        t = partial_name(final)
        self.items.append((t, os.fspath(final)))
        return t

    def commit(self):
        for t, final in self.items:
            os.replace(t, final)
        self.items = []

    def abort(self):
        for t, _ in self.items:
            try:
                os.remove(t)
            except OSError:
                pass
        self.items = []

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is not None:
            self.abort()
        return False


class OutputDir:
    """A folder of outputs written together or not at all. Files are written into a temporary
    folder next to the target (``<parent>/.<name>.partial-<pid>``, see ``path``); ``commit()``
    puts it in place of the target in one step when the target holds nothing else (a rename, or
    an atomic exchange with the previous set, renameat2 RENAME_EXCHANGE, on Linux; the previous
    set then removed), else renames its files into the target one by one (other files stay). Leaving the ``with`` block by an
    exception, or SIGTERM / SIGINT meanwhile, removes the temporary: the previous set stays as it
    was. A SIGKILL leaves the previous set too, and the temporary, which the next run removes
    (its process is gone). Refused before anything is written: a target that is a file, a parent
    folder that does not exist or cannot be written."""

    def __init__(self, target, what="output directory"):
        self.target = os.path.abspath(os.fspath(target))
        parent, name = os.path.split(self.target)
        if os.path.exists(self.target) and not os.path.isdir(self.target):
            raise InputError(f"{what} '{target}' is a file")
        if not os.path.isdir(parent):
            raise InputError(f"{what} '{target}': the directory '{parent}' does not exist")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"{what} '{target}': cannot write in the directory '{parent}'")
        self.prefix = os.path.join(parent, f".{name}.partial-")
        self.tmp = None
        self._old = {}

    def path(self, name):
        """Where to write output ``name`` (in the temporary folder)."""
        return os.path.join(self.tmp, name)

    def final(self, name):
        return os.path.join(self.target, name)

    def __enter__(self):
        import glob
        import shutil
        import signal

        for stale in glob.glob(self.prefix + "*"):
            pid = stale[len(self.prefix):]
            if pid.isdigit() and not _alive(int(pid)):
                shutil.rmtree(stale, ignore_errors=True)
        self.tmp = self.prefix + str(os.getpid())
        shutil.rmtree(self.tmp, ignore_errors=True)
        os.mkdir(self.tmp)
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old[sig] = signal.signal(sig, _interrupted)
            except ValueError:      # not the main thread
                pass
        return self

    def commit(self):
        """Put the new set in place: the temporary folder renamed to the target when there is
        none; exchanged with it atomically when it holds only files of this set (an earlier run's
        outputs); else (the target holds other files, which stay) each file renamed into it."""
        import shutil

        new = set(os.listdir(self.tmp))
        if not os.path.isdir(self.target):
            os.rename(self.tmp, self.target)
        elif set(os.listdir(self.target)) <= new and _exchange(self.tmp, self.target):
            shutil.rmtree(self.tmp, ignore_errors=True)
        else:
            for name in sorted(new):
                os.replace(os.path.join(self.tmp, name), os.path.join(self.target, name))
            os.rmdir(self.tmp)
        self.tmp = None

    def __exit__(self, kind, value, tb):
        import shutil
        import signal

        for sig, h in self._old.items():
            signal.signal(sig, h)
        self._old = {}
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            self.tmp = None
        return False


class Interrupted(Exception):
    """SIGTERM or SIGINT while an output set was being written (exit status 1)."""


def _interrupted(signum, frame):
    raise Interrupted(f"signal {signum}: stopped, the output set was not written")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _exchange(a, b):
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where unavailable."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    return fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


class ArgumentParser(__import__("argparse").ArgumentParser):
    """argparse's parser whose usage errors raise InputError (one line, exit 2 through
    one_line_errors) instead of printing the usage."""

    def error(self, message):
        raise InputError(f"{' '.join(message.split())} (see --help)")


def one_line_errors(prog, main, argv=None):
    """Run ``main(argv)``; any failure ends with one line ``<prog>: error: ...`` on stderr, never
    a traceback: exit 2 for bad input (InputError), 1 for anything else (an output fault, a bug)."""
    import sys
    try:
        return main(argv)
    except InputError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        where = f"'{exc.filename}': " if getattr(exc, "filename", None) else ""
        print(f"{prog}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_FAILURE
    except Exception as exc:  # noqa: BLE001 - the one-line promise covers unexpected failures too
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"{prog}: error: {type(exc).__name__}: {msg}", file=sys.stderr)
        return EXIT_FAILURE
