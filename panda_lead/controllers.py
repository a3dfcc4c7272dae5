"""The three controllers as batched action functions ``act(obs, task) -> (N, 3) in [-1, 1]``.

All three drive the same env (and so the same IK+PD core); only the lead differs:
classical = zero lead; analytic = ``v*tau + a*tau^2/2`` from the *observed* target velocity
and acceleration (so observation noise hits it as it hits a policy); policy = a PPO model.
"""

from __future__ import annotations

import numpy as np

from .config import OBS_SCALE
from .core import analytic_lead
from .kalman import DEFAULT_JERK_PSD, steady_state_gain, transition, update

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


# --- The analytic lead as a good engineer would deploy it (issue 36) ---------------------------
# Under noise it filters its inputs; under latency it predicts through the delay. Both read
# what an engineer knows of the installation (the sensors' noise, the measured latency) from
# the env's config, never the true target. The filter (its tuned jerk density, its gain) is
# panda_lead/kalman.py's, shared with the env's own (EnvConfig.target_filter).


def make_filtered_analytic(tau: float = DEFAULT_TAU, jerk_psd: float = DEFAULT_JERK_PSD):
    """The analytic lead from a Kalman estimate of the target's velocity and acceleration, fed
    the observed (noisy) target position, velocity and acceleration. Without noise the gain is
    the identity to within 1e-6 and this is the analytic lead. Where the IK aims at the noisy
    reading too (noisy_ik_target), the lead also moves its aim to the filtered position."""
    state: dict = {}

    def act(obs, task) -> np.ndarray:
        max_lead = task.config.max_lead
        if task.config.action != "lead":
            raise ValueError("the analytic lead is a Cartesian lead: it needs action 'lead'")
        slices = {f: slice(a, b) for f, a, b in task.layout}
        missing = {"target_pos", "target_vel", "target_acc"} - set(slices)
        if missing:
            raise ValueError(f"the filtered analytic lead observes {sorted(missing)}")
        z = np.stack([obs[:, slices[f]] * OBS_SCALE[f]
                      for f in ("target_pos", "target_vel", "target_acc")], axis=1)  # (N, 3, 3)
        z = np.asarray(z, float)
        noise = task.config.obs_noise
        key = (task.dt, tuple(noise.get(f, 0.0) for f in ("target_pos", "target_vel",
                                                          "target_acc")))
        if state.get("key") != key:
            state["key"], state["gain"] = key, steady_state_gain(task.dt, key[1], jerk_psd)
        first = np.asarray(task.core.time) <= 0.5 * task.dt  # a fresh episode: start from z
        x = state.get("x")
        if x is None or x.shape != z.shape:
            x = z.copy()
        else:
            x = update(x, z, transition(task.dt), state["gain"])
            x[first] = z[first]
        state["x"] = x
        if max_lead == 0:
            return classical(obs, task)
        lead = analytic_lead(x[:, 1], x[:, 2], tau, max_lead)
        if task.config.noisy_ik_target:  # the IK aims at the reading: move it to the estimate
            lead = np.clip(lead + x[:, 0] - z[:, 0], -max_lead, max_lead)
        return (lead / max_lead).astype(np.float32)

    return act


def make_predicting_analytic(tau: float = DEFAULT_TAU):
    """The analytic lead that predicts through a known latency. The lead's channel: what it
    observes is obs_delay steps old and its lead lands action_delay steps late, while the IK
    aims at the present target, so it extrapolates the target's velocity by the acceleration
    over both (v + a d) before leading by tau. The target camera (target_delay d_t): the IK
    too aims at the target of d_t ago, so the lead reaches over d_t + tau from there."""
    def act(obs, task) -> np.ndarray:
        max_lead = task.config.max_lead
        if max_lead == 0:
            return classical(obs, task)
        slices = {f: slice(a, b) for f, a, b in task.layout}
        vel = np.asarray(obs[:, slices["target_vel"]] * OBS_SCALE["target_vel"], float)
        acc = np.asarray(obs[:, slices["target_acc"]] * OBS_SCALE["target_acc"], float)
        delay = (np.asarray(task.obs_delay) + np.asarray(task.action_delay)) * task.dt
        reach = tau + np.asarray(task.target_delay)[:, None] * task.dt  # each slot's camera
        lead = analytic_lead(vel + acc * delay[:, None], acc, reach, max_lead)
        return (lead / max_lead).astype(np.float32)

    return act


# --- preview rivals: classical controllers that know the planned path (issue 37) ------------
# They read each arm's target path ahead from its trajectory (panda_lead/preview.py); settings
# tuned on seeds.TUNE_SEEDS with `uv run studies/preview_rivals.py`
# (results/studies/preview/rivals_tuning.md), never on the test seeds.
PREVIEW_RIVALS = ("future_target", "feedforward", "feedforward_plan")
FUTURE_TAU = 0.04
FEEDFORWARD_TAU, FEEDFORWARD_GAIN, FEEDFORWARD_TAU_IK = 0.02, 0.8, 0.01
FEEDFORWARD_CLIP = True  # the correction clipped to what the motors can push (2.13 cm, not 2.77)
# ... as preview.make_feedforward's keywords (the plan-following rival's fallback, its meta)
FEEDFORWARD_SETTINGS = dict(tau=FEEDFORWARD_TAU, gain=FEEDFORWARD_GAIN, tau_ik=FEEDFORWARD_TAU_IK,
                            clip=FEEDFORWARD_CLIP)
# the feedforward that follows its plan where the arm can (rivals_tuning_plan.md): from the
# fallback (the feedforward above) to the plan by a smoothstep from 0.2 s over 0.4 s
PLAN_HANDOVER = (0.2, 0.4)


def make_future_target(tau: float = FUTURE_TAU):
    """The IK aimed at the exact future target p(t + tau): a Cartesian lead."""
    from .preview import make_future_target as make

    return make(tau)


def make_feedforward(tau: float = FEEDFORWARD_TAU, gain: float = FEEDFORWARD_GAIN,
                     tau_ik: float | None = FEEDFORWARD_TAU_IK, clip: bool = FEEDFORWARD_CLIP):
    """Joint goals that invert the simulated servos on the planned joint path (action
    joint_target): see preview.make_feedforward."""
    from .preview import make_feedforward as make

    return make(tau, gain, tau_ik, clip)


def make_planned_feedforward(handover: tuple[float, float] = PLAN_HANDOVER):
    """The feedforward that follows its plan open-loop wherever the arm can, the feedforward
    above elsewhere (action joint_target): see preview.make_planned_feedforward."""
    from .preview import make_planned_feedforward as make

    return make(handover, FEEDFORWARD_SETTINGS)
