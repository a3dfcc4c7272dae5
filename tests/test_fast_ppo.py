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


def test_one_gsde_update_matches_sb3_bit_for_bit():
    """With gSDE exploration (--use-sde) the fast path stays SB3's update: its log-probability
    and entropy come from SB3's own state-dependent distribution."""
    model, vec = _collected(use_sde=True, log_std_init=-2.0)
    try:
        assert model.use_sde and model._fast_path_applies()
        before, (p_ref, m_ref, log_ref, _), (p_fast, m_fast, log_fast, _) = _compare(model)
    finally:
        vec.close()
    assert not torch.equal(before["log_std"], p_ref["log_std"])
    assert p_ref["log_std"].shape == (64, 3)  # gSDE's matrix: hidden units x actions
    for k in p_ref:
        assert torch.equal(p_ref[k], p_fast[k]), k
    for (a1, b1), (a2, b2) in zip(m_ref, m_fast, strict=True):
        assert torch.equal(a1, a2) and torch.equal(b1, b2)
    assert log_ref == log_fast


def test_a_gsde_run_saves_a_model_that_loads_and_acts_as_trained(tmp_path):
    """The sidecar records use_sde; models.load_policy rebuilds the gSDE policy from it, its
    deterministic action is the trained policy's mean, and eval.py --adopt keeps it."""
    from panda_lead.cli.train import parse_args
    from panda_lead.models import load_policy, read_sidecar
    from panda_lead.training import train

    args = parse_args(["--timesteps", "256", "--eval-freq", "0", "--n-envs", "2", "--n-steps",
                       "64", "--batch-size", "64", "--n-epochs", "1", "--n-workers", "1",
                       "--no-progress", "--seed", "5", "--use-sde", "--sde-sample-freq", "8",
                       "--runs-dir", str(tmp_path)])
    run_dir = train(args)
    model = run_dir / "final_model.zip"
    assert read_sidecar(model)["policy"]["use_sde"] is True
    policy, _, _ = load_policy(model)
    assert policy.use_sde and policy.log_std.shape == (64, 3)
    obs = np.random.default_rng(0).normal(size=(5, policy.observation_space.shape[0]))
    act = policy.predict(obs.astype(np.float32), deterministic=True)[0]
    with torch.no_grad():
        mean = policy.action_net(policy.mlp_extractor.forward_actor(
            torch.as_tensor(obs, dtype=torch.float32)))
    assert np.allclose(act, np.clip(mean.numpy(), -1, 1))
    # ... and adopted as an archive entry of its own (eval.py --adopt), still a gSDE policy
    import os

    from panda_lead.cli import models as model_commands

    old = os.getcwd()
    os.chdir(tmp_path)
    try:
        model_commands.main(["--adopt", str(model), "--name", "sde"], "eval.py")
    finally:
        os.chdir(old)
    adopted, _, _ = load_policy(tmp_path / "archive" / "sde.zip")
    assert adopted.use_sde and all(torch.equal(a, b) for a, b in zip(
        adopted.state_dict().values(), policy.state_dict().values(), strict=True))


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


# CAPS's smoothness terms (issue 36): off by default (the tests above hold FastPPO to SB3 at
# the default), on they pair each observation with the next one of its episode and shape the
# policy's mean action.

def _caps_model(env: dict | None = None, **caps):
    """A model whose collected rollout spans an episode's end: 30-step episodes, 64 steps."""
    from panda_lead.config import EnvConfig

    torch.set_num_threads(1)
    env = EnvConfig(**{"episode_steps": 30, **(env or {})})
    vec = make_vec_env(env, 3, 0, "batched", 1)
    config = TrainConfig(env=env, n_envs=3, n_steps=64, batch_size=64, n_epochs=3, seed=3,
                         **caps)
    model = build_ppo(config, vec)
    model.learn(64 * 3)  # one rollout and update, then a fresh rollout (unflattened)
    from stable_baselines3.common.callbacks import CallbackList

    cb = CallbackList([])
    cb.init_callback(model)
    model.collect_rollouts(model.env, cb, model.rollout_buffer, n_rollout_steps=64)
    return model, vec


def test_caps_pairs_each_observation_with_the_next_of_its_episode():
    model, vec = _caps_model(caps_temporal=1.0)
    try:
        buf = model.rollout_buffer
        steps_first = np.array(buf.observations)  # (n_steps, n_envs, obs_dim), before flattening
        starts = np.array(buf.episode_starts)
        successor, has_next = (t.numpy() for t in model._neighbours(1))
        predecessor, has_previous = (t.numpy() for t in model._neighbours(-1))
    finally:
        vec.close()
    n_steps, n_envs = starts.shape
    assert starts[1:].sum() >= n_envs  # the rollout crosses resets (30-step episodes)
    flat = steps_first.swapaxes(0, 1).reshape(n_steps * n_envs, -1)
    for env in range(n_envs):
        for step in range(n_steps):
            i = env * n_steps + step
            expect = step < n_steps - 1 and not starts[step + 1, env]
            assert bool(has_next[i]) == expect, (env, step)
            if expect:
                assert np.array_equal(flat[successor[i]], steps_first[step + 1, env])
            expect = step > 0 and not starts[step, env]  # (the curvature term's other side)
            assert bool(has_previous[i]) == expect, (env, step)
            if expect:
                assert np.array_equal(flat[predecessor[i]], steps_first[step - 1, env])


def _smoothness(model, buf):
    """The quantities the CAPS terms penalise, on the rollout ``buf`` (unflattened): the mean
    squared change of the mean action to the next observation, under the spatial term's
    noise, and its mean squared second difference within an episode."""
    obs = torch.as_tensor(np.array(buf.observations).swapaxes(0, 1))
    starts = np.array(buf.episode_starts).swapaxes(0, 1)
    n_envs, n_steps, dim = obs.shape
    obs = obs.reshape(-1, dim)
    with torch.no_grad():
        mean = model._mean_action(obs)
        gen = torch.Generator().manual_seed(0)
        noisy = obs + model.caps_sigma * torch.randn(obs.shape, generator=gen)
        spatial = ((mean - model._mean_action(noisy)) ** 2).mean().item()
    mean = mean.reshape(n_envs, n_steps, -1)
    keep = torch.as_tensor(starts[:, 1:] == 0)
    temporal = ((mean[:, 1:] - mean[:, :-1]) ** 2).mean(dim=-1)[keep].mean().item()
    both = keep[:, 1:] & keep[:, :-1]
    second = mean[:, 2:] - 2 * mean[:, 1:-1] + mean[:, :-2]
    curvature = (second ** 2).mean(dim=-1)[both].mean().item()
    return temporal, spatial, curvature


@pytest.mark.parametrize("term", ["temporal", "spatial", "curvature"])
def test_caps_terms_make_the_policy_smoother_than_ppo_alone(term):
    """From the same weights, rollout and random state, an update with the term weighted
    heavily leaves the policy's mean action smoother on the rollout than PPO's update alone,
    and logs the term."""
    model, vec = _caps_model()
    try:
        state = (copy.deepcopy(model.policy.state_dict()),
                 copy.deepcopy(model.policy.optimizer.state_dict()),
                 copy.deepcopy(model.rollout_buffer), np.random.get_state(), model._n_updates)
        results = {}
        for weight in (0.0, 1e4):
            setattr(model, f"caps_{term}", weight)
            torch.manual_seed(0)
            _, _, logs, _ = _update(model, FastPPO.train, state, True)
            results[weight] = (_smoothness(model, state[2]), logs)
    finally:
        vec.close()
    index = ["temporal", "spatial", "curvature"].index(term)
    assert results[1e4][0][index] < 0.5 * results[0.0][0][index]
    assert "train/caps_temporal" not in results[0.0][1]  # off: SB3's logs, nothing added
    assert "train/caps_curvature" not in results[0.0][1]
    assert results[1e4][1][f"train/caps_{term}"] > 0


def test_the_curvature_weight_can_differ_in_episodes_with_latency():
    """caps_curvature_delayed: the installation feature's delays tell the update which
    observations belong to an episode with latency. On a rollout holding both kinds, the term
    the loss adds is each observation's squared second difference (computed here from the
    unflattened rollout, episode by episode) times its episode's weight: latency's weight
    alone counts those episodes only, and equal weights give the one-weight term."""
    from panda_lead.config import OBS_15

    world = dict(obs_features=OBS_15 + ("installation",), obs_delay=3, action_delay=3,
                 target_delay=3, random_delay=True, nominal_share=0.5)
    model, vec = _caps_model(world, caps_curvature_delayed=0.0)
    try:
        buf = model.rollout_buffer
        obs = np.array(buf.observations).swapaxes(0, 1)  # (envs, steps, dim), before flattening
        starts = np.array(buf.episode_starts).swapaxes(0, 1)
        with torch.no_grad():
            mean = model._mean_action(torch.as_tensor(obs.reshape(-1, obs.shape[-1])))
            mean = mean.reshape(obs.shape[0], obs.shape[1], -1)
            second = ((mean[:, 2:] - 2 * mean[:, 1:-1] + mean[:, :-2]) ** 2).mean(dim=-1)
            keep = starts[:, 1:] == 0
            both = keep[:, 1:] & keep[:, :-1]  # the three in one episode
            delayed = np.abs(obs[:, 1:-1, [15, 16, 17]]).sum(axis=-1) > 0
            assert 0 < (both & delayed).sum() < both.sum()  # both kinds in the rollout
            per = second.numpy() * both
            flat = model._flat_tensors()
            successor, has_next = model._neighbours(1)
            predecessor, has_previous = model._neighbours(-1)
            mb = {"observations": flat["observations"], "has_next": has_next,
                  "delayed": model._delayed(flat["observations"]),  # as _train marks them
                  "next_observations": flat["observations"][successor],
                  "has_previous": has_previous,
                  "previous_observations": flat["observations"][predecessor]}
            terms = {}
            for weights in ((0.0, 7.0), (7.0, 7.0), (2.0, 7.0)):  # (the rest, with latency)
                model.caps_curvature, model.caps_curvature_delayed = weights
                mean_flat = model._mean_action(mb["observations"])
                terms[weights] = model._caps_losses(mb, mean_flat)[2:]
    finally:
        vec.close()
    count = both.sum()
    for (rest, late), (curvature, weighted) in terms.items():
        assert float(curvature) == pytest.approx(per.sum() / count, rel=1e-4)
        want = (late * per[delayed].sum() + rest * per[~delayed].sum()) / count
        assert float(weighted) == pytest.approx(want, rel=1e-4)


def test_caps_needs_the_fast_update_and_sane_weights():
    from panda_lead.errors import UserError

    with pytest.raises(UserError, match="need the fast update"):
        TrainConfig(caps_temporal=0.1, fast_update=False)
    with pytest.raises(UserError, match="need the fast update"):
        TrainConfig(caps_curvature=0.1, fast_update=False)
    for bad in (dict(caps_spatial=-1.0), dict(caps_temporal=float("nan")),
                dict(caps_sigma=0.0), dict(caps_curvature=-0.5)):
        with pytest.raises(UserError, match="caps"):
            TrainConfig(**bad)
    with pytest.raises(UserError, match="installation feature"):
        TrainConfig(caps_curvature_delayed=10.0)  # no installation: no latency to see
    with pytest.raises(UserError, match="caps-curvature-delayed must be"):
        TrainConfig(caps_curvature_delayed=float("inf"))


def test_caps_outside_the_fast_path_is_an_error_not_a_silent_drop():
    model, vec = _collected(clip_range_vf=0.2)  # outside the fast path: SB3's train()
    try:
        model.caps_temporal = 0.5
        with pytest.raises(ValueError, match="CAPS"):
            model.train()
    finally:
        vec.close()


@pytest.mark.parametrize("deterministic", [False, True])
def test_the_collection_forward_is_sb3s_bit_for_bit(deterministic):
    """FastActorCriticPolicy.forward (what collection calls each step) against SB3's
    ActorCriticPolicy.forward on the same weights, observations and torch stream: the same
    actions, values and log-probabilities, and the stream left in the same state."""
    from stable_baselines3.common.policies import ActorCriticPolicy

    from panda_lead.training.fast_ppo import FastActorCriticPolicy

    model, vec = _collected()
    vec.close()
    policy = model.policy
    assert type(policy) is FastActorCriticPolicy
    obs = torch.as_tensor(np.array(model.rollout_buffer.observations[:, 0]))  # 64 real ones
    outputs = []
    for forward in (ActorCriticPolicy.forward, FastActorCriticPolicy.forward):
        torch.manual_seed(11)
        with torch.no_grad():
            out = forward(policy, obs, deterministic)
        outputs.append((*out, torch.randn(3)))  # the draw after it: the stream's state
    for a, b in zip(*outputs, strict=True):
        assert a.shape == b.shape and torch.equal(a, b)


def test_the_profiles_sigmoid_tanh_is_tanh_to_float32_rounding():
    """studies/profile_update.py's sigtanh what-if (tanh as 2 sigmoid(2x) - 1) computes the same
    function and gradient as torch.tanh to within float32 rounding, and reaches every tanh of
    both networks; otherwise its timing would be of another network."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
    from profile_update import sigmoid_tanh, use_sigmoid_tanh

    x = torch.cat([torch.linspace(-20, 20, 40001), torch.randn(1000) * 1e-4]).requires_grad_()
    ours, theirs = sigmoid_tanh()(x), torch.tanh(x)
    assert (ours - theirs).abs().max() < 3e-7
    (g_ours,) = torch.autograd.grad(ours.sum(), x)
    (g_theirs,) = torch.autograd.grad(theirs.sum(), x)
    assert (g_ours - g_theirs).abs().max() < 1e-6
    model, vec = _collected()
    vec.close()
    nets = (model.policy.mlp_extractor.policy_net, model.policy.mlp_extractor.value_net)
    assert sum(type(layer) is torch.nn.Tanh for net in nets for layer in net) == 4
    use_sigmoid_tanh(model.policy)
    assert not any(type(layer) is torch.nn.Tanh for net in nets for layer in net)
    assert sum(type(layer).__name__ == "SigmoidTanh" for net in nets for layer in net) == 4


def test_the_activation_benchmark_times_each_op(capsys):
    """profile_update.py --activations: a row per op, each a positive time (performance.md's
    tanh figures come from it)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
    from profile_update import Args, activations

    activations(Args(activations=3))
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    times = {r.split("|")[1].strip(): float(r.split("|")[2]) for r in rows[1:]}
    assert {"torch.tanh", "torch.sigmoid", "numpy tanh"} <= set(times)
    assert all(t > 0 for t in times.values())


def test_the_policy_loss_leaves_out_the_steps_the_planners_hand_holds():
    """With plan_weight observed, steps at weight 1 (the hand holds the arm, the action changes
    nothing) add nothing to the policy loss: an update on a rollout held throughout leaves the
    actor as it was (fresh Adam moments, no CAPS, no entropy bonus) and still fits the value
    net; on a rollout the lead holds throughout it is the plain update bit for bit."""
    from panda_lead.config import EnvConfig, obs_layout

    torch.set_num_threads(1)
    features = ("ee_pos", "tip_error", "plan_weight")
    env = EnvConfig(episode_steps=30, follow_plan=True, obs_features=features)
    vec = make_vec_env(env, 3, 0, "batched", 1)
    try:
        model = build_ppo(TrainConfig(env=env, n_envs=3, n_steps=64, batch_size=64,
                                      n_epochs=2, seed=3), vec)
        col = obs_layout(features)[-1][1]
        assert type(model) is FastPPO and model.plan_column == col
        model.learn(64 * 3)
        from stable_baselines3.common.callbacks import CallbackList

        cb = CallbackList([])
        cb.init_callback(model)
        model.collect_rollouts(model.env, cb, model.rollout_buffer, n_rollout_steps=64)
        optim = copy.deepcopy(model.policy.optimizer.state_dict())
        optim["state"] = {}  # fresh moments: a zero gradient moves nothing

        def state(weight):
            buf = copy.deepcopy(model.rollout_buffer)
            buf.observations[..., col] = weight
            return (copy.deepcopy(model.policy.state_dict()), optim, buf,
                    np.random.get_state(), model._n_updates)

        before = {k: v.clone() for k, v in model.policy.state_dict().items()}
        held, _, _, _ = _update(model, FastPPO.train, state(1.0), True)
        actor = [k for k in before if k.startswith(("mlp_extractor.policy_net", "action_net",
                                                    "log_std"))]
        critic = [k for k in before if k.startswith(("mlp_extractor.value_net", "value_net"))]
        assert actor and critic
        assert all(torch.equal(held[k], before[k]) for k in actor)
        assert all(not torch.equal(held[k], before[k]) for k in critic)
        led_state = state(0.0)
        masked, _, _, _ = _update(model, FastPPO.train, led_state, True)
        model.plan_column = None
        plain, _, _, _ = _update(model, FastPPO.train, led_state, True)
        assert all(not torch.equal(masked[k], before[k]) for k in actor)
        assert all(torch.equal(masked[k], plain[k]) for k in before)
    finally:
        vec.close()


def test_the_plan_weight_needs_the_fast_update_and_the_linear_rate_stops_at_zero():
    from panda_lead.config import EnvConfig
    from panda_lead.errors import UserError
    from panda_lead.training.fast_ppo import linear_schedule

    env = EnvConfig(follow_plan=True, obs_features=("ee_pos", "plan_weight"))
    with pytest.raises(UserError, match="plan_weight .* needs the fast update"):
        TrainConfig(env=env, fast_update=False)
    rate = linear_schedule(1e-3)
    assert rate(1.0) == 1e-3 and rate(0.25) == 2.5e-4
    # the rollout that crosses --timesteps is updated on at progress < 0: no negative rate
    assert rate(0.0) == 0.0 and rate(-0.4) == 0.0
