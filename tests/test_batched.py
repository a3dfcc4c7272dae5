"""The batched core is the single env, bit for bit: make_vec vs make, batched rollouts vs one
at a time, SB3's LeadVecEnv vs Gymnasium's vector env, the single env's fast path
(task_one.LeadTaskOne) vs the reference LeadTask of one slot; training streams are
independent."""

import gymnasium as gym
import numpy as np
import pytest

from panda_lead import trajectory
from panda_lead.config import OBS_FEATURES, EnvConfig
from panda_lead.controllers import classical, make_analytic, make_policy
from panda_lead.env import PandaLeadEnv
from panda_lead.rollout import ARRAY_KEYS, record, record_many
from panda_lead.seeds import EVAL_SET, POOL_SEEDS, TEST_SEEDS, TRAIN_SEED_LOW, TUNE_SEEDS
from panda_lead.task import LeadTask
from panda_lead.vector import PandaLeadVecEnv

try:
    from panda_lead.task_one import LEAN_FEATURES, LeadTaskOne
except ImportError:  # the fast path deleted (task_one.py says how): the reference alone
    LeadTaskOne, LEAN_FEATURES = None, tuple(OBS_FEATURES)

# The single env's task: the reference (LeadTask of one slot) and the fast path.
SINGLE_TASKS = [LeadTask] + ([LeadTaskOne] if LeadTaskOne is not None else [])

STEPS = 60
# 24 trajectory seeds, 8 of each shape (the seed draws the shape; we pick seeds so each shape is
# covered, plus forced shapes for the last three).
SEEDS = [s for s in range(200) if trajectory.sample(s).shape == "circle"][:7] + \
        [s for s in range(200) if trajectory.sample(s).shape == "fig8"][:7] + \
        [s for s in range(200) if trajectory.sample(s).shape == "fly"][:7] + [900, 901, 902]
SHAPES = [None] * 21 + ["circle", "fig8", "fly"]


def _single_episode(seed, shape, actions, task_cls):
    e = gym.make("PandaLead-v0", episode_steps=STEPS, max_episode_steps=STEPS)
    assert type(e.unwrapped.task) is task_cls
    options = {"traj_seed": seed, **({"shape": shape} if shape else {})}
    obs, _ = e.reset(seed=seed, options=options)
    out = [(obs, 0.0, 0.0, e.unwrapped.core.qpos[0].copy())]
    for a in actions:
        obs, r, term, trunc, info = e.step(a)
        out.append((obs, r, info["distance"], e.unwrapped.core.qpos[0].copy()))
    assert trunc and not term
    return out


@pytest.mark.parametrize("task_cls", SINGLE_TASKS, ids=lambda cls: cls.__name__)
@pytest.mark.parametrize("kind", ["zero", "random"])
def test_vector_env_episodes_are_the_single_envs_bit_for_bit(kind, task_cls, monkeypatch):
    """Each row of the vector env is the single env's episode, the single env on its fast
    path (the default) and on the reference LeadTask of one slot."""
    import panda_lead.env

    monkeypatch.setattr(panda_lead.env, "SingleTask", task_cls)
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
        alone = _single_episode(seed, shape, actions[:, i], task_cls)
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


# Settings that take different routes through the single env's step (task_one.py): the lean
# route with noise, weights, a settled-only reward, every feature, stacking; ragged ends; and
# the routes LeadTaskOne hands to LeadTask (delays, joint actions, the IK at every substep, the
# collision-aware IK, which runs on the batch).
SINGLE_CONFIGS = {
    "default": {},
    "weights": dict(w_tracking=0.7, tracking_scale=0.04, w_action=0.2, w_action_change=0.1,
                    w_alive=0.05, reward_after_s=0.05, obs_features=LEAN_FEATURES,
                    obs_noise={"ee_pos": 0.01, "target_vel": 0.05, "tip_error_avg": 0.001}),
    "stack": dict(obs_stack=3, obs_features=("tip_error", "tip_error_avg", "joint_vel")),
    # the tip error from two noisy readings neither of which is observed (hidden channels)
    "readings": dict(obs_features=("tip_error", "tip_error_avg", "target_vel"),
                     obs_noise={"ee_pos": 0.01, "target_pos": 0.02, "tip_error": 0.003,
                                "tip_error_avg": 0.001, "target_vel": 0.05}, random_noise=True),
    "ragged": dict(max_lead=1.0, terminate_on_collision=True, w_termination=2.0,
                   w_collision=30.0, obs_noise={"joint_pos": 0.02}, obs_features=LEAN_FEATURES),
    "latency": dict(obs_delay=2, action_delay=1, random_delay=True, obs_stack=2,
                    obs_noise={"joint_vel": 0.1}, obs_features=OBS_FEATURES),
    "joint": dict(action="joint", ik={"iters": 2}),
    "joint_target": dict(action="joint_target"),
    "substep_ik": dict(ik={"substep_ik": True}),
    "clearance": dict(ik={"clearance": 0.02}),
    "iters": dict(ik={"iters": 3, "max_step": 0.02}),
    "lead_filter": dict(lead_filter_hz=8.0, obs_features=("tip_error", "prev_action")),
    # the lead's low-pass in the noisy episodes only (half of them drawn noise-free)
    "noisy_lead_filter": dict(noisy_lead_filter_hz=10.0, random_noise=True, nominal_share=0.5,
                              obs_features=("tip_error", "prev_action"),
                              obs_noise={"target_pos": 0.01}),
    "target_camera": dict(target_delay=2, obs_features=OBS_FEATURES),
    # the camera's delay and the noise's level drawn per episode, the IK at the noisy reading
    "random_camera": dict(target_delay=3, random_delay=True, random_noise=True,
                          noisy_ik_target=True, obs_features=OBS_FEATURES,
                          obs_noise={"ee_pos": 0.01, "target_pos": 0.01, "target_vel": 0.1}),
    "noisy_ik_target": dict(noisy_ik_target=True, obs_noise={"target_pos": 0.01}),
    # the installation's known latencies and noise observed, drawn per episode
    "installation": dict(obs_features=("tip_error", "prev_action", "installation",
                                       "target_pos", "target_vel", "target_acc"),
                         obs_delay=2, action_delay=1, target_delay=2, random_delay=True,
                         random_noise=True, nominal_share=0.5, target_filter=True,
                         obs_noise={"target_pos": 0.01, "target_vel": 0.1, "target_acc": 1.0}),
    "installation_lean": dict(obs_features=("tip_error", "installation"), random_noise=True,
                              obs_noise={"target_pos": 0.01, "ee_pos": 0.005}),
    # the feedforward rival under the lead, the path ahead observed
    "feedforward": dict(feedforward=True, obs_features=("tip_error", "target_preview")),
    # the lap-to-lap correction in the loop (it learns from the tip's error lap after lap)
    "repetitive": dict(repetitive_gain=0.5, repetitive_advance=3, repetitive_smooth=1,
                       obs_features=("tip_error", "prev_action")),
    # the same filter on the tip's readings, episodes at their own noise levels
    "arm_filter": dict(arm_filter=True, target_filter=True, random_noise=True,
                       nominal_share=0.5, obs_features=OBS_FEATURES,
                       obs_noise={"ee_pos": 0.01, "ee_vel": 0.1, "target_pos": 0.01}),
    # the tracker's Kalman filter in the env, its estimate observed and aimed at
    "target_filter": dict(target_filter=True, noisy_ik_target=True, random_noise=True,
                          obs_features=OBS_FEATURES,
                          obs_noise={"target_pos": 0.01, "target_vel": 0.1, "target_acc": 1.0}),
}


def _same(a, b, where) -> None:
    """Equal bit for bit, with the same types (and dtypes and shapes for arrays)."""
    assert type(a) is type(b), (where, type(a), type(b))
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, (where, i))
    elif isinstance(a, np.ndarray):
        assert (a.dtype, a.shape) == (b.dtype, b.shape), (where, a, b)
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), (where, a, b)
    else:
        assert a == b or (a != a and b != b), (where, a, b)


@pytest.mark.skipif(LeadTaskOne is None, reason="the fast path is deleted")
@pytest.mark.parametrize("name", list(SINGLE_CONFIGS))
def test_the_fast_single_task_is_the_reference_bit_for_bit(name):
    """LeadTaskOne.step_one (the single env's fast path) returns what LeadTask.step_one of a
    task of one slot returns, bit for bit and type for type, over several episodes with random
    and out-of-range actions, observation noise from the slot's generator, and ends; and the
    task's and core's state after each step is the reference's."""
    # the lap-to-lap law acts only after 0.5 s and a lap: circles of 0.42-0.56 s laps, 1.2 s
    steps, seeds = (120, (21, 23, 27)) if name == "repetitive" else (25, (20, 21, 22))
    config = EnvConfig(**{"episode_steps": steps, **SINGLE_CONFIGS[name]})
    fast, ref = LeadTaskOne(config, 1, nthread=1), LeadTask(config, 1, nthread=1)
    assert fast._lean_lead == (name in ("default", "weights", "stack", "readings", "ragged",
                                         "iters", "installation_lean"))
    rng = np.random.default_rng(4)
    ends = 0
    for episode in range(3):
        for task in (fast, ref):
            task.rngs[0] = np.random.default_rng(episode)
        obs = fast.reset([0], [seeds[episode]])
        _same(obs, ref.reset([0], [seeds[episode]]), ("reset", episode))
        for t in range(config.episode_steps):
            action = rng.uniform(-1.3, 1.3, fast.action_dim)
            if name == "ragged" and t >= 4:  # aim at the shoulder: fold, collide, terminate
                action = np.clip(np.array([0.0, 0.0, 0.35]) - obs[6:9], -1, 1)
            action = action.astype(np.float32 if t % 2 else np.float64)
            out = fast.step_one(action)
            _same(out, ref.step_one(action), (episode, t))
            obs = out[0]
            for a, b in ((fast.core.qpos, ref.core.qpos), (fast.core.q_goal, ref.core.q_goal),
                         (fast.prev_action, ref.prev_action), (fast.lead, ref.lead),
                         (fast.ee_vel, ref.ee_vel), (fast.err_avg, ref.err_avg),
                         (fast.core.collision_depth, ref.core.collision_depth)):
                _same(a, b, (episode, t))
            if out[2] or out[3]:
                ends += out[2]
                break
        if name == "repetitive":  # the law acted (not only the setting carried)
            assert np.abs(ref._corrector.state["c"]).max() > 1e-3, episode
    if name == "ragged":
        assert ends, "no episode terminated: the ends were not exercised"


@pytest.mark.parametrize("task_cls", SINGLE_TASKS, ids=lambda cls: cls.__name__)
@pytest.mark.parametrize("name", ["default", "weights"])
def test_the_single_envs_deferred_arrays_are_the_batchs(name, task_cls):
    """The single env's step (LeadTaskOne.step_one, ArmOne.step_one) leaves the task's
    prev_action, lead, ee_vel and last tip position, and the core's flags and q_goal, to be
    made when first read (core_one._Deferred): read after any step, or only after some, or
    across a reset, they are a batch's rows bit for bit, fresh arrays each step as the
    batch's (and so are the reference's, LeadTask of one slot)."""
    config = EnvConfig(**{"episode_steps": 12, **SINGLE_CONFIGS[name]})
    one, many = task_cls(config, 1, nthread=1), LeadTask(config, 3, nthread=1)
    rng = np.random.default_rng(3)
    for episode in range(2):
        for i, task in enumerate((one, many, many, many)):  # noise: slot 1 is the one
            task.rngs[max(i - 1, 0)] = np.random.default_rng(episode + i)
        one.rngs[0] = np.random.default_rng(episode + 2)
        one.reset([0], [11 + episode])
        many.reset(None, [10, 11 + episode, 12])
        for t in range(config.episode_steps):
            actions = rng.uniform(-1.2, 1.2, (3, 3))
            one.step_one(actions[1].astype(np.float32))
            many.step(actions.astype(np.float32))
            if (t + episode) % 3:  # some steps are never read
                continue
            held, values = one.lead, one.lead.copy()
            for a, b in ((one.prev_action, many.prev_action), (one.lead, many.lead),
                         (one.ee_vel, many.ee_vel), (one._prev_ee, many._prev_ee),
                         (one.core.q_goal, many.core.q_goal),
                         (one.core.self_collision, many.core.self_collision),
                         (one.core.collision_depth, many.core.collision_depth),
                         (one.core.floor_contact, many.core.floor_contact),
                         (one.core.unstable, many.core.unstable)):
                assert a.dtype == b.dtype and a.shape[1:] == b.shape[1:]
                assert np.array_equal(a[0], b[1]), (episode, t)
            assert one.lead is held  # made once, then kept until the next step
    one.step_one(np.ones(3, np.float32))
    assert one.lead is not held and np.array_equal(held, values)  # a step leaves it as it was
