#!/usr/bin/env python3
"""Accuracy of the reduced desired velocity of hyper = 'eq_deim' on the validation set.

For each m_v: the agents A of the first m_v DEIM dofs of the desired velocity (the ROM file's
pairs/<k>/eq/v_deim), P = both dofs of each, and vhat = V^T U (U_P)^+ v_P (the online
assembly of cr_hyper_eq), compared with the exact V^T v at every validation configuration of
the snapshot database (its stored desired velocities, out of the training set). Prints, per
m_v: the agents read, the relative error |vhat - V^T v| / |V^T v| (mean and max over the
configurations), and the same for the plain DEIM (the m_v dofs alone, (U_I)^{-1}) and for the
orthogonal projection V^T U U^T v (the best any m_v-mode reconstruction can do).

  scripts/post/deim_desired_accuracy.py ROM_FILE DATABASE [--pair K] [--m 50 100 147 ...]

Exit codes: 0 success, 2 missing/unreadable input (message on stderr).
"""
import argparse
import os
import sys

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402
from crowdrom_io import InputError  # noqa: E402

PROG = "deim_desired_accuracy"


def rel(err, ref):
    e = np.linalg.norm(err, axis=1) / np.maximum(np.linalg.norm(ref, axis=1), 1e-300)
    return e.mean(), e.max()


def main(argv=None):
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    ap.add_argument("rom")
    ap.add_argument("database")
    ap.add_argument("--pair", type=int, default=1)
    ap.add_argument("--m", type=int, nargs="+", default=[25, 50, 100, 147, 200, 250])
    a = ap.parse_args(argv)
    with cio.open_h5(a.rom, cio.ROM_SCHEMA, "ROM file") as f:
        pair = cio.read_rom_pair(f, a.pair)
        deim = cio.read_rom_pair_vdeim(f, a.pair)
    if deim is None:
        raise InputError(f"'{a.rom}': pair {a.pair} stores no DEIM of the desired velocity (eq/v_deim)")
    with cio.open_h5(a.database, cio.DB_SCHEMA, "snapshot database") as f:
        vd = cio.read_database_desired(f, "valid")
    v = pair["V"]
    x = vd.reshape(-1, vd.shape[-1])            # [configurations, n_dof]
    ref = x @ v                                 # exact vhat
    u_all, idx_all = deim["U"], deim["indices"] - 1
    print(f"{PROG}: pair ({pair['n']}, {pair['r']}), Nb = {v.shape[1]}, {x.shape[0]} validation configurations, "
          f"DEIM stored m = {u_all.shape[1]}")
    print("| m_v | agents read | eq_deim: mean / max rel. error of vhat | plain DEIM (m_v dofs) | best m_v-mode projection |")
    print("|---|---|---|---|---|")
    for m in a.m:
        if m > u_all.shape[1]:
            continue
        u = u_all[:, :m]
        idx = idx_all[:m]
        agents = np.unique(idx // 2)
        rows = np.ravel(np.column_stack([2 * agents, 2 * agents + 1]))
        over = x[:, rows] @ np.linalg.pinv(u[rows, :]).T @ u.T @ v
        plain = x[:, idx] @ np.linalg.inv(u[idx, :]).T @ u.T @ v
        proj = x @ u @ u.T @ v
        e1, e2, e3 = rel(over - ref, ref), rel(plain - ref, ref), rel(proj - ref, ref)
        print(f"| {m} | {len(agents)} | {e1[0]:.2e} / {e1[1]:.2e} | {e2[0]:.2e} / {e2[1]:.2e} | "
              f"{e3[0]:.2e} / {e3[1]:.2e} |")
    return 0


if __name__ == "__main__":
    sys.exit(cio.one_line_errors(PROG, main))
