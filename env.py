"""`PandaLead-v0`: the Gymnasium env in which a policy outputs a Cartesian lead for the IK target.

``import env`` registers it: ``gymnasium.make("PandaLead-v0", **settings)`` builds the single
env, ``gymnasium.make_vec("PandaLead-v0", num_envs=N, **settings)`` the natively batched one
(N arms in one `mujoco.batch.Batch`, no processes). Every setting lives in `EnvConfig`.
Both envs run the same code (`LeadTask`, N episodes at once), so for the same trajectory seeds
they produce bit-identical episodes.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math
import textwrap
from dataclasses import dataclass, field
from functools import cache
from typing import Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

import trajectory
from core import N_JOINTS, ArmBatch, IKConfig, reachable
from errors import UserError, did_you_mean
from seeds import TRAIN_SEED_HIGH, TRAIN_SEED_LOW

# Observation features in their fixed order (a selection keeps this order) and their sizes.
OBS_FEATURES = {
    "ee_pos": 3, "ee_vel": 3, "target_pos": 3, "target_vel": 3, "target_acc": 3,
    "joint_pos": N_JOINTS, "joint_vel": N_JOINTS, "prev_action": 3,
}
# Each feature is divided by a fixed scale so that every input of the policy is of order one
# (velocities peak near 2.5 m/s, accelerations near 30 m/s^2): a fixed scale needs no running
# statistics to save beside a model, unlike VecNormalize.
OBS_SCALE = {
    "ee_pos": 1.0, "ee_vel": 2.5, "target_pos": 1.0, "target_vel": 2.5, "target_acc": 30.0,
    "joint_pos": 1.0, "joint_vel": 2.5, "prev_action": 1.0,
}
DEFAULT_OBS = ("ee_pos", "ee_vel", "target_pos", "target_vel", "target_acc")
REWARD_TERMS = ("distance", "tracking", "action", "action_change", "collision", "alive",
                "termination")


def check_features(features) -> tuple[str, ...]:
    """Validate a feature selection and put it in the canonical order."""
    features = (features,) if isinstance(features, str) else tuple(features)
    for f in features:
        if f not in OBS_FEATURES:
            raise UserError(f"unknown observation feature {f!r}" + did_you_mean(f, OBS_FEATURES))
    if not features:
        raise UserError("the observation needs at least one feature")
    return tuple(f for f in OBS_FEATURES if f in features)


def obs_layout(features) -> list[tuple[str, int, int]]:
    """(feature, start, stop) for each selected feature: the index table of the observation."""
    layout, start = [], 0
    for f in check_features(features):
        layout.append((f, start, start + OBS_FEATURES[f]))
        start += OBS_FEATURES[f]
    return layout


@dataclass(frozen=True)
class EnvConfig:
    """Every setting of PandaLead-v0. Sidecars store it whole; the command line sets it as
    ``--env.max-lead 0.1``; presets are values of it."""

    obs_features: tuple[str, ...] = DEFAULT_OBS
    """Observation features (kept in the table's order; see the observation table)."""
    max_lead: float = 0.15
    """Lead in metres per axis at action +-1."""
    episode_steps: int = 200
    """Control steps per episode (100 Hz: 200 = 2 s; the test rollouts use 500 = 5 s)."""
    shapes: tuple[str, ...] | None = None
    """Shapes training targets are drawn from (None: circle, fig8 and fly, as the seed says)."""
    w_distance: float = 1.0
    """Weight of -distance (per metre of tip-target error)."""
    w_tracking: float = 0.0
    """Weight of exp(-distance / tracking_scale)."""
    tracking_scale: float = 0.05
    """Length scale of the tracking term (m)."""
    w_action: float = 0.0
    """Weight of -|action|^2."""
    w_action_change: float = 0.0
    """Weight of -|action - previous action|^2."""
    w_collision: float = 0.0
    """Weight of -penetration depth (per metre) of the deepest self-collision in the step."""
    w_alive: float = 0.0
    """Bonus per step."""
    w_termination: float = 0.0
    """Penalty on the step that terminates (self-collision when terminating on it, instability)."""
    terminate_on_collision: bool = False
    """End the episode (terminated) on a self-collision."""
    obs_noise: dict[str, float] = field(default_factory=dict)
    """Gaussian noise std per observation feature, in the feature's unit (m, m/s, m/s^2, rad)."""
    ik_iters: int = 1
    """DLS iterations per control step."""
    ik_clearance: float = 0.0
    """Collision-aware IK: keep the arm's links this far apart (m; e.g. 0.02) by a velocity
    damper on the IK step (clearance.py); 0: off, the plain IK."""
    obs_delay: int = 0
    """Observation latency in control steps (10 ms each): the policy sees the state of k steps ago."""
    action_delay: int = 0
    """Action latency in control steps: the lead applied now is the action chosen k steps ago."""
    random_delay: bool = False
    """Draw each episode's delays uniformly from 0..obs_delay and 0..action_delay."""
    action: Literal["lead", "joint"] = "lead"
    """lead: the action is a Cartesian lead added to the IK target (3-D); joint: a residual
    added to the IK's joint goal (7-D, one per joint; it can move the elbow, a lead cannot)."""
    max_joint_offset: float = 0.2
    """With action "joint": the joint-goal offset (rad) at action +-1."""
    max_peak_speed: float | None = None
    """Redraw training trajectories until their peak speed is at most this (m/s); None: any.
    Named trajectory seeds (test, evaluation) are never filtered."""

    def __post_init__(self):
        # Normalise (tuples in canonical order, plain floats) so equal settings compare equal.
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("obs_features", check_features(self.obs_features))
        if self.shapes is not None:
            shapes = (self.shapes,) if isinstance(self.shapes, str) else tuple(self.shapes)
            for s in shapes:
                if s not in trajectory.SHAPES:
                    raise UserError(f"unknown shape {s!r}" + did_you_mean(s, trajectory.SHAPES))
            set_("shapes", shapes or None)
        if not isinstance(self.obs_noise, dict):
            raise UserError(f"obs_noise must map feature names to a std, got {self.obs_noise!r}")
        for f, std in self.obs_noise.items():
            if f not in OBS_FEATURES:
                raise UserError(f"obs_noise: unknown feature {f!r}" + did_you_mean(f, OBS_FEATURES))
            if not (isinstance(std, int | float) and math.isfinite(std) and std >= 0):
                raise UserError(f"obs_noise[{f!r}] must be a finite std >= 0, got {std!r}")
        set_("obs_noise", {f: float(v) for f, v in self.obs_noise.items()})
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.type == "float":
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                    raise UserError(f"{f.name} must be a finite number, got {v!r}")
                set_(f.name, float(v))
            elif f.type in ("int", "bool") and type(v) is not (int if f.type == "int" else bool):
                kind = "an integer" if f.type == "int" else "true or false"
                raise UserError(f"{f.name} must be {kind}, got {v!r}")
        if self.max_lead < 0:
            raise UserError(f"max_lead must be >= 0, got {self.max_lead}")
        if self.episode_steps < 1:
            raise UserError(f"episode_steps must be >= 1, got {self.episode_steps}")
        if self.ik_iters < 1:
            raise UserError(f"ik_iters must be >= 1, got {self.ik_iters}")
        if self.ik_clearance < 0 or (self.ik_clearance > 0 and self.ik_iters != 1):
            raise UserError(f"ik_clearance must be >= 0 and needs ik_iters 1, got "
                            f"{self.ik_clearance} with ik_iters {self.ik_iters}")
        if not (0 <= self.obs_delay <= 50 and 0 <= self.action_delay <= 50):
            raise UserError(f"obs_delay and action_delay must be 0..50 steps, got "
                            f"{self.obs_delay}, {self.action_delay}")
        if self.action not in ("lead", "joint"):
            raise UserError(f"action must be 'lead' or 'joint', got {self.action!r}")
        if self.action == "joint" and "prev_action" in self.obs_features:
            raise UserError("prev_action is a 3-D lead feature; it cannot be observed with "
                            "action 'joint'")
        if self.max_joint_offset < 0:
            raise UserError(f"max_joint_offset must be >= 0, got {self.max_joint_offset}")
        if self.max_peak_speed is not None:
            cap = self.max_peak_speed
            if isinstance(cap, bool) or not isinstance(cap, int | float) or not cap > 0.25:
                raise UserError(f"max_peak_speed must be a speed above 0.25 m/s, got {cap!r}")
            set_("max_peak_speed", float(cap))
        if self.tracking_scale <= 0:
            raise UserError(f"tracking_scale must be > 0, got {self.tracking_scale}")

    @classmethod
    def from_dict(cls, settings: dict) -> EnvConfig:
        """From a sidecar or keyword arguments; an unknown name is one clear error."""
        if not isinstance(settings, dict):
            raise UserError(f"env settings must be a mapping, got {type(settings).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        for k in settings:
            if k not in names:
                raise UserError(f"unknown env setting {k!r}" + did_you_mean(k, names))
        return cls(**settings)

    def replace(self, **changes) -> EnvConfig:
        return self.from_dict({**self.to_dict(), **changes})

    def to_dict(self) -> dict:
        """JSON-friendly (lists for tuples): what sidecars and config.json hold."""
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


@cache
def config_docs() -> dict[str, str]:
    """Each EnvConfig field's docstring (the string under it), read from the source."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(EnvConfig)))
    body, docs = tree.body[0].body, {}
    for a, b in zip(body, body[1:], strict=False):
        documented = isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant)
        if isinstance(a, ast.AnnAssign) and documented:
            docs[a.target.id] = " ".join(str(b.value.value).split())
    return docs


def arguments_table() -> str:
    """The env docstring's arguments table, made from EnvConfig (so it cannot drift)."""
    rows = ["| name | type | default | meaning |", "|---|---|---|---|"]
    defaults = EnvConfig()
    for f in dataclasses.fields(EnvConfig):
        cells = (f.name, f.type, repr(getattr(defaults, f.name)), config_docs()[f.name])
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


def _as_config(config: EnvConfig | dict | None, overrides: dict) -> EnvConfig:
    if config is None:
        return EnvConfig.from_dict(overrides)
    base = config if isinstance(config, EnvConfig) else EnvConfig.from_dict(config)
    return base.replace(**overrides) if overrides else base


class LeadTask:
    """N episodes of the lead task on one `ArmBatch`: the code both envs run.

    ``rngs[i]`` is episode slot i's generator: it draws slot i's training trajectories and its
    observation noise, so a slot's episodes depend on its own stream alone.
    """

    def __init__(self, config: EnvConfig, n: int, nthread: int = 0):
        self.config = c = config
        self.n = n
        self.layout = obs_layout(c.obs_features)
        self.core = ArmBatch(n, IKConfig(iters=c.ik_iters, clearance=c.ik_clearance), nthread=nthread)
        self.dt = self.core.dt
        self.obs_dim = self.layout[-1][2]
        self._noise_std = np.zeros(self.obs_dim)
        self._inv_scale = np.ones(self.obs_dim)
        for f, a, b in self.layout:
            self._noise_std[a:b] = c.obs_noise.get(f, 0.0)
            self._inv_scale[a:b] = 1.0 / OBS_SCALE[f]
        self._noisy = np.flatnonzero(self._noise_std)
        self._w = {k: getattr(c, f"w_{k}") for k in REWARD_TERMS}
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.action_dim = 3 if c.action == "lead" else N_JOINTS
        self.prev_action = np.zeros((n, self.action_dim))
        self.lead = np.zeros((n, 3))
        self.ee_vel = np.zeros((n, 3))
        self._prev_ee = np.zeros((n, 3))
        self.traj_seeds = np.zeros(n, dtype=np.int64)
        self.shapes = [""] * n
        self.trajs: list = [None] * n
        self._reachable = np.ones((n, c.episode_steps + 1), dtype=bool)
        self._raw = np.zeros((n, self.obs_dim))
        self._all = np.arange(n)
        # Latency: the last obs_delay+1 observations and action_delay+1 actions per slot, newest
        # first; each slot reads the entry of its own delay (fixed, or drawn per episode).
        self._delayed = bool(c.obs_delay or c.action_delay)
        self._obs_hist = np.zeros((n, c.obs_delay + 1, self.obs_dim), dtype=np.float32)
        self._act_hist = np.zeros((n, c.action_delay + 1, self.action_dim))
        self.obs_delay = np.full(n, c.obs_delay)
        self.action_delay = np.full(n, c.action_delay)
        # Peak-speed cap of drawn (training) trajectories; a curriculum raises it as it goes.
        self.speed_cap = c.max_peak_speed

    def set_speed_cap(self, cap: float | None) -> None:
        """Peak-speed cap (m/s) of the training trajectories drawn from now on (None: any)."""
        self.speed_cap = cap

    def reset(self, ids=None, traj_seeds=None, shapes=None) -> np.ndarray:
        """Start new episodes in slots ``ids`` (default all); returns the observation of all.
        Trajectory seeds (and shapes) default to draws from each slot's own generator."""
        ids = self._all if ids is None else np.asarray(ids, dtype=np.int64).reshape(-1)
        trajs = []
        for j, i in enumerate(ids):
            shape = None if shapes is None else shapes[j]
            if traj_seeds is None or traj_seeds[j] is None:
                traj = self._draw(i, shape)
            else:
                traj = trajectory.sample(int(traj_seeds[j]), shape)
            seed = traj.seed
            self.trajs[i], self.traj_seeds[i], self.shapes[i] = traj, seed, traj.shape
            trajs.append(traj)
        core = self.core
        core.reset(ids, trajs, self.config.episode_steps)
        self._reachable[ids] = reachable(core.target_pos[ids])
        self.prev_action[ids] = 0.0
        self.lead[ids] = 0.0
        self.ee_vel[ids] = 0.0
        self._prev_ee[ids] = core.tip_pos[ids]
        if not self._delayed:
            return self.observe(ids)
        if self.config.random_delay:
            for i in ids:
                self.obs_delay[i] = self.rngs[i].integers(self.config.obs_delay + 1)
                self.action_delay[i] = self.rngs[i].integers(self.config.action_delay + 1)
        self._act_hist[ids] = 0.0  # before the episode the lead was zero (classical)
        self._obs_hist[ids] = self.observe(ids)[ids, None, :]  # before it, the arm stood still
        return self._obs_hist[self._all, self.obs_delay]

    def _draw(self, i: int, shape: str | None):
        """A training trajectory from slot i's own stream (under the speed cap, if any)."""
        while True:
            seed = int(self.rngs[i].integers(TRAIN_SEED_LOW, TRAIN_SEED_HIGH))
            pick = shape
            if pick is None and self.config.shapes is not None:
                pick = self.config.shapes[int(self.rngs[i].integers(len(self.config.shapes)))]
            traj = trajectory.sample(seed, pick)
            if self.speed_cap is None or traj.peak_speed <= self.speed_cap:
                return traj

    def observe(self, ids=None, target=None) -> np.ndarray:
        """The (scaled, float32) observation of every slot; noise is drawn for slots ``ids``
        only (default all): a slot's generator advances only when its observation is used.
        ``target``: the core's current (pos, vel, acc), when the caller already has it."""
        core, raw = self.core, self._raw
        pos, vel, acc = core.target() if target is None else target
        source = {"ee_pos": core.tip_pos, "ee_vel": self.ee_vel, "target_pos": pos,
                  "target_vel": vel, "target_acc": acc, "joint_pos": core.qpos,
                  "joint_vel": core.qvel, "prev_action": self.prev_action}
        for f, a, b in self.layout:
            raw[:, a:b] = source[f]
        if len(self._noisy):
            std = self._noise_std[self._noisy]
            for i in self._all if ids is None else ids:
                raw[i, self._noisy] += self.rngs[i].normal(0.0, std)
        return (raw * self._inv_scale).astype(np.float32)

    def step(self, actions: np.ndarray):
        """One control step of every slot -> (obs, reward, terminated, truncated, info), where
        info holds (N, ...) arrays: distance, reward_terms, self_collision, collision_depth,
        reachable, lead, unstable."""
        action = np.array(actions, dtype=np.float64).reshape(self.n, self.action_dim)
        if not np.isfinite(action).all():
            bad = np.flatnonzero(~np.isfinite(action).all(axis=1))
            raise ValueError(f"action must be finite, got {action[bad[0]]} (trajectory seed "
                             f"{self.traj_seeds[bad[0]]})")
        np.clip(action, -1.0, 1.0, out=action)
        core = self.core
        applied = action
        if self._delayed:
            self._act_hist[:, 1:] = self._act_hist[:, :-1]
            self._act_hist[:, 0] = action
            applied = self._act_hist[self._all, self.action_delay]
        if self.action_dim == 3:
            self.lead = applied * self.config.max_lead
            core.step(self.lead)
        else:
            core.step(joint_offset=applied * self.config.max_joint_offset)
        ee = core.tip_pos
        np.subtract(ee, self._prev_ee, out=self.ee_vel)
        self.ee_vel /= self.dt
        self._prev_ee[:] = ee
        now = core.target()  # (pos, vel, acc) after the step: the distance and the observation
        dist = np.linalg.norm(ee - now[0], axis=1)
        unstable = core.unstable
        terminated = unstable | (core.self_collision & self.config.terminate_on_collision)
        truncated = ~terminated & (core.step_count >= self.config.episode_steps)
        w, da = self._w, action - self.prev_action
        terms = {
            "distance": -w["distance"] * dist,
            "tracking": w["tracking"] * np.exp(-dist / self.config.tracking_scale),
            "action": -w["action"] * np.einsum("ij,ij->i", action, action),
            "action_change": -w["action_change"] * np.einsum("ij,ij->i", da, da),
            "collision": -w["collision"] * core.collision_depth,
            "alive": np.full(self.n, w["alive"]),
            "termination": np.where(terminated, -w["termination"], 0.0),
        }
        if unstable.any():  # a blown-up arm earns only its termination cost
            for k in REWARD_TERMS[:-1]:
                terms[k] = np.where(unstable, 0.0, terms[k])
        reward = sum(terms.values())
        self.prev_action = action
        obs = self.observe(target=now)
        if self._delayed:
            self._obs_hist[:, 1:] = self._obs_hist[:, :-1]
            self._obs_hist[:, 0] = obs
            obs = self._obs_hist[self._all, self.obs_delay]
        obs[unstable] = 0.0  # never hand NaNs to the learner
        k = np.minimum(core.step_count, self.config.episode_steps)
        info = {"distance": dist, "reward_terms": terms, "self_collision": core.self_collision,
                "collision_depth": core.collision_depth, "unstable": unstable,
                "reachable": self._reachable[self._all, k], "lead": self.lead}
        return obs, reward, terminated, truncated, info


def _failure(info: dict, i: int, terminated: bool) -> str | None:
    if not terminated:
        return None
    return "unstable" if info["unstable"][i] else "self_collision"


class PandaLeadEnv(gym.Env):
    """A Franka Panda keeps its tip on a fast target; the action is a lead for the IK target.

    Each step (100 Hz) the target moves along an analytic trajectory (`trajectory.py`); the
    IK+PD core (`core.ArmBatch`) aims the tip at ``target + lead`` for 5 physics steps (500 Hz).
    Zero action is exactly the classical controller.

    ## Action space
    ``Box(-1, 1, (3,), float32)``; ``lead = action * max_lead`` (metres, world x, y, z).
    Actions outside [-1, 1] are clipped; NaN or infinite actions raise ``ValueError``.

    ## Observation space
    ``Box(-inf, inf, (n,), float32)``: the selected features, always in this order:

    | feature     | size | meaning (world frame)                                | divided by |
    |-------------|------|------------------------------------------------------|------------|
    | ee_pos      | 3    | tip position (m)                                     | 1          |
    | ee_vel      | 3    | tip velocity, finite difference over one step (m/s)  | 2.5        |
    | target_pos  | 3    | target position (m)                                  | 1          |
    | target_vel  | 3    | target velocity, analytic (m/s)                      | 2.5        |
    | target_acc  | 3    | target acceleration, analytic (m/s^2)                | 30         |
    | joint_pos   | 7    | arm joint angles (rad)                               | 1          |
    | joint_vel   | 7    | arm joint velocities (rad/s)                         | 2.5        |
    | prev_action | 3    | the previous action, in [-1, 1]                      | 1          |

    Default: the 15-D ``ee_pos, ee_vel, target_pos, target_vel, target_acc``; ``obs_layout()``
    gives the index ranges. ``obs_noise`` adds Gaussian noise (std per feature, in the
    feature's physical unit) to what the policy sees; the IK target is always the true target.

    ## Reward
    A sum of weighted terms, each reported in ``info["reward_terms"]`` (they add up to the
    reward exactly); ``d`` is the tip-target distance (m) after the step:
    distance ``-w_distance*d``; tracking ``w_tracking*exp(-d/tracking_scale)``; action
    ``-w_action*|a|^2``; action_change ``-w_action_change*|a - a_prev|^2``; collision
    ``-w_collision*depth`` (deepest self-collision penetration in m); alive ``w_alive``;
    termination ``-w_termination`` on the step that terminates.

    ## Starting state
    The arm at the MJCF "home" keyframe, at rest; the trajectory drawn from ``self.np_random``
    (a seed from the training range, the shape from ``shapes``) unless ``reset(options=...)``
    names ``traj_seed`` (and optionally ``shape``): ``reset(options={"traj_seed": 7})`` plays
    test trajectory 7.

    ## Episode end
    ``truncated`` after ``episode_steps`` steps (the env precomputes the episode's target path
    at reset; ``gymnasium.make`` also adds its TimeLimit of 200 steps, the default length: to
    change the length through make, pass ``episode_steps=N, max_episode_steps=N``).
    ``terminated`` only for a real failure: a self-collision when ``terminate_on_collision``
    is set, or an unstable simulation (``info["failure"] == "unstable"``, always).

    ## Arguments
    ``PandaLeadEnv(config: EnvConfig | dict | None = None, render_mode=None, width=640,
    height=480, **settings)``; settings override the config's fields:

    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 100}

    def __init__(self, config: EnvConfig | dict | None = None, render_mode: str | None = None,
                 width: int = 640, height: int = 480, **settings):
        self.cfg = _as_config(config, settings)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserError(f"render_mode must be one of {self.metadata['render_modes']}, "
                            f"got {render_mode!r}")
        self.task = LeadTask(self.cfg, 1, nthread=1)
        self.task.rngs[0] = self.np_random  # the env's own seeded generator drives slot 0
        self.core = self.task.core
        self.dt = self.task.dt
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}
        self.action_space = spaces.Box(-1.0, 1.0, (self.task.action_dim,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.task.obs_dim,), np.float32)
        self.render_mode, self._width, self._height = render_mode, width, height
        self._renderer = self._viewer = self._render_data = None
        self.trail: list[np.ndarray] = []

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
        super().reset(seed=seed)
        self.task.rngs[0] = self.np_random
        options = options or {}
        seeds = [options["traj_seed"]] if "traj_seed" in options else None
        obs = self.task.reset([0], seeds, [options.get("shape")])
        self.trail = []
        return obs[0], {"traj_seed": int(self.task.traj_seeds[0]), "shape": self.task.shapes[0]}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.task.step(action)
        term, trunc = bool(terminated[0]), bool(truncated[0])
        out = {"distance": float(info["distance"][0]),
               "reward_terms": {k: float(v[0]) for k, v in info["reward_terms"].items()},
               "self_collision": bool(info["self_collision"][0]),
               "collision_depth": float(info["collision_depth"][0]),
               "reachable": bool(info["reachable"][0]), "lead": info["lead"][0].copy()}
        failure = _failure(info, 0, term)
        if failure:
            out["failure"] = failure
            out["message"] = (f"{failure} at t={self.core.time[0]:.2f}s "
                              f"(trajectory seed {self.task.traj_seeds[0]})")
        if self.render_mode is not None:
            self.trail.append(self.core.target()[0][0].copy())
        if self.render_mode == "human":
            self.render()
        return obs[0], float(reward[0]), term, trunc, out

    # --- rendering -------------------------------------------------------------------------
    def render(self):
        import mujoco

        self._render_data = self.core.get_data(0, self._render_data)
        if self.render_mode == "human":
            import mujoco.viewer

            if self._viewer is None:
                self._viewer = mujoco.viewer.launch_passive(self.core.model, self._render_data)
            self._viewer.sync()
            return None
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.core.model, self._height, self._width)
        r = self._renderer
        r.update_scene(self._render_data, camera="workspace")
        scene = r.scene
        for p in self.trail[-40:]:  # a short trail behind the target marker
            if scene.ngeom >= scene.maxgeom:
                break
            mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE,
                                np.array([0.006, 0, 0]), p, np.eye(3).ravel(),
                                np.array([1.0, 0.4, 0.4, 0.5], dtype=np.float32))
            scene.ngeom += 1
        return r.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None


PandaLeadEnv.__doc__ += textwrap.indent(arguments_table(), "    ") + "\n"


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
        self.cfg = _as_config(config, settings)
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


gym.register(id="PandaLead-v0", entry_point=PandaLeadEnv, vector_entry_point=PandaLeadVecEnv,
             max_episode_steps=EnvConfig.episode_steps)
