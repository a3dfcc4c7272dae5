"""The batched core is the single env, bit for bit: make_vec vs make, batched rollouts vs one
at a time, SB3's LeadVecEnv vs Gymnasium's vector env; training streams are independent."""

import gymnasium as gym
import numpy as np
import pytest

from panda_lead import trajectory
from panda_lead.config import OBS_FEATURES, EnvConfig
from panda_lead.controllers import classical, make_analytic, make_policy
from panda_lead.env import PandaLeadEnv
from panda_lead.rollout import ARRAY_KEYS, record, record_many
from panda_lead.seeds import EVAL_SET, POOL_SEEDS, TEST_SEEDS, TRAIN_SEED_LOW, TUNE_SEEDS
from panda_lead.vector import PandaLeadVecEnv

STEPS = 60
# 24 trajectory seeds, 8 of each shape (the seed draws the shape; we pick seeds so each shape is
# covered, plus forced shapes for the last three).
SEEDS = [s for s in range(200) if trajectory.sample(s).shape == "circle"][:7] + \
        [s for s in range(200) if trajectory.sample(s).shape == "fig8"][:7] + \
        [s for s in range(200) if trajectory.sample(s).shape == "fly"][:7] + [900, 901, 902]
SHAPES = [None] * 21 + ["circle", "fig8", "fly"]


def _single_episode(seed, shape, actions):
    e = gym.make("PandaLead-v0", episode_steps=STEPS, max_episode_steps=STEPS)
    options = {"traj_seed": seed, **({"shape": shape} if shape else {})}
    obs, _ = e.reset(seed=seed, options=options)
    out = [(obs, 0.0, 0.0, e.unwrapped.core.qpos[0].copy())]
    for a in actions:
        obs, r, term, trunc, info = e.step(a)
        out.append((obs, r, info["distance"], e.unwrapped.core.qpos[0].copy()))
    assert trunc and not term
    return out


@pytest.mark.parametrize("kind", ["zero", "random"])
def test_vector_env_episodes_are_the_single_envs_bit_for_bit(kind):
    rng = np.random.default_rng(7)
    n = len(SEEDS)
    actions = np.zeros((STEPS, n, 3), np.float32) if kind == "zero" else \
        rng.uniform(-1.2, 1.2, (STEPS, n, 3)).astype(np.float32)
    v = gym.make_vec("PandaLead-v0", num_envs=n, episode_steps=STEPS, num_threads=2)
    obs, info = v.reset(options={"traj_seeds": SEEDS, "shapes": SHAPES})
    vec = [(obs, np.zeros(n), np.zeros(n), v.unwrapped.task.core.qpos.copy())]
    for t in range(STEPS):
        obs, r, term, trunc, inf = v.step(actions[t])
        vec.append((obs, r, inf["distance"], v.unwrapped.task.core.qpos.copy()))
    assert trunc.all() and not term.any()
    shapes_played = set()
    for i, (seed, shape) in enumerate(zip(SEEDS, SHAPES, strict=True)):
        alone = _single_episode(seed, shape, actions[:, i])
        shapes_played.add(trajectory.sample(seed, shape).shape)
        for t, (o, r, d, q) in enumerate(alone):
            vo, vr, vd, vq = vec[t]
            assert np.array_equal(o, vo[i]) and np.array_equal(q, vq[i]), (seed, t)
            if t:
                assert r == vr[i] and d == vd[i], (seed, t)
    assert shapes_played == set(trajectory.SHAPES)


def _assert_same_rollouts(batch, alone):
    assert len(batch) == len(alone)
    for a, b in zip(batch, alone, strict=True):
        for k in ARRAY_KEYS:
            assert np.array_equal(getattr(a, k), getattr(b, k)), (a.seed, k)
        assert a.meta == b.meta


@pytest.fixture(scope="module")
def policy():
    from stable_baselines3 import PPO

    e = PandaLeadEnv(obs_features=OBS_FEATURES)
    model = PPO("MlpPolicy", e, seed=0, device="cpu", policy_kwargs=dict(net_arch=[64, 64]))
    return model


@pytest.mark.parametrize("controller", ["classical", "analytic", "policy"])
def test_batched_rollouts_equal_one_at_a_time(controller, policy):
    config = EnvConfig(episode_steps=STEPS, obs_features=OBS_FEATURES,
                               obs_noise={"target_vel": 0.05, "ee_pos": 0.002})
    act = {"classical": classical, "analytic": make_analytic(),
           "policy": make_policy(policy)}[controller]
    seeds, shapes = SEEDS[::2], SHAPES[::2]
    batch = record_many(config, act, seeds, shapes, batch_size=5)  # uneven chunks on purpose
    single = PandaLeadEnv(config)
    alone = [record(single, act, s, sh) for s, sh in zip(seeds, shapes, strict=True)]
    _assert_same_rollouts(batch, alone)
    assert len({r.shape for r in batch}) == 3


def test_zero_action_rollout_is_the_classical_core():
    from panda_lead.core import ArmBatch

    seeds = SEEDS[::4]
    rollouts = record_many(EnvConfig(episode_steps=STEPS), classical, seeds)
    arms = ArmBatch(len(seeds), nthread=1)
    arms.reset(trajs=[trajectory.sample(s) for s in seeds], n_steps=STEPS)
    for t in range(STEPS):
        arms.step()  # no lead at all
        for i, r in enumerate(rollouts):
            assert np.array_equal(r.qpos[t], arms.qpos[i])
            assert np.array_equal(r.ee_pos[t], arms.tip_pos[i])


def test_sb3_vec_env_matches_gymnasium_vector_env_and_resets_in_step():
    from panda_lead.sb3_vecenv import LeadVecEnv

    n, steps = 4, 30
    config = EnvConfig(episode_steps=steps)
    sb3 = LeadVecEnv(config, n, nthread=1)
    sb3.seed(5)
    gv = PandaLeadVecEnv(n, config)
    obs_a = sb3.reset()  # SB3's training streams; Gymnasium's env plays the trajectories drawn
    obs_b, _ = gv.reset(options={"traj_seeds": sb3.task.traj_seeds.tolist()})
    np.testing.assert_array_equal(obs_a, obs_b)
    rng = np.random.default_rng(0)
    for t in range(steps):
        a = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        sb3.step_async(a)
        obs_a, r_a, done, infos = sb3.step_wait()
        obs_b, r_b, term, trunc, _ = gv.step(a)
        np.testing.assert_array_equal(r_a, r_b.astype(np.float32))
        if t < steps - 1:
            np.testing.assert_array_equal(obs_a, obs_b)
    # The episode ended: SB3 gets the last observation in the info and a fresh start at once.
    assert done.all() and trunc.all()
    for i in range(n):
        np.testing.assert_array_equal(infos[i]["terminal_observation"], obs_b[i])
        assert infos[i]["TimeLimit.truncated"] is True
    assert sb3.task.core.step_count.tolist() == [0] * n


def _training_trajectories(seed: int, count: int, n_envs: int = 32) -> list[int]:
    from panda_lead.sb3_vecenv import LeadVecEnv

    vec = LeadVecEnv(EnvConfig(episode_steps=1), n_envs, nthread=1)
    vec.seed(seed)
    vec.reset()
    drawn = list(vec.task.traj_seeds)
    while len(drawn) < count:
        vec.task.reset()
        drawn += list(vec.task.traj_seeds)
    return drawn[:count]


def test_training_seeds_draw_independent_trajectory_streams():
    a, b = _training_trajectories(1, 10_000), _training_trajectories(2, 10_000)
    shared = len(set(a) & set(b)) / 10_000
    assert shared < 0.01, f"training seeds 1 and 2 share {shared:.1%} of their trajectories"
    assert len(set(a)) > 9_900  # within one training seed the envs do not repeat each other
    held_out = set(TEST_SEEDS) | {s for s, _ in EVAL_SET} | set(TUNE_SEEDS) | set(POOL_SEEDS)
    assert min(a + b) >= TRAIN_SEED_LOW and not held_out & set(a + b)


def test_numpy_actor_is_sb3s_deterministic_policy(policy):
    rng = np.random.default_rng(3)
    obs = rng.normal(0, 1, (50, policy.observation_space.shape[0])).astype(np.float32)
    ours = make_policy(policy)(obs, None)
    theirs, _ = policy.predict(obs, deterministic=True)
    np.testing.assert_allclose(ours, theirs, atol=1e-5)  # float64 vs torch's float32
    assert np.abs(ours).max() <= 1.0
