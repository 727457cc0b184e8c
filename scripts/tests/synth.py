"""Small synthetic, mutually consistent crowdrom files for the Python tests.

``make_study(tmp)`` writes, with h5py and the Fortran-order convention (h5py shows every
Fortran dimension reversed, so a Fortran [n_dof, M] dataset is written as an (M, n_dof) array):

* a snapshot database (schema crowdrom-snapshots): a hall scene, velocities that are smooth
  functions of (mu, nu) in a 9-dimensional subspace with quickly decaying amplitudes, positions by
  the explicit scheme, sparse multipliers (CSR) in a 10-contact dictionary;
* a ROM file (schema crowdrom-rom, version 2): the POD of the training velocities, gIS cone
  computed on the synthetic multipliers, an mCPG history, PGA histories, an inf-sup table, two
  prepared pairs (POD modes + orthonormal supremizers) with EIM/EQ data, and /pod_compare;
* a ROM run file (schema crowdrom-romrun) with three settings whose Galerkin coefficients carry a
  learnable drift: alpha = a* - g(a*), a* = V_n^T u_FOM and g_i(a) = amp s_i sin(a_i / s_i + 0.5)
  (a contraction, so Delta alpha = g(a*) is a smooth function of alpha, component by component);
* the sweep CSV of the run.

Everything derives from one seed; ``rom_variant`` changes the basis (another supremizer) and
``config_hash`` the database fingerprint, to build mismatched ROMs (variant 1: pair 1 has 5 POD
modes instead of 6; variant 2: the first POD mode has the other sign).
"""
import os
import sys

import h5py
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import crowdrom_io as cio  # noqa: E402

CSV_HEADER = ("setting,set,n,r,n_basis,hyper,contacts,solver,m_v,m_b,m_d,E_avg,E_max,E_proj_avg,"
              "max_overlap,agents_not_left,agents_not_left_fom,infeasible_steps,capped_steps,"
              "t_step_rom,t_step_fom_uzawa,t_step_fom_exact,speedup_uzawa,speedup_exact")

N_AGENTS, N_STEPS, DT, RADIUS = 6, 10, 0.05, 0.05
N_TRAIN, N_VALID = 40, 8
PARAM_NAMES = ["l_exit", "speed"]
HALL_L, HALL_H, WALL, L_EXIT = 1.0, 0.8, 0.05, 0.3
N_DICT = 10
AMPS = np.array([1.0, 0.7, 0.5, 0.35, 0.25, 0.18, 0.01, 0.006, 0.003])
T_UZAWA, T_EXACT = 1.0e-2, 2.0e-3


def _scene(l_exit=L_EXIT):
    L, H, t = HALL_L, HALL_H, WALL
    x_lo, x_hi = 0.5 * (L - l_exit), 0.5 * (L + l_exit)
    polys = [[(-t, -t), (0, -t), (0, H + t), (-t, H + t)],          # left
             [(L, -t), (L + t, -t), (L + t, H + t), (L, H + t)],    # right
             [(-t, -t), (L + t, -t), (L + t, 0), (-t, 0)],          # bottom
             [(0, H), (x_lo, H), (x_lo, H + t), (0, H + t)],        # top, left of the exit
             [(x_hi, H), (L, H), (L, H + t), (x_hi, H + t)]]        # top, right of the exit
    verts = [v for p in polys for v in p] + [(0.5 * L, 0.35 * H)]
    start = np.cumsum([0] + [len(p) for p in polys] + [1])
    return {"obstacle_kind": np.array([3] * 5 + [1], dtype=np.int32),
            "obstacle_radius": np.array([0.0] * 5 + [0.08]),
            "obstacle_vertex_start": start.astype(np.int32),
            "obstacle_vertices": np.array(verts, dtype=float),
            "exit_segment": np.array([[x_lo, H], [x_hi, H]]),
            "domain": np.array([-t, -t, L + t, H + 3 * t])}


def _params(rng, n):
    lo, hi = np.array([0.27, 0.9]), np.array([0.33, 1.1])
    return lo + (hi - lo) * rng.random((n, 2))


def _velocities(params, w):
    """u [n_S, N_T, n_dof] = sum_j c_j(mu, nu) w_j with smooth c_j."""
    nu = np.arange(1, N_STEPS + 1)[None, :]
    u = np.zeros((params.shape[0], N_STEPS, w.shape[0]))
    for j in range(w.shape[1]):
        ph = 6.0 * (j + 1) * (params[:, :1] - 0.3) + 1.5 * (params[:, 1:] - 1.0) + 0.4 * j
        c = AMPS[j] * params[:, 1:] * (1.5 + np.cos(0.25 * (j + 1) * nu + ph))
        u += c[:, :, None] * w[:, j][None, None, :]
    return u


def _positions(q0, u):
    q = np.empty((u.shape[0], N_STEPS + 1, u.shape[2]))
    q[:, 0] = q0
    q[:, 1:] = q0 + DT * np.cumsum(u, axis=1)
    return q


def _flat(a):
    """[n_S, per, n] -> the h5py layout ((per n_S), n) of a Fortran [n, per n_S] dataset."""
    return np.ascontiguousarray(a.reshape(-1, a.shape[-1]))


def _multipliers(rng, n_col):
    off, idx, val = [0], [], []
    for _ in range(n_col):
        k = int(rng.integers(0, 4))
        sel = np.sort(rng.choice(N_DICT, size=k, replace=False)) + 1
        idx += sel.tolist()
        val += (0.1 + rng.random(k) * (1.0 + sel / N_DICT)).tolist()
        off.append(len(idx))
    return (np.array(off, dtype=np.int64), np.array(idx, dtype=np.int32), np.array(val))


def _gis(off, idx, val, r_max):
    """Greedy index selection on CSR columns (errors relative to the largest snapshot norm)."""
    n_col = off.size - 1
    cols = [(idx[off[c]:off[c + 1]] - 1, val[off[c]:off[c + 1]]) for c in range(n_col)]
    res2 = np.array([np.sum(v ** 2) for _, v in cols])
    n1 = np.sqrt(res2.max())
    chosen, err_max, err_mean = [], [1.0], [np.mean(np.sqrt(res2)) / n1]
    covered = np.zeros(N_DICT, bool)
    while len(chosen) < r_max:
        worst = int(np.argmax(res2))
        i_w, v_w = cols[worst]
        cand = [(v, i) for i, v in zip(i_w, v_w) if not covered[i]]
        if not cand:
            break
        i = max(cand)[1]
        covered[i] = True
        chosen.append(i + 1)
        for c, (ii, vv) in enumerate(cols):
            hit = ii == i
            if hit.any():
                res2[c] = max(res2[c] - np.sum(vv[hit] ** 2), 0.0)
        err_max.append(np.sqrt(res2.max()) / n1)
        err_mean.append(np.mean(np.sqrt(res2)) / n1)
    return np.array(chosen, dtype=np.int32), np.array(err_max), np.array(err_mean)


def _orth_complement(rng, base, k):
    x = rng.standard_normal((base.shape[0], k))
    for _ in range(2):
        x -= base @ (base.T @ x)
    q, _ = np.linalg.qr(x)
    return q


def make_database(path, seed=7, config_hash="0123456789abcdef"):
    rng = np.random.default_rng(seed)
    n_dof = 2 * N_AGENTS
    w, _ = np.linalg.qr(rng.standard_normal((n_dof, len(AMPS))))
    gx, gy = np.meshgrid([0.2, 0.5, 0.8], [0.15, 0.55])
    q0 = np.stack([gx.ravel(), gy.ravel()], axis=1).ravel()
    sets = {}
    with h5py.File(path, "w") as f:
        a = f.attrs
        a["schema"], a["schema_version"] = np.bytes_("crowdrom-snapshots"), np.int32(1)
        a["config_hash"] = np.bytes_(config_hash)
        a["n_agents"], a["n_steps"] = np.int32(N_AGENTS), np.int32(N_STEPS)
        a["dt"], a["agent_radius"] = DT, RADIUS
        a["n_train"], a["n_valid"], a["n_params"] = np.int32(N_TRAIN), np.int32(N_VALID), np.int32(2)
        a["param_names"] = np.bytes_(",".join(PARAM_NAMES))
        a["complete"] = np.int32(1)
        f["initial_positions"] = q0
        s = f.create_group("scene")
        for k, v in _scene().items():
            s[k] = v
        s.attrs["n_walls"], s.attrs["l_exit"] = np.int32(5), L_EXIT
        s.attrs["hall_length"], s.attrs["hall_width"], s.attrs["wall_thickness"] = HALL_L, HALL_H, WALL
        c = f.create_group("contacts")
        ia = np.array([1, 1, 2, 2, 3, 4, 5, 1, 3, 6], dtype=np.int32)
        ib = np.array([2, 3, 3, 4, 5, 5, 6, 0, 0, 0], dtype=np.int32)
        ob = np.array([0, 0, 0, 0, 0, 0, 0, 4, 5, 6], dtype=np.int32)
        c["ia"], c["ib"], c["ob"] = ia, ib, ob
        c["key"] = np.arange(1, N_DICT + 1, dtype=np.int64)
        for name, n_s in (("train", N_TRAIN), ("valid", N_VALID)):
            p = _params(rng, n_s)
            u = _velocities(p, w)
            q = _positions(q0, u)
            g = f.create_group(name)
            g["params"] = p                                  # Fortran [n_mu, n_S]
            g["positions"] = _flat(q)                        # Fortran [n_dof, (N_T+1) n_S]
            g["velocities"] = _flat(u)                       # Fortran [n_dof, N_T n_S]
            g["desired"] = _flat(u + 0.1)
            # each sample's scene as crowd_snapshots stores it (Fortran [2 n_v, n_S], [4, n_S])
            scs = [_scene(l_exit=pk[0]) for pk in p]
            g["scene_vertices"] = np.array([sc["obstacle_vertices"].ravel() for sc in scs])
            g["scene_exit"] = np.array([sc["exit_segment"].ravel() for sc in scs])
            off, idx, val = _multipliers(rng, n_s * N_STEPS)
            g["lambda_offset"], g["lambda_index"], g["lambda_value"] = off, idx, val
            st = g.create_group("stats")
            st["time"] = np.full(n_s, 0.01)
            sets[name] = {"params": p, "u": u, "q": q, "csr": (off, idx, val)}
        # every dataset with its checksum, as crowd_snapshots writes them
        cio.stamp_checksums(f)
    return {"path": path, "q0": q0, "w": w, "sets": sets, "config_hash": config_hash}


def make_rom(path, db, rom_variant=0):
    """ROM file for database ``db`` (dict from make_database); returns the pairs' bases."""
    rng = np.random.default_rng(100 + rom_variant)
    u = db["sets"]["train"]["u"]
    S = _flat(u).T                                           # [n_dof, N_T n_train]
    U, sig, _ = np.linalg.svd(S, full_matrices=False)
    U *= np.where(U[np.argmax(np.abs(U), axis=0), np.arange(U.shape[1])] < 0, -1.0, 1.0)
    if rom_variant == 2:                                     # another sign of mode 1
        U[:, 0] *= -1
    pairs = {1: (5 if rom_variant == 1 else 6, 4, 2), 2: (4, 3, 3)}   # k: (n, r, n_pga)
    bases = {}
    off, idx, val = db["sets"]["train"]["csr"]
    indices, e_max, e_mean = _gis(off, idx, val, N_DICT)
    with h5py.File(path, "w") as f:
        a = f.attrs
        a["schema"], a["schema_version"] = np.bytes_("crowdrom-rom"), np.int32(2)
        a["database"] = np.bytes_(os.path.abspath(db["path"]))
        a["database_config_hash"] = np.bytes_(db["config_hash"])
        a["n_agents"], a["n_steps"], a["agent_radius"], a["dt"] = np.int32(N_AGENTS), np.int32(N_STEPS), RADIUS, DT
        a["n_pairs"] = np.int32(len(pairs))
        f["pod/sigma"] = sig
        f["pod"].attrs["method"] = np.bytes_("tsqr")
        sup = _orth_complement(rng, U[:, :6], 2)
        f["basis/v"] = np.hstack([U[:, :6], sup]).T
        f["basis"].attrs["n_pod"], f["basis"].attrs["n_pga"] = np.int32(6), np.int32(2)
        for name, method, em, en in (("cone", "gis", e_max, e_mean),
                                     ("cone_mcpg", "mcpg", np.minimum(1.0, e_max * 1.3 + 0.02),
                                      np.minimum(1.0, e_mean * 1.2 + 0.01))):
            g = f.create_group(name)
            g.attrs["method"], g.attrs["r"] = np.bytes_(method), np.int32(len(em) - 1)
            g["err_max"], g["err_mean"] = em, en
            if method == "gis":
                g["indices"] = indices
        f["pga/err"] = np.array([1.0, 0.4, 0.05, 8e-3, 9e-5])
        f["contacts/ia"] = np.arange(1, N_DICT + 1, dtype=np.int32)
        nn, rr = np.meshgrid([2, 4, 6], [2, 4, 8], indexing="ij")
        g = f.create_group("infsup")
        g["n"], g["r"] = nn.ravel().astype(np.int32), rr.ravel().astype(np.int32)
        gam = np.where(rr.ravel() > nn.ravel(), 0.0, 0.3 / rr.ravel())
        g["gamma_low_min"], g["gamma_up_min"], g["gamma_up_mean"] = 0.9 * gam, gam, 1.5 * gam
        g["gamma_low_min_pga"], g["gamma_up_min_pga"] = 0.2 + 0.9 * gam, 0.25 + gam
        g["gamma_up_mean_pga"], g["n_pga"] = 0.3 + gam, (rr.ravel() // 2).astype(np.int32)
        for k, (n, r, n_pga) in pairs.items():
            sup = _orth_complement(rng, U[:, :n], n_pga)
            v = np.hstack([U[:, :n], sup])
            bases[k] = (v, n, r)
            g = f.create_group(f"pairs/{k}")
            g.attrs["n"], g.attrs["r"] = np.int32(n), np.int32(r)
            g.attrs["n_pga"], g.attrs["n_basis"] = np.int32(n_pga), np.int32(n + n_pga)
            g["v"] = v.T                                     # Fortran [n_dof, n_basis]
            g["pga_err"] = np.geomspace(1.0, 1e-5, n_pga + 1)
            for s, p in (("s1", 12), ("s2", 120), ("s3", 10)):
                m = 6
                e = g.create_group(f"eim/{s}")
                e["sigma"] = np.geomspace(5.0, 5e-4 * (1 + k), p // 2)
                e["err"] = np.geomspace(0.5, 1e-3 * k, m)
                e.attrs["m"], e.attrs["p"] = np.int32(m), np.int32(p)
                q = g.create_group(f"eq/{s}")
                q["err"] = np.geomspace(0.8, 1e-4 * k, m)
                q["indices"] = np.arange(1, m + 1, dtype=np.int32)
                q["weights"] = np.tril(np.ones((m, m)))
                q.attrs["m"], q.attrs["p"] = np.int32(m), np.int32(p)
        g = f.create_group("pod_compare")
        g["n"] = np.array([2, 4, 6, 8], dtype=np.int32)
        g["t_exact"] = np.array([0.5, 0.5, 0.51, 0.5])
        g["t_rpod"] = np.array([0.01, 0.015, 0.02, 0.03])
        g["sigma_exact"] = sig
        g["sigma_rpod"] = sig[:8] * (1 + 1e-3 * np.arange(8))
    return bases


def drift(a_star, scale, amp):
    """g(a*) = amp s sin(a*/s + 0.5) component by component (Lipschitz amp < 1)."""
    return amp * scale * np.sin(a_star / scale + 0.5)


def _err_time(q_ref, q):
    return np.linalg.norm(q_ref - q, axis=2) / np.linalg.norm(q_ref, axis=2)


def _e_mu(q_ref, q):
    num = np.sqrt(DT * np.sum((q_ref[:, 1:] - q[:, 1:]) ** 2, axis=(1, 2)))
    return num / np.sqrt(DT * np.sum(q_ref[:, 1:] ** 2, axis=(1, 2)))


SETTINGS = [  # pair, hyper, drift amplitude, t_step, with train set
    dict(pair=1, hyper="eq", amp=0.4, t_step=2.0e-4, train=True),
    dict(pair=1, hyper="none", amp=0.25, t_step=1.0e-3, train=True),
    dict(pair=2, hyper="eim", amp=0.3, t_step=4.0e-4, train=False),
]


def make_romrun(path, db, rom_path, bases, csv_path=None):
    """ROM run file (and sweep CSV) for the settings in SETTINGS."""
    rng = np.random.default_rng(3)
    rows = []
    with h5py.File(path, "w") as f:
        a = f.attrs
        a["schema"], a["schema_version"] = np.bytes_("crowdrom-romrun"), np.int32(1)
        a["rom_file"], a["database"] = np.bytes_(os.path.abspath(rom_path)), np.bytes_(os.path.abspath(db["path"]))
        a["n_agents"], a["n_steps"], a["dt"], a["agent_radius"] = np.int32(N_AGENTS), np.int32(N_STEPS), DT, RADIUS
        a["param_names"] = np.bytes_(",".join(PARAM_NAMES))
        a["n_settings"] = np.int32(len(SETTINGS))
        t = f.create_group("fom_timing")
        t.attrs["t_step_uzawa"], t.attrs["t_step_exact"] = T_UZAWA, T_EXACT
        t.attrs["exact_solver"] = np.bytes_("active_set")
        for k, s in enumerate(SETTINGS, start=1):
            v, n, r = bases[s["pair"]]
            n_basis = v.shape[1]
            g = f.create_group(f"setting_{k}")
            astar_train = db["sets"]["train"]["u"] @ v[:, :n]
            scale = astar_train.reshape(-1, n).std(axis=0) + 1e-3
            e_avg = None
            for name in (["train", "valid"] if s["train"] else ["valid"]):
                d = db["sets"][name]
                astar = d["u"] @ v[:, :n]                            # [n_S, N_T, n]
                alpha = np.zeros(astar.shape[:2] + (n_basis,))
                alpha[:, :, :n] = astar - drift(astar, scale, s["amp"])
                alpha[:, :, n:] = 0.02 * rng.standard_normal(alpha[:, :, n:].shape)
                q = _positions(db["q0"], alpha @ v.T)
                qp = _positions(db["q0"], (d["u"] @ v) @ v.T)
                e_mu = _e_mu(d["q"], q)
                gs = g.create_group(name)
                gs["params"] = d["params"]
                gs["alpha"] = _flat(alpha)                           # Fortran [n_basis, N_T n_S]
                gs["positions"] = _flat(q)
                gs["err_time"] = _err_time(d["q"], q)                # Fortran [N_T+1, n_S]
                gs["E_mu"], gs["E_proj"] = e_mu, _e_mu(d["q"], qp)
                gs["max_overlap"] = np.zeros(e_mu.size)
                gs["n_not_left"] = np.zeros(e_mu.size, dtype=np.int32)
                gs["time"] = np.full(e_mu.size, s["t_step"] * N_STEPS)
                if name == "valid":
                    e_avg = float(e_mu.mean())
                rows.append([k, name, n, r, n_basis, s["hyper"], "cone", "nnls", 2 * n, r, 2 * r,
                             float(e_mu.mean()), float(e_mu.max()), float(gs["E_proj"][()].mean()),
                             0.0, 0, 0, 0, 0, s["t_step"], T_UZAWA, T_EXACT,
                             T_UZAWA / s["t_step"], T_EXACT / s["t_step"]])
            at = g.attrs
            at["n"], at["r"], at["n_basis"], at["pair"] = np.int32(n), np.int32(r), np.int32(n_basis), np.int32(s["pair"])
            at["hyper"], at["contacts"], at["solver"] = np.bytes_(s["hyper"]), np.bytes_("cone"), np.bytes_("nnls")
            at["m_v"], at["m_b"], at["m_d"] = np.int32(2 * n), np.int32(r), np.int32(2 * r)
            at["E_avg"], at["t_step"] = e_avg, s["t_step"]
            at["speedup_uzawa"], at["speedup_exact"] = T_UZAWA / s["t_step"], T_EXACT / s["t_step"]
    if csv_path:
        with open(csv_path, "w") as fh:
            fh.write(CSV_HEADER + "\n")
            for row in rows:
                fh.write(",".join(repr(x) if isinstance(x, float) else str(x) for x in row) + "\n")
    return rows


def make_study(tmp, name="study", seed=7, config_hash="0123456789abcdef", rom_variant=0):
    """Database, ROM, ROM run and CSV under directory ``tmp``; returns their paths."""
    tmp = os.fspath(tmp)
    paths = {k: os.path.join(tmp, f"{name}_{k}") for k in ("db.h5", "rom.h5", "romrun.h5", "sweep.csv")}
    db = make_database(paths["db.h5"], seed=seed, config_hash=config_hash)
    bases = make_rom(paths["rom.h5"], db, rom_variant=rom_variant)
    make_romrun(paths["romrun.h5"], db, paths["rom.h5"], bases, csv_path=paths["sweep.csv"])
    return {"db": paths["db.h5"], "rom": paths["rom.h5"], "romrun": paths["romrun.h5"],
            "csv": paths["sweep.csv"], "data": db, "bases": bases}
