"""Gymnasium's vector contract for the native vector env (make_vec's default for PandaLead-v0),
checked against Gymnasium's own SyncVectorEnv over single envs, bit for bit; the single env,
the vector env and SB3's LeadVecEnv give the same episodes; SB3's episode statistics."""

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import run_script
from gymnasium.vector import AutoresetMode

from panda_lead.config import OBS_FEATURES, EnvConfig
from panda_lead.env import PandaLeadEnv
from panda_lead.errors import UserError
from panda_lead.sb3_vecenv import LeadVecEnv
from panda_lead.vector import PandaLeadVecEnv

# Settings that take different code (each is a branch of the single env's fast step): ragged
# episode ends (self-collisions terminate, with big leads), observation noise (drawn per env),
# non-zero reward weights and a settled-only reward, delays and stacking, other actions and IKs.
try:  # the features the single env's lean route builds (the "weights" config stays on it)
    from panda_lead.task_one import LEAN_FEATURES
except ImportError:  # the fast path deleted (task_one.py says how)
    LEAN_FEATURES = tuple(OBS_FEATURES)
CONFIGS = {
    "default": {},
    "ragged": dict(max_lead=1.0, terminate_on_collision=True, w_termination=2.0,
                   w_collision=30.0, obs_noise={"ee_pos": 0.01, "target_vel": 0.05},
                   episode_steps=30),
    "weights": dict(w_tracking=0.7, tracking_scale=0.04, w_action=0.2, w_action_change=0.1,
                    w_alive=0.05, reward_after_s=0.05, obs_features=LEAN_FEATURES),
    "latency": dict(obs_delay=2, action_delay=1, random_delay=True, obs_stack=2,
                    obs_noise={"joint_vel": 0.1}, obs_features=OBS_FEATURES),
    "joint": dict(action="joint", ik={"iters": 2}),
    "joint_target": dict(action="joint_target"),
    "substep_ik": dict(ik={"substep_ik": True, "nullspace_gain": 0.0}),
    "clearance": dict(ik={"clearance": 0.02}),
}
N, STEPS = 5, 12


def assert_same(a, b, path="") -> None:
    """Equal bit for bit, with the same types, dtypes, keys and masks (object arrays: each)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), (path, sorted(a), sorted(b))
        for k in a:
            assert_same(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert isinstance(b, np.ndarray) and b.dtype == object and a.shape == b.shape, path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and (a.dtype, a.shape) == (b.dtype, b.shape), path
        assert np.array_equal(a, b), (path, a, b)
    else:
        assert type(a) is type(b) and a == b, (path, a, b)


def _actions(config: dict, rng, dtype, kind: str = "random", obs=None, t: int = 0):
    dim = 3 if config.get("action", "lead") == "lead" else 7
    if kind == "zero":
        return np.zeros((N, dim), dtype)
    a = rng.uniform(-1.2, 1.2, (N, dim))
    if config.get("terminate_on_collision"):
        # Env i aims its tip at its own shoulder from step 3 i on (obs[6:9] is the target):
        # it folds into itself and terminates, each env at its own time.
        fold = np.clip(np.array([0.0, 0.0, 0.35]) - obs[:, 6:9], -1, 1)
        a = np.where((np.arange(N) * 3 <= t % 30)[:, None], fold, 0.1 * a)
    return a.astype(dtype)


def _pair(config: dict, mode=AutoresetMode.NEXT_STEP, **kw):
    config = {"episode_steps": STEPS, **config, **kw}
    native = gym.make_vec("PandaLead-v0", num_envs=N, autoreset_mode=mode, num_threads=1,
                          **config)
    sync = gym.make_vec("PandaLead-v0", num_envs=N, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": mode}, **config)
    return native, sync


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("mode", list(AutoresetMode))
def test_native_is_sync_bit_for_bit(name, mode):
    """Observations, rewards, ends and every info key and mask, over several episodes per env,
    for every autoreset mode; float64 actions in some steps, float32 in others."""
    config = CONFIGS[name]
    native, sync = _pair(config, mode)
    assert native.metadata["autoreset_mode"] == mode == sync.metadata["autoreset_mode"]
    obs, info = native.reset(seed=40)
    assert_same((obs, info), sync.reset(seed=40))
    rng = np.random.default_rng(1)
    ended_at = set()
    for t in range(3 * config.get("episode_steps", STEPS)):
        actions = _actions(config, rng, np.float64 if t % 2 else np.float32,
                           "zero" if name == "default" and t < STEPS else "random", obs, t)
        out = native.step(actions)
        obs = out[0]
        assert_same(out, sync.step(actions), f"{name} {mode} step {t}")
        done = out[2] | out[3]
        if done.any():
            ended_at.add(t)
        if mode == AutoresetMode.DISABLED and done.any():  # the user resets the ended envs
            obs, info = native.reset(options={"reset_mask": done})
            assert_same((obs, info), sync.reset(options={"reset_mask": done}))
    assert len(ended_at) >= 2  # several episodes
    if name == "ragged":
        assert len(ended_at) > 3, "no episode ended early: the ends are not ragged"


def test_reset_seeds_env_i_with_seed_plus_i_as_the_single_env():
    native = gym.make_vec("PandaLead-v0", num_envs=3)
    _, info = native.reset(seed=7)
    for i in range(3):
        _, alone = gym.make("PandaLead-v0").reset(seed=7 + i)
        assert info["traj_seed"][i] == alone["traj_seed"] and info["shape"][i] == alone["shape"]
    # A list seeds each env; None leaves an env's generator as it is.
    _, before = native.reset()
    native.unwrapped.task.rngs[1] = np.random.default_rng(123)
    expected = np.random.default_rng(123)
    _, info = native.reset(seed=[3, None, 9])
    assert info["traj_seed"][0] == gym.make("PandaLead-v0").reset(seed=3)[1]["traj_seed"]
    assert info["traj_seed"][2] == gym.make("PandaLead-v0").reset(seed=9)[1]["traj_seed"]
    from panda_lead.seeds import TRAIN_SEED_HIGH, TRAIN_SEED_LOW

    assert info["traj_seed"][1] == expected.integers(TRAIN_SEED_LOW, TRAIN_SEED_HIGH)
    with pytest.raises(ValueError, match="one seed per env \\(3\\), got 2"):
        native.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="one value per env"):
        native.reset(options={"traj_seeds": [1, 2]})


def test_reset_options_as_the_single_env_and_per_env():
    native = gym.make_vec("PandaLead-v0", num_envs=2)
    _, info = native.reset(options={"traj_seed": 5, "shape": "fig8"})
    assert info["traj_seed"].tolist() == [5, 5] and info["shape"].tolist() == ["fig8"] * 2
    _, info = native.reset(options={"traj_seeds": [1, 2], "shapes": [None, "fly"]})
    assert info["traj_seed"].tolist() == [1, 2] and info["shape"][1] == "fly"
    assert info["_traj_seed"].dtype == bool and info["_traj_seed"].all()


def test_info_masks_say_which_envs_reset_and_which_stepped():
    """On the next-step autoreset step, the env that resets reports its new episode's
    reset info (its new trajectory seed) and no step info; the others their step info."""
    v = gym.make_vec("PandaLead-v0", num_envs=3, episode_steps=4)
    v.reset(seed=0)
    v.step(np.zeros((3, 3), np.float32))
    v.reset(options={"reset_mask": np.array([False, True, False])})  # env 1 starts later
    for _ in range(3):
        _, _, _, trunc, info = v.step(np.zeros((3, 3), np.float32))
    assert trunc.tolist() == [True, False, True]
    _, reward, term, trunc, info = v.step(np.zeros((3, 3), np.float32))  # 0 and 2 reset
    assert info["_traj_seed"].tolist() == [True, False, True]
    assert info["traj_seed"][[0, 2]].tolist() == v.unwrapped.task.traj_seeds[[0, 2]].tolist()
    assert info["traj_seed"][1] == 0 and info["shape"][1] is None
    assert info["_distance"].tolist() == [False, True, False]
    assert info["distance"][0] == info["distance"][2] == 0.0 and info["distance"][1] > 0
    assert info["reward_terms"]["_distance"].tolist() == [False, True, False]
    assert reward[[0, 2]].tolist() == [0.0, 0.0] and not term.any()
    assert trunc.tolist() == [False, True, False]  # env 1's fourth step


def test_autoreset_step_uses_each_envs_action_as_given():
    """Regression: on a step where one env autoresets, every other env's float64 action was
    rounded to float32, so an env's episode depended on when its neighbours' ended."""
    config = dict(max_lead=1.0, terminate_on_collision=True, episode_steps=200)
    v = PandaLeadVecEnv(2, **config)
    alone = PandaLeadEnv(**config)
    v.reset(options={"traj_seeds": [3, 4]})
    alone.reset(options={"traj_seed": 3})
    task = v.task
    ended = None
    for t in range(200):
        # env 0: a small float64 lead (0.015 is not a float32); env 1 folds into itself
        fold = np.clip(np.array([0.0, 0.0, 0.35]) - task.core.target()[0][1], -1, 1)
        actions = np.array([[0.015, -0.0105, 0.0205], fold])
        _, _, term, trunc, _ = v.step(actions)
        alone.step(actions[0])
        assert np.array_equal(task.core.qpos[0], alone.core.qpos[0]), t
        if ended is not None and t == ended + 1:
            break  # the autoreset step of env 1 has been checked
        if term[1] and ended is None:
            assert not (term[0] or trunc[0])
            ended = t
    assert ended is not None, "env 1 never ended before env 0"


def test_the_ghost_step_draws_no_noise_from_the_resetting_envs_generator():
    """The batch steps a resetting env once more (its result discarded): its noise generator
    must not advance, or its next trajectory would differ from the single env's."""
    native, sync = _pair(dict(obs_noise={"ee_pos": 0.01}))
    native.reset(seed=3)
    sync.reset(seed=3)
    for _ in range(STEPS + 1):
        a = np.zeros((N, 3), np.float32)
        out = native.step(a)
        assert_same(out, sync.step(a))
    assert out[4]["_traj_seed"].all()  # every env reset with its next trajectory


def test_soak_counts_env_steps_not_autoreset_steps():
    # 2 envs, 5-step episodes, 20 env steps: exactly two episodes each; the steps that only
    # reset are not steps (counting them, the study stopped after one episode each).
    out = run_script("studies/soak.py", "--steps", 20, "--envs", 2, "--episode-steps", 5,
                     "--workers", 1, check=True).stdout
    assert "steps 20 in" in out and "episodes 4 " in out, out


def test_render_returns_one_frame_per_env_from_the_single_envs_renderer():
    # In a process of its own: after several EGL contexts were made and closed in one process,
    # a later test's torch setup was seen to segfault (Mesa EGL, 2 cores), so the GL state of
    # this test never outlives it.
    if not os.environ.get("PANDA_LEAD_RENDER_CHILD"):
        node = (f"{Path(__file__).resolve()}::"
                "test_render_returns_one_frame_per_env_from_the_single_envs_renderer")
        # -n 0: one test needs no pytest-xdist workers of its own (addopts asks for two;
        # starting them tripled this test's time)
        out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p",
                              "no:cacheprovider", node],
                             env={**os.environ, "PANDA_LEAD_RENDER_CHILD": "1"},
                             capture_output=True, text=True, timeout=900)
        assert out.returncode == 0 and "1 passed" in out.stdout, (out.stdout[-3000:]
                                                                  + out.stderr[-2000:])
        return
    native, sync = _pair({}, render_mode="rgb_array", width=64, height=48)
    assert "rgb_array" in native.metadata["render_modes"]
    assert native.render_mode == "rgb_array"
    native.reset(seed=1)
    sync.reset(seed=1)
    native.render(), sync.render()  # a fresh MuJoCo renderer's first frame differs slightly
    rng = np.random.default_rng(0)
    for i in range(STEPS + 2):  # across an autoreset (the trail starts again)
        a = rng.uniform(-1, 1, (N, 3)).astype(np.float32)
        native.step(a)
        sync.step(a)
        if i not in (0, 1, STEPS - 2, STEPS - 1, STEPS, STEPS + 1):
            continue  # a software-rendered frame costs ~0.15 s: around the autoreset only
        frames = native.render()
        assert isinstance(frames, tuple) and len(frames) == N
        assert frames[0].shape == (48, 64, 3) and frames[0].dtype == np.uint8
        for x, y in zip(frames, sync.render(), strict=True):
            assert np.array_equal(x, y)
    native.close()
    sync.close()
    assert gym.make_vec("PandaLead-v0", num_envs=2).render() is None


def test_unsupported_settings_are_clear_errors():
    with pytest.raises(UserError, match="rgb_array.*gymnasium.make"):
        gym.make_vec("PandaLead-v0", num_envs=2, render_mode="human")
    with pytest.raises(UserError, match="did you mean 'SameStep'"):
        gym.make_vec("PandaLead-v0", num_envs=2, autoreset_mode="SameStp")
    v = gym.make_vec("PandaLead-v0", num_envs=2, autoreset_mode="SameStep")  # the value
    assert v.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    # A vector setting given to the single envs of the sync vectorization says where it goes.
    with pytest.raises(UserError, match="vector_kwargs"):
        gym.make_vec("PandaLead-v0", num_envs=2, vectorization_mode="sync",
                     autoreset_mode=AutoresetMode.SAME_STEP)
    with pytest.raises(TypeError, match="numpy array"):
        v.reset(options={"reset_mask": [True, False]})
    with pytest.raises(ValueError, match="at least one"):
        v.reset(options={"reset_mask": np.zeros(2, dtype=bool)})


def test_disabled_autoreset_asks_for_a_reset_of_the_ended_envs():
    v = gym.make_vec("PandaLead-v0", num_envs=2, episode_steps=2,
                     autoreset_mode=AutoresetMode.DISABLED)
    v.reset(seed=0)
    a = np.zeros((2, 3), np.float32)
    v.step(a)
    assert v.step(a)[3].all()
    with pytest.raises(RuntimeError, match="reset_mask"):
        v.step(a)
    obs, info = v.reset(options={"reset_mask": np.array([True, True])})
    assert info["_traj_seed"].all()
    assert not v.step(a)[3].any()


def test_wrappers_go_through_the_sync_vectorization():
    """Gymnasium refuses wrappers=[...] with a vector entry point; the sync route applies
    them to each single env, and gives the native env's numbers."""
    double = lambda e: gym.wrappers.TransformReward(e, lambda r: 2 * r)  # noqa: E731
    with pytest.raises(gym.error.Error, match="wrappers"):
        gym.make_vec("PandaLead-v0", num_envs=2, wrappers=[double])
    wrapped = gym.make_vec("PandaLead-v0", num_envs=2, vectorization_mode="sync",
                           wrappers=[double])
    native = gym.make_vec("PandaLead-v0", num_envs=2)
    assert_same(wrapped.reset(seed=5)[0], native.reset(seed=5)[0])
    a = np.full((2, 3), 0.3, np.float32)
    w, n = wrapped.step(a), native.step(a)
    assert_same(w[0], n[0])
    assert np.array_equal(w[1], 2 * n[1])
    from gymnasium.wrappers.vector import RecordEpisodeStatistics

    stats = RecordEpisodeStatistics(gym.make_vec("PandaLead-v0", num_envs=2, episode_steps=3))
    stats.reset(seed=0)
    for _ in range(3):
        *_, info = stats.step(a)
    assert info["_episode"].all() and info["episode"]["l"].tolist() == [3, 3]


def test_one_episode_length_whichever_way_the_vector_env_is_made():
    v = gym.make_vec("PandaLead-v0", num_envs=2, max_episode_steps=4)
    assert v.spec.max_episode_steps == 4 == v.unwrapped.cfg.episode_steps
    v.reset(seed=0)
    ends = [bool(v.step(np.zeros((2, 3), np.float32))[3].all()) for _ in range(4)]
    assert ends == [False, False, False, True]
    assert gym.make_vec("PandaLead-v0", num_envs=2).spec.max_episode_steps == 200
    same = gym.make_vec("PandaLead-v0", num_envs=2, max_episode_steps=6, episode_steps=6)
    assert same.spec.max_episode_steps == 6
    with pytest.raises(UserError, match="episode_steps=5 and max_episode_steps=6 disagree"):
        gym.make_vec("PandaLead-v0", num_envs=2, max_episode_steps=6, episode_steps=5)
    with pytest.raises(UserError, match="disagree"):
        gym.make_vec("PandaLead-v0", num_envs=2, max_episode_steps=6,
                     config=EnvConfig(episode_steps=5))
    from_dict = gym.make_vec("PandaLead-v0", num_envs=2, max_episode_steps=6,
                             config={"max_lead": 0.1})
    assert from_dict.unwrapped.cfg.episode_steps == 6 and from_dict.unwrapped.cfg.max_lead == 0.1


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", ["default", "ragged", "weights", "latency"])
def test_sb3_vec_env_is_the_single_env_on_the_training_streams(name, dtype):
    """SB3's LeadVecEnv (same-step reset, env i on SeedSequence(s).spawn(n)[i]) against
    single envs given those streams (set_stream, as the training vec envs do), across
    episode ends: rewards, ends, observations, terminal observations."""
    config = EnvConfig(**{"episode_steps": STEPS, **CONFIGS[name]})
    sb3 = LeadVecEnv(config, N, nthread=1)
    sb3.seed(11)
    singles = [PandaLeadEnv(config) for _ in range(N)]
    for e, stream in zip(singles, np.random.SeedSequence(11).spawn(N), strict=True):
        e.set_stream(stream)
    obs = sb3.reset()
    for i, e in enumerate(singles):
        assert np.array_equal(obs[i], e.reset()[0])
    rng = np.random.default_rng(2)
    ends = 0
    for t in range(3 * config.episode_steps):
        actions = _actions(CONFIGS[name], rng, dtype, obs=obs, t=t)
        sb3.step_async(actions)
        obs, reward, done, infos = sb3.step_wait()
        for i, e in enumerate(singles):
            o, r, term, trunc, info = e.step(actions[i])
            assert reward[i] == np.float32(r) and done[i] == (term or trunc), (t, i)
            if term or trunc:
                ends += 1
                assert np.array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["TimeLimit.truncated"] == trunc
                o, _ = e.reset()
            assert np.array_equal(obs[i], o), (t, i)
    assert ends >= N


def test_sb3_vec_env_reports_episode_statistics_as_vecmonitor():
    from stable_baselines3.common.vec_env import VecMonitor

    config = EnvConfig(episode_steps=5, w_alive=0.1)
    own = LeadVecEnv(config, 2, nthread=1)
    monitored = VecMonitor(LeadVecEnv(config, 2, nthread=1))
    own.seed(3)
    monitored.seed(3)
    own.reset()
    monitored.reset()
    returns = np.zeros(2, np.float32)
    for t in range(10):
        a = np.full((2, 3), 0.1 * t, np.float32)
        own.step_async(a)
        _, reward, done, infos = own.step_wait()
        monitored.step_async(a)
        _, _, _, m_infos = monitored.step_wait()
        returns += reward
        for i in range(2):
            if done[i]:
                ep = infos[i]["episode"]
                assert ep["r"] == returns[i] == m_infos[i]["episode"]["r"]
                assert ep["l"] == 5 == m_infos[i]["episode"]["l"] and ep["t"] >= 0
                assert type(ep["r"]) is type(m_infos[i]["episode"]["r"])
                returns[i] = 0
            else:
                assert "episode" not in infos[i]
    # SB3's own logging reads it without any monitor. (In a fresh process: in this
    # environment, building a torch optimizer after MuJoCo has rendered through EGL in the
    # same process segfaults, and other test files render.)
    code = ("from stable_baselines3 import PPO\n"
            "from panda_lead.config import EnvConfig\n"
            "from panda_lead.sb3_vecenv import LeadVecEnv\n"
            "vec = LeadVecEnv(EnvConfig(episode_steps=5), 2, nthread=1)\n"
            "model = PPO('MlpPolicy', vec, n_steps=8, batch_size=16, n_epochs=1, device='cpu')\n"
            "model.learn(16)\n"
            "print(len(model.ep_info_buffer), model.ep_info_buffer[0]['l'])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert int(out[0]) >= 2 and out[1] == "5"
