"""The tracker's Kalman filter on the target's readings, shared by the filtered analytic lead
(controllers.make_filtered_analytic) and the env's own filter (EnvConfig.target_filter), so
that a learned lead and its classical rival get the same estimate of the target.

A constant-acceleration model per axis, state (position, velocity, acceleration), all three
measured directly; steady state, so the filter is a fixed 3 x 3 gain per noise level.
"""

from __future__ import annotations

import functools

import numpy as np

# Tuned on seeds.TUNE_SEEDS at 1 cm of noise with `uv run studies/deploy.py --tune-filter`.
DEFAULT_JERK_PSD = 1e3  # (m/s^3)^2 s: the white-jerk process noise of the target model


def transition(dt: float) -> np.ndarray:
    """The constant-acceleration model's one-step transition (3 x 3)."""
    return np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])


def steady_state_gain(dt: float, r_std: np.ndarray, jerk_psd: float) -> np.ndarray:
    """The steady-state Kalman gain (3 x 3) of the model of one axis, measured directly with
    standard deviations ``r_std`` (m, m/s, m/s^2): the Riccati recursion iterated to its fixed
    point. With no noise it is the identity (to within 1e-6): the estimate is the reading."""
    f = transition(dt)
    # white jerk of spectral density q integrated over one step (the discrete Wiener model)
    q = jerk_psd * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                             [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                             [dt ** 3 / 6, dt ** 2 / 2, dt]])
    r = np.diag(np.maximum(np.asarray(r_std, float), 1e-9) ** 2)
    p = np.eye(3)
    for _ in range(2000):
        prior = f @ p @ f.T + q
        gain = prior @ np.linalg.inv(prior + r)
        p = (np.eye(3) - gain) @ prior
    return gain


# Under EnvConfig.random_noise each episode's noise is a share s in [0, 1] of obs_noise, and the
# filter is the one for that level (the installation knows its sensors): the gains of
# GAIN_LEVELS + 1 evenly spaced shares, each episode taking the nearest (~50 ms each, once).
GAIN_LEVELS = 20


def gains_by_share(dt: float, r_std, jerk_psd: float) -> np.ndarray:
    """(GAIN_LEVELS + 1, 3, 3) steady-state gains for noise r_std times 0, 1/L, ..., 1."""
    return _gains_by_share(float(dt), tuple(float(v) for v in r_std), float(jerk_psd))


@functools.lru_cache(maxsize=8)
def _gains_by_share(dt: float, r_std: tuple, jerk_psd: float) -> np.ndarray:
    shares = np.linspace(0.0, 1.0, GAIN_LEVELS + 1)
    table = np.stack([steady_state_gain(dt, s * np.asarray(r_std), jerk_psd) for s in shares])
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

