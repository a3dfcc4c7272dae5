"""The training envs, and the rule that gives every env of every training seed its own stream of
trajectories: env i of training seed s draws from ``SeedSequence(s).spawn(n_envs)[i]``."""

from __future__ import annotations

import signal

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

from ..config import EnvConfig, as_config


class StreamSeeded(VecEnvWrapper):
    """SB3's own ``seed(s)`` gives env i the seed ``s + i`` (and PPO calls it with its seed), so
    training seeds s and s+1 would share n-1 of their n streams. Here ``seed(s)`` hands env i
    the stream ``SeedSequence(s).spawn(n)[i]`` instead, as the batched env does: the same
    trajectories whichever vec env runs them."""

    def seed(self, seed: int | None = None):
        if seed is not None:
            for i, stream in enumerate(np.random.SeedSequence(seed).spawn(self.num_envs)):
                self.venv.env_method("set_stream", stream, indices=[i])
        return [None] * self.num_envs

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        return self.venv.step_wait()


def _single(settings: dict, quiet_signals: bool):
    def thunk():
        import gymnasium as gym

        import panda_lead  # noqa: F401  (registers PandaLead-v0 in a worker process)

        if quiet_signals:  # signals are the main process's to handle (it saves the model)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        return gym.make("PandaLead-v0", **settings)

    return thunk


def make_vec_env(env_config: EnvConfig | dict, n_envs: int, seed: int, kind: str = "batched",
                 n_workers: int = 0):
    """The training envs, with episode statistics (``info["episode"]``). batched: one
    `mujoco.batch.Batch` of n_envs arms in this process (sb3_vecenv.LeadVecEnv; n_workers =
    MuJoCo threads, 0 = all cores); subproc: SB3's SubprocVecEnv, a process per env (the
    reference configuration); dummy: a loop of single envs in this process. LeadVecEnv reports
    episode statistics itself; SB3's own vec envs get them from a VecMonitor."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    config = as_config(env_config, {})
    if kind == "batched":
        from ..sb3_vecenv import LeadVecEnv

        vec = LeadVecEnv(config, n_envs, nthread=n_workers)
    else:
        fns = [_single(config.to_dict(), kind == "subproc") for _ in range(n_envs)]
        vec = StreamSeeded(SubprocVecEnv(fns, start_method="forkserver") if kind == "subproc"
                           else DummyVecEnv(fns))
    vec.seed(seed)
    return vec if kind == "batched" else VecMonitor(vec)
