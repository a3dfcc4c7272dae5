"""Would a real Panda accept this motion? The libfranka limits check, MuJoCo-free (numpy only).

A real Panda is commanded every millisecond (1 kHz); this repo's controller decides joint goals
every 10 ms (100 Hz). So the check has three stages, each the one a deployment would run:

1. **Interpolate** the 100 Hz joint goals to 1 kHz. A 100 Hz controller on a real arm must fill
   the nine milliseconds between its decisions, and the robot rejects a command whose
   acceleration jumps (libfranka's ``joint_motion_generator_acceleration_discontinuity``), so
   the honest filler is smooth: a C2 cubic spline through the goals (``method="cubic"``, the
   default). It passes through every goal the controller chose and adds no motion of its own;
   on a real arm it costs one or two control steps of look-ahead buffer. ``method="linear"``
   (piecewise linear, what a naive bridge sends) is kept to show why it is not used: its
   velocity steps every 10 ms, and after the low-pass every smooth path above about 1 rad/s^2
   breaks the joint jerk limits.
2. **Low-pass** the 1 kHz stream as libfranka does by default (``franka::lowpassFilter``, a
   first-order filter at ``kDefaultCutoffFrequency`` = 100 Hz, applied to every command unless
   the user switches it off).
3. **Differentiate** the filtered command by backward finite differences at 1 kHz (how the
   robot sees a command's velocity, acceleration and jerk: from the last commanded values) and
   compare the peaks with the Panda's published limits, per joint, and for the tip (the
   commanded joint goals through the Panda's forward kinematics to the tool centre point).

The limits (docs/deploy.md cites their source): joint velocity, acceleration and jerk per joint
below; tip velocity 1.7 m/s, acceleration 13 m/s^2, jerk 6,500 m/s^3. A margin is value /
limit; a motion is accepted when every margin is <= 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Franka "Robot and interface specifications" (Panda, FCI), limits in joint space.
JOINT_VEL = np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100])  # rad/s
JOINT_ACC = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])  # rad/s^2
JOINT_JERK = np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0])  # rad/s^3
# ... and in Cartesian space (translation of the end effector).
TIP_VEL, TIP_ACC, TIP_JERK = 1.7, 13.0, 6500.0  # m/s, m/s^2, m/s^3

ROBOT_DT = 0.001  # s: the Panda's command period (1 kHz)
LIBFRANKA_CUTOFF = 100.0  # Hz: libfranka's kDefaultCutoffFrequency
METHODS = ("cubic", "linear")

# The Panda's modified (Craig) Denavit-Hartenberg parameters, (a, d, alpha) per joint, from the
# same Franka documentation page; then the flange (d = 0.107 m) and the tool centre point of the
# Franka hand 0.1034 m beyond it (the MuJoCo model's "tip" site sits there too).
_DH = ((0.0, 0.333, 0.0), (0.0, 0.0, -np.pi / 2), (0.0, 0.316, np.pi / 2),
       (0.0825, 0.0, np.pi / 2), (-0.0825, 0.384, -np.pi / 2), (0.0, 0.0, np.pi / 2),
       (0.088, 0.0, np.pi / 2))
_FLANGE_TO_TIP = 0.107 + 0.1034


def upsample(x: np.ndarray, dt: float, method: str = "cubic",
             robot_dt: float = ROBOT_DT) -> np.ndarray:
    """Samples ``x`` (T, ...) taken every ``dt`` seconds, interpolated onto a ``robot_dt``
    grid from the first sample to the last: ((T - 1) * dt / robot_dt + 1, ...) rows.

    cubic: the natural C2 cubic spline through every sample (second derivatives from the
    tridiagonal system of a uniform grid). linear: straight segments between samples."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    x = np.asarray(x, dtype=float)
    ratio = dt / robot_dt
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ValueError(f"dt {dt} must be a whole multiple of robot_dt {robot_dt}")
    r, n = int(round(ratio)), len(x)
    if n < 2:
        return x.copy()
    seg = np.repeat(np.arange(n - 1), r)  # which interval each fine sample lies in
    u = np.tile(np.arange(r) / r, n - 1)  # and where in it, 0 <= u < 1
    seg, u = np.append(seg, n - 2), np.append(u, 1.0)
    shape = (-1,) + (1,) * (x.ndim - 1)
    u = u.reshape(shape)
    x0, x1 = x[seg], x[seg + 1]
    if method == "linear" or n < 3:
        return x0 + u * (x1 - x0)
    m = _natural_second_derivatives(x, dt)  # (T, ...) in units per s^2
    m0, m1 = m[seg], m[seg + 1]
    h2 = dt * dt
    return ((1 - u) * x0 + u * x1
            + h2 / 6.0 * (((1 - u) ** 3 - (1 - u)) * m0 + (u ** 3 - u) * m1))


def _natural_second_derivatives(x: np.ndarray, dt: float) -> np.ndarray:
    """M with M[0] = M[-1] = 0 and M[i-1] + 4 M[i] + M[i+1] = 6 (x[i-1] - 2 x[i] + x[i+1]) / dt^2
    (the natural spline on a uniform grid), solved by the Thomas algorithm: O(T)."""
    n = len(x)
    flat = x.reshape(n, -1)
    rhs = 6.0 * (flat[:-2] - 2 * flat[1:-1] + flat[2:]) / (dt * dt)  # (n - 2, k)
    c = np.empty(n - 2)
    d = np.empty_like(rhs)
    c[0], d[0] = 0.25, rhs[0] / 4.0
    for i in range(1, n - 2):  # forward sweep; diagonal 4, off-diagonals 1
        denom = 4.0 - c[i - 1]
        c[i] = 1.0 / denom
        d[i] = (rhs[i] - d[i - 1]) / denom
    inner = np.empty_like(rhs)
    inner[-1] = d[-1]
    for i in range(n - 4, -1, -1):
        inner[i] = d[i] - c[i] * inner[i + 1]
    m = np.zeros_like(flat)
    m[1:-1] = inner
    return m.reshape(x.shape)


def lowpass(x: np.ndarray, robot_dt: float = ROBOT_DT,
            cutoff: float = LIBFRANKA_CUTOFF) -> np.ndarray:
    """libfranka's first-order low-pass (franka::lowpassFilter) along axis 0, started at x[0]:
    y[k] = y[k-1] + g (x[k] - y[k-1]), g = robot_dt / (robot_dt + 1 / (2 pi cutoff))."""
    x = np.asarray(x, dtype=float)
    g = robot_dt / (robot_dt + 1.0 / (2.0 * np.pi * cutoff))
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = y[k - 1] + g * (x[k] - y[k - 1])
    return y


def derivatives(x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backward finite differences along axis 0: velocity, acceleration, jerk, each as long as
    x (the first rows, with no history, are 0: the robot starts at rest)."""
    x = np.asarray(x, dtype=float)
    out = []
    cur = x
    for _ in range(3):
        d = np.zeros_like(cur)
        d[1:] = (cur[1:] - cur[:-1]) / dt
        out.append(d)
        cur = d
    return out[0], out[1], out[2]


def tip_positions(q: np.ndarray) -> np.ndarray:
    """Forward kinematics (Franka's published DH parameters): (M, 7) joint angles to (M, 3)
    positions of the hand's tool centre point in the base frame, metres."""
    q = np.asarray(q, dtype=float).reshape(-1, 7)
    m = len(q)
    t = np.broadcast_to(np.eye(4), (m, 4, 4)).copy()
    for (a, d, alpha), theta in zip(_DH, q.T, strict=True):
        ca, sa = np.cos(alpha), np.sin(alpha)
        ct, st = np.cos(theta), np.sin(theta)
        link = np.zeros((m, 4, 4))  # RotX(alpha) TransX(a) RotZ(theta) TransZ(d)
        link[:, 0, 0], link[:, 0, 1], link[:, 0, 3] = ct, -st, a
        link[:, 1, 0], link[:, 1, 1], link[:, 1, 2], link[:, 1, 3] = st * ca, ct * ca, -sa, -sa * d
        link[:, 2, 0], link[:, 2, 1], link[:, 2, 2], link[:, 2, 3] = st * sa, ct * sa, ca, ca * d
        link[:, 3, 3] = 1.0
        t = t @ link
    return t[:, :3, 3] + _FLANGE_TO_TIP * t[:, :3, 2]


@dataclass(frozen=True)
class Check:
    """One motion against the limits: accepted when worst_margin <= 1."""

    accepted: bool
    worst_margin: float  # max over every limit of peak value / limit
    worst_limit: str  # which limit, e.g. "joint 2 jerk" or "tip acceleration"
    margins: dict  # limit name -> peak / limit
    worst_time: float = float("nan")  # s from the first goal: when the worst limit peaks


def command_stream(q_goal: np.ndarray, dt: float, q_start: np.ndarray | None = None,
                   method: str = "cubic", filtered: bool = True,
                   robot_dt: float = ROBOT_DT) -> np.ndarray:
    """The 1 kHz joint command a real Panda would receive for 100 Hz goals ``q_goal`` (T, 7),
    or for several episodes at once (T, N, 7): the arm at rest at ``q_start`` (default the
    first goal) for two control periods, then the goals, interpolated and (by default)
    low-passed as libfranka does."""
    q_goal = np.asarray(q_goal, dtype=float)
    start = q_goal[0] if q_start is None else np.broadcast_to(q_start, q_goal[0].shape)
    knots = np.concatenate([start[None], start[None], q_goal])  # at rest: no velocity yet
    stream = upsample(knots, dt, method, robot_dt)
    return lowpass(stream, robot_dt) if filtered else stream


def check(q_goal: np.ndarray, dt: float, q_start: np.ndarray | None = None,
          method: str = "cubic", filtered: bool = True, skip: float = 0.0,
          robot_dt: float = ROBOT_DT) -> Check:
    """Check the 100 Hz joint goals of one episode (T, 7) against the Panda's limits.

    ``skip`` seconds of the stream (counted from the first goal) are left out of the peaks: the
    swing from the home pose to a target far away is a motion a real deployment plans on its
    own (a move-to-start), not the tracking controller's."""
    return check_many(np.asarray(q_goal)[None], dt, q_start, method, filtered, skip,
                      robot_dt)[0]


def check_many(q_goals: np.ndarray, dt: float, q_start: np.ndarray | None = None,
               method: str = "cubic", filtered: bool = True, skip: float = 0.0,
               robot_dt: float = ROBOT_DT) -> list[Check]:
    """``check`` for N episodes of equal length at once, (N, T, 7): one pass of the filter's
    time loop for all of them."""
    q = np.moveaxis(np.asarray(q_goals, dtype=float), 0, 1)  # (T, N, 7)
    stream = command_stream(q, dt, q_start, method, filtered, robot_dt)
    first = int(round((2 * dt + skip) / robot_dt))  # two rest periods precede the first goal
    n = q.shape[1]
    margins: list[dict[str, float]] = [{} for _ in range(n)]
    peaks_at: list[dict[str, int]] = [{} for _ in range(n)]  # limit name -> its peak's sample
    vel, acc, jerk = (v[first:] for v in derivatives(stream, robot_dt))
    for name, values, limits in (("velocity", vel, JOINT_VEL), ("acceleration", acc, JOINT_ACC),
                                 ("jerk", jerk, JOINT_JERK)):
        size = np.abs(values)
        peak = size.max(axis=0) / limits if len(values) else np.zeros((n, 7))
        at = size.argmax(axis=0) if len(values) else np.zeros((n, 7), dtype=int)
        for i in range(n):
            for j in range(7):
                margins[i][f"joint {j + 1} {name}"] = float(peak[i, j])
                peaks_at[i][f"joint {j + 1} {name}"] = int(at[i, j])
    del vel, acc, jerk
    for i in range(n):
        tip = tip_positions(stream[:, i])
        for name, values, limit in zip(("velocity", "acceleration", "jerk"),
                                       derivatives(tip, robot_dt), (TIP_VEL, TIP_ACC, TIP_JERK),
                                       strict=True):
            norm = np.linalg.norm(values[first:], axis=1)
            margins[i][f"tip {name}"] = float(norm.max() / limit) if len(norm) else 0.0
            peaks_at[i][f"tip {name}"] = int(norm.argmax()) if len(norm) else 0
    out = []
    for m, at in zip(margins, peaks_at, strict=True):
        worst = max(m, key=m.get)
        # the stream's sample -> s from the first goal (two rest periods precede it)
        when = (first + at[worst]) * robot_dt - 2 * dt
        out.append(Check(bool(m[worst] <= 1.0), m[worst], worst, m, when))
    return out
