"""Stable-Baselines3's view of the batched env: an SB3 `VecEnv` over one `env.LeadTask`.

N arms step in one `mujoco.batch.Batch` in this process (MuJoCo's threads, no pipes, no
worker processes). SB3 wants its own conventions, which differ from Gymnasium's vector API:
an episode that ends is reset within the same step, its last observation goes into
``info["terminal_observation"]``, and ``info["TimeLimit.truncated"]`` marks a timeout so
that PPO bootstraps from it instead of treating it as a failure. It also reports each
episode's return and length, ``info["episode"] = {"r", "l", "t"}``, as SB3's VecMonitor
would, so that SB3's logs have them without a VecMonitor around it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from .config import EnvConfig
from .task import LeadTask


class LeadVecEnv(VecEnv):
    """``n_envs`` PandaLead-v0 episodes for SB3. ``seed(s)`` gives env i the stream
    ``SeedSequence(s).spawn(n_envs)[i]``: its own trajectories, disjoint from every other
    env's and from every other training seed's (see seeds.py). (This is the training rule;
    Gymnasium's vector env seeds env i with s + i, as Gymnasium's own vector envs do.)

    On the step an episode ends, its info holds ``episode``: ``r`` its return (summed in
    float32, as SB3's VecMonitor sums it), ``l`` its length in steps, ``t`` seconds since the
    env was made; a VecMonitor around it reports the same r and l."""

    def __init__(self, config: EnvConfig, n_envs: int, nthread: int = 0):
        self.task = LeadTask(config, n_envs, nthread=nthread)
        obs_space = spaces.Box(-np.inf, np.inf, (self.task.obs_dim,), np.float32)
        act_space = spaces.Box(-1.0, 1.0, (self.task.action_dim,), np.float32)
        super().__init__(n_envs, obs_space, act_space)
        self._actions = np.zeros((n_envs, self.task.action_dim), dtype=np.float32)
        self._stream_seed: int | None = None
        self._t_start = time.time()
        self._returns = np.zeros(n_envs, dtype=np.float32)  # of the running episodes
        self._lengths = np.zeros(n_envs, dtype=np.int32)

    def seed(self, seed: int | None = None) -> Sequence[None]:
        self._stream_seed = seed
        return [None] * self.num_envs

    def reset(self) -> np.ndarray:
        if self._stream_seed is not None:
            streams = np.random.SeedSequence(self._stream_seed).spawn(self.num_envs)
            self.task.rngs = [np.random.default_rng(s) for s in streams]
            self._stream_seed = None  # a later reset() continues the streams
        self._returns[:] = 0.0
        self._lengths[:] = 0
        return self.task.reset()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.task.step(self._actions)
        reward = reward.astype(np.float32)
        done = terminated | truncated
        self._returns += reward
        self._lengths += 1
        # SB3 reads only its own keys: no per-env copies of the task's info arrays on the hot
        # path.
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        ended = np.flatnonzero(done)
        if len(ended):
            t = round(time.time() - self._t_start, 6)
            for i in ended:
                infos[i]["terminal_observation"] = obs[i].copy()
                infos[i]["TimeLimit.truncated"] = bool(truncated[i])
                infos[i]["episode"] = {"r": self._returns[i], "l": self._lengths[i], "t": t}
                if info["unstable"][i]:
                    infos[i]["failure"] = "unstable"
            self._returns[ended] = 0.0
            self._lengths[ended] = 0
            obs[ended] = self.task.reset(ended)[ended]  # the others keep their (noisy) obs
        return obs, reward, done, infos

    def close(self) -> None:
        pass

    # SB3's VecEnv interface for attribute access; the batch has no per-env objects.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        # render_mode: SB3 asks at construction; a batch renders nothing (eval.py renders).
        value = None if attr_name == "render_mode" else getattr(self.task.config, attr_name)
        return [value] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError("the batched env's settings are fixed at construction (EnvConfig)")

    # Task-wide methods: one call sets every env of the batch (SB3's env_method, all indices).
    TASK_METHODS = ("set_speed_cap",)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        if method_name not in self.TASK_METHODS:
            raise AttributeError(f"the batched env has no per-env method {method_name!r}")
        if len(self._indices(indices)) != self.num_envs:
            raise AttributeError(f"{method_name} sets every env of the batch at once")
        return [getattr(self.task, method_name)(*args, **kwargs)] * self.num_envs

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)
