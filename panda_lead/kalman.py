"""The tracker's Kalman filter on the target's readings, shared by the filtered analytic lead
(controllers.make_filtered_analytic) and the env's own filter (EnvConfig.target_filter), so
that a learned lead and its classical rival get the same estimate of the target; and the same
filter on the tip's readings (EnvConfig.arm_filter), where the acceleration is not measured.

A constant-acceleration model per axis, state (position, velocity, acceleration), measured
directly (all three, or position and velocity); steady state, so the filter is a fixed 3 x 3
gain per noise level (a zero column for a state not measured).
"""

from __future__ import annotations

import functools

import numpy as np

# Tuned on seeds.TUNE_SEEDS at 1 cm of noise with `uv run studies/deploy.py --tune-filter`.
DEFAULT_JERK_PSD = 1e3  # (m/s^3)^2 s: the white-jerk process noise of the target model


def transition(dt: float) -> np.ndarray:
    """The constant-acceleration model's one-step transition (3 x 3)."""
    return np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def steady_state_gain(dt: float, r_std: np.ndarray, jerk_psd: float, measured: int = 3
                      ) -> np.ndarray:
    """The steady-state Kalman gain (3 x 3) of the model of one axis whose first ``measured``
    states are read directly with standard deviations ``r_std`` (m, m/s, m/s^2; the first
    ``measured`` used): the Riccati recursion iterated to its fixed point. A state not
    measured has a zero column. With no noise the measured states' estimates are their
    readings (the gain there is the identity to within 1e-6)."""
    f = transition(dt)
    # white jerk of spectral density q integrated over one step (the discrete Wiener model)
    q = jerk_psd * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                             [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                             [dt ** 3 / 6, dt ** 2 / 2, dt]])
    r = np.diag(np.maximum(np.asarray(r_std, float)[:measured], 1e-9) ** 2)
    p = np.eye(3)
    if measured == 3:  # H = I
        for _ in range(2000):
            prior = f @ p @ f.T + q
            gain = prior @ np.linalg.inv(prior + r)
            p = (np.eye(3) - gain) @ prior
        return gain
    h = np.eye(3)[:measured]
    for _ in range(2000):
        prior = f @ p @ f.T + q
        k = prior @ h.T @ np.linalg.inv(h @ prior @ h.T + r)
        p = (np.eye(3) - k @ h) @ prior
    return k @ h


# Under EnvConfig.random_noise each episode's noise is a share s in [0, 1] of obs_noise, and the
# filter is the one for that level (the installation knows its sensors): the gains of
# GAIN_LEVELS + 1 evenly spaced shares, each episode taking the nearest (~50 ms each, once).
GAIN_LEVELS = 20


def gains_by_share(dt: float, r_std, jerk_psd: float, measured: int = 3) -> np.ndarray:
    """(GAIN_LEVELS + 1, 3, 3) steady-state gains for noise r_std times 0, 1/L, ..., 1."""
    return _gains_by_share(float(dt), tuple(float(v) for v in r_std), float(jerk_psd), measured)


@functools.lru_cache(maxsize=8)
def _gains_by_share(dt: float, r_std: tuple, jerk_psd: float, measured: int) -> np.ndarray:
    shares = np.linspace(0.0, 1.0, GAIN_LEVELS + 1)
    table = np.stack([steady_state_gain(dt, s * np.asarray(r_std), jerk_psd, measured)
                      for s in shares])
    table.setflags(write=False)
    return table


def update(x: np.ndarray, z: np.ndarray, f: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """One predict-and-correct step of (N, 3, axes) estimates ``x`` (rows: position, velocity,
    acceleration) with readings ``z`` of the same shape; ``gain`` one (3, 3) for every row or
    an (N, 3, 3) of each row's own."""
    prior = np.einsum("ij,njk->nik", f, x)
    if gain.ndim == 3:
        return prior + np.einsum("nij,njk->nik", gain, z - prior)
    return prior + np.einsum("ij,njk->nik", gain, z - prior)



class ReadingFilter:
    """The filter on one quantity's readings in an env's observation, per slot (N estimates,
    started from the first reading of each episode): ``cols`` the column slices of its
    position, velocity (and acceleration) readings in the raw observation, which it replaces
    by its estimates. ``error_sign``: how the tip error (tip reading - target reading) moves
    when this quantity's position estimate moves off its reading (+1 the tip, -1 the target).
    ``by_share``: each episode's gain is the one for its own noise level (set_levels)."""

    def __init__(self, cols: list[slice], error_sign: float, dt: float, r_std, n: int,
                 by_share: bool):
        self.cols, self.error_sign, self.f = cols, error_sign, transition(dt)
        measured = len(cols)
        self.gain = steady_state_gain(dt, r_std, DEFAULT_JERK_PSD, measured)
        self.table = None
        if by_share:
            self.table = gains_by_share(dt, r_std, DEFAULT_JERK_PSD, measured)
            self.gain = np.broadcast_to(self.gain, (n, 3, 3)).copy()
        self.estimate = np.zeros((n, 3, 3))
        self.fresh = np.ones(n, dtype=bool)

    def restart(self, ids, shares=None) -> None:
        """Slots ``ids`` start an episode: from their next reading, with the gain of their
        noise shares (under by_share)."""
        self.fresh[ids] = True
        if self.table is not None:
            levels = len(self.table) - 1
            self.gain[ids] = self.table[np.rint(shares * levels).astype(np.int64)]

    def apply(self, raw: np.ndarray, rows, error_cols) -> None:
        """One predict-and-correct step of slots ``rows`` from their readings in ``raw``,
        written back over them (and the tip error moved with the position estimate)."""
        z = np.zeros((len(rows), 3, 3))
        for j, c in enumerate(self.cols):
            z[:, j] = raw[rows, c]
        gain = self.gain[rows] if self.gain.ndim == 3 else self.gain
        x = update(self.estimate[rows], z, self.f, gain)
        fresh = self.fresh[rows]
        x[fresh] = z[fresh]  # a new episode starts from its first reading
        self.estimate[rows], self.fresh[rows] = x, False
        for j, c in enumerate(self.cols):
            raw[rows, c] = x[:, j]
        if error_cols is not None:
            raw[rows, error_cols] += self.error_sign * (x[:, 0] - z[:, 0])
