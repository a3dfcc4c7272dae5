"""Analytic target trajectories: one trajectory's parameters as text, or a 3-D plot of it.

    uv run trajectory.py --seed 3                     # parameters and peaks as text
    uv run trajectory.py --seed 3 --out traj.png      # 3-D plot to a PNG
    uv run trajectory.py --show --seed 3 --shape fig8 # plot in a window (needs a display)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError, check_output, exit_on_user_error, parse_cli
from ..seeds import check_seed
from ..trajectory import REACH_RADIUS, SHOULDER, Trajectory, leaves_reach, out_of_reach, sample

# The longest span drawn or checked (the env's longest episode is 1,000 s): beyond it the path
# would be sampled into arrays of billions of points, a typo rather than a wish.
MAX_DURATION_S = 1000.0


@dataclass
class Args:
    seed: int = 0
    """Trajectory seed (an integer in 0..2^63-1)."""
    shape: str | None = None
    """Force the shape (circle, fig8, fly) instead of drawing it from the seed."""
    duration: float = 5.0
    """Seconds of trajectory to draw (at most 1,000)."""
    show: bool = False
    """Open a plot window (needs a display; otherwise pass --out)."""
    out: Path | None = None
    """Save the plot to this PNG instead of (or as well as) showing it. An existing file is
    kept unless --force."""
    force: bool = False
    """Replace an existing --out file."""


def plot(traj: Trajectory, duration: float, out: Path | None, show: bool) -> None:
    import matplotlib

    if out is not None and not show:
        matplotlib.use("Agg")  # no window wanted: never touch a GUI toolkit
    import matplotlib.pyplot as plt

    ts = np.arange(0.0, duration + 1e-9, 0.01)
    pos, vel, _ = traj.at(ts)
    # Zoom on the path and the base; the sphere is cut to that box, which 3-D axes cannot do.
    lo = np.minimum(pos.min(0) - 0.1, [-0.2, -0.2, 0.0])
    hi = np.maximum(pos.max(0) + 0.1, [0.2, 0.2, SHOULDER[2] + 0.1])
    lo[2] = 0.0
    fig = plt.figure(figsize=(8, 7))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*pos.T, color="tab:blue", lw=1.5, label="target path")
    bad = out_of_reach(pos)
    if bad.any():
        ax.scatter(*pos[bad].T, color="tab:red", s=6, label="out of reach")
    # An arrow every 0.1 s, as long as the distance covered in 0.1 s; one lap only, because
    # later laps would draw the same arrows again.
    lap = ts <= min(duration, traj.params.get("lap_time", duration)) + 1e-9
    q = np.flatnonzero(lap)[::10]
    ax.quiver(*pos[q].T, *(0.1 * vel[q]).T, color="tab:orange", lw=0.8, label="velocity x 0.1 s")
    ax.scatter(*pos[0], color="tab:green", s=30, label="t = 0")
    th, ph = np.meshgrid(np.linspace(0, 2 * np.pi, 97), np.linspace(0, np.pi, 49))
    sphere = np.stack([np.sin(ph) * np.cos(th), np.sin(ph) * np.sin(th), np.cos(ph)])
    sphere = SHOULDER[:, None, None] + REACH_RADIUS * sphere
    outside = ((sphere < lo[:, None, None]) | (sphere > hi[:, None, None])).any(axis=0)
    sphere[:, outside] = np.nan
    if not outside.all():
        ax.plot_wireframe(*sphere, color="0.6", lw=0.4, label="reach sphere")
    ax.plot([0, 0], [0, 0], [0, SHOULDER[2]], color="k", lw=4, label="base to shoulder")
    ax.scatter(0, 0, 0, color="k", marker="s", s=40)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), xlabel="x (m)",
           ylabel="y (m)", zlabel="z (m)")
    ax.set_box_aspect(hi - lo)
    far = np.linalg.norm(pos - SHOULDER, axis=1).max()
    ax.set_title(f"seed {traj.seed}  {traj.shape}  peak speed {traj.peak_speed:.2f} m/s  "
                 f"peak acc {traj.peak_acc:.1f} m/s²\nfarthest {far:.2f} m from the shoulder "
                 f"(reach {REACH_RADIUS} m), out of reach {bad.mean():.0%} of {duration:g} s")
    ax.legend(loc="upper left", fontsize=8)
    if out is not None:
        from ..atomicio import atomic_write  # the repo's one writer: atomic, ordinary permissions

        with atomic_write(out, ".tmp.png") as tmp:
            fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
        print(f"wrote {out}")
    if show:
        plt.show()
    plt.close(fig)


@exit_on_user_error
def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    args = parse_cli(Args, argv, prog=prog, description=__doc__)
    check_seed(args.seed)
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION_S):
        raise UserError(f"--duration must be a number of seconds in (0, {MAX_DURATION_S:g}], "
                        f"got {args.duration}")
    try:
        traj = sample(args.seed, args.shape)
    except ValueError as e:  # an unknown shape, with "did you mean"
        raise UserError(str(e)) from None
    if args.out is not None:
        check_output(args.out, "--out", args.force)
    from ..display import has_display

    display = has_display()
    if args.show and args.out is None and not display:
        raise UserError("no display: use --out FILE.png")
    if args.show or args.out is not None:
        plot(traj, args.duration, args.out, args.show and display)
        return 0
    print(f"seed {traj.seed}: {traj.shape}")
    for k, v in traj.params.items():
        text = (np.array2string(np.asarray(v), precision=4, prefix=" " * 15)
                if isinstance(v, list) else f"{v:.4g}")
        print(f"  {k:12s} {text}")
    print(f"  leaves reach in the first {args.duration:g} s: "
          f"{leaves_reach(traj, args.duration)}")
    return 0
