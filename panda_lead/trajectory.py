"""Analytic target trajectories for the Panda tracking task: circle, figure-of-eight, fly spline.

``sample(seed, shape=None)`` returns a ``Trajectory`` whose ``at(t)`` gives position, velocity
and acceleration in closed form, for a scalar time or a 1-D array of times (one call per episode).
The command line (`uv run trajectory.py`) is panda_lead.cli.trajectory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from .errors import did_you_mean

SHAPES = ("circle", "fig8", "fly")
SHOULDER = np.array([0.0, 0.0, 0.333])
REACH_RADIUS = 0.94  # furthest the tip gets from the shoulder
FLOOR_MARGIN = 0.03  # a target below this height counts as unreachable
# The tip cannot enter the base column without the arm folding into itself.
BASE_COLUMN_RADIUS, BASE_COLUMN_TOP = 0.12, 0.30
MAX_SPEED = 2.5  # m/s, bound on |vel|
MAX_ACC = 30.0  # m/s^2, bound on |acc|
# Centres and waypoints are drawn uniformly from this box (m). Tuned so that ~10% of
# trajectories leave the reach sphere in their first 5 s (see README) and some pass the base.
WORKSPACE_LO = np.array([0.1, -0.5, 0.12])
WORKSPACE_HI = np.array([0.75, 0.5, 0.8])

SLOW_PROB = 0.15  # share of deliberately slow trajectories
SLOW_SPEED = (0.2, 0.5)  # m/s, peak-speed level of a slow trajectory
FAST_SPEED = (0.8, MAX_SPEED)  # m/s, the rest: fast enough that a PD visibly lags
CIRCLE_RADIUS = (0.05, 0.25)
FIG8_HALF_WIDTH = (0.1, 0.3)  # amplitude along u
FIG8_HALF_HEIGHT = (0.05, 0.15)  # amplitude along w (two lobes)
FLY_WAYPOINTS = (5, 8)  # inclusive range of K


@dataclass(frozen=True)
class Trajectory:
    """One drawn trajectory. ``params`` is JSON-friendly; it includes peak_speed, peak_acc and
    lap_time (the period: every shape is a closed loop)."""

    shape: str
    seed: int
    params: dict
    _eval: Callable = field(repr=False, compare=False)

    @property
    def peak_speed(self) -> float:
        return self.params["peak_speed"]

    @property
    def peak_acc(self) -> float:
        return self.params["peak_acc"]

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos, vel, acc) at time t >= 0: shape (3,) each for a scalar, (N, 3) for N times."""
        ts = np.asarray(t, dtype=np.float64)
        if ts.ndim > 1:
            raise ValueError(f"t must be a scalar or a 1-D array, got shape {ts.shape}")
        if not np.all(np.isfinite(ts)) or np.any(ts < 0):
            raise ValueError(f"t must be finite and >= 0, got min {np.min(ts, initial=0.0)}")
        pos, vel, acc = self._eval(np.atleast_1d(ts)[:, None])
        if ts.ndim == 0:
            return pos[0], vel[0], acc[0]
        return pos, vel, acc


def check_shape(shape) -> None:
    if shape not in SHAPES:
        raise ValueError(f"unknown shape {shape!r}" + did_you_mean(shape, SHAPES))


def sample(seed: int, shape: str | None = None) -> Trajectory:
    """Draw a trajectory from ``seed``; ``shape`` forces the shape without changing any draw."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if shape is not None:
        check_shape(shape)
    rng = np.random.default_rng(int(seed))
    # The shape is always drawn first, so forcing it leaves every later draw unchanged.
    drawn = SHAPES[int(rng.integers(len(SHAPES)))]
    shape = drawn if shape is None else shape
    slow = rng.random() < SLOW_PROB
    speed = rng.uniform(*(SLOW_SPEED if slow else FAST_SPEED))
    params, fn = _BUILDERS[shape](rng, speed)
    params = {"speed_level": float(speed), **params}
    return Trajectory(shape, int(seed), params, fn)


def _plane(rng) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal u, w spanning a plane with a uniformly random orientation."""
    n = rng.standard_normal(3)
    n /= np.linalg.norm(n)
    helper = np.eye(3)[np.argmin(np.abs(n))]  # the axis least parallel to n
    u0 = np.cross(n, helper)
    u0 /= np.linalg.norm(u0)
    w0 = np.cross(n, u0)
    psi = rng.uniform(0, 2 * np.pi)  # in-plane rotation: matters for the figure of eight
    return np.cos(psi) * u0 + np.sin(psi) * w0, -np.sin(psi) * u0 + np.cos(psi) * w0


def _circle(rng, speed):
    centre = rng.uniform(WORKSPACE_LO, WORKSPACE_HI)
    radius = rng.uniform(*CIRCLE_RADIUS)
    u, w = _plane(rng)
    phase = rng.uniform(0, 2 * np.pi)
    direction = 1.0 if rng.random() < 0.5 else -1.0
    speed = min(speed, np.sqrt(MAX_ACC * radius))  # centripetal acc v^2/r <= MAX_ACC
    omega = direction * speed / radius
    params = dict(centre=centre.tolist(), radius=radius, u=u.tolist(), w=w.tolist(),
                  phase=phase, direction=direction, omega=omega,
                  lap_time=2 * np.pi / abs(omega), peak_speed=speed,
                  peak_acc=speed**2 / radius)
    return _floats(params), partial(_circle_eval, centre, radius * u, radius * w, phase, omega)


def _circle_eval(c, ru, rw, phase, omega, t):
    th = phase + omega * t
    cos, sin = np.cos(th), np.sin(th)
    return (c + cos * ru + sin * rw, omega * (-sin * ru + cos * rw),
            -omega**2 * (cos * ru + sin * rw))


def _fig8(rng, speed):
    centre = rng.uniform(WORKSPACE_LO, WORKSPACE_HI)
    a, h = rng.uniform(*FIG8_HALF_WIDTH), rng.uniform(*FIG8_HALF_HEIGHT)
    u, w = _plane(rng)
    phase = rng.uniform(0, 2 * np.pi)
    # p = a sin(th) u + h sin(2 th) w. At unit rate |p'|^2 = a^2 cos^2 + 4h^2 cos^2(2th) peaks
    # at th=0; |p''|^2 = (a^2 + 64h^2) x - 64h^2 x^2 with x = sin^2(th) in [0, 1].
    v1 = np.hypot(a, 2 * h)
    x = min(1.0, (a**2 + 64 * h**2) / (128 * h**2))
    a1 = np.sqrt((a**2 + 64 * h**2) * x - 64 * h**2 * x**2)
    omega = min(speed / v1, np.sqrt(MAX_ACC / a1))
    params = dict(centre=centre.tolist(), half_width=a, half_height=h, u=u.tolist(),
                  w=w.tolist(), phase=phase, omega=omega, lap_time=2 * np.pi / omega,
                  peak_speed=omega * v1, peak_acc=omega**2 * a1)
    return _floats(params), partial(_fig8_eval, centre, a * u, h * w, phase, omega)


def _fig8_eval(c, au, hw, phase, omega, t):
    th = phase + omega * t
    s1, c1, s2, c2 = np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th)
    return (c + s1 * au + s2 * hw, omega * (c1 * au + 2 * c2 * hw),
            -omega**2 * (s1 * au + 4 * s2 * hw))


def _fly(rng, speed):
    k = int(rng.integers(FLY_WAYPOINTS[0], FLY_WAYPOINTS[1] + 1))
    pts = rng.uniform(WORKSPACE_LO, WORKSPACE_HI, size=(k, 3))
    # Catmull-Rom = cubic Hermite with tangents (P[i+1] - P[i-1]) / 2; the loop wraps around.
    p0, p1, p2, p3 = (np.roll(pts, -s, axis=0) for s in (-1, 0, 1, 2))
    m1, m2 = (p2 - p0) / 2, (p3 - p1) / 2
    coef = np.stack([p1, m1, 3 * (p2 - p1) - 2 * m1 - m2, 2 * (p1 - p2) + m1 + m2], axis=1)
    # Acceleration is linear in u, so its peak sits at a segment end; speed^2 is a quartic
    # whose maxima are at the ends or at real roots of its derivative.
    v1, a1 = 0.0, 0.0
    for c in coef:
        d1, d2, d3 = c[1], 2 * c[2], 3 * c[3]  # p'(u) = d1 + d2 u + d3 u^2
        roots = np.roots([2 * d3 @ d3, 3 * d2 @ d3, d2 @ d2 + 2 * d1 @ d3, d1 @ d2])
        us = np.concatenate([[0.0, 1.0], roots.real[(abs(roots.imag) < 1e-9)]])
        us = us[(us >= 0) & (us <= 1)][:, None]
        v1 = max(v1, np.linalg.norm(d1 + d2 * us + d3 * us**2, axis=1).max())
        a1 = max(a1, np.linalg.norm(d2 + 2 * d3 * np.array([[0.0], [1.0]]), axis=1).max())
    rate = min(speed / v1, np.sqrt(MAX_ACC / a1))  # segments per second
    params = dict(waypoints=pts.tolist(), segment_time=1 / rate, lap_time=k / rate,
                  peak_speed=rate * v1, peak_acc=rate**2 * a1)
    return _floats(params), partial(_fly_eval, coef, rate)


def _fly_eval(coef, rate, t):
    s = rate * t[:, 0]
    u = (s - np.floor(s))[:, None]
    c0, c1, c2, c3 = np.moveaxis(coef[np.floor(s).astype(np.int64) % len(coef)], 1, 0)
    return (c0 + u * (c1 + u * (c2 + u * c3)), rate * (c1 + u * (2 * c2 + 3 * u * c3)),
            rate**2 * (2 * c2 + 6 * u * c3))


_BUILDERS = {"circle": _circle, "fig8": _fig8, "fly": _fly}


def _floats(params: dict) -> dict:
    return {k: v if isinstance(v, list) else float(v) for k, v in params.items()}


def out_of_reach(pos: np.ndarray) -> np.ndarray:
    """Mask of positions (..., 3) beyond the reach sphere or below the floor margin."""
    pos = np.asarray(pos, dtype=float)
    far = np.linalg.norm(pos - SHOULDER, axis=-1) > REACH_RADIUS
    return far | (pos[..., 2] < FLOOR_MARGIN)


def reachable(pos: np.ndarray) -> np.ndarray | bool:
    """Whether the tip can reach a position (or each row of an (..., 3) array): inside the
    reach sphere, above the floor margin, and not inside the base column. The one definition:
    the env's reachability flag, rollouts and leaves_reach all use it."""
    p = np.asarray(pos, dtype=float)
    in_column = (np.linalg.norm(p[..., :2], axis=-1) < BASE_COLUMN_RADIUS) & (
        p[..., 2] < BASE_COLUMN_TOP)
    ok = ~out_of_reach(p) & ~in_column
    return bool(ok) if ok.ndim == 0 else ok


def leaves_reach(traj: Trajectory, duration: float = 5.0, hz: float = 100.0) -> bool:
    """Whether the target is unreachable at any sample of the first ``duration`` seconds."""
    pos, _, _ = traj.at(np.arange(int(round(duration * hz)) + 1) / hz)
    return bool((~reachable(pos)).any())
