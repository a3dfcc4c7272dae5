"""The target_preview observation (issue 37): the target's future positions, a variant that
knows the planned path. The reference batched task computes it at each reset; the single
env's fast path reads the same rows as Python floats, so both observe the same, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from panda_lead import trajectory
from panda_lead.config import OBS_SCALE, EnvConfig, obs_layout
from panda_lead.errors import UserError
from panda_lead.task import LeadTask
from panda_lead.task_one import LeadTaskOne

PREVIEW = EnvConfig(episode_steps=30, obs_features=("ee_pos", "target_pos", "tip_error",
                                                     "target_preview"))
JERK = PREVIEW.replace(obs_features=("ee_pos", "target_pos", "tip_error", "preview_jerk"),
                       preview_times=(0.02, 0.05, 0.08, 0.12, 0.2, 0.3))


def _preview_of(obs: np.ndarray, config: EnvConfig) -> np.ndarray:
    a, b = next((a, b) for f, a, b in obs_layout(config.obs_features) if f == "target_preview")
    return obs[:, a:b] * OBS_SCALE["target_preview"]


def test_the_preview_is_the_future_target_minus_the_present_past_the_episodes_end():
    task = LeadTask(PREVIEW, 2)
    seeds = [4, 17]
    obs = task.reset(None, seeds)
    for step in range(PREVIEW.episode_steps + 1):
        got = _preview_of(obs, PREVIEW).reshape(2, -1, 3)
        t = step * task.dt
        for i, s in enumerate(seeds):
            traj = trajectory.sample(s)
            want = np.stack([traj.at(t + h)[0] - traj.at(t)[0] for h in PREVIEW.preview_times])
            assert np.allclose(got[i], want, atol=1e-6), (step, s)  # float32 observation
        if step < PREVIEW.episode_steps:
            obs, *_ = task.step(np.zeros((2, 3)))
    # at the last step the farthest point lies 0.3 s past the episode's end, and differs
    # from the nearest: the path ahead was computed beyond the end
    assert not np.allclose(got[:, -1], got[:, 0])


def test_preview_jerk_is_what_the_taylor_guess_misses_per_h_cubed():
    task = LeadTask(JERK, 1)
    obs = task.reset(None, [9])
    traj = trajectory.sample(9)
    a, b = next((a, b) for f, a, b in obs_layout(JERK.obs_features) if f == "preview_jerk")
    for step in range(5):
        t = step * task.dt
        p, v, acc = traj.at(t)[:3]
        for j, h in enumerate(JERK.preview_times):
            ahead = traj.at(t + h)[0]
            # the definition, and what it must mean: the future position is the Taylor
            # guess plus jerk h^3 / 6
            jerk = obs[0, a + 3 * j:a + 3 * j + 3] * OBS_SCALE["preview_jerk"]
            assert np.allclose(p + v * h + acc * h * h / 2 + jerk * h ** 3 / 6, ahead, atol=1e-5)
        obs, *_ = task.step(np.zeros((1, 3)))


@pytest.mark.parametrize("config", [PREVIEW, PREVIEW.replace(obs_noise={"target_preview": 0.01}),
                                    PREVIEW.replace(obs_stack=2), JERK,
                                    JERK.replace(obs_features=JERK.obs_features
                                                 + ("target_preview",))],
                         ids=["plain", "noise", "stack", "jerk", "both"])
def test_the_single_envs_task_observes_the_reference_bit_for_bit(config):
    fast, ref = LeadTaskOne(config, 1, nthread=1), LeadTask(config, 1, nthread=1)
    assert fast._lean_lead  # the fast route (Python floats) runs with the preview observed
    rng = np.random.default_rng(2)
    for episode in range(2):
        for task in (fast, ref):
            task.rngs[0] = np.random.default_rng(episode)
        a, b = fast.reset([0], [30 + episode]), ref.reset([0], [30 + episode])
        assert np.array_equal(a, b)
        for _ in range(config.episode_steps):
            action = rng.uniform(-1.2, 1.2, 3)
            out_a, out_b = fast.step_one(action), ref.step_one(action)
            assert np.array_equal(out_a[0], out_b[0]) and out_a[1] == out_b[1]
            if out_a[2] or out_a[3]:
                break


def test_a_batch_observes_each_slot_as_one_slot_alone():
    seeds = [5, 6, 7]
    batch = LeadTask(PREVIEW, len(seeds), nthread=1)
    obs = batch.reset(None, seeds)
    alone = [LeadTask(PREVIEW, 1, nthread=1) for _ in seeds]
    single = [t.reset(None, [s]) for t, s in zip(alone, seeds, strict=True)]
    rng = np.random.default_rng(0)
    for _ in range(10):
        for i in range(len(seeds)):
            assert np.array_equal(obs[i], single[i][0])
        actions = rng.uniform(-1, 1, (len(seeds), 3))
        obs, *_ = batch.step(actions)
        single = [t.step(actions[i:i + 1])[0] for i, t in enumerate(alone)]


def test_bad_preview_times_are_one_clear_error():
    for bad in ([0.1, 0.2], [0.05, 0.1, 0.1, 0.2, 0.25, 0.3], [0, 0.1, 0.15, 0.2, 0.25, 0.3],
                [0.1, 0.2, 0.3, 0.4, 0.5, 2.0], "soon"):
        with pytest.raises(UserError, match="preview_times"):
            EnvConfig(preview_times=bad)
    c = EnvConfig.from_dict({**PREVIEW.to_dict(), "preview_times": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]})
    assert c.preview_times == (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
