"""`PandaLeadEnv`, the single Gymnasium env of PandaLead-v0: ``gymnasium.make("PandaLead-v0")``.

It is the batched task with N=1 (task.LeadTask), so its episodes are those of the vector envs
bit for bit. ``import panda_lead`` registers it.
"""

from __future__ import annotations

import dataclasses
import sys
import textwrap
from collections.abc import Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .config import EnvConfig, arguments_table, as_config
from .errors import UserError, did_you_mean
from .task_one import LeadTaskOne as SingleTask  # the fast path; task.LeadTask: same episodes


class EpisodeStepsSpec:
    """The ``spec`` of the single and the vector env: ``gymnasium.make`` and ``make_vec`` record
    one without ``max_episode_steps`` (none is registered); it is filled in from the one home of
    the episode length, ``self.cfg.episode_steps``, so RL Zoo and wrappers read the truth."""

    _spec = None

    @property
    def spec(self):
        return self._spec

    @spec.setter
    def spec(self, value) -> None:
        steps = self.cfg.episode_steps
        if value is not None and value.max_episode_steps != steps:
            value = dataclasses.replace(value, max_episode_steps=steps)
        self._spec = value


class NotCopyable:
    """copy.copy, copy.deepcopy and pickle refuse the env in one line (see "Copies" in the
    single env's manual): its state lives in MuJoCo's C structures and values made lazily, and a
    copy that silently does not continue the episode is worse than none."""

    def __reduce_ex__(self, protocol):
        raise TypeError(
            f"{type(self).__name__} cannot be copied or pickled (its episode state lives in "
            "MuJoCo's C structures; a copy would not continue the episode): make a new env, "
            "and replay: reset(seed=s, options={'traj_seed': n}) and the same actions repeat "
            "an episode bit for bit")


class PandaLeadEnv(EpisodeStepsSpec, NotCopyable, gym.Env):
    """A Franka Panda keeps its tip on a fast target; the action is a lead for the IK target.

    Each step (100 Hz) the target moves along an analytic trajectory (`trajectory.py`); the
    IK+PD core (`core.ArmBatch`) aims the tip at ``target + lead`` for 5 physics steps (500 Hz).
    Zero action is exactly the classical controller.

    ## Action space
    ``Box(-1, 1, (3,), float32)``; ``lead = action * max_lead`` (metres, world x, y, z).
    Actions outside [-1, 1] are clipped; NaN or infinite actions raise ``ValueError``.

    ## Observation space
    ``Box(-inf, inf, (n,), float32)``: the selected features, always in this order:

    | feature        | size | meaning (world frame)                                | divided by |
    |----------------|------|------------------------------------------------------|------------|
    | ee_pos         | 3    | tip position (m)                                     | 1          |
    | ee_vel         | 3    | tip velocity, finite difference over one step (m/s)  | 2.5        |
    | target_pos     | 3    | target position (m)                                  | 1          |
    | target_vel     | 3    | target velocity, analytic (m/s)                      | 2.5        |
    | target_acc     | 3    | target acceleration, analytic (m/s^2)                | 30         |
    | joint_pos      | 7    | arm joint angles (rad)                               | 1          |
    | joint_vel      | 7    | arm joint velocities (rad/s)                         | 2.5        |
    | prev_action    | 3    | the previous action, in [-1, 1]                      | 1          |
    | tip_error      | 3    | tip minus target (m)                                 | 0.05       |
    | tip_error_avg  | 3    | its running average, clipped per axis (m; see below) | 0.01       |
    | target_preview | 18   | p(t + h) - p(t), h in preview_times (m; see below)   | 0.1        |
    | preview_jerk   | 18   | 6 (p(t + h) - p - v h - a h^2/2) / h^3 (m/s^3)       | 250        |
    | installation   | 4    | the episode's 3 delays (steps), target noise (cm)    | 3          |
    | recent_actions | 18   | the last 6 actions sent, newest first (not delayed)  | 1          |
    | repetitive_correction | 3 | the in-loop lap-to-lap correction added now (m) | 0.05 |
    | plan_weight | 1 | the planner's hand's weight in the next goal (follow_plan; 0 without) | 1 |

    Default: the 15-D ``ee_pos, ee_vel, target_pos, target_vel, target_acc``; ``obs_layout()``
    gives the index ranges. ``tip_error_avg`` moves each step ``dt/error_avg_time`` of the way
    towards the tip error clipped per axis at ``error_avg_clip``; it is 0 at reset.
    ``target_preview`` KNOWS THE PLANNED PATH (a labelled variant, never mixed with the causal
    results): the target's future positions relative to now, from the analytic trajectory.
    ``preview_jerk`` knows the same path, as what the present target's Taylor guess misses per
    look-ahead (the path's mean jerk over the next h seconds).
    ``installation`` is what an engineer knows of the installation (the episode's obs, action
    and target delays and its target reading's noise std), never noisy.
    ``obs_noise`` adds Gaussian noise (std per feature, in the feature's physical unit) to what
    the policy sees; the IK aims at the true target unless ``noisy_ik_target`` (the reading) or
    ``target_filter`` (the tracker's Kalman estimate of it) says otherwise (docs/env.md).

    ## Reward
    A sum of weighted terms, each reported in ``info["reward_terms"]`` (they add up to the
    reward exactly); ``d`` is the tip-target distance (m) after the step:
    distance ``-w_distance*d``; tracking ``w_tracking*exp(-d/tracking_scale)``; action
    ``-w_action*|a|^2``; action_change ``-w_action_change*|a - a_prev|^2``; collision
    ``-w_collision*depth`` (deepest self-collision penetration in m); limit ``-w_limit*``
    the joint goals' acceleration over the Panda's limits (clipped excess, from 0.5 s on);
    alive ``w_alive``;
    termination ``-w_termination`` on the step that terminates.

    ## Starting state
    The arm at the MJCF "home" keyframe, at rest; the trajectory drawn from ``self.np_random``
    (a seed from the training range, the shape from ``shapes``) unless ``reset(options=...)``
    names ``traj_seed`` (and optionally ``shape``): ``reset(options={"traj_seed": 7})`` plays
    test trajectory 7. ``options`` is a dict of those two keys only: another key (a typo such
    as ``"trajseed"``), a seed outside 0..2^63-1 or an unknown shape is a one-line
    ``UserError``, never a silently random trajectory.

    ## Episode end
    ``truncated`` after ``episode_steps`` steps: the env precomputes the episode's target path
    at reset, so the length has one home, this setting. ``gymnasium.make("PandaLead-v0",
    episode_steps=500)`` runs 500 steps and its ``spec.max_episode_steps`` says 500; no
    TimeLimit is registered. Gymnasium's ``max_episode_steps=N`` (``gymnasium.make``,
    ``make_vec`` in either mode, or a ``TimeLimit`` you wrap the env in) sets the episode
    length the same way wherever it is given: given alone it becomes ``episode_steps`` (a
    TimeLimit's, at the first reset under it, the env finding the TimeLimit among its callers);
    given beside an ``episode_steps`` that differs, it is refused in one line (a UserError).
    ``terminated`` only for a real failure: a self-collision when ``terminate_on_collision``
    is set, or an unstable simulation (``info["failure"] == "unstable"``, always).

    ## Rendering
    ``render_mode="rgb_array"``: ``render()`` returns the ``workspace`` camera's frame with the
    renderer settings of eval.py's videos (no shadows, no floor reflection, no multisampling:
    in a software renderer such as headless EGL those cost most of a frame), so Gymnasium's
    ``RecordVideo`` works at eval.py's speed. ``render_mode="human"`` opens MuJoCo's viewer and
    needs a display: without one it is refused at construction (a UserError) instead of the
    viewer ending the process. Headless, Gymnasium's ``check_env(env)`` builds an env for each
    render mode, "human" too: call ``check_env(env.unwrapped, skip_render_check=True)``.

    ## Copies
    ``copy.deepcopy(env)`` and ``pickle.dumps(env)`` are refused in one line (TypeError). The
    state of an episode lives in MuJoCo's C structures and in values the step makes lazily; a
    copy that quietly restarts the tip's velocity and jumps the tip (what one used to do) is
    worse than none, and a pickle carried 59 MB of model. An episode is repeated exactly by
    replaying it instead: ``reset(seed=s, options={"traj_seed": n})`` and the same actions.

    ## Arguments
    ``PandaLeadEnv(config: EnvConfig | dict | None = None, render_mode=None, width=640,
    height=480, **settings)``; settings override the config's fields:

    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 100}

    def __init__(self, config: EnvConfig | dict | None = None, render_mode: str | None = None,
                 width: int = 640, height: int = 480, **settings):
        for name in VECTOR_SETTINGS:
            if name in settings:
                raise UserError(f"{name} is a setting of the vector env, not of a single env; "
                                f"with make_vec(..., vectorization_mode='sync') pass "
                                f"vector_kwargs={{{name!r}: ...}}"
                                if name == "autoreset_mode" else
                                f"{name} is a setting of the native vector env "
                                f"(make_vec's default vectorization), not of a single env")
        # Whether the caller named the episode length (a TimeLimit may set it only if not).
        self._steps_given = "episode_steps" in settings or _episode_steps_in(config) is not None
        self.cfg = as_config(config, settings)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(f"render_mode must be one of {self.metadata['render_modes']}, "
                            f"got {render_mode!r}")
        if render_mode == "human":
            from .display import has_display

            if not has_display():  # MuJoCo's viewer would end the process (exit 1) at a step
                raise UserError("render_mode='human' opens MuJoCo's viewer and needs a display "
                                "(none is set: DISPLAY, WAYLAND_DISPLAY); headless, use "
                                "render_mode='rgb_array' (e.g. with RecordVideo)")
        self.task = SingleTask(self.cfg, 1, nthread=1)
        self.task.rngs[0] = self.np_random  # the env's own seeded generator drives slot 0
        self.core = self.task.core
        self.dt = self.task.dt
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}
        self.action_space = spaces.Box(-1.0, 1.0, (self.task.action_dim,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.task.obs_dim,), np.float32)
        self.render_mode, self._width, self._height = render_mode, width, height
        self._frames = self._viewer = self._render_data = None
        self.trail: list[np.ndarray] = []

    def set_stream(self, stream: np.random.SeedSequence) -> None:
        """Draw training trajectories (and observation noise) from this stream from now on: how
        a training vec env gives env i the repo's stream ``SeedSequence(s).spawn(n)[i]``."""
        self.np_random = np.random.default_rng(stream)
        self.task.rngs[0] = self.np_random

    def set_speed_cap(self, cap: float | None) -> None:
        """See LeadTask.set_speed_cap (the speed curriculum calls it through env_method)."""
        self.task.set_speed_cap(cap)

    # Sidecars and older callers read these.
    @property
    def config(self) -> dict:
        return self.cfg.to_dict()

    @property
    def max_lead(self) -> float:
        return self.cfg.max_lead

    @property
    def _layout(self):
        return self.task.layout

    @property
    def traj(self):
        return self.task.trajs[0]

    @property
    def lead(self) -> np.ndarray:
        return self.task.lead[0]

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        options = checked_reset_options(options, RESET_OPTIONS)
        limit = time_limit_around(self)
        if limit is not None and limit != self.cfg.episode_steps:
            self._take_episode_steps(limit)
        super().reset(seed=seed)
        self.task.rngs[0] = self.np_random
        seeds = [options["traj_seed"]] if "traj_seed" in options else None
        obs = self.task.reset([0], seeds, [options.get("shape")])
        self.trail = []
        return obs[0], {"traj_seed": int(self.task.traj_seeds[0]), "shape": self.task.shapes[0]}

    def _take_episode_steps(self, steps: int) -> None:
        """A TimeLimit of ``steps`` wraps this env: that is its episode length, as
        ``max_episode_steps`` is the native vector env's, or refused if the caller named
        another (see "Episode end")."""
        if self._steps_given:
            raise UserError(
                f"episode_steps={self.cfg.episode_steps} and max_episode_steps={steps} (a "
                "TimeLimit around the env) disagree: the episode length has one home, "
                "episode_steps; give one of the two")
        self.cfg = self.cfg.replace(episode_steps=steps)  # checked as any setting is
        self.close()  # frames and viewer were bound to the old core
        cap = self.task.speed_cap  # a curriculum's cap, set before this first reset
        self.task = SingleTask(self.cfg, 1, nthread=1)  # its paths are sized by the length
        self.task.set_speed_cap(cap)
        self.core = self.task.core
        if self._spec is not None:
            self.spec = self._spec  # the setter reports the new length

    def step(self, action):
        # The task's one-slot step gives the info this env reports, as Python scalars.
        obs, reward, terminated, truncated, info = self.task.step_one(action)
        if terminated:
            info["message"] = failure_message(info["failure"], self.core.time[0],
                                              self.task.traj_seeds[0])
        if self.render_mode is not None:
            self.trail.append(self.core.target()[0][0])
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    # --- rendering -------------------------------------------------------------------------
    def render(self):
        if self.render_mode == "human":
            import mujoco.viewer

            self._render_data = self.core.get_data(0, self._render_data)
            if self._viewer is None:
                self._viewer = mujoco.viewer.launch_passive(self.core.model, self._render_data)
            self._viewer.sync()
            return None
        if self.render_mode != "rgb_array":
            return None
        if self._frames is None:
            self._frames = ArmFrames(self.core.model, self._width, self._height)
        return self._frames.render(self.core, 0, self.trail)

    def close(self):
        if self._frames is not None:
            self._frames.close()
            self._frames = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


class ArmFrames:
    """rgb_array frames of the arms of a core, from the ``workspace`` camera, with a short
    trail behind the target marker: the one rendering code of the single env and the vector
    env (which renders each of its arms through one of these)."""

    TRAIL = 40  # target positions drawn behind the marker (0.4 s at 100 Hz)

    def __init__(self, model, width: int = 640, height: int = 480):
        from . import video

        # eval.py's video settings (no multisampling, shadows or reflections): in a software
        # renderer they cost most of a frame (RecordVideo of a 5 s episode: 338 s with them).
        self._video = video.VideoConfig(width=width, height=height)
        self._renderer = video._renderer(model, self._video)
        self._data = None

    def render(self, core, i: int, trail: list[np.ndarray]) -> np.ndarray:
        """Arm i's frame, (height, width, 3) uint8; ``trail``: its target's past positions."""
        import mujoco

        from . import video

        self._data = core.get_data(i, self._data)
        r = self._renderer
        r.update_scene(self._data, camera="workspace")
        scene = r.scene
        video._scene_flags(scene, self._video)
        for p in trail[-self.TRAIL:]:
            if scene.ngeom >= scene.maxgeom:
                break
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE,
                                np.array([0.006, 0, 0]), p, np.eye(3).ravel(),
                                np.array([1.0, 0.4, 0.4, 0.5], dtype=np.float32))
            scene.ngeom += 1
        return r.render()

    def close(self) -> None:
        self._renderer.close()


def failure_message(failure: str, t: float, traj_seed: int) -> str:
    """info["message"] of a terminating failure (the single env's and the vector env's)."""
    return f"{failure} at t={t:.2f}s (trajectory seed {traj_seed})"


# The keys of reset(options=...): the single env's, and the vector env's (one value for
# every env, or one per env, and which envs to reset).
RESET_OPTIONS = ("traj_seed", "shape")
VECTOR_RESET_OPTIONS = RESET_OPTIONS + ("traj_seeds", "shapes", "reset_mask")


def checked_reset_options(options, valid: tuple[str, ...]) -> dict:
    """reset's ``options`` as a dict, checked: a mapping of ``valid`` keys only (a typo would
    otherwise play a random trajectory), seeds in 0..2^63-1 (None: drawn), known shapes (None:
    as the seed says). Anything else is a one-line UserError."""
    from . import trajectory
    from .seeds import MAX_SEED

    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise UserError(f"reset(options=...) must be a dict such as {{'traj_seed': 7}}, got "
                        f"{type(options).__name__} {options!r:.80}")
    for key in options:
        if key not in valid:
            raise UserError(f"unknown reset option {key!r}" + did_you_mean(key, valid))
    for key, value in options.items():
        if key in ("traj_seeds", "shapes"):
            if isinstance(value, str | bytes | Mapping) or not hasattr(value, "__len__"):
                raise UserError(f"reset option {key!r} must be a list (one per env), got "
                                f"{value!r:.80}")
            values = list(value)
        elif key in ("traj_seed", "shape"):
            values = [value]
        else:
            continue
        for v in values:
            if v is None:
                continue
            if key.startswith("traj_seed"):
                if (isinstance(v, bool) or not isinstance(v, int | np.integer)
                        or not 0 <= int(v) <= MAX_SEED):
                    raise UserError(f"reset option {key!r}: a trajectory seed is an integer "
                                    f"in 0..2^63-1, got {v!r:.80}")
            elif not isinstance(v, str) or v not in trajectory.SHAPES:
                raise UserError(f"reset option {key!r}: unknown shape {v!r:.80}"
                                + did_you_mean(v, trajectory.SHAPES))
    return dict(options)


def time_limit_around(env) -> int | None:
    """The ``max_episode_steps`` of the TimeLimit nearest ``env`` that is resetting it, found
    among the callers of ``env.reset`` (a TimeLimit calls its env's reset from its own), or
    None. ``gymnasium.make`` keeps its ``max_episode_steps`` to the TimeLimit it adds and never
    tells the env; this is how the env learns it. Only frames of functions named ``reset`` are
    read; a few microseconds a reset."""
    frame = sys._getframe().f_back
    for _ in range(64):
        if frame is None:
            return None
        code = frame.f_code
        if code.co_name == "reset" and "self" in code.co_varnames:
            owner = frame.f_locals.get("self")
            if isinstance(owner, gym.wrappers.TimeLimit) and owner.unwrapped is env:
                steps = getattr(owner, "_max_episode_steps", None)
                return steps if isinstance(steps, int) else None
        frame = frame.f_back
    return None


def _episode_steps_in(config) -> int | None:
    """The episode length a config names (None: a dict that leaves it to the default)."""
    if isinstance(config, EnvConfig):
        return config.episode_steps
    if isinstance(config, dict):
        return config.get("episode_steps")
    return None


# Settings of the vector env that a single env does not take (make_vec passes its keyword
# arguments to every single env with vectorization_mode="sync").
VECTOR_SETTINGS = ("autoreset_mode", "num_threads")


PandaLeadEnv.__doc__ += textwrap.indent(arguments_table(), "    ") + "\n"
