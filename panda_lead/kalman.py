"""The tracker's Kalman filter on the target's readings, shared by the filtered analytic lead
(controllers.make_filtered_analytic) and the env's own filter (EnvConfig.target_filter), so
that a learned lead and its classical rival get the same estimate of the target.

A constant-acceleration model per axis, state (position, velocity, acceleration), all three
measured directly; steady state, so the filter is a fixed 3 x 3 gain per noise level.
"""

from __future__ import annotations

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


def update(x: np.ndarray, z: np.ndarray, f: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """One predict-and-correct step of (N, 3, axes) estimates ``x`` (rows: position, velocity,
    acceleration) with readings ``z`` of the same shape."""
    prior = np.einsum("ij,njk->nik", f, x)
    return prior + np.einsum("ij,njk->nik", gain, z - prior)
