"""A SubprocVecEnv whose workers each own a batch of envs and answer with stacked arrays.

SB3's SubprocVecEnv gives every env its own process: one pipe round trip (~95 us) per env per
step, more than the env's own physics. Here ``n_envs`` envs are split over ``n_workers``
processes; each worker steps its envs in a loop and sends back one array per quantity, so a
vectorised step costs one round trip per *worker*. Infos are trimmed to what SB3 reads
(``terminal_observation``, ``TimeLimit.truncated`` and any failure), because pickling the
full per-step info dicts costs more than the step. It is a drop-in VecEnv for train.py.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

# The worker lives in its own module: unpickling it in a new process must not import
# stable-baselines3 (and with it torch, ~400 MB per process).
from vecenv_worker import worker


class BatchedSubprocVecEnv(VecEnv):
    """``n_envs`` PandaLeadEnv instances in ``n_workers`` processes (envs split evenly)."""

    def __init__(self, env_kwargs: dict, n_envs: int, n_workers: int,
                 start_method: str = "forkserver"):
        if not 1 <= n_workers <= n_envs:
            raise ValueError(f"need 1 <= n_workers <= n_envs, got {n_workers} and {n_envs}")
        import env as env_mod

        probe = env_mod.PandaLeadEnv(**env_kwargs)
        obs_space, act_space = probe.observation_space, probe.action_space
        probe.close()
        ctx = mp.get_context(start_method)
        sizes = [n_envs // n_workers + (w < n_envs % n_workers) for w in range(n_workers)]
        self._slices = np.split(np.arange(n_envs), np.cumsum(sizes)[:-1])
        self.remotes, self.processes = [], []
        for size in sizes:
            remote, work = ctx.Pipe()
            p = ctx.Process(target=worker, args=(work, remote, env_kwargs, size), daemon=True)
            p.start()
            work.close()
            self.remotes.append(remote)
            self.processes.append(p)
        self.waiting = self.closed = False
        super().__init__(n_envs, obs_space, act_space)

    def step_async(self, actions: np.ndarray) -> None:
        for remote, idx in zip(self.remotes, self._slices, strict=True):
            remote.send(("step", actions[idx]))
        self.waiting = True

    def step_wait(self):
        results = [remote.recv() for remote in self.remotes]
        self.waiting = False
        obs = np.concatenate([r[0] for r in results])
        rew = np.concatenate([r[1] for r in results])
        done = np.concatenate([r[2] for r in results])
        infos = [info for r in results for info in r[3]]
        return obs, rew, done, infos

    def reset(self):
        for remote, idx in zip(self.remotes, self._slices, strict=True):
            remote.send(("reset", ([self._seeds[i] for i in idx],
                                   [self._options[i] for i in idx])))
        obs = np.concatenate([remote.recv() for remote in self.remotes])
        self._reset_seeds()
        self._reset_options()
        return obs

    def close(self) -> None:
        if self.closed:
            return
        if self.waiting:
            for remote in self.remotes:
                remote.recv()
        for remote in self.remotes:
            remote.send(("close", None))
        for p in self.processes:
            p.join()
        for remote in self.remotes:
            remote.close()
        self.closed = True

    def _route(self, indices: VecEnvIndices):
        """Per worker: (remote, local indices, global indices) for the requested envs."""
        wanted = set(self._get_indices(indices))
        for remote, idx in zip(self.remotes, self._slices, strict=True):
            local = [j for j, g in enumerate(idx) if g in wanted]
            if local:
                yield remote, local

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        out = []
        for remote, local in self._route(indices):
            remote.send(("get_attr", (local, attr_name)))
            out.extend(remote.recv())
        return out

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for remote, local in self._route(indices):
            remote.send(("set_attr", (local, attr_name, value)))
            remote.recv()

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None,
                   **method_kwargs) -> list[Any]:
        out = []
        for remote, local in self._route(indices):
            remote.send(("env_method", (local, method_name, method_args, method_kwargs)))
            out.extend(remote.recv())
        return out

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))  # the workers hold bare envs

    def get_images(self) -> Sequence[np.ndarray | None]:
        raise NotImplementedError("render in the main process (eval.py --video), not in workers")
