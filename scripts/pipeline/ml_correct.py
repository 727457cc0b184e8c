#!/usr/bin/env python3
"""ML-corrected reduced-order model (the paper's section 3.4) for one setting of a crowd_rom run.

For each truncation n (default 5, 10, ... up to the number N of POD modes of the setting's ROM
pair) and each regressor (random forest, multi-layer perceptron) a map

    Psi: features(sigma) = (alpha_1..alpha_n [, mu] [, nu])  ->  Delta alpha in R^n

is learned on the training set, with target Delta alpha = V_n^T u_FOM - alpha_n: the drift
between the Galerkin coefficients of the ROM and the optimal (orthogonal projection)
coefficients of the full-order velocity on the first n POD modes. This is the variant of
section 3.4 and of the results (the correction stays in span(phi_1..phi_n)); regressing the
truncated tail alpha_{n+1..}, which the results paragraph also mentions, is not done because the
enriched basis is supremized (its tail is not a POD tail). The corrected velocities are

    u^(nu) = V_n (alpha_n(nu) + Psi(features(nu)))

and the positions follow the explicit scheme q(nu) = q(nu-1) + h u(nu) from the FOM initial
positions. Errors are the paper's time-integrated relative position errors E_mu, averaged over
the validation parameters (E_avg), for the baseline ROM, the corrected ROM and the projection
V_n V_n^T u_FOM (the best any correction in span(phi_1..phi_n) can do).

The corrected positions overlap (nothing in the regression keeps agents apart), so every
corrected configuration is then projected exactly onto the configurations without overlap
(q_proj = argmin |q - q_ml|^2, the Fortran program crowd_project: one projection of the full
model's kind with desired velocity 0 and h = 1, the full model's exact solver); the accuracy
(E_avg, E_disp, mobility, deepest overlaps) is reported before and after, with the projection
time per step and per query (each regressor's best n by default, --project-all: every n;
--no-project skips it).

The quantities of interest (evacuation curves, t50 / t90 / t100 with their censoring, steady
flows, overlaps, agents through walls, displacement) of the corrected validation trajectories of
each regressor's best n, and of the same after the projection, are computed by crowd_predict
(model = 'positions': the one definition of the QoIs, src/model/cr_qoi.f90) and stored in the
output as QoI groups <regressor>/best/qoi and <regressor>/best/projected_qoi (the layout of the
QoI product, read by crowdrom_io.read_qoi_group); --no-qoi skips them (root attribute qoi = 0).

The correction is a post-processing of the ROM coefficients: it is applied to all validation
steps in one batch. Its cost per step (batch prediction time / number of steps) is added to the
ROM step time to give the corrected speedups against the FOM (Uzawa and exact solver).

Inputs: a ROM run file (schema crowdrom-romrun) with the setting's 'train' and 'valid' sets;
the ROM file and snapshot database named in its attributes (overridable). Outputs: an HDF5
file (schema crowdrom-ml, see --help-output), the trained models (joblib, with metadata that
ties them to the ROM), a Markdown table on stdout and optionally a CSV table.

Prediction for any list of parameters (--predict PRED.h5): PRED.h5 is a crowd_predict product of
the reduced model (model = 'rom', trajectories = .true.: it holds each query's coefficients alpha);
the saved models of the same ROM pair (--models-dir, truncation --n or each regressor's best n of a
training output --ml-output) correct those coefficients as above, the corrected positions are
integrated from the ROM file's initial positions, and their quantities of interest are computed by
crowd_predict itself (model = 'positions', the one definition of the QoIs) into a product of the
same schema, model "ml <regressor> n=<n>", whose per-query CPU seconds are the reduced query's
plus its share of the batch prediction. One output per regressor (-o; with several regressors
<stem>_<regressor>.h5). No database and no ROM run file are needed.

Exit status: 0 success, 2 bad input (one 'ml_correct: error:' line on stderr), 1 other failure.
"""
import argparse
import copy
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "ml_correct"
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_CONFIG = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ml_config.json")
REGRESSORS = ("random_forest", "mlp")
MODEL_FORMAT = "crowdrom-ml-model"
MODEL_FORMAT_VERSION = 1

OUTPUT_DOC = """\
Output HDF5 file (schema 'crowdrom-ml', version 1). Shapes as h5py shows them (the Fortran order
is the reverse); K = number of n values, n_S = validation samples, N_T = steps, n_dof = 2 n_a.
  root attributes: schema, schema_version, program, mode ('train' or 'predict-only'), romrun,
    rom_file, database, database_config_hash, setting, pair, pair_n, pair_r, pair_n_basis,
    hyper, n_agents, n_steps, dt, n_valid, n_train, features (comma-separated names with n as
    'alpha_1..alpha_n'), target ('delta_alpha'), config (JSON), sklearn_version,
    t_step_rom, t_step_fom_uzawa, t_step_fom_exact, speedup_rom_uzawa, speedup_rom_exact,
    E_avg_baseline_stored (the setting's E_avg attribute)
  n_values [K]; valid_params [n_S, n_mu]
  E_avg_baseline (scalar), E_mu_baseline [n_S]: ROM vs FOM, recomputed from the run's positions
  E_avg_projection [K], E_mu_projection [K, n_S]: positions of V_n V_n^T u_FOM
  <regressor>/ (random_forest, mlp): E_avg [K], E_mu [K, n_S], factor [K] (= baseline / corrected),
    t_fit [K] (s), t_predict_step [K] (s per step, batch), t_predict_single [K] (s per call on one
    step), t_step [K] (= t_step_rom + t_predict_step), speedup [K] (against the Uzawa FOM, the
    paper's reference), speedup_exact [K]; attributes best_n, best_E_avg
  <regressor>/best/positions [(N_T+1) n_S, n_dof] (corrected validation positions for best_n, the
    layout of the database and ROM run positions), <regressor>/best/err_time [n_S, N_T+1]
  accuracy before the projection: E_avg_baseline_disp, mobility_baseline (the ROM itself);
    <regressor>/E_disp, mobility [K] (means over the samples)
  exact projection (root attribute projected = 1; -1 in every figure when --no-project):
    root attributes project_solver, project_tol, project_refine_max, t_query_rom, t_query_fom_exact (-1: not in the
    ROM run file); <regressor>/: overlap_agents, overlap_walls [K] (deepest overlaps of the
    corrected positions, m), E_avg_proj, E_disp_proj, mobility_proj, overlap_agents_proj,
    overlap_walls_proj [K] (the same after the projection), moved_fraction [K] (agents moved per
    configuration / n_agents), t_project_step [K] (s per configuration nu >= 1),
    t_project_query [K] (s per sample, its N_T + 1 configurations), t_query [K] (= t_query_rom
    + N_T t_predict_step + t_project_query), speedup_query_exact [K] (t_query_fom_exact /
    t_query), speedup_exact_proj [K] (per step: t_step_fom_exact / (t_step + t_project_step));
    <regressor>/best/projected_positions [(N_T+1) n_S, n_dof], best/projected_err_time
  quantities of interest (root attribute qoi = 1; 0 with --no-qoi): <regressor>/best/qoi, the QoI
    group (docs/queries.md: curve [n_S, n_exits, N_T+1], curve_total, t_evac and censored [n_S, 3],
    exit_width, flow_rate, flow, flow_defined, overlap_agents, overlap_obstacles, n_through,
    displacement) of the corrected validation trajectories (best n), computed by crowd_predict
    model = 'positions'; <regressor>/best/projected_qoi the same after the exact projection
"""


def fail(msg, code=2):
    print(f"{PROG}: error: {msg}", file=sys.stderr)
    sys.exit(code)


def warn(msg):
    print(f"{PROG}: warning: {msg}", file=sys.stderr)


def log(msg, quiet=False):
    if not quiet:
        print(f"{PROG}: {msg}", flush=True)


# ------------------------------------------------------------------------------ configuration

def _merge(base, over, where):
    """Deep merge ``over`` into a copy of ``base``; unknown keys are errors (keys '_...' ignored)."""
    out = copy.deepcopy(base)
    for key, val in over.items():
        if key.startswith("_"):
            continue
        if key not in base:
            known = ", ".join(k for k in base if not k.startswith("_"))
            raise InputError(f"{where}: unknown key '{key}' (known: {known})")
        if isinstance(base[key], dict) and key not in ("random_forest", "mlp"):
            if not isinstance(val, dict):
                raise InputError(f"{where}: '{key}' must be an object")
            out[key] = _merge(base[key], val, f"{where}: {key}")
        elif key in ("random_forest", "mlp"):
            if not isinstance(val, dict):
                raise InputError(f"{where}: '{key}' must be an object")
            out[key].update({k: v for k, v in val.items() if not k.startswith("_")})
        else:
            out[key] = val
    return out


def _read_json(path):
    try:
        with open(path) as fh:
            return json.load(fh)
    except FileNotFoundError:
        raise InputError(f"config file not found: '{path}'") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"config file '{path}': invalid JSON: {exc}") from None


def load_config(path=None, overrides=None):
    """Defaults from ml_config.json, then the user's file, then ``overrides`` (a dict); checked."""
    cfg = _read_json(DEFAULT_CONFIG)
    cfg = {k: v for k, v in cfg.items() if not k.startswith("_")}
    if path:
        user = _read_json(path)
        if not isinstance(user, dict):
            raise InputError(f"config file '{path}': the top level must be an object")
        cfg = _merge(cfg, user, f"config file '{path}'")
    if overrides:
        cfg = _merge(cfg, overrides, "config override")
    check_config(cfg)
    return cfg


def check_config(cfg):
    """Ranges, types and the regressor arguments (against sklearn's own parameter lists)."""
    problems = []
    nv = cfg["n_values"]
    if not isinstance(nv, list) or not all(isinstance(x, int) and x >= 1 for x in nv):
        problems.append("n_values must be a list of integers >= 1 (empty: automatic)")
    if not isinstance(cfg["n_step"], int) or cfg["n_step"] < 1:
        problems.append("n_step must be an integer >= 1")
    for key in ("append_mu", "append_nu"):
        if not isinstance(cfg["features"][key], bool):
            problems.append(f"features.{key} must be true or false")
    if not isinstance(cfg["scale_target"], bool):
        problems.append("scale_target must be true or false")
    regs = cfg["regressors"]
    if not isinstance(regs, list) or not regs or any(r not in REGRESSORS for r in regs) \
            or len(set(regs)) != len(regs):
        problems.append(f"regressors must be a non-empty list of distinct names from {list(REGRESSORS)}")
    if not isinstance(cfg["timing_repeats"], int) or cfg["timing_repeats"] < 1:
        problems.append("timing_repeats must be an integer >= 1")
    if cfg["project"] not in ("best", "all", "none"):
        problems.append("project must be 'best', 'all' or 'none'")
    for name in REGRESSORS:
        try:
            make_regressor(name, cfg)
        except InputError as exc:
            problems.append(str(exc))
    if problems:
        raise InputError("bad ML configuration: " + "; ".join(problems))


def make_regressor(name, cfg):
    """A fresh sklearn estimator from the config section ``name``."""
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.neural_network import MLPRegressor

    cls = {"random_forest": RandomForestRegressor, "mlp": MLPRegressor}[name]
    kw = dict(cfg[name])
    valid = cls().get_params()
    bad = [k for k in kw if k not in valid]
    if bad:
        raise InputError(f"{name}: unknown argument(s) {bad} of {cls.__name__}")
    if name == "mlp" and "hidden_layer_sizes" in kw:
        kw["hidden_layer_sizes"] = tuple(kw["hidden_layer_sizes"])
    try:
        est = cls(**kw)
        # sklearn validates constructor arguments at fit time; do it now to report early
        if hasattr(est, "_validate_params"):
            est._validate_params()
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: bad argument: {exc}") from None
    return est


# ------------------------------------------------------------------------------ data

def feature_names(n, param_names, n_mu, cfg):
    names = [f"alpha_{i}" for i in range(1, n + 1)]
    if cfg["features"]["append_mu"]:
        pn = param_names if len(param_names) == n_mu else [f"mu_{j}" for j in range(1, n_mu + 1)]
        names += [f"mu:{p}" for p in pn]
    if cfg["features"]["append_nu"]:
        names.append("nu")
    return names


def make_features(alpha, params, n, cfg):
    """alpha [n_S, N_T, n_basis], params [n_S, n_mu] -> X [n_S N_T, n_features] (rows: sample
    major, step minor)."""
    n_s, nt, _ = alpha.shape
    cols = [alpha[:, :, :n].reshape(n_s * nt, n)]
    if cfg["features"]["append_mu"]:
        cols.append(np.repeat(params, nt, axis=0))
    if cfg["features"]["append_nu"]:
        cols.append(np.tile(np.arange(1, nt + 1, dtype=float), n_s)[:, None])
    return np.hstack(cols)


def basis_hash(v_n):
    """Fingerprint of the first n basis vectors (the data a model was trained for)."""
    return hashlib.sha256(np.ascontiguousarray(v_n, dtype="<f8").tobytes()).hexdigest()[:16]


class Study:
    """Everything one ML correction run needs, read and cross-checked."""

    def __init__(self, romrun, setting, rom=None, database=None, need_train=True):
        self.romrun_path = os.fspath(romrun)
        with cio.open_h5(romrun, cio.ROMRUN_SCHEMA, "ROM run file") as f:
            self.meta = cio.romrun_meta(f)
            self.setting = cio.romrun_setting(f, setting)
            self.n_steps, self.n_dof = self.meta["n_steps"], 2 * self.meta["n_agents"]
            if "valid" not in self.setting["sets"]:
                raise InputError(f"'{romrun}': setting {setting} has no 'valid' set")
            if need_train and "train" not in self.setting["sets"]:
                raise InputError(f"'{romrun}': setting {setting} has no 'train' set (run crowd_rom "
                                 "with the training set too, or use --predict-only with saved models)")
            self.rom_valid = cio.romrun_set(f, setting, "valid", self.n_steps, self.n_dof)
            self.rom_train = (cio.romrun_set(f, setting, "train", self.n_steps, self.n_dof)
                              if need_train else None)
            for name, rs in (("valid", self.rom_valid), ("train", self.rom_train)):
                if rs is not None and "diverged_step" in rs and np.any(rs["diverged_step"] > 0):
                    raise InputError(f"'{romrun}': setting {setting} has {int(np.sum(rs['diverged_step'] > 0))} "
                                     f"diverged reduced trajectories in its '{name}' set (crowd_rom stopped them); "
                                     "the correction needs every trajectory: choose another setting")
        self.rom_path = rom or cio.resolve_path(self.meta["rom_file"], romrun)
        self.db_path = database or cio.resolve_path(self.meta["database"], romrun)
        with cio.open_h5(self.rom_path, cio.ROM_SCHEMA, "ROM file") as f:
            self.rom_hash = cio.attr(f, "database_config_hash", str)
            self.pair = cio.read_rom_pair(f, self.setting["pair"])
        with cio.open_h5(self.db_path, cio.DB_SCHEMA, "database") as f:
            self.db_meta = cio.read_database_meta(f)
            self.q0 = cio.dataset(f, "initial_positions").ravel()
            self.db_valid = cio.read_database_set(f, "valid")
            self.db_train = cio.read_database_set(f, "train") if need_train else None
        self._check()
        self.h = self.meta["dt"]
        self.param_names = self.db_meta["param_names"]

    def _check(self):
        s, p, m, d = self.setting, self.pair, self.meta, self.db_meta
        if d["config_hash"] and self.rom_hash != d["config_hash"]:
            raise InputError(f"ROM file '{self.rom_path}' was built from a database with config_hash "
                             f"{self.rom_hash}, but '{self.db_path}' has {d['config_hash']}")
        for key in ("n_agents", "n_steps"):
            if m[key] != d[key]:
                raise InputError(f"{key} = {m[key]} in the ROM run file but {d[key]} in the database")
        if abs(m["dt"] - d["dt"]) > 1e-14 * max(1.0, abs(d["dt"])):
            raise InputError(f"dt = {m['dt']} in the ROM run file but {d['dt']} in the database")
        if self.q0.size != self.n_dof:
            raise InputError(f"'{self.db_path}': initial_positions has {self.q0.size} entries, "
                             f"expected {self.n_dof}")
        if p["V"].shape != (self.n_dof, p["n_basis"]):
            raise InputError(f"'{self.rom_path}': pair {p['index']} basis has shape {p['V'].shape}, "
                             f"expected ({self.n_dof}, {p['n_basis']})")
        if s["n_basis"] != p["n_basis"]:
            raise InputError(f"setting {s['index']} has n_basis = {s['n_basis']} but pair {p['index']} "
                             f"of '{self.rom_path}' has {p['n_basis']}")
        if s["n"] != p["n"]:
            warn(f"setting {s['index']} has n = {s['n']}, pair {p['index']} has {p['n']} POD modes; "
                 f"the correction uses the pair's")
        for name, rs in (("valid", self.rom_valid), ("train", self.rom_train)):
            if rs is not None and rs["alpha"].shape[2] != p["n_basis"]:
                raise InputError(f"'{self.romrun_path}': setting {s['index']}/{name}/alpha has "
                                 f"{rs['alpha'].shape[2]} coefficients, the pair's basis {p['n_basis']}")
        # ROM samples -> database samples (same parameters)
        self.valid_idx = cio.match_samples(self.db_valid["params"], self.rom_valid["params"],
                                           self.db_path, f"'{self.romrun_path}' setting {s['index']}/valid")
        if self.rom_train is not None:
            self.train_idx = cio.match_samples(self.db_train["params"], self.rom_train["params"],
                                               self.db_path, f"'{self.romrun_path}' setting {s['index']}/train")

    def n_values(self, cfg, requested=None):
        n_pod = self.pair["n"]
        if requested:
            vals = list(requested)
        elif cfg["n_values"]:
            vals = list(cfg["n_values"])
        else:
            vals = list(range(cfg["n_step"], n_pod + 1, cfg["n_step"]))
            if not vals or vals[-1] != n_pod:
                vals.append(n_pod)
        bad = [n for n in vals if n < 1 or n > n_pod]
        if bad:
            raise InputError(f"n = {bad} outside 1..{n_pod} (POD modes of pair {self.pair['index']})")
        return sorted(set(vals))

    def metadata(self, n, features, regressor, cfg):
        import sklearn

        p = self.pair
        return {"format": MODEL_FORMAT, "format_version": MODEL_FORMAT_VERSION,
                "rom_file": os.path.abspath(self.rom_path), "database_config_hash": self.rom_hash,
                "pair": p["index"], "pair_n": p["n"], "pair_r": p["r"], "pair_n_basis": p["n_basis"],
                "n": n, "basis_hash": basis_hash(p["V"][:, :n]), "features": features,
                "target": "delta_alpha", "regressor": regressor, "regressor_config": cfg[regressor],
                "scale_target": cfg["scale_target"], "sklearn_version": sklearn.__version__,
                "romrun": os.path.abspath(self.romrun_path), "setting": self.setting["index"]}


# ------------------------------------------------------------------------------ models

def model_path(models_dir, regressor, n):
    return os.path.join(models_dir, f"{regressor}_n{n}.joblib")


def save_model(path, bundle, outs):
    """Write the model under a temporary name of the output set ``outs`` (renamed with the other
    outputs when the whole run succeeded; removed when it fails)."""
    import joblib

    joblib.dump(bundle, outs.tmp(path))


def load_model(path, expected):
    """Load a saved model and refuse it unless it was trained for the same ROM (database hash,
    pair, basis), the same n and the same features."""
    import joblib
    import sklearn

    if not os.path.exists(path):
        raise InputError(f"saved model not found: '{path}' (train first, without --predict-only)")
    try:
        bundle = joblib.load(path)
    except Exception as exc:  # noqa: BLE001 - any unpickling problem is a bad input file
        raise InputError(f"cannot load model '{path}': {exc}") from None
    meta = bundle.get("meta", {}) if isinstance(bundle, dict) else {}
    if meta.get("format") != MODEL_FORMAT:
        raise InputError(f"'{path}' is not a {MODEL_FORMAT} file")
    checks = [("database_config_hash", "ROM built from database config_hash"),
              ("pair", "ROM pair index"), ("pair_n", "pair POD modes n"), ("pair_r", "pair cone size r"),
              ("pair_n_basis", "pair basis size"), ("n", "truncation n"),
              ("basis_hash", "basis fingerprint (first n basis vectors)"), ("features", "features")]
    for key, what in checks:
        if meta.get(key) != expected[key]:
            raise InputError(f"model '{path}' does not match this ROM: {what} is {meta.get(key)!r} in "
                             f"the model, {expected[key]!r} here (model trained with ROM "
                             f"'{meta.get('rom_file')}')")
    if meta.get("sklearn_version") != sklearn.__version__:
        warn(f"model '{path}' was saved with scikit-learn {meta.get('sklearn_version')}, "
             f"this is {sklearn.__version__}")
    return bundle


def fit_bundle(regressor, cfg, x, y, meta):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.preprocessing import StandardScaler

    xs = StandardScaler().fit(x)
    ys = StandardScaler().fit(y) if cfg["scale_target"] else None
    est = make_regressor(regressor, cfg)
    yt = ys.transform(y) if ys is not None else y
    if yt.shape[1] == 1:
        yt = yt.ravel()
    note = ""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        est.fit(xs.transform(x), yt)
    if any(issubclass(w.category, ConvergenceWarning) for w in caught):
        note = " (optimizer hit max_iter)"
    return {"model": est, "x_scaler": xs, "y_scaler": ys, "meta": meta}, note


def predict(bundle, x, n):
    y = bundle["model"].predict(bundle["x_scaler"].transform(x))
    y = np.asarray(y).reshape(x.shape[0], n)
    if bundle["y_scaler"] is not None:
        y = bundle["y_scaler"].inverse_transform(y)
    return y


def time_predict(bundle, x, n, repeats):
    """(best batch time over ``repeats``, median single-row time) in seconds."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        predict(bundle, x, n)
        best = min(best, time.perf_counter() - t0)
    singles = []
    for i in range(min(10, x.shape[0])):
        t0 = time.perf_counter()
        predict(bundle, x[i:i + 1], n)
        singles.append(time.perf_counter() - t0)
    return best, float(np.median(singles))


# ------------------------------------------------------------------------------ output

def _atomic_h5(path, write):
    cio.write_h5_atomic(path, write)


def table_rows(res):
    rows = []
    for reg in res["regressors"]:
        r = res[reg]
        for i, n in enumerate(res["n_values"]):
            rows.append({"regressor": reg, "n": n, "E_avg_baseline": res["E_avg_baseline"],
                         "E_avg": r["E_avg"][i], "E_avg_projection": res["E_avg_projection"][i],
                         "factor": r["factor"][i], "t_fit": r["t_fit"][i],
                         "t_predict_step": r["t_predict_step"][i], "t_step": r["t_step"][i],
                         "speedup_uzawa": r["speedup"][i], "speedup_exact": r["speedup_exact"][i],
                         "E_disp": r["E_disp"][i], "mobility": r["mobility"][i],
                         **{k: r[k][i] for k in PROJ_KEYS}})
    return rows


def _na(x, fmt):
    """x formatted, or 'n/a' for the -1 of a missing figure."""
    return format(x, fmt) if x >= 0 else "n/a"


def markdown(rows):
    head = ["regressor", "n", "E_avg baseline", "E_avg corrected", "E_avg projection", "factor",
            "t_fit (s)", "t_predict/step (s)", "t_step (s)", "speedup (Uzawa)", "speedup (exact)"]
    keys = ["regressor", "n", "E_avg_baseline", "E_avg", "E_avg_projection", "factor", "t_fit",
            "t_predict_step", "t_step", "speedup_uzawa", "speedup_exact"]
    fmt = {"E_avg_baseline": "{:.3e}", "E_avg": "{:.3e}", "E_avg_projection": "{:.3e}",
           "factor": "{:.2f}", "t_fit": "{:.2f}", "t_predict_step": "{:.2e}", "t_step": "{:.2e}",
           "speedup_uzawa": "{:.3g}", "speedup_exact": "{:.3g}"}
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(fmt.get(k, "{}").format(r[k]) for k in keys) + " |")
    proj_rows = [r for r in rows if r["E_avg_proj"] >= 0]
    if proj_rows:
        head = ["regressor", "n", "E_avg ML -> projected", "E_disp ML -> projected",
                "overlap agents / walls ML (m)", "after projection (m)", "mobility ML -> projected",
                "agents moved", "t_project/step (s)", "t_project/query (s)", "t_query (s)",
                "speedup/query (exact)", "speedup/step (exact)"]
        lines += ["", "After the exact projection (crowd_project; only the projected n):", "",
                  "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in proj_rows:
            lines.append(f"| {r['regressor']} | {r['n']} | {r['E_avg']:.3e} -> {r['E_avg_proj']:.3e} | "
                         f"{r['E_disp']:.3e} -> {r['E_disp_proj']:.3e} | {r['overlap_agents']:.2e} / "
                         f"{r['overlap_walls']:.2e} | {r['overlap_agents_proj']:.2e} / {r['overlap_walls_proj']:.2e} | "
                         f"{r['mobility']:.3f} -> {r['mobility_proj']:.3f} | {100 * r['moved_fraction']:.1f}% | "
                         f"{r['t_project_step']:.2e} | {r['t_project_query']:.2e} | {_na(r['t_query'], '.2e')} | "
                         f"{_na(r['speedup_query_exact'], '.3g')} | {_na(r['speedup_exact_proj'], '.3g')} |")
    return "\n".join(lines)


def csv_text(rows):
    keys = list(rows[0].keys()) if rows else []
    out = [",".join(keys)]
    for r in rows:
        out.append(",".join(repr(float(r[k])) if isinstance(r[k], (float, np.floating)) else str(r[k])
                            for k in keys))
    return "\n".join(out) + "\n"


def write_output(path, st, res, cfg, mode):
    import h5py
    import sklearn

    s, p, m = st.setting, st.pair, st.meta

    def write(f):
        a = f.attrs
        a["schema"], a["schema_version"], a["program"] = cio.ML_SCHEMA, cio.ML_VERSION, "ml_correct.py"
        a["mode"] = mode
        a["romrun"] = os.path.abspath(st.romrun_path)
        a["rom_file"] = os.path.abspath(st.rom_path)
        a["database"] = os.path.abspath(st.db_path)
        a["database_config_hash"] = st.rom_hash
        a["setting"], a["pair"] = s["index"], p["index"]
        a["pair_n"], a["pair_r"], a["pair_n_basis"] = p["n"], p["r"], p["n_basis"]
        a["hyper"] = s["hyper"]
        a["n_agents"], a["n_steps"], a["dt"] = m["n_agents"], m["n_steps"], m["dt"]
        a["n_valid"] = st.rom_valid["params"].shape[0]
        a["n_train"] = 0 if st.rom_train is None else st.rom_train["params"].shape[0]
        a["features"] = ",".join(["alpha_1..alpha_n"] + feature_names(
            0, st.param_names, st.rom_valid["params"].shape[1], cfg))
        a["target"] = "delta_alpha"
        a["config"] = json.dumps(cfg, sort_keys=True)
        a["sklearn_version"] = sklearn.__version__
        a["t_step_rom"] = s["t_step"]
        a["t_step_fom_uzawa"], a["t_step_fom_exact"] = m["t_step_uzawa"], m["t_step_exact"]
        a["speedup_rom_uzawa"], a["speedup_rom_exact"] = s["speedup_uzawa"], s["speedup_exact"]
        a["E_avg_baseline_stored"] = s["E_avg"]
        f["n_values"] = np.asarray(res["n_values"], dtype=np.int32)
        f["valid_params"] = st.rom_valid["params"]
        f["E_avg_baseline"] = res["E_avg_baseline"]
        f["E_mu_baseline"] = res["E_mu_baseline"]
        f["E_avg_projection"] = np.asarray(res["E_avg_projection"])
        f["E_avg_baseline_disp"] = res["E_disp_baseline"]
        f["mobility_baseline"] = res["mobility_baseline"]
        pr = res.get("projection")
        a["projected"] = 1 if pr else 0
        a["project_solver"] = pr["solver"] if pr else ""
        a["project_tol"] = pr["tol"] if pr else -1.0
        a["project_refine_max"] = pr["refine_max"] if pr else -1
        a["t_query_rom"] = pr["t_query_rom"] if pr else -1.0
        a["t_query_fom_exact"] = pr["t_query_fom_exact"] if pr else -1.0
        f["E_mu_projection"] = np.asarray(res["E_mu_projection"])
        for reg in res["regressors"]:
            r = res[reg]
            g = f.create_group(reg)
            for key in ("E_avg", "E_mu", "factor", "t_fit", "t_predict_step", "t_predict_single",
                        "t_step", "speedup", "speedup_exact", "E_disp", "mobility") + PROJ_KEYS:
                g[key] = np.asarray(r[key], dtype=float)
            g.attrs["best_n"] = r["best_n"]
            g.attrs["best_E_avg"] = r["best_E_avg"]
            b = g.create_group("best")
            q = r["best_positions"]
            b["positions"] = q.reshape(q.shape[0] * q.shape[1], q.shape[2])
            b["err_time"] = r["best_err_time"]
            if "best_projected" in r:
                qp = r["best_projected"]
                b["projected_positions"] = qp.reshape(qp.shape[0] * qp.shape[1], qp.shape[2])
                b["projected_err_time"] = r["best_projected_err_time"]
            for key, product in sorted(r.get("qoi_products", {}).items()):
                with h5py.File(product, "r") as src:
                    src.copy("qoi", b, name=key)
        a["qoi"] = 1 if any(res[reg].get("qoi_products") for reg in res["regressors"]) else 0

    _atomic_h5(path, write)


# ------------------------------------------------------------------------------ main work

def run(st, cfg, n_values, models_dir, predict_only, quiet=False, outs=None):
    """Train (or load) and evaluate every (regressor, n); return the result dictionary. Trained
    models go to temporaries of the output set ``outs`` (committed with the other outputs)."""
    h, nt = st.h, st.n_steps
    V = st.pair["V"]
    q_val = st.db_valid["positions"][st.valid_idx]
    n_valid = q_val.shape[0]
    # baseline ROM error, recomputed from the run's positions
    e_base = cio.time_integrated_error(q_val, st.rom_valid["positions"], h)
    res = {"n_values": n_values, "regressors": list(cfg["regressors"]),
           "E_mu_baseline": e_base, "E_avg_baseline": float(e_base.mean()),
           "E_disp_baseline": float(cio.displacement_error(q_val, st.rom_valid["positions"]).mean()),
           "mobility_baseline": float(cio.mobility(q_val, st.rom_valid["positions"]).mean())}
    stored = st.setting["E_avg"]
    if abs(res["E_avg_baseline"] - stored) > 1e-6 * max(abs(stored), 1e-300):
        warn(f"recomputed baseline E_avg = {res['E_avg_baseline']:.6e} differs from the stored "
             f"E_avg = {stored:.6e} of setting {st.setting['index']}")
    if "E_mu" in st.rom_valid and st.rom_valid["E_mu"].size == n_valid:
        d = np.max(np.abs(st.rom_valid["E_mu"] - e_base) / np.maximum(np.abs(e_base), 1e-300))
        if d > 1e-6:
            warn(f"recomputed E_mu differs from the stored E_mu by up to {d:.2e} (relative)")
    log(f"setting {st.setting['index']} (pair {st.pair['index']}: N = {st.pair['n']}, "
        f"R = {st.pair['r']}, n_basis = {st.pair['n_basis']}, hyper = {st.setting['hyper']}): "
        f"baseline E_avg = {res['E_avg_baseline']:.4e} (stored {stored:.4e}) on {n_valid} "
        f"validation samples", quiet)

    # projection reference and training targets per n
    u_valid_fom = st.db_valid.get("velocities")
    if u_valid_fom is not None:
        u_valid_fom = u_valid_fom[st.valid_idx]
    if st.rom_train is not None:
        u_train = st.db_train["velocities"][st.train_idx]         # [n_S, N_T, n_dof]
        a_train = st.rom_train["alpha"]
        p_train = st.rom_train["params"]
    a_val, p_val = st.rom_valid["alpha"], st.rom_valid["params"]
    res["E_mu_projection"], res["E_avg_projection"] = [], []
    for n in n_values:
        if u_valid_fom is not None:
            Vn = V[:, :n]
            u_proj = (u_valid_fom @ Vn) @ Vn.T
            e = cio.time_integrated_error(q_val, cio.integrate_positions(st.q0, u_proj, h), h)
        else:
            e = np.full(n_valid, np.nan)
        res["E_mu_projection"].append(e)
        res["E_avg_projection"].append(float(np.mean(e)))

    t_rom = st.setting["t_step"]
    t_uz, t_ex = st.meta["t_step_uzawa"], st.meta["t_step_exact"]
    jobs = [(reg, n) for reg in cfg["regressors"] for n in n_values]
    t_start = time.perf_counter()
    for reg in cfg["regressors"]:
        res[reg] = {k: [] for k in ("E_avg", "E_mu", "factor", "t_fit", "t_predict_step",
                                    "t_predict_single", "t_step", "speedup", "speedup_exact",
                                    "E_disp", "mobility")}
        res[reg]["_q"] = {}
    for j, (reg, n) in enumerate(jobs, start=1):
        Vn = V[:, :n]
        names = feature_names(n, st.param_names, p_val.shape[1], cfg)
        meta = st.metadata(n, names, reg, cfg)
        path = model_path(models_dir, reg, n)
        t0 = time.perf_counter()
        if predict_only:
            bundle = load_model(path, meta)
            t_fit, note = 0.0, " (loaded)"
        else:
            x = make_features(a_train, p_train, n, cfg)
            y = (u_train @ Vn).reshape(-1, n) - a_train[:, :, :n].reshape(-1, n)
            bundle, note = fit_bundle(reg, cfg, x, y, meta)
            t_fit = time.perf_counter() - t0
            save_model(path, bundle, outs)
        xv = make_features(a_val, p_val, n, cfg)
        dalpha = predict(bundle, xv, n).reshape(n_valid, nt, n)
        u_corr = (a_val[:, :, :n] + dalpha) @ Vn.T                    # [n_S, N_T, n_dof]
        q_corr = cio.integrate_positions(st.q0, u_corr, h)
        e = cio.time_integrated_error(q_val, q_corr, h)
        t_batch, t_single = time_predict(bundle, xv, n, cfg["timing_repeats"])
        t_pred = t_batch / (n_valid * nt)
        r = res[reg]
        r["E_mu"].append(e)
        r["E_avg"].append(float(e.mean()))
        r["factor"].append(res["E_avg_baseline"] / max(float(e.mean()), 1e-300))
        r["t_fit"].append(t_fit)
        r["t_predict_step"].append(t_pred)
        r["t_predict_single"].append(t_single)
        r["t_step"].append(t_rom + t_pred)
        r["speedup"].append(t_uz / (t_rom + t_pred))
        r["speedup_exact"].append(t_ex / (t_rom + t_pred))
        r["E_disp"].append(float(cio.displacement_error(q_val, q_corr).mean()))
        r["mobility"].append(float(cio.mobility(q_val, q_corr).mean()))
        r["_q"][n] = q_corr
        el = time.perf_counter() - t_start
        log(f"[{j}/{len(jobs)}] {reg} n = {n}: fit {t_fit:.2f} s{note}, E_avg = {e.mean():.4e} "
            f"(x{r['factor'][-1]:.2f} better, projection {res['E_avg_projection'][n_values.index(n)]:.4e}), "
            f"predict {t_pred:.2e} s/step; elapsed {el:.1f} s, remaining ~"
            f"{el / j * (len(jobs) - j):.1f} s", quiet)
    for reg in cfg["regressors"]:
        r = res[reg]
        i = int(np.argmin(r["E_avg"]))
        r["best_n"], r["best_E_avg"] = n_values[i], r["E_avg"][i]
        r["best_positions"] = r["_q"][n_values[i]]
        r["best_err_time"] = cio.error_in_time(q_val, r["best_positions"])
    return res


PROJ_KEYS = ("overlap_agents", "overlap_walls", "E_avg_proj", "E_disp_proj", "mobility_proj",
             "overlap_agents_proj", "overlap_walls_proj", "moved_fraction", "t_project_step",
             "t_project_query", "t_query", "speedup_query_exact", "speedup_exact_proj")


def query_costs(st):
    """(t_query_rom, t_query_fom_exact) of the setting's validation row in the ROM run file (its
    ``table/``; the row of the last set run, whose t_step_rom is the setting's t_step); -1 where
    the file predates the per-query columns."""
    t_rom = t_fom = -1.0
    with cio.open_h5(st.romrun_path, cio.ROMRUN_SCHEMA, "ROM run file") as f:
        if "fom_timing" in f and "t_query_exact" in f["fom_timing"].attrs:
            t_fom = float(cio.scalar(f["fom_timing"].attrs["t_query_exact"]))
        if "table" in f and all(k in f["table"] for k in ("setting", "t_step_rom", "t_query_rom")):
            g = f["table"]
            k = cio.dataset(g, "setting").ravel()
            ts = cio.dataset(g, "t_step_rom").ravel()
            tq = cio.dataset(g, "t_query_rom").ravel()
            rows = np.flatnonzero(k == st.setting["index"])
            match = [i for i in rows if abs(ts[i] - st.setting["t_step"]) <= 1e-12 * max(ts[i], 1e-300)]
            if match:
                t_rom = float(tq[match[-1]])
            elif rows.size:
                t_rom = float(tq[rows[-1]])
    return t_rom, t_fom


def project_all(st, res, exe, workdir, quiet=False, refine_max=0, every_n=False):
    """Exact projection (crowd_project) of the corrected validation positions of each regressor's
    best n (``every_n``: of every (regressor, n)) in one request; fills the PROJ_KEYS lists of each
    regressor (-1 for an n not projected)."""
    q_val = st.db_valid["positions"][st.valid_idx]
    n_s, nt = q_val.shape[0], st.n_steps
    jobs = [(reg, n) for reg in res["regressors"] for n in res["n_values"]
            if every_n or n == res[reg]["best_n"]]
    q = np.concatenate([res[reg]["_q"][n] for reg, n in jobs])
    params = np.tile(st.rom_valid["params"], (len(jobs), 1))
    log(f"exact projection of {len(jobs)} x {n_s} corrected trajectories ({q.shape[0] * q.shape[1]} "
        f"configurations) with crowd_project", quiet)
    p = cio.run_projection(exe, st.db_path, params, q, workdir, refine_max=refine_max, show_progress=not quiet)
    t_query_rom, t_query_fom = query_costs(st)
    res["projection"] = {"solver": p["solver"], "tol": p["tol"], "refine_max": refine_max,
                         "t_query_rom": t_query_rom, "t_query_fom_exact": t_query_fom}
    t_ex = st.meta["t_step_exact"]
    for reg in res["regressors"]:
        for key in PROJ_KEYS:
            res[reg][key] = [-1.0] * len(res["n_values"])
    for j, (reg, n) in enumerate(jobs):
        sl = slice(j * n_s, (j + 1) * n_s)
        r, i = res[reg], res["n_values"].index(n)
        qp = p["positions"][sl]
        r["overlap_agents"][i] = float(p["overlap_agents_before"][sl].max())
        r["overlap_walls"][i] = float(p["overlap_walls_before"][sl].max())
        r["E_avg_proj"][i] = float(cio.time_integrated_error(q_val, qp, st.h).mean())
        r["E_disp_proj"][i] = float(cio.displacement_error(q_val, qp).mean())
        r["mobility_proj"][i] = float(cio.mobility(q_val, qp).mean())
        r["overlap_agents_proj"][i] = float(p["overlap_agents_after"][sl].max())
        r["overlap_walls_proj"][i] = float(p["overlap_walls_after"][sl].max())
        r["moved_fraction"][i] = float(p["n_moved"][sl].mean()) / (st.n_dof // 2)
        t_step_proj = float(p["time"][sl][:, 1:].mean())
        t_query_proj = float(p["time"][sl].sum(axis=1).mean())
        r["t_project_step"][i] = t_step_proj
        r["t_project_query"][i] = t_query_proj
        tq = (t_query_rom + nt * r["t_predict_step"][i] + t_query_proj) if t_query_rom >= 0 else -1.0
        r["t_query"][i] = tq
        r["speedup_query_exact"][i] = t_query_fom / tq if tq > 0 and t_query_fom > 0 else -1.0
        r["speedup_exact_proj"][i] = t_ex / (r["t_step"][i] + t_step_proj)
        if n == r["best_n"]:
            r["best_projected"] = qp
            r["best_projected_err_time"] = cio.error_in_time(q_val, qp)
    for reg in res["regressors"]:
        r = res[reg]
        i = res["n_values"].index(r["best_n"])
        log(f"{reg} n = {r['best_n']}: after projection E_avg {r['E_avg'][i]:.4e} -> {r['E_avg_proj'][i]:.4e}, "
            f"E_disp {r['E_disp'][i]:.4e} -> {r['E_disp_proj'][i]:.4e}, overlap agents/walls "
            f"{r['overlap_agents'][i]:.2e}/{r['overlap_walls'][i]:.2e} -> {r['overlap_agents_proj'][i]:.2e}/"
            f"{r['overlap_walls_proj'][i]:.2e} m, mobility {r['mobility'][i]:.3f} -> {r['mobility_proj'][i]:.3f}; "
            f"projection {r['t_project_step'][i]:.2e} s per step, {r['t_project_query'][i]:.2e} s per query", quiet)


def no_projection(res):
    """-1 in every projection figure (--no-project)."""
    for reg in res["regressors"]:
        for key in PROJ_KEYS:
            res[reg][key] = [-1.0] * len(res["n_values"])


# ------------------------------------------------------------------------------ quantities of interest

def predict_program():
    """crowd_predict of $CROWDROM_BIN, else of this checkout's build (InputError if missing)."""
    exe = os.path.join(os.environ.get("CROWDROM_BIN") or os.path.join(ROOT, "build", "bin"), "crowd_predict")
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        raise InputError(f"crowd_predict not found or not executable: '{exe}' (set CROWDROM_BIN)")
    return exe


def measure_qoi(exe, rom_path, params, param_names, q, label, output, workdir, cpu_seconds=None):
    """The QoIs of given trajectories q [n_Q, N_T + 1, n_dof] (parameters params [n_Q, n_mu], the
    study's component names param_names) in the QoI product ``output``, by crowd_predict with
    model = 'positions' on the ROM file's study (the one definition of the QoIs)."""
    nq = q.shape[0]
    stem = os.path.join(tempfile.mkdtemp(prefix="qoi_", dir=workdir), "positions")

    def write(f):
        d = f.create_dataset("params", data=params)
        d.attrs["param_names"] = np.bytes_(",".join(param_names))
        f.create_dataset("positions", data=q.reshape(nq * q.shape[1], -1))
        if cpu_seconds is not None:
            f.create_dataset("cpu_seconds", data=cpu_seconds)
    cio.write_h5_atomic(stem + ".h5", write)
    with open(stem + ".nml", "w") as fh:
        fh.write(f"&predict rom_file = '{os.path.abspath(rom_path)}', model = 'positions', "
                 f"label = '{label}', params_file = '{stem}.h5', output = '{os.path.abspath(output)}' /\n")
    p = subprocess.run([exe, stem + ".nml"], capture_output=True, text=True)
    if p.returncode != 0:
        err = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")]
        raise RuntimeError(f"crowd_predict (QoIs of the corrected positions): "
                           f"{err[0] if err else p.stderr.strip()[-300:]}")


def qoi_study(rom_path):
    """The ROM file's study (its component names) for crowd_predict; InputError naming --no-qoi."""
    with cio.open_h5(rom_path, cio.ROM_SCHEMA, "ROM file") as f:
        try:
            return cio.read_rom_study(f)
        except InputError as exc:
            raise InputError(f"{exc}; the QoIs of the corrected trajectories need it (or skip them with "
                             "--no-qoi)") from None


def qoi_all(st, res, exe, workdir, quiet=False):
    """QoIs of each regressor's corrected validation trajectories (best n) and of their exact
    projection when made: products in ``workdir``, named in res[reg]["qoi_products"]."""
    names = qoi_study(st.rom_path)["param_names"]
    params = st.rom_valid["params"]
    if len(names) != params.shape[1]:
        raise InputError(f"'{st.rom_path}': its study names {len(names)} parameter components, the "
                         f"validation parameters of '{st.romrun_path}' have {params.shape[1]}")
    for reg in res["regressors"]:
        r = res[reg]
        r["qoi_products"] = {}
        runs = [("qoi", r["best_positions"], f"ml {reg} n={r['best_n']}")]
        if "best_projected" in r:
            runs.append(("projected_qoi", r["best_projected"], f"ml {reg} n={r['best_n']} projected"))
        for key, q, label in runs:
            out = os.path.join(workdir, f"{reg}_{key}.h5")
            measure_qoi(exe, st.rom_path, params, names, q, label, out, workdir)
            r["qoi_products"][key] = out
        log(f"{reg} n = {r['best_n']}: QoIs of the corrected trajectories by crowd_predict "
            f"({', '.join(r['qoi_products'])})", quiet)


# ------------------------------------------------------------------------------ any list of queries

def predict_queries(args, cfg):
    """--predict: ML-corrected QoIs for the queries of a crowd_predict product (module doc)."""
    pred_path = args.predict
    pred = cio.read_prediction(pred_path)
    if "alpha" not in pred or int(pred.get("pair", 0)) <= 0:
        raise InputError(f"'{pred_path}': no reduced coefficients (run crowd_predict with model = 'rom' and "
                         "trajectories = .true.)")
    if np.any(pred["diverged_step"] > 0):
        raise InputError(f"'{pred_path}': {int(np.sum(pred['diverged_step'] > 0))} reduced trajectories diverged "
                         "(the correction needs every trajectory)")
    rom_path = args.rom or cio.resolve_path(pred["rom_file"], pred_path)
    with cio.open_h5(rom_path, cio.ROM_SCHEMA, "ROM file") as f:
        rom_hash = cio.attr(f, "database_config_hash", str)
        pair = cio.read_rom_pair(f, int(pred["pair"]))
        study = cio.read_rom_study(f)
    alpha, params, h = pred["alpha"], pred["params"], float(pred["dt"])
    if alpha.shape[2] != pair["n_basis"] or pair["n"] != int(pred["pair_n"]) or pair["r"] != int(pred["pair_r"]):
        raise InputError(f"'{pred_path}' was predicted with pair {pred['pair']} (N, R) = ({pred['pair_n']}, "
                         f"{pred['pair_r']}), basis {alpha.shape[2]}; '{rom_path}' pair {pair['index']} has "
                         f"({pair['n']}, {pair['r']}), basis {pair['n_basis']}")
    regs = list(cfg["regressors"])
    n_of = {}
    for reg in regs:
        if args.n:
            if len(args.n) != 1:
                raise InputError("--predict takes one truncation --n (or --ml-output for each regressor's best n)")
            n_of[reg] = args.n[0]
        elif args.ml_output:
            with cio.open_h5(args.ml_output, cio.ML_SCHEMA, "ML output") as f:
                n_of[reg] = cio.attr(cio.group(f, reg), "best_n", int)
        else:
            raise InputError("--predict needs --n N or --ml-output FILE (each regressor's best n)")
        if not 1 <= n_of[reg] <= pair["n"]:
            raise InputError(f"n = {n_of[reg]} outside 1..{pair['n']} (POD modes of pair {pair['index']})")
    out = args.output or os.path.splitext(pred_path)[0] + "_ml.h5"
    outs = {reg: (out if len(regs) == 1 else f"{os.path.splitext(out)[0]}_{reg}.h5") for reg in regs}
    cio.check_outputs([(f"output ({r})", o) for r, o in outs.items()],
                      [("prediction", pred_path), ("ROM file", rom_path), ("--config", args.config)])
    exe = predict_program()
    nq, nt = alpha.shape[0], alpha.shape[1]
    with cio.OutputSet() as oset, tempfile.TemporaryDirectory(
            prefix=".ml_predict_", dir=os.path.dirname(os.path.abspath(out))) as work:
        for reg in regs:
            n = n_of[reg]
            Vn = pair["V"][:, :n]
            names = feature_names(n, pred["param_names"], params.shape[1], cfg)
            expected = {"database_config_hash": rom_hash, "pair": pair["index"], "pair_n": pair["n"],
                        "pair_r": pair["r"], "pair_n_basis": pair["n_basis"], "n": n,
                        "basis_hash": basis_hash(Vn), "features": names}
            bundle = load_model(model_path(args.models_dir, reg, n), expected)
            t0 = time.process_time()
            dalpha = predict(bundle, make_features(alpha, params, n, cfg), n).reshape(nq, nt, n)
            q = cio.integrate_positions(study["q0"], (alpha[:, :, :n] + dalpha) @ Vn.T, h)
            t_ml = time.process_time() - t0
            log(f"{reg} n = {n}: {nq} queries corrected in {t_ml:.2e} CPU s; QoIs by crowd_predict", args.quiet)
            measure_qoi(exe, rom_path, params, pred["param_names"], q, f"ml {reg} n={n}",
                        oset.tmp(outs[reg]), work, cpu_seconds=pred["cpu_seconds"] + t_ml / nq)
        oset.commit()
    for reg in regs:
        log(f"wrote {outs[reg]}", args.quiet)
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(prog="ml_correct.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("romrun", nargs="?", help="ROM run file (schema crowdrom-romrun)")
    ap.add_argument("--setting", type=int, default=1, help="setting index k (1-based, default 1)")
    ap.add_argument("--rom", help="ROM file (default: the run file's rom_file attribute)")
    ap.add_argument("--database", help="snapshot database (default: the run file's database attribute)")
    ap.add_argument("--config", help="JSON file overriding keys of scripts/pipeline/ml_config.json")
    ap.add_argument("--n", type=int, nargs="+", help="truncations n (default: config n_values, "
                    "else n_step, 2 n_step, ... up to the pair's POD modes)")
    ap.add_argument("--regressors", nargs="+", choices=REGRESSORS, help="override config regressors")
    ap.add_argument("--append-mu", action="store_true", help="append the parameters mu to the "
                    "features (config features.append_mu)")
    ap.add_argument("--append-nu", action="store_true", help="append the step index nu to the "
                    "features (config features.append_nu)")
    ap.add_argument("-o", "--output", help="output HDF5 (default: <romrun>_ml_s<k>.h5)")
    ap.add_argument("--models-dir", help="where models are saved/loaded (default: <output>_models/)")
    ap.add_argument("--predict", metavar="PRED",
                    help="ML-corrected QoIs for the queries of a crowd_predict product PRED (model = 'rom', "
                    "trajectories = .true.) with saved models (--models-dir, --n or --ml-output); no ROM run file")
    ap.add_argument("--ml-output", help="with --predict: a training output (crowdrom-ml) giving each "
                    "regressor's best n")
    ap.add_argument("--predict-only", action="store_true",
                    help="reuse saved models (no training set needed); refuses models of another ROM")
    ap.add_argument("--csv", help="also write the result table as CSV")
    ap.add_argument("--no-project", action="store_true",
                    help="skip the exact projection of the corrected positions (crowd_project)")
    ap.add_argument("--project-all", action="store_true",
                    help="project the corrected positions of every n (default: each regressor's best n only; "
                    "the other n get -1 in the projection columns)")
    ap.add_argument("--project-refine", type=int, default=0, metavar="N",
                    help="refinement projections per configuration at most (default 0: the "
                    "first-order projection from the previous projected configuration; see docs/user-guide.md)")
    ap.add_argument("--crowd-project", help="the crowd_project program (default: $CROWDROM_BIN/crowd_project, "
                    "else build/bin/crowd_project of this checkout)")
    ap.add_argument("--no-qoi", action="store_true",
                    help="skip the quantities of interest of the corrected trajectories (crowd_predict "
                    "model = 'positions' on the ROM file's study); the output then has qoi = 0")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    ap.add_argument("--help-output", action="store_true", help="describe the output file and exit")
    args = ap.parse_args(argv)
    if args.help_output:
        print(OUTPUT_DOC)
        return 0
    if args.predict:
        if args.romrun:
            fail("--predict takes no ROM run file argument")
        if not args.models_dir:
            fail("--predict needs --models-dir (the saved models)")
        over = {"regressors": args.regressors} if args.regressors else {}
        feats = {k: True for k, v in (("append_mu", args.append_mu), ("append_nu", args.append_nu)) if v}
        if feats:
            over["features"] = feats
        try:
            return predict_queries(args, load_config(args.config, over))
        except InputError as exc:
            fail(str(exc))
    if not args.romrun:
        fail("missing the ROM run file argument (see --help)")
    try:
        import sklearn  # noqa: F401
    except ImportError:
        fail("scikit-learn is not installed in this Python (use the project venv .venv)", 1)
    try:
        over = {"regressors": args.regressors} if args.regressors else {}
        feats = {k: True for k, v in (("append_mu", args.append_mu), ("append_nu", args.append_nu)) if v}
        if feats:
            over["features"] = feats
        cfg = load_config(args.config, over)
        st = Study(args.romrun, args.setting, rom=args.rom, database=args.database,
                   need_train=not args.predict_only)
        n_values = st.n_values(cfg, args.n)
        stem = os.path.splitext(args.romrun)[0]
        out = args.output or f"{stem}_ml_s{args.setting}.h5"
        models_dir = args.models_dir or (os.path.splitext(out)[0] + "_models")
        for what, path in (("output", out), ("CSV", args.csv)):
            if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
                raise InputError(f"{what} directory does not exist: "
                                 f"'{os.path.dirname(os.path.abspath(path))}'")
        # outputs must not name an input (nor each other): checked before any work
        cio.check_outputs([("output", out), ("--csv", args.csv)],
                          [("ROM run file", args.romrun), ("ROM file", st.rom_path),
                           ("database", st.db_path), ("--config", args.config)])
        if os.path.isfile(models_dir):
            raise InputError(f"models directory '{models_dir}' is a file")
        log(f"romrun '{args.romrun}', ROM '{st.rom_path}', database '{st.db_path}'; n = {n_values}; "
            f"regressors {cfg['regressors']}; models in '{models_dir}'", args.quiet)
        exe = None
        if args.project_refine < 0:
            raise InputError(f"--project-refine {args.project_refine}: must be >= 0")
        # the exact projection of the corrected positions: the config's "project" ('best': each
        # regressor's best n, 'all': every n, 'none': skipped), overridden by the options
        if cfg["project"] == "all":
            args.project_all = True
        if cfg["project"] == "none" and not args.project_all:
            args.no_project = True
            log("exact projection of the corrected positions skipped (config \"project\": \"none\")",
                args.quiet)
        if not args.no_project:
            exe = args.crowd_project or os.path.join(
                os.environ.get("CROWDROM_BIN") or os.path.join(ROOT, "build", "bin"), "crowd_project")
            if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
                raise InputError(f"crowd_project not found or not executable: '{exe}' (build it with "
                                 "scripts/setup.sh, name it with --crowd-project, or skip the projection "
                                 "with --no-project)")
        exe_qoi = None
        if not args.no_qoi:
            qoi_study(st.rom_path)
            try:
                exe_qoi = predict_program()
            except InputError as exc:
                raise InputError(f"{exc}, or skip the QoIs of the corrected trajectories with --no-qoi") from None
    except InputError as exc:
        fail(str(exc))
    # the output file, the CSV and the trained models are one result: all written under
    # temporary names, then renamed together; any failure leaves earlier outputs untouched
    made_dir = False
    try:
        with cio.OutputSet() as outs:
            if not args.predict_only and not os.path.isdir(models_dir):
                os.makedirs(models_dir)
                made_dir = True
            res = run(st, cfg, n_values, models_dir, args.predict_only, args.quiet, outs=outs)
            with tempfile.TemporaryDirectory(prefix=".ml_project_",
                                             dir=os.path.dirname(os.path.abspath(out))) as work:
                if exe:
                    project_all(st, res, exe, work, args.quiet, args.project_refine, args.project_all)
                else:
                    no_projection(res)
                if exe_qoi:
                    qoi_all(st, res, exe_qoi, work, args.quiet)
                for reg in res["regressors"]:
                    del res[reg]["_q"]
                rows = table_rows(res)
                write_output(outs.tmp(out), st, res, cfg, "predict-only" if args.predict_only else "train")
            if args.csv:
                with open(outs.tmp(args.csv), "w") as fh:
                    fh.write(csv_text(rows))
            outs.commit()
    except BaseException as exc:
        if made_dir:
            try:
                os.rmdir(models_dir)
            except OSError:
                pass
        if isinstance(exc, InputError):
            fail(str(exc))
        raise
    print(markdown(rows))
    log(f"wrote {out}" + (f" and {args.csv}" if args.csv else "") +
        ("" if args.predict_only else f"; models in '{models_dir}'"), args.quiet)
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
