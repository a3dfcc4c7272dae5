"""PandaLead-v0: API checks, zero action == classical, reward bookkeeping, determinism."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

from panda_lead import trajectory
from panda_lead.config import (
    OBS_FEATURES,
    OBS_SCALE,
    REWARD_TERMS,
    EnvConfig,
    arguments_table,
    config_docs,
)
from panda_lead.core import ArmBatch
from panda_lead.env import PandaLeadEnv
from panda_lead.errors import UserError
from panda_lead.rollout import record
from panda_lead.task import LeadTask
from panda_lead.vector import PandaLeadVecEnv


def test_registered_and_passes_gymnasium_and_sb3_checkers():
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    e = gym.make("PandaLead-v0", episode_steps=20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test, except:
        # Gymnasium's own MuJoCo envs use unbounded observation boxes too; not a defect.
        warnings.filterwarnings("ignore", message=".*observation space (min|max)imum value")
        gym_check(e.unwrapped, skip_render_check=True)
        sb3_check(e.unwrapped, warn=True)
    assert e.unwrapped.metadata["render_fps"] == 100
    assert e.action_space.dtype == np.float32 and e.action_space.shape == (3,)


def test_zero_action_reproduces_the_classical_core_exactly():
    seed, steps = 11, 150
    e = PandaLeadEnv(episode_steps=steps)
    e.reset(seed=0, options={"traj_seed": seed})
    core = ArmBatch(1, nthread=1)
    core.reset(trajs=[trajectory.sample(seed)], n_steps=steps)
    for _ in range(steps):
        e.step(np.zeros(3, dtype=np.float32))
        core.step()  # no lead at all
        assert np.array_equal(e.core.qpos, core.qpos)
        assert np.array_equal(e.core.qvel, core.qvel)
        assert np.array_equal(e.core.tip_pos, core.tip_pos)


def test_reward_terms_add_up_and_are_weighted():
    kw = dict(w_distance=1.3, w_tracking=0.7, tracking_scale=0.04, w_action=0.2,
              w_action_change=0.1, w_collision=50.0, w_alive=0.05, w_termination=3.0)
    e = PandaLeadEnv(episode_steps=60, **kw)
    e.reset(seed=3, options={"traj_seed": 5})
    rng = np.random.default_rng(0)
    prev = np.zeros(3)
    for _ in range(60):
        a = rng.uniform(-1, 1, 3).astype(np.float32)
        _, reward, term, trunc, info = e.step(a)
        terms = info["reward_terms"]
        assert set(terms) == set(REWARD_TERMS)
        assert reward == pytest.approx(sum(terms.values()), abs=1e-12)
        d = info["distance"]
        assert terms["distance"] == pytest.approx(-1.3 * d)
        assert terms["tracking"] == pytest.approx(0.7 * np.exp(-d / 0.04))
        assert terms["action"] == pytest.approx(-0.2 * float(a.astype(float) @ a.astype(float)))
        da = a.astype(float) - prev
        assert terms["action_change"] == pytest.approx(-0.1 * float(da @ da))
        assert terms["alive"] == pytest.approx(0.05)
        prev = a.astype(float)
        if term or trunc:
            break
    assert trunc and not term


def test_observation_layout_follows_the_feature_order():
    e = PandaLeadEnv(obs_features=("target_acc", "ee_pos", "prev_action"))
    assert [f for f, _, _ in e._layout] == ["ee_pos", "target_acc", "prev_action"]
    obs, _ = e.reset(seed=0, options={"traj_seed": 2})
    assert obs.shape == (9,) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[0:3], e.core.tip_pos[0], atol=1e-6)
    obs, *_ = e.step(np.array([0.5, -0.5, 1.0], dtype=np.float32))
    np.testing.assert_allclose(obs[6:9], [0.5, -0.5, 1.0])
    acc = e.core.target()[2][0]
    np.testing.assert_allclose(obs[3:6], acc / OBS_SCALE["target_acc"], rtol=1e-6)


def test_tip_error_is_the_tip_minus_the_target_at_its_scale():
    e = PandaLeadEnv(obs_features=("ee_pos", "target_pos", "tip_error"))
    obs, _ = e.reset(seed=0, options={"traj_seed": 2})
    for _ in range(3):  # at reset (the home pose, ~40 cm off) and after steps
        tip, target = e.core.tip_pos[0], e.core.target()[0][0]
        np.testing.assert_allclose(obs[6:9], (tip - target) / OBS_SCALE["tip_error"], rtol=1e-6)
        assert np.linalg.norm(tip - target) > 0.01  # a real error, not zeros that pass anyway
        obs, *_ = e.step(np.array([0.3, -0.2, 0.1], dtype=np.float32))


def test_tip_error_avg_is_a_running_average_of_the_clipped_error():
    e = PandaLeadEnv(obs_features=("tip_error_avg",), error_avg_time=0.2, error_avg_clip=0.02)
    obs, _ = e.reset(seed=0, options={"traj_seed": 2})
    np.testing.assert_array_equal(obs, 0.0)  # nothing averaged before the first step
    rate, expected = e.core.dt / 0.2, np.zeros(3)
    for _ in range(40):  # the swing from the home pose: the clip bites, then lets go
        obs, *_ = e.step(np.array([0.2, 0.1, -0.3], dtype=np.float32))
        err = e.core.tip_pos[0] - e.core.target()[0][0]
        expected = expected + rate * (np.clip(err, -0.02, 0.02) - expected)
        np.testing.assert_allclose(obs * OBS_SCALE["tip_error_avg"], expected, rtol=1e-5,
                                   atol=1e-9)
    assert np.abs(expected).max() > 0.005  # it moved: not a zero that passes anyway
    e.reset(seed=0, options={"traj_seed": 2})
    assert not e.task.err_avg.any()  # a reset forgets it


def test_lead_is_scaled_and_clipped():
    e = PandaLeadEnv(max_lead=0.1)
    e.reset(seed=0, options={"traj_seed": 1})
    *_, info = e.step(np.array([2.0, -0.5, 0.0], dtype=np.float32))
    np.testing.assert_allclose(info["lead"], [0.1, -0.05, 0.0])


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(UserError, match="did you mean 'target_acc'"):
        PandaLeadEnv(obs_features=("target_ac",))
    with pytest.raises(UserError, match="did you mean 'circle'"):
        PandaLeadEnv(shapes=("circel",))
    with pytest.raises(UserError, match="did you mean 'max_lead'"):
        PandaLeadEnv(max_leed=0.1)
    for bad in (dict(ik={"iters": 0}), dict(tracking_scale=0.0), dict(max_lead=float("nan")),
                dict(obs_noise={"ee_pos": float("nan")}), dict(episode_steps=1.5)):
        with pytest.raises(UserError):
            PandaLeadEnv(**bad)
    e = PandaLeadEnv()
    e.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        e.step(np.array([np.nan, 0, 0], dtype=np.float32))


def test_same_seed_same_episode_and_reset_restores_everything():
    e = PandaLeadEnv(episode_steps=80, obs_features=OBS_FEATURES,
                             obs_noise={"ee_pos": 0.01})
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (80, 3)).astype(np.float32)

    def run():
        obs, _ = e.reset(seed=123)
        out = [obs]
        for a in actions:
            obs, *_ = e.step(a)
            out.append(obs)
        return np.array(out)

    first = run()
    # Disturb every piece of state, then rerun: the reset must restore all of it.
    e.reset(seed=999)
    for a in actions[:30]:
        e.step(-a)
    np.testing.assert_array_equal(first, run())


def test_training_shapes_are_respected():
    e = PandaLeadEnv(shapes=("circle",))
    e.reset(seed=0)
    shapes = set()
    for _ in range(10):
        _, info = e.reset()
        shapes.add(info["shape"])
    assert shapes == {"circle"}


def test_terminates_on_self_collision_only_when_asked():
    def fold(e):
        # Drive the IK target into the arm's own body: tip at the shoulder.
        hit = None
        for _ in range(200):
            lead = (np.array([0.0, 0.0, 0.35]) - e.core.target()[0][0]) / e.max_lead
            _, r, term, trunc, info = e.step(np.clip(lead, -1, 1).astype(np.float32))
            if info["self_collision"] or term or trunc:
                hit = (term, info)
                break
        return hit

    on = PandaLeadEnv(max_lead=1.0, terminate_on_collision=True, w_termination=5.0)
    on.reset(seed=0, options={"traj_seed": 4})
    hit = fold(on)
    assert hit is not None, "the arm never folded into itself"
    term, info = hit
    assert term and info["failure"] == "self_collision"
    assert info["reward_terms"]["termination"] == -5.0


def test_record_writes_one_row_per_step():
    e = PandaLeadEnv(episode_steps=50)
    r = record(e, lambda obs, task: np.zeros((len(obs), 3), np.float32), traj_seed=8)
    assert len(r.t) == 50 and r.ee_pos.shape == (50, 3) and r.qpos.shape == (50, 7)
    np.testing.assert_allclose(r.t, np.arange(1, 51) * 0.01)
    assert r.meta["seed"] == 8 and r.meta["shape"] in trajectory.SHAPES
    assert r.meta["duration"] == pytest.approx(0.5)


def test_evaluate_groups_drawn_shapes_by_the_shape_played():
    from panda_lead import trajectory
    from panda_lead.controllers import classical
    from panda_lead.training import evaluate

    res = evaluate(classical, {}, 20, episodes=[(0, None), (1, None), (2, "fly")])
    played = {trajectory.sample(0).shape, trajectory.sample(1).shape, "fly"}
    assert {k.split("/")[0] for k in res if "/" in k} == played


def test_arguments_table_in_the_docstring_is_the_config():
    import dataclasses

    from panda_lead.core import IKConfig

    doc = PandaLeadEnv.__doc__
    for cls, prefix in ((EnvConfig, ""), (IKConfig, "ik.")):
        defaults = cls()
        for f in dataclasses.fields(cls):
            if f.name == "ik":
                continue  # a row per IK knob instead
            row = next(line for line in doc.splitlines()
                       if line.strip().startswith(f"| {prefix}{f.name} |"))
            assert repr(getattr(defaults, f.name)) in row
            assert config_docs(cls)[f.name], f"{f.name} has no one-line docstring"


def test_config_round_trips_through_its_dict():
    c = EnvConfig(obs_features=("target_vel", "ee_pos"), shapes=("fly",),
                          obs_noise={"ee_pos": 0.01}, max_lead=0.1)
    assert c.obs_features == ("ee_pos", "target_vel")  # canonical order
    assert EnvConfig.from_dict(c.to_dict()) == c
    assert PandaLeadEnv(c).cfg == c == PandaLeadEnv(**c.to_dict()).cfg


def test_episode_length_has_one_home_whichever_way_the_env_is_made():
    assert gym.make("PandaLead-v0").spec.max_episode_steps == EnvConfig().episode_steps
    single = gym.make("panda_lead/PandaLead-v0", episode_steps=7)
    vec = gym.make_vec("PandaLead-v0", num_envs=2, episode_steps=7)
    assert single.spec.max_episode_steps == 7
    single.reset(seed=0)
    vec.reset(seed=0)
    a = np.zeros(3, np.float32)
    ends_single = [single.step(a)[3] for _ in range(7)]
    ends_vec = [vec.step(np.zeros((2, 3), np.float32))[3] for _ in range(7)]
    assert ends_single == [False] * 6 + [True]  # 7 steps, not the default 200
    assert [bool(e.all()) for e in ends_vec] == [False] * 6 + [True]


def test_vector_entry_point():
    v = gym.make_vec("PandaLead-v0", num_envs=3)
    assert isinstance(v.unwrapped, PandaLeadVecEnv) and v.num_envs == 3
    obs, info = v.reset(seed=0)
    assert obs.shape == (3, 15) and obs.dtype == np.float32 and len(set(info["traj_seed"])) == 3
    v.close()


@pytest.mark.parametrize("k", [1, 3])
def test_observation_delay_shows_the_state_of_k_steps_ago(k):
    rng = np.random.default_rng(k)
    actions = rng.uniform(-1, 1, (40, 3)).astype(np.float32)
    now = PandaLeadEnv(episode_steps=40)
    late = PandaLeadEnv(episode_steps=40, obs_delay=k)
    seen_now = [now.reset(seed=1, options={"traj_seed": 5})[0]]
    seen_late = [late.reset(seed=1, options={"traj_seed": 5})[0]]
    for a in actions:
        seen_now.append(now.step(a)[0])
        seen_late.append(late.step(a)[0])
        # Only the observation is late: the arm itself moves exactly as without delay.
        assert np.array_equal(now.core.qpos, late.core.qpos)
    for t in range(len(seen_late)):
        np.testing.assert_array_equal(seen_late[t], seen_now[max(t - k, 0)])


@pytest.mark.parametrize("k", [1, 2])
def test_action_delay_applies_the_action_of_k_steps_ago(k):
    rng = np.random.default_rng(10 + k)
    actions = rng.uniform(-1, 1, (40, 3)).astype(np.float32)
    shifted = np.concatenate([np.zeros((k, 3), np.float32), actions[:-k]])
    late = PandaLeadEnv(episode_steps=40, action_delay=k)
    ref = PandaLeadEnv(episode_steps=40)
    late.reset(seed=0, options={"traj_seed": 9})
    ref.reset(seed=0, options={"traj_seed": 9})
    for a, b in zip(actions, shifted, strict=True):
        _, _, _, _, info = late.step(a)
        _, _, _, _, ref_info = ref.step(b)
        assert np.array_equal(late.core.qpos, ref.core.qpos)
        np.testing.assert_array_equal(info["lead"], ref_info["lead"])


def test_random_delays_are_drawn_per_episode_and_reproducible():
    from panda_lead.controllers import make_analytic
    from panda_lead.rollout import record, record_many

    config = EnvConfig(episode_steps=30, obs_delay=3, action_delay=3, random_delay=True)
    batch = record_many(config, make_analytic(), range(12))
    single = PandaLeadEnv(config)
    for r in batch[:4]:
        assert np.array_equal(r.ee_pos, record(single, make_analytic(), r.seed).ee_pos)
    task = LeadTask(config, 64, nthread=1)
    task.rngs = [np.random.default_rng(s) for s in range(64)]
    task.reset()
    assert set(task.obs_delay) == {0, 1, 2, 3} and set(task.action_delay) == {0, 1, 2, 3}


def test_speed_cap_filters_training_draws_only():
    config = EnvConfig(max_peak_speed=1.0)
    task = LeadTask(config, 32, nthread=1)
    task.rngs = [np.random.default_rng(s) for s in range(32)]
    task.reset()
    assert max(t.peak_speed for t in task.trajs) <= 1.0
    fast = next(s for s in range(100) if trajectory.sample(s).peak_speed > 1.5)
    task.reset([0], [fast])  # a named (test) seed is played as it is
    assert task.trajs[0].peak_speed > 1.5
    with pytest.raises(UserError):
        EnvConfig(max_peak_speed=0.1)


def test_speed_curriculum_raises_the_cap_linearly_then_lifts_it():
    from panda_lead import training
    from panda_lead.cli.train import parse_args

    assert training.speed_cap(0, 0.8, 1000) == pytest.approx(0.8)
    assert training.speed_cap(500, 0.8, 1000) == pytest.approx(0.8 + (trajectory.MAX_SPEED - 0.8) / 2)
    assert training.speed_cap(1000, 0.8, 1000) is None
    args = parse_args(["--curriculum-steps", "300000", "--curriculum-start-speed", "0.6"])
    assert args.curriculum_steps == 300000 and args.curriculum_start_speed == 0.6
    # On by default; the presets (the reference ladder) and the reference settings run without.
    assert parse_args([]).curriculum_steps == training.TrainConfig().curriculum_steps > 0
    assert parse_args(["--preset", "v5"]).curriculum_steps == 0
    assert parse_args(["--reference-hparams"]).curriculum_steps == 0
    assert parse_args(["--preset", "v5", "--curriculum-steps", "1000"]).curriculum_steps == 1000
    # A run folder from before the curriculum existed resumes without one.
    assert training.TrainConfig.from_dict({"n_envs": 4}).curriculum_steps == 0


def test_speed_curriculum_reaches_sb3s_own_vec_envs():
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    from panda_lead import training

    vec = VecMonitor(DummyVecEnv([lambda: PandaLeadEnv(episode_steps=5)] * 2))
    callback = training.SpeedCurriculum(vec, 0.6, 1000)
    callback.init_callback(type("Model", (), {"num_timesteps": 0, "logger": _NullLogger(),
                                              "get_env": lambda self: vec})())
    callback.on_rollout_start()
    assert [e.task.speed_cap for e in vec.venv.envs] == [pytest.approx(0.6)] * 2
    callback.num_timesteps = 1000
    callback.on_rollout_start()
    assert [e.task.speed_cap for e in vec.venv.envs] == [None, None]
    # The batched env takes the same call, for all its envs at once (and only so).
    from panda_lead.sb3_vecenv import LeadVecEnv

    batched = VecMonitor(LeadVecEnv(EnvConfig(episode_steps=5), 3, nthread=1))
    callback = training.SpeedCurriculum(batched, 0.6, 1000)
    callback.init_callback(type("Model", (), {"num_timesteps": 0, "logger": _NullLogger(),
                                              "get_env": lambda self: batched})())
    callback.on_rollout_start()
    assert batched.venv.task.speed_cap == pytest.approx(0.6)
    with pytest.raises(AttributeError):
        batched.env_method("set_speed_cap", None, indices=[0])
    with pytest.raises(AttributeError):
        batched.env_method("reset")


class _NullLogger:
    def record(self, *args, **kwargs):
        pass


def test_joint_residual_action_moves_the_joint_goal_and_zero_is_classical():
    e = PandaLeadEnv(action="joint", episode_steps=30)
    assert e.action_space.shape == (7,)
    ref = ArmBatch(1, nthread=1)
    ref.reset(trajs=[trajectory.sample(4)], n_steps=30)
    e.reset(seed=0, options={"traj_seed": 4})
    for _ in range(10):
        e.step(np.zeros(7, np.float32))
        ref.step()
        assert np.array_equal(e.core.qpos, ref.qpos)  # zero residual: the classical controller
    goal = e.core.ik(e.core.target()[0])
    e.step(np.array([1, 0, 0, 0, 0, 0, -1], np.float32))
    np.testing.assert_allclose(e.core.q_goal[0] - goal[0], [0.2, 0, 0, 0, 0, 0, -0.2], atol=1e-12)
    with pytest.raises(UserError):
        EnvConfig(action="joint", obs_features=("ee_pos", "prev_action"))


def test_the_env_page_documents_every_setting():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "env.md").read_text()
    assert arguments_table() in page
