"""The three controllers as action functions ``act(obs, env) -> action in [-1, 1]^3``.

All three drive the same env (and so the same IK+PD core); only the lead differs:
classical = zero lead; analytic = ``v*tau + a*tau^2/2`` from the *observed* target velocity
and acceleration (so observation noise hits it as it hits a policy); policy = a PPO model.
"""

from __future__ import annotations

import numpy as np

from core import analytic_lead
from env import OBS_SCALE

CONTROLLERS = ("classical", "analytic", "policy")
# Tuned on seeds.TUNE_SEEDS (never the test seeds) with `uv run ikpd.py --tune-tau`; see README.
DEFAULT_TAU = 0.04

_ZERO = np.zeros(3, dtype=np.float32)


def classical(obs, env) -> np.ndarray:
    return _ZERO


def make_analytic(tau: float = DEFAULT_TAU):
    def act(obs, env) -> np.ndarray:
        env = env.unwrapped
        slices = {f: slice(a, b) for f, a, b in env._layout}
        _, true_vel, true_acc = env.core.target()
        # The observation is scaled (env.OBS_SCALE); undo that to get m/s and m/s^2.
        vel = obs[slices["target_vel"]] * OBS_SCALE["target_vel"] if "target_vel" in slices \
            else true_vel
        acc = obs[slices["target_acc"]] * OBS_SCALE["target_acc"] if "target_acc" in slices \
            else true_acc
        lead = analytic_lead(np.asarray(vel, float), np.asarray(acc, float), tau, env.max_lead)
        return (lead / env.max_lead).astype(np.float32) if env.max_lead > 0 else _ZERO

    return act


def make_policy(model, deterministic: bool = True):
    def act(obs, env) -> np.ndarray:
        action, _ = model.predict(obs, deterministic=deterministic)
        return action

    return act
