"""The three controllers as batched action functions ``act(obs, task) -> (N, 3) in [-1, 1]``.

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


def classical(obs, task) -> np.ndarray:
    return np.zeros((len(obs), 3), dtype=np.float32)


def make_analytic(tau: float = DEFAULT_TAU):
    def act(obs, task) -> np.ndarray:
        max_lead = task.config.max_lead
        if max_lead == 0:
            return classical(obs, task)
        slices = {f: slice(a, b) for f, a, b in task.layout}
        _, true_vel, true_acc = task.core.target()
        # The observation is scaled (env.OBS_SCALE); undo that to get m/s and m/s^2. The lead
        # is computed from what the controller observes, so observation noise reaches it.
        vel = obs[:, slices["target_vel"]] * OBS_SCALE["target_vel"] if "target_vel" in slices \
            else true_vel
        acc = obs[:, slices["target_acc"]] * OBS_SCALE["target_acc"] if "target_acc" in slices \
            else true_acc
        lead = analytic_lead(np.asarray(vel, float), np.asarray(acc, float), tau, max_lead)
        return (lead / max_lead).astype(np.float32)

    return act


def make_policy(model, deterministic: bool = True):
    def act(obs, task) -> np.ndarray:
        action, _ = model.predict(obs, deterministic=deterministic)
        return action

    return act
