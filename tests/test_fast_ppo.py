"""FastPPO (panda_lead/training/fast_ppo.py) is SB3's PPO update, only driven with fewer
Python-level operations: from the same rollout buffer, weights and random state, one update
of each must leave bit-identical parameters, optimiser state and logs."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from panda_lead.training import TrainConfig, make_vec_env

stable_baselines3 = pytest.importorskip("stable_baselines3")
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.logger import Logger  # noqa: E402

from panda_lead.training.fast_ppo import FastPPO, build_ppo  # noqa: E402


class Recorded(Logger):
    """A logger that keeps what train() records."""

    def __init__(self):
        super().__init__(folder=None, output_formats=[])
        self.values = {}

    def record(self, key, value, exclude=None):
        self.values[key] = value


def _collected(n_envs=4, n_steps=64, batch_size=64, n_epochs=3, **ppo):
    # (clip_range_vf is no TrainConfig field: set on the model after it is built)
    vf = ppo.pop("clip_range_vf", None)
    """A FastPPO model with one collected rollout (a few updates in, so the weights, Adam's
    moments and the policy's std are not at their initial values)."""
    torch.set_num_threads(1)
    vec = make_vec_env({}, n_envs, 0, "batched", 1)
    config = TrainConfig(n_envs=n_envs, n_steps=n_steps, batch_size=batch_size,
                         n_epochs=n_epochs, seed=3, **ppo)
    model = build_ppo(config, vec)  # FastPPO, as train.py builds it
    assert type(model) is FastPPO
    if vf is not None:
        from stable_baselines3.common.utils import FloatSchedule

        model.clip_range_vf = FloatSchedule(vf)
    model.learn(2 * n_steps * n_envs)  # two rollouts and updates
    from stable_baselines3.common.callbacks import CallbackList

    cb = CallbackList([])
    cb.init_callback(model)
    model.collect_rollouts(model.env, cb, model.rollout_buffer, n_rollout_steps=n_steps)
    return model, vec


def _update(model, train, state, foreach):
    """Restore ``state`` (weights, optimiser, buffer, numpy's stream), run ``train`` with
    Adam's ``foreach`` setting (None: SB3's Adam as it comes); return the parameters, the
    optimiser state and the logged values after it."""
    policy_sd, optim_sd, buf, rng, n_updates = state
    model.policy.load_state_dict(policy_sd)
    model.policy.optimizer.load_state_dict(copy.deepcopy(optim_sd))
    for group in model.policy.optimizer.param_groups:
        group["foreach"] = foreach
    model.rollout_buffer = copy.deepcopy(buf)
    model._n_updates = n_updates
    np.random.set_state(rng)
    model.set_logger(Recorded())
    train(model)
    params = {k: v.clone() for k, v in model.policy.state_dict().items()}
    moments = [(s["exp_avg"].clone(), s["exp_avg_sq"].clone())
               for s in model.policy.optimizer.state_dict()["state"].values()]
    return params, moments, dict(model.logger.values), np.random.get_state()[1].copy()


def _compare(model):
    state = (copy.deepcopy(model.policy.state_dict()),
             copy.deepcopy(model.policy.optimizer.state_dict()),
             copy.deepcopy(model.rollout_buffer), np.random.get_state(), model._n_updates)
    before = {k: v.clone() for k, v in model.policy.state_dict().items()}
    assert model.policy.optimizer.param_groups[0]["foreach"] is True  # as build_ppo makes it
    ref = _update(model, PPO.train, state, None)
    fast = _update(model, FastPPO.train, state, True)
    return before, ref, fast


def test_one_update_matches_sb3_bit_for_bit():
    model, vec = _collected()
    try:
        before, (p_ref, m_ref, log_ref, rng_ref), (p_fast, m_fast, log_fast, rng_fast) = \
            _compare(model)
    finally:
        vec.close()
    # The update moved every weight tensor (so the comparison below is not of untouched weights).
    assert all(not torch.equal(before[k], p_ref[k]) for k in before)
    for k in p_ref:
        assert torch.equal(p_ref[k], p_fast[k]), k
    for (a1, b1), (a2, b2) in zip(m_ref, m_fast, strict=True):
        assert torch.equal(a1, a2) and torch.equal(b1, b2)
    assert log_ref == log_fast
    assert np.array_equal(rng_ref, rng_fast)  # the same minibatch draws, no more, no fewer


def test_kl_early_stop_matches_sb3():
    """With a tiny target_kl both stop at the same minibatch: the same weights, the same
    number of epochs counted."""
    model, vec = _collected(n_epochs=5, target_kl=1e-6)
    try:
        _, (p_ref, _, log_ref, _), (p_fast, _, log_fast, _) = _compare(model)
    finally:
        vec.close()
    for k in p_ref:
        assert torch.equal(p_ref[k], p_fast[k]), k
    assert log_ref["train/n_updates"] == log_fast["train/n_updates"]
    assert log_ref == log_fast


def test_unsupported_shape_falls_back_to_sb3():
    """A clipped value function is outside the fast path: train() is SB3's own."""
    model, vec = _collected(clip_range_vf=0.2)
    try:
        assert not model._fast_path_applies()
        _, (p_ref, _, _, _), (p_fast, _, _, _) = _compare(model)
    finally:
        vec.close()
    for k in p_ref:
        assert torch.equal(p_ref[k], p_fast[k]), k


def _tiny_run(tmp_path, name, *flags):
    """A tiny in-process training run (4 updates, evaluations off): its final policy weights
    (the saved bytes) and Adam's moments."""
    import io
    import zipfile

    from panda_lead.cli.train import parse_args
    from panda_lead.training import train

    args = parse_args(["--timesteps", "512", "--eval-freq", "0", "--n-envs", "2", "--n-steps",
                       "64", "--batch-size", "64", "--n-epochs", "2", "--n-workers", "1",
                       "--no-progress", "--seed", "5", "--runs-dir", str(tmp_path / name),
                       *flags])
    run_dir = train(args)
    with zipfile.ZipFile(run_dir / "final_model.zip") as z:
        weights = z.read("policy.pth")
        optim = torch.load(io.BytesIO(z.read("policy.optimizer.pth")), weights_only=True)
    moments = [t for s in optim["state"].values() for t in (s["exp_avg"], s["exp_avg_sq"])]
    return weights, moments


def test_a_run_is_bit_reproducible_and_the_same_as_sb3s_update(tmp_path):
    """Two runs with one seed save the same policy bytes; a run with SB3's own PPO
    (--no-fast-update) saves the same weights and Adam moments too (its optimiser file differs
    only in Adam's foreach flag): the whole run, collection included, is the same PPO."""
    weights, moments = _tiny_run(tmp_path, "a")
    again, again_moments = _tiny_run(tmp_path, "b")
    sb3, sb3_moments = _tiny_run(tmp_path, "sb3", "--no-fast-update")
    assert weights == again == sb3
    assert len(moments) == len(sb3_moments) > 0
    for a, b, c in zip(moments, again_moments, sb3_moments, strict=True):
        assert torch.equal(a, b) and torch.equal(a, c)
