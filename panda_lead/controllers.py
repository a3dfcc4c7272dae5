"""The three controllers as batched action functions ``act(obs, task) -> (N, 3) in [-1, 1]``.

All three drive the same env (and so the same IK+PD core); only the lead differs:
classical = zero lead; analytic = ``v*tau + a*tau^2/2`` from the *observed* target velocity
and acceleration (so observation noise hits it as it hits a policy); policy = a PPO model.
"""

from __future__ import annotations

import numpy as np

from .config import OBS_SCALE
from .core import analytic_lead

CONTROLLERS = ("classical", "analytic", "policy")
# Tuned on seeds.TUNE_SEEDS (never the test seeds) with `uv run studies/tau.py`.
DEFAULT_TAU = 0.04


def classical(obs, task) -> np.ndarray:
    return np.zeros((len(obs), task.action_dim), dtype=np.float32)


def make_analytic(tau: float = DEFAULT_TAU):
    def act(obs, task) -> np.ndarray:
        if task.config.action != "lead":
            raise ValueError("the analytic lead is a Cartesian lead: it needs action 'lead'")
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
    """A PPO model as a controller. Deterministic actions are the Gaussian policy's mean,
    computed in float64 numpy one row at a time (a stack of (1, d) @ (d, k) products), so an
    arm's action does not depend on how many arms are evaluated together; torch's batched
    matmul rounds differently for different batch sizes, which would make a 1,000-seed batch
    differ from one-at-a-time runs in the last bits. Stochastic actions go through SB3."""
    if not deterministic:
        return lambda obs, task: model.predict(obs, deterministic=False)[0]
    layers = _numpy_actor(model)

    def act(obs, task) -> np.ndarray:
        h = np.asarray(obs, dtype=np.float64)[:, None, :]
        for weight_t, bias, fn in layers:
            h = h @ weight_t + bias
            if fn is not None:
                h = fn(h)
        return np.clip(h[:, 0, :], -1.0, 1.0).astype(np.float32)

    return act


def _numpy_actor(model):
    """(weight^T, bias, activation) per layer of an SB3 MlpPolicy's actor, in float64."""
    import torch

    policy = getattr(model, "policy", model)  # a PPO model or its policy alone
    activations = {torch.nn.Tanh: np.tanh, torch.nn.ReLU: lambda x: np.maximum(x, 0.0)}
    fn = activations.get(policy.activation_fn)
    if fn is None or getattr(policy, "squash_output", False):
        raise ValueError(f"no numpy actor for {policy.activation_fn} / squashed outputs")
    layers = []
    for module in [*policy.mlp_extractor.policy_net, policy.action_net]:
        if isinstance(module, torch.nn.Linear):
            w = module.weight.detach().cpu().double().numpy()
            b = module.bias.detach().cpu().double().numpy()
            layers.append([w.T.copy(), b, None])
        elif type(module) in activations:
            layers[-1][2] = fn
        else:
            raise ValueError(f"no numpy actor for layer {module}")
    return [tuple(layer) for layer in layers]
