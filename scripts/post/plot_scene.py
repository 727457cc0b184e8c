#!/usr/bin/env python3
"""Draw a crowdrom full-order-model (FOM) trajectory file: hall, obstacles and agents.

Reads an HDF5 file with root attribute schema = "crowdrom-fom" (see the FOM schema in the
crowdrom documentation; h5py shows Fortran dimensions reversed) and writes one PNG with one
panel per selected output step, optionally an animated GIF.

Exit codes: 0 success, 2 missing/unreadable file or wrong schema (message on stderr).
"""
import argparse
import os
import sys

import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)),  # this folder and scripts/ (crowdrom_io)
                os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
import crowdrom_io as cio  # noqa: E402

SCHEMA = cio.FOM_SCHEMA


def _fail(msg):
    print(f"plot_scene: error: {msg}", file=sys.stderr)
    sys.exit(cio.EXIT_BAD_INPUT)


def load(path):
    """Load scene and trajectory arrays from a FOM file (exit 2 on a bad file)."""
    try:
        return cio.read_fom(path)
    except cio.InputError as exc:
        _fail(str(exc))


def draw_scene(ax, d):
    """Obstacles (disk, capsule, convex polygon), exit opening and domain box."""
    from matplotlib.patches import Circle, Polygon, Rectangle

    xmin, ymin, xmax, ymax = d["domain"]
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False,
                           edgecolor="0.7", lw=0.5, ls=":"))
    style = dict(facecolor="0.55", edgecolor="0.25", lw=0.8)
    for k, kind in enumerate(d["kind"]):
        v = d["verts"][d["vstart"][k]:d["vstart"][k + 1]]
        r = d["oradius"][k]
        if kind == 1:  # disk: centre = first vertex
            ax.add_patch(Circle(v[0], r, **style))
        elif kind == 2:  # thick segment (capsule): two endpoints, half-thickness r
            a, b = v[0], v[1]
            t = b - a
            n = np.array([-t[1], t[0]]) / max(np.hypot(*t), 1e-300) * r
            ax.add_patch(Polygon([a + n, b + n, b - n, a - n], closed=True, **style))
            ax.add_patch(Circle(a, r, **style))
            ax.add_patch(Circle(b, r, **style))
        elif kind == 3:  # convex polygon
            ax.add_patch(Polygon(v, closed=True, **style))
    e = d["exit"]
    ax.plot(e[:, 0], e[:, 1], color="tab:green", lw=3, solid_capstyle="butt", label="exit")
    pad = 0.02 * max(xmax - xmin, ymax - ymin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")


def draw_agents(ax, d, i, show_left=True, contacts=False):
    """Agents at output index i as disks of the true radius; return the artists."""
    from matplotlib.collections import LineCollection, PatchCollection
    from matplotlib.patches import Circle

    artists = []
    pos, inside = d["pos"][i], d["inside"][i]
    disks = [Circle(p, d["radius"]) for p in pos[inside]]
    pc = PatchCollection(disks, facecolor="tab:blue", edgecolor="navy", lw=0.5)
    artists.append(ax.add_collection(pc))
    if show_left and (~inside).any():
        gone = [Circle(p, d["radius"]) for p in pos[~inside]]
        artists.append(ax.add_collection(
            PatchCollection(gone, facecolor="tab:blue", edgecolor="none", alpha=0.15)))
    if contacts and "contacts" in d:
        c = d["contacts"]
        lo, hi = int(c["offset"][i]), int(c["offset"][i + 1])
        ia, ib, lam = c["ia"][lo:hi], c["ib"][lo:hi], c["lambda"][lo:hi]
        sel = (ib > 0) & (lam > 0)
        if sel.any():
            segs = np.stack([pos[ia[sel] - 1], pos[ib[sel] - 1]], axis=1)
            artists.append(ax.add_collection(LineCollection(segs, colors="tab:red", lw=1.2, zorder=3)))
    return artists


def panel_title(d, i):
    return f"step {d['step'][i]}  t = {d['time'][i]:.3g}  inside {int(d['inside'][i].sum())}"


def pick_steps(d, requested):
    """Output indices for the requested step numbers (default first, middle, last)."""
    n_out = len(d["step"])
    if not requested:
        return sorted({0, (n_out - 1) // 2, n_out - 1})
    idx = []
    for s in requested:
        hit = np.nonzero(d["step"] == s)[0]
        if hit.size == 0:
            _fail(f"step {s} is not in the file (output steps {d['step'][0]}..{d['step'][-1]})")
        idx.append(int(hit[0]))
    return idx


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", help="crowdrom FOM HDF5 file")
    p.add_argument("-o", "--output", default=None, help="PNG to write (default: <file>.png)")
    p.add_argument("--steps", type=int, nargs="+", default=None,
                   help="simulation step numbers to draw (default: first, middle, last output)")
    p.add_argument("--contacts", action="store_true",
                   help="draw active agent-agent contacts (lambda > 0) as lines between centres")
    p.add_argument("--hide-left", action="store_true", help="omit agents that have left")
    p.add_argument("--animate", metavar="OUT.gif", default=None,
                   help="also write an animation of all output steps (needs pillow)")
    p.add_argument("--fps", type=int, default=10, help="animation frames per second")
    p.add_argument("--dpi", type=int, default=120)
    args = p.parse_args(argv)
    # every argument and output checked before anything is drawn or written
    if args.dpi < 1:
        _fail(f"--dpi {args.dpi}: must be >= 1")
    if args.fps < 1:
        _fail(f"--fps {args.fps}: must be >= 1")
    out = args.output or (args.file.rsplit(".", 1)[0] + ".png")
    try:
        cio.check_outputs([("output", out), ("--animate", args.animate)], [("file", args.file)])
    except cio.InputError as exc:
        _fail(str(exc))
    if args.animate:
        try:
            import PIL  # noqa: F401
        except ImportError:
            _fail("--animate needs pillow (pip install pillow)")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = load(args.file)
    idx = pick_steps(d, args.steps)
    with cio.OutputSet() as outs:
        draw(args, d, idx, outs.tmp(out), outs.tmp(args.animate) if args.animate else None, plt)
        outs.commit()
    print(f"plot_scene: wrote {out}")
    if args.animate:
        print(f"plot_scene: wrote {args.animate}")
    return 0


def draw(args, d, idx, out, gif, plt):
    """The PNG (and GIF) under the temporary names `out` and `gif`."""
    fig, axes = plt.subplots(1, len(idx), figsize=(4.5 * len(idx), 4.5), squeeze=False)
    for ax, i in zip(axes[0], idx):
        draw_scene(ax, d)
        draw_agents(ax, d, i, show_left=not args.hide_left, contacts=args.contacts)
        ax.set_title(panel_title(d, i), fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=args.dpi, format="png")
    plt.close(fig)

    if gif:
        from matplotlib.animation import FuncAnimation, PillowWriter
        fig, ax = plt.subplots(figsize=(5, 5))
        draw_scene(ax, d)
        state = {"artists": []}

        def frame(i):
            for a in state["artists"]:
                a.remove()
            state["artists"] = draw_agents(ax, d, i, show_left=not args.hide_left,
                                           contacts=args.contacts)
            ax.set_title(panel_title(d, i), fontsize=9)
            return state["artists"]

        anim = FuncAnimation(fig, frame, frames=len(d["step"]), blit=False)
        anim.save(gif, writer=PillowWriter(fps=args.fps), dpi=args.dpi // 2 or 60)
        plt.close(fig)


if __name__ == "__main__":
    sys.exit(cio.one_line_errors("plot_scene", main))
