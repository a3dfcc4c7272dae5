"""`PandaLeadVecEnv`: ``gymnasium.make_vec("PandaLead-v0", num_envs=N)``, N arms in one batch."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from .config import EnvConfig, as_config
from .task import LeadTask


class PandaLeadVecEnv(VectorEnv):
    """N PandaLead-v0 envs in one batch: ``gymnasium.make_vec("PandaLead-v0", num_envs=N)``.

    Gymnasium's next-step autoreset: the step after an episode ends resets that env (its
    action is ignored). ``reset(seed=s)`` seeds env i with ``SeedSequence(s).spawn(N)[i]``,
    so every env draws its trajectories from its own stream. ``num_threads`` (default: all
    cores) is MuJoCo's thread count; results do not depend on it. ``info`` holds (N, ...)
    arrays (distance, reward_terms, self_collision, collision_depth, reachable, lead, unstable).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int, config: EnvConfig | dict | None = None,
                 num_threads: int = 0, max_episode_steps: int | None = None, **settings):
        if max_episode_steps is not None and "episode_steps" not in settings and config is None:
            settings["episode_steps"] = int(max_episode_steps)
        self.cfg = as_config(config, settings)
        self.num_envs = int(num_envs)
        self.task = LeadTask(self.cfg, self.num_envs, nthread=num_threads)
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.task.action_dim,),
                                              dtype=np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.task.obs_dim,),
                                                   np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              self.num_envs)
        self._needs_reset = np.zeros(self.num_envs, dtype=bool)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            streams = np.random.SeedSequence(seed).spawn(self.num_envs)
            self.task.rngs = [np.random.default_rng(s) for s in streams]
        options = options or {}
        obs = self.task.reset(None, options.get("traj_seeds"), options.get("shapes"))
        self._needs_reset[:] = False
        return obs, self._reset_info()

    def _reset_info(self) -> dict:
        return {"traj_seed": self.task.traj_seeds.copy(), "shape": np.array(self.task.shapes)}

    def step(self, actions):
        done = np.flatnonzero(self._needs_reset)
        if len(done):  # next-step autoreset: these envs start over, their action is unused
            actions = np.array(actions, dtype=np.float32, copy=True)
            actions[done] = 0.0
        obs, reward, terminated, truncated, info = self.task.step(actions)
        if len(done):
            obs[done] = self.task.reset(done)[done]
            reward[done] = 0.0
            terminated[done] = truncated[done] = False
        self._needs_reset = terminated | truncated
        return obs, reward, terminated, truncated, info
