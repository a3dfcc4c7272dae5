"""`PandaLead-v0`: the Gymnasium env in which a policy outputs a Cartesian lead for the IK target.

``import env`` registers it; ``gymnasium.make("PandaLead-v0", **kwargs)`` builds it.
"""

from __future__ import annotations

import difflib
import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import trajectory
from core import N_JOINTS, ArmCore, IKConfig, load_model, reachable
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


def _did_you_mean(name: str, valid) -> str:
    close = difflib.get_close_matches(name, list(valid), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"{hint} (valid: {', '.join(valid)})"


def check_features(features) -> tuple[str, ...]:
    """Validate a feature selection and put it in the canonical order."""
    features = tuple(features)
    for f in features:
        if f not in OBS_FEATURES:
            raise ValueError(f"unknown observation feature {f!r}" + _did_you_mean(f, OBS_FEATURES))
    if not features:
        raise ValueError("the observation needs at least one feature")
    return tuple(f for f in OBS_FEATURES if f in features)


def obs_layout(features) -> list[tuple[str, int, int]]:
    """(feature, start, stop) for each selected feature: the index table of the observation."""
    layout, start = [], 0
    for f in check_features(features):
        layout.append((f, start, start + OBS_FEATURES[f]))
        start += OBS_FEATURES[f]
    return layout


class PandaLeadEnv(gym.Env):
    """A Franka Panda keeps its tip on a fast target; the action is a lead for the IK target.

    Each step (100 Hz) the target moves along an analytic trajectory (`trajectory.py`); the
    IK+PD core (`ikpd.ArmCore`) aims the tip at ``target + lead`` for 5 physics steps (500 Hz).
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
    gives the index ranges. Each feature is divided by the fixed scale in the table (OBS_SCALE)
    so that the policy's inputs are of order one. ``obs_noise`` adds Gaussian noise (std per
    feature, in the feature's physical unit) to what the policy sees; the IK target itself is
    always the true target.

    ## Reward
    A sum of weighted terms, each reported in ``info["reward_terms"]`` (they add up to the
    reward exactly); ``d`` is the tip-target distance (m) after the step:
    distance ``-w_distance*d``; tracking ``w_tracking*exp(-d/tracking_scale)``; action
    ``-w_action*|a|^2``; action_change ``-w_action_change*|a - a_prev|^2``; collision
    ``-w_collision*depth`` (deepest self-collision penetration in m); alive ``w_alive``;
    termination ``-w_termination`` on the step that terminates.

    ## Starting state
    The arm at Franka's "ready" pose at rest; the trajectory drawn from ``self.np_random``
    (seed from the training stream, shape from ``shapes``) unless ``reset(options=...)`` names
    ``traj_seed`` (and optionally ``shape``).

    ## Episode end
    ``truncated`` after ``episode_steps`` steps (the env owns its time limit because it
    precomputes the episode's target path at reset). ``terminated`` only for a real failure:
    a self-collision when ``terminate_on_collision`` is set, or an unstable simulation
    (``info["failure"] == "unstable"``, always).

    ## Arguments
    | name                   | type            | default        | meaning                           |
    |------------------------|-----------------|----------------|-----------------------------------|
    | obs_features           | tuple[str]      | DEFAULT_OBS    | observation features (see above)  |
    | max_lead               | float           | 0.15           | lead (m per axis) at action +-1   |
    | episode_steps          | int             | 200            | steps per episode (100 Hz)        |
    | shapes                 | tuple[str]|None | None (all)     | shapes to draw training targets   |
    | w_distance             | float           | 1.0            | weight of -distance (per m)       |
    | w_tracking             | float           | 0.0            | weight of exp(-d/tracking_scale)  |
    | tracking_scale         | float           | 0.05           | length scale of that term (m)     |
    | w_action               | float           | 0.0            | weight of -|a|^2                  |
    | w_action_change        | float           | 0.0            | weight of -|a - a_prev|^2         |
    | w_collision            | float           | 0.0            | weight of -penetration (per m)    |
    | w_alive                | float           | 0.0            | bonus per step                    |
    | w_termination          | float           | 0.0            | penalty on a terminating step     |
    | terminate_on_collision | bool            | False          | end the episode on self-collision |
    | obs_noise              | dict|None       | None           | {feature: std} Gaussian noise     |
    | ik_iters               | int             | 1              | DLS iterations per control step   |
    | render_mode            | str|None        | None           | "rgb_array"                       |
    | width, height          | int             | 640, 480       | rendered frame size               |
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(self, obs_features=DEFAULT_OBS, max_lead: float = 0.15,
                 episode_steps: int = 200, shapes=None, w_distance: float = 1.0,
                 w_tracking: float = 0.0, tracking_scale: float = 0.05, w_action: float = 0.0,
                 w_action_change: float = 0.0, w_collision: float = 0.0, w_alive: float = 0.0,
                 w_termination: float = 0.0, terminate_on_collision: bool = False,
                 obs_noise: dict | None = None, ik_iters: int = 1,
                 render_mode: str | None = None, width: int = 640, height: int = 480):
        self._features = check_features(obs_features)
        self._layout = obs_layout(self._features)
        if shapes is not None:
            shapes = tuple([shapes] if isinstance(shapes, str) else shapes)
            for s in shapes:
                if s not in trajectory.SHAPES:
                    raise ValueError(f"unknown shape {s!r}" + _did_you_mean(s, trajectory.SHAPES))
        obs_noise = dict(obs_noise or {})
        for f in obs_noise:
            if f not in OBS_FEATURES:
                raise ValueError(f"obs_noise: unknown feature {f!r}" + _did_you_mean(f, OBS_FEATURES))
        if not (max_lead >= 0 and math.isfinite(max_lead)):
            raise ValueError(f"max_lead must be a finite non-negative number, got {max_lead}")
        if int(episode_steps) < 1:
            raise ValueError(f"episode_steps must be >= 1, got {episode_steps}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        self._max_lead = float(max_lead)
        self._episode_steps = int(episode_steps)
        self._shapes = shapes
        self._w = {"distance": w_distance, "tracking": w_tracking, "action": w_action,
                   "action_change": w_action_change, "collision": w_collision,
                   "alive": w_alive, "termination": w_termination}
        self._tracking_scale = float(tracking_scale)
        self._terminate_on_collision = bool(terminate_on_collision)
        self._obs_noise = obs_noise
        self._ik_iters = int(ik_iters)
        self.render_mode, self._width, self._height = render_mode, width, height
        # Everything a sidecar needs to rebuild this env (JSON-friendly).
        self.config = dict(
            obs_features=list(self._features), max_lead=self._max_lead,
            episode_steps=self._episode_steps, shapes=list(shapes) if shapes else None,
            tracking_scale=self._tracking_scale, terminate_on_collision=self._terminate_on_collision,
            obs_noise=obs_noise, ik_iters=self._ik_iters,
            **{f"w_{k}": float(v) for k, v in self._w.items()},
        )

        self.core = ArmCore(load_model(), IKConfig(iters=self._ik_iters))
        self.dt = self.core.dt
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}
        self.action_space = spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
        n_obs = self._layout[-1][2]
        self.observation_space = spaces.Box(-np.inf, np.inf, (n_obs,), dtype=np.float32)
        self._raw_obs = np.zeros(n_obs)
        self._noise_std = np.zeros(n_obs)
        self._inv_scale = np.ones(n_obs)
        for f, a, b in self._layout:
            self._noise_std[a:b] = obs_noise.get(f, 0.0)
            self._inv_scale[a:b] = 1.0 / OBS_SCALE[f]
        self._has_noise = bool(self._noise_std.any())
        # One bound getter per selected feature, made once: the step builds no dict of every
        # feature just to use a few of them.
        core = self.core
        source = {
            "ee_pos": lambda: core.tip_pos, "ee_vel": lambda: self._ee_vel,
            "target_pos": lambda: self._target_now[0], "target_vel": lambda: self._target_now[1],
            "target_acc": lambda: self._target_now[2], "joint_pos": lambda: core.qpos,
            "joint_vel": lambda: core.qvel, "prev_action": lambda: self._prev_action,
        }
        self._getters = [(source[f], a, b) for f, a, b in self._layout]
        self._renderer = None
        self.traj = None
        self._reset_episode_state()

    def _reset_episode_state(self) -> None:
        self._prev_action = np.zeros(3)
        self._prev_ee = self.core.tip_pos.copy()  # copied: the core updates tip_pos in place
        self._ee_vel = np.zeros(3)
        self.lead = np.zeros(3)
        self.trail: list[np.ndarray] = []

    # --- gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        shape = options.get("shape")
        if "traj_seed" in options:
            traj_seed = int(options["traj_seed"])
        else:
            traj_seed = int(self.np_random.integers(TRAIN_SEED_LOW, TRAIN_SEED_HIGH))
            if shape is None and self._shapes is not None:
                shape = self._shapes[int(self.np_random.integers(len(self._shapes)))]
        self.traj = trajectory.sample(traj_seed, shape)
        self.core.reset(self.traj, self._episode_steps)
        self._reachable = reachable(self.core.target_path[0])
        self._reset_episode_state()
        self._target_now = self.core.target()
        info = {"traj_seed": traj_seed, "shape": self.traj.shape}
        return self._observe(), info

    def step(self, action):
        action = np.array(action, dtype=np.float64).reshape(3)
        a0, a1, a2 = action.tolist()  # plain floats: cheaper than numpy for three numbers
        if not (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)):
            raise ValueError(f"action must be finite, got {action} (seed {self._seed_text()})")
        if not (-1.0 <= a0 <= 1.0 and -1.0 <= a1 <= 1.0 and -1.0 <= a2 <= 1.0):
            np.minimum(np.maximum(action, -1.0, out=action), 1.0, out=action)
        core = self.core
        self.lead = action * self._max_lead
        core.step(self.lead)
        k = core.step_count
        self._target_now = core.target()
        target = self._target_now[0]
        ee = core.tip_pos
        np.subtract(ee, self._prev_ee, out=self._ee_vel)  # in place: no arrays made per step
        self._ee_vel /= self.dt
        self._prev_ee[:] = ee
        diff = ee - target
        dist = math.sqrt(diff @ diff)

        failure = None
        if core.unstable:
            failure = "unstable"
        elif self._terminate_on_collision and core.self_collision:
            failure = "self_collision"
        terminated = failure is not None
        truncated = not terminated and k >= self._episode_steps

        w = self._w
        da = action - self._prev_action
        terms = {
            "distance": -w["distance"] * dist,
            "tracking": w["tracking"] * math.exp(-dist / self._tracking_scale),
            "action": -w["action"] * float(action @ action),
            "action_change": -w["action_change"] * float(da @ da),
            "collision": -w["collision"] * core.collision_depth,
            "alive": w["alive"],
            "termination": -w["termination"] if terminated else 0.0,
        }
        reward = sum(terms.values())
        self._prev_action = action
        obs = self._observe()
        if failure == "unstable":
            obs = np.zeros_like(obs)  # never hand NaNs to the learner
            reward = terms["termination"]
            terms = {**dict.fromkeys(terms, 0.0), "termination": reward}
        info = {
            "distance": dist, "reward_terms": terms, "self_collision": core.self_collision,
            "collision_depth": core.collision_depth,
            "reachable": bool(self._reachable[k]) if k < len(self._reachable)
            else bool(reachable(target)),
            "lead": self.lead.copy(),
        }
        if failure:
            info["failure"] = failure
            info["message"] = f"{failure} at t={core.time:.2f}s (trajectory seed {self._seed_text()})"
        if self.render_mode == "rgb_array":
            self.trail.append(target.copy())
        return obs, reward, terminated, truncated, info

    def _seed_text(self) -> str:
        return str(getattr(self.traj, "seed", "?"))

    def _observe(self) -> np.ndarray:
        obs = self._raw_obs
        for getter, a, b in self._getters:
            obs[a:b] = getter()
        if self._has_noise:
            obs += self.np_random.normal(0.0, self._noise_std)
        return (obs * self._inv_scale).astype(np.float32)

    # --- helpers for baselines and rendering -----------------------------------------------
    @property
    def max_lead(self) -> float:
        return self._max_lead

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        import mujoco

        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.core.model, self._height, self._width)
        r = self._renderer
        r.update_scene(self.core.data, camera="workspace")
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


gym.register(id="PandaLead-v0", entry_point=PandaLeadEnv)
