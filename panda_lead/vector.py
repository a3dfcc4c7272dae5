"""`PandaLeadVecEnv`: ``gymnasium.make_vec("PandaLead-v0", num_envs=N)``, N arms in one batch.

It follows Gymnasium's vector API as `gymnasium.vector.SyncVectorEnv` over N single envs
does, bit for bit (tests/test_vector.py): the same seeding, the same info layout, the same
autoreset modes, frames from the same renderer; only the stepping is batched.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv

from .config import EnvConfig, as_config, failure_of
from .env import (
    VECTOR_RESET_OPTIONS,
    ArmFrames,
    EpisodeStepsSpec,
    NotCopyable,
    _episode_steps_in,
    checked_reset_options,
    failure_message,
)
from .errors import UserError, did_you_mean
from .task import LeadTask

AUTORESET_MODES = [m.value for m in AutoresetMode]


class PandaLeadVecEnv(EpisodeStepsSpec, NotCopyable, VectorEnv):
    """N PandaLead-v0 envs in one batch: ``gymnasium.make_vec("PandaLead-v0", num_envs=N)``.

    All N arms step in one `mujoco.batch.Batch` in this process; ``num_threads`` (default:
    all cores) is MuJoCo's thread count, and results do not depend on it. Everything else is
    what ``make_vec(..., vectorization_mode="sync")`` gives over N single envs, bit for bit:

    - ``reset(seed=s)`` seeds env i with ``s + i`` (a list seeds each env; None leaves one as
      it is), as the single env ``reset(seed=s + i)`` does: the same trajectories.
      ``options``: ``traj_seed``/``shape`` (every env, as the single env takes them) or
      ``traj_seeds``/``shapes`` (one per env), and ``reset_mask`` (reset only those envs);
      any other key, a seed outside 0..2^63-1 or an unknown shape is a one-line UserError.
    - ``info`` follows Gymnasium's vector convention: each key of the single env's info is an
      array over the envs with a boolean mask ``_key`` saying which envs have it; the reset
      info (``traj_seed``, ``shape``) only for the envs that reset, the step info
      (``distance``, ``reward_terms``, ``self_collision``, ``collision_depth``,
      ``reachable``, ``lead``; ``failure``, ``message`` on a failure) for those that stepped.
    - ``autoreset_mode`` (``AutoresetMode`` or its value, in ``metadata["autoreset_mode"]``):
      NEXT_STEP (default): the step after an episode ends resets that env and ignores its
      action; SAME_STEP: it resets within the step that ends it, whose observation and info
      are in ``info["final_obs"]`` and ``info["final_info"]``; DISABLED: you reset ended envs
      yourself, ``reset(options={"reset_mask": mask})``, before stepping them again.
    - ``render_mode="rgb_array"``: ``render()`` returns a tuple of frames, one per env.
    - The episode length has one home, ``episode_steps`` (``spec.max_episode_steps`` reports
      it); ``max_episode_steps=N`` given alone sets it, beside a different ``episode_steps``
      it is refused (as the single env does, and so ``vectorization_mode="sync"``).
    - ``copy.deepcopy`` and ``pickle`` are refused in one line, as the single env's are.

    Gymnasium's ``make_vec(..., wrappers=[...])`` wraps single envs, so it refuses this
    vectorization before the env is built. Use ``make_vec(..., vectorization_mode="sync",
    wrappers=[...])`` (N single envs in a loop, each wrapped), or wrap this env in Gymnasium's
    vector wrappers (``gymnasium.wrappers.vector``, e.g. ``RecordEpisodeStatistics``).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"],
                "render_fps": 100}

    def __init__(self, num_envs: int, config: EnvConfig | dict | None = None,
                 num_threads: int = 0, max_episode_steps: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, width: int = 640, height: int = 480,
                 **settings):
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise UserError(f"num_envs must be a positive integer, got {num_envs!r}")
        if max_episode_steps is not None:
            given = settings.get("episode_steps", _episode_steps_in(config))
            if given is None:
                settings["episode_steps"] = max_episode_steps
            elif given != max_episode_steps:
                raise UserError(
                    f"episode_steps={given} and max_episode_steps={max_episode_steps} disagree: "
                    "the episode length has one home, episode_steps; give one of the two")
        self.cfg = as_config(config, settings)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise UserError(
                f"the vector env renders render_mode='rgb_array' (one frame per env), got "
                f"{render_mode!r}; to watch one arm, gymnasium.make('PandaLead-v0', "
                f"render_mode='human')")
        self.num_envs = num_envs
        self.task = LeadTask(self.cfg, num_envs, nthread=num_threads)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode,
                         "render_fps": int(round(1.0 / self.task.dt))}
        self.render_mode, self._width, self._height = render_mode, width, height
        self._frames: ArmFrames | None = None
        self.trails: list[list[np.ndarray]] = [[] for _ in range(num_envs)]
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.task.action_dim,),
                                              dtype=np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.task.obs_dim,),
                                                   np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              num_envs)
        self._obs = np.zeros((num_envs, self.task.obs_dim), dtype=np.float32)
        self._needs_reset = np.zeros(num_envs, dtype=bool)  # ended, not yet reset

    # --- reset -----------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        n, options = self.num_envs, checked_reset_options(options, VECTOR_RESET_OPTIONS)
        mask = np.ones(n, dtype=bool)
        if "reset_mask" in options:
            mask = _checked_mask(options.pop("reset_mask"), n)
        if seed is None:
            seeds = [None] * n
        elif isinstance(seed, int) and not isinstance(seed, bool):
            seeds = [seed + i for i in range(n)]  # as SyncVectorEnv: env i gets seed + i
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"reset(seed=[...]) needs one seed per env ({n}), got "
                                 f"{len(seeds)}")
        ids = np.flatnonzero(mask)
        for i in ids:
            if seeds[i] is not None:  # the single env's reset(seed=s): np_random from s
                self.task.rngs[i] = seeding.np_random(seeds[i])[0]
        traj_seeds = _per_env(options, "traj_seed", n)
        shapes = _per_env(options, "shape", n)
        obs = self.task.reset(ids, None if traj_seeds is None else [traj_seeds[i] for i in ids],
                              None if shapes is None else [shapes[i] for i in ids])
        self._obs[ids] = obs[ids]
        self._needs_reset[ids] = False
        for i in ids:
            self.trails[i] = []
        return self._obs.copy(), self._reset_info(mask)

    def _reset_info(self, mask: np.ndarray) -> dict:
        """The single env's reset info of the envs in mask, in Gymnasium's vector layout."""
        shapes = np.full(self.num_envs, None, dtype=object)
        shapes[mask] = [self.task.shapes[i] for i in np.flatnonzero(mask)]
        return {"traj_seed": np.where(mask, self.task.traj_seeds, 0), "_traj_seed": mask.copy(),
                "shape": shapes, "_shape": mask.copy()}

    # --- step ------------------------------------------------------------------------------
    def step(self, actions):
        mode, task = self.autoreset_mode, self.task
        pending = self._needs_reset
        if mode == AutoresetMode.DISABLED and pending.any():
            raise RuntimeError(
                f"envs {np.flatnonzero(pending).tolist()} ended and were not reset: with "
                "autoreset_mode DISABLED, reset them first with reset(options={'reset_mask': "
                "mask}) (or make the env with autoreset_mode NEXT_STEP or SAME_STEP)")
        resets = pending if mode == AutoresetMode.NEXT_STEP else np.zeros_like(pending)
        if resets.any():
            # Next-step autoreset: these envs only reset. The batch steps them anyway (their
            # action zeroed, the result discarded, their generators untouched); every other
            # env's action is used as given (float64 stays float64).
            actions = np.array(actions, dtype=np.float64).reshape(self.num_envs, -1)
            actions[resets] = 0.0
            obs, reward, terminated, truncated, info = task.step(
                actions, discard=np.flatnonzero(resets))
        else:
            obs, reward, terminated, truncated, info = task.step(actions)
        stepped = ~resets
        self._extend_trails(stepped)
        if resets.any():
            reward[resets] = 0.0
            terminated[resets] = truncated[resets] = False
        ended = terminated | truncated
        if mode == AutoresetMode.SAME_STEP:  # ended envs reset now; their step goes in final_*
            infos = self._step_info(info, terminated, ~ended)
            if ended.any():
                final_obs = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(ended):
                    final_obs[i] = obs[i].copy()
                infos.update(final_obs=final_obs, _final_obs=ended.copy(),
                             final_info=self._step_info(info, terminated, ended),
                             _final_info=ended.copy())
            resets = ended
        else:
            infos = self._step_info(info, terminated, stepped)
        if resets.any():
            ids = np.flatnonzero(resets)
            obs[ids] = task.reset(ids)[ids]
            for i in ids:
                self.trails[i] = []
            infos.update(self._reset_info(resets))
        self._needs_reset = ended & (mode != AutoresetMode.SAME_STEP)
        self._obs = obs
        return obs.copy(), reward, terminated, truncated, infos

    def _step_info(self, info: dict, terminated: np.ndarray, rows: np.ndarray) -> dict:
        """The single env's step info of the envs in ``rows``, in Gymnasium's vector layout
        (what VectorEnv._add_info builds from each env's info): a key only if some env has it,
        its values where they exist (zero or None elsewhere), and its ``_key`` mask."""
        out: dict = {}
        if not rows.any():
            return out
        col = rows[:, None]
        out["distance"] = np.where(rows, info["distance"], 0.0)
        out["reward_terms"] = {}
        for k, v in info["reward_terms"].items():
            out["reward_terms"][k], out["reward_terms"]["_" + k] = np.where(rows, v, 0.0), rows.copy()
        out["self_collision"] = info["self_collision"] & rows
        out["collision_depth"] = np.where(rows, info["collision_depth"], 0.0)
        out["reachable"] = info["reachable"] & rows
        out["lead"] = np.where(col, info["lead"], 0.0)
        for k in list(out):
            out["_" + k] = rows.copy()
        failed = terminated & rows
        if failed.any():
            task, core = self.task, self.task.core
            failure = np.full(self.num_envs, None, dtype=object)
            message = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(failed):
                failure[i] = failure_of(info, i, True)
                message[i] = failure_message(failure[i], core.time[i], task.traj_seeds[i])
            out.update(failure=failure, _failure=failed.copy(), message=message,
                       _message=failed.copy())
        return out

    # --- rendering -------------------------------------------------------------------------
    def _extend_trails(self, stepped: np.ndarray) -> None:
        if self.render_mode is None:
            return
        pos = self.task.core.target()[0]
        for i in np.flatnonzero(stepped):
            self.trails[i].append(pos[i])

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One rgb_array frame per env (as SyncVectorEnv's render), or None without a
        render_mode."""
        if self.render_mode != "rgb_array":
            return None
        if self._frames is None:
            self._frames = ArmFrames(self.task.core.model, self._width, self._height)
        return tuple(self._frames.render(self.task.core, i, self.trails[i])
                     for i in range(self.num_envs))

    def close_extras(self, **kwargs) -> None:
        if self._frames is not None:
            self._frames.close()
            self._frames = None

    # --- task-wide settings ------------------------------------------------------------------
    def set_speed_cap(self, cap: float | None) -> None:
        """See LeadTask.set_speed_cap (every env of the batch at once)."""
        self.task.set_speed_cap(cap)


def _autoreset_mode(mode) -> AutoresetMode:
    if isinstance(mode, AutoresetMode):
        return mode
    if isinstance(mode, str) and mode in AUTORESET_MODES:
        return AutoresetMode(mode)
    raise UserError(f"unknown autoreset_mode {mode!r}" + did_you_mean(mode, AUTORESET_MODES)
                    + "; or gymnasium.vector.AutoresetMode.NEXT_STEP, SAME_STEP, DISABLED")


def _checked_mask(mask, n: int) -> np.ndarray:
    """options["reset_mask"], checked as SyncVectorEnv checks it."""
    if not isinstance(mask, np.ndarray):
        raise TypeError(f"options['reset_mask'] must be a numpy array, got {type(mask)}")
    if mask.shape != (n,):
        raise ValueError(f"options['reset_mask'] must have shape ({n},), got {mask.shape}")
    if mask.dtype != np.bool_:
        raise TypeError(f"options['reset_mask'] must have dtype bool, got {mask.dtype}")
    if not mask.any():
        raise ValueError("options['reset_mask'] must reset at least one env, got none")
    return mask.copy()


def _per_env(options: dict, name: str, n: int) -> list | None:
    """options[name] (one value for every env, as the single env takes it) or
    options[name + "s"] (one per env), as a list of n; None when neither is given."""
    if name + "s" in options:
        values = list(options[name + "s"])
        if len(values) != n:
            raise ValueError(f"options[{name + 's'!r}] needs one value per env ({n}), got "
                             f"{len(values)}")
        return values
    if name in options:
        return [options[name]] * n
    return None
