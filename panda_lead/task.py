"""`LeadTask`: N episodes of the lead task on one `ArmBatch`, the code every env runs.

The single env (env.py), Gymnasium's vector env (vector.py) and SB3's VecEnv (sb3_vecenv.py)
are thin views over it, which is why their episodes are bit-identical for the same trajectory
seeds.
"""

from __future__ import annotations

import math
from itertools import chain
from operator import itemgetter, mul

import numpy as np

from . import trajectory
from .config import OBS_SCALE, REWARD_TERMS, EnvConfig, action_dim, obs_layout
from .core import ArmBatch, _Deferred
from .seeds import TRAIN_SEED_HIGH, TRAIN_SEED_LOW
from .trajectory import reachable

# step_one's order of the observation features (its tuple of their values)
_SOURCES = ("ee_pos", "ee_vel", "target_pos", "target_vel", "target_acc", "joint_pos",
            "joint_vel", "prev_action", "tip_error", "tip_error_avg")


class LeadTask:
    """N episodes of the lead task on one `ArmBatch`: the code both envs run.

    ``rngs[i]`` is episode slot i's generator: it draws slot i's training trajectories and its
    observation noise, so a slot's episodes depend on its own stream alone.
    """

    prev_action = _Deferred("_pending_step", "_make_step")
    lead = _Deferred("_pending_step", "_make_step")
    ee_vel = _Deferred("_pending_step", "_make_step")
    _prev_ee = _Deferred("_pending_step", "_make_step")

    def __init__(self, config: EnvConfig, n: int, nthread: int = 0):
        self.config = c = config
        self.n = n
        self.layout = obs_layout(c.obs_features)
        self.core = ArmBatch(n, c.ik, nthread=nthread)
        self.dt = self.core.dt
        base = self.layout[-1][2]  # one observation; obs_stack of them are stacked
        self.obs_dim = base * c.obs_stack
        self._noise_std = np.zeros(base)
        self._inv_scale = np.ones(base)
        for f, a, b in self.layout:
            self._noise_std[a:b] = c.obs_noise.get(f, 0.0)
            self._inv_scale[a:b] = 1.0 / OBS_SCALE[f]
        self._noisy = np.flatnonzero(self._noise_std)
        self._inv_scale_list = self._inv_scale.tolist()
        self._features = [f for f, _, _ in self.layout]
        # step_one's: the observed features' positions in its tuple of every feature
        at = [_SOURCES.index(f) for f in self._features]
        self._pick = itemgetter(*at) if len(at) > 1 else lambda source: (source[at[0]],)
        self._base_dim = base
        self._joints_observed = bool({"joint_pos", "joint_vel"} & set(self._features))
        self._error_observed = "tip_error" in self._features
        # tip_error_avg: a running average of the clipped tip error (EnvConfig.error_avg_*),
        # updated only when it is observed
        self._avg_observed = "tip_error_avg" in self._features
        self.err_avg = np.zeros((n, 3))
        self._avg_rate, self._avg_clip = self.dt / c.error_avg_time, c.error_avg_clip
        self._w = {k: getattr(c, f"w_{k}") for k in REWARD_TERMS}
        # step_one's weights, signed as its terms use them (one unpack, not a dict lookup each)
        self._signed_w = (-self._w["distance"], self._w["tracking"], -self._w["action"],
                          -self._w["action_change"], -self._w["collision"], self._w["alive"],
                          -self._w["termination"])
        self._reward_from = c.reward_after_s - 1e-9  # step()'s threshold on the time
        self._alive = np.full(n, self._w["alive"])
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.action_dim = action_dim(c.action)
        self._pending_step = None  # (see _make_step)
        self.prev_action = np.zeros((n, self.action_dim))
        self.lead = np.zeros((n, 3))
        self.ee_vel = np.zeros((n, 3))
        self._prev_ee = np.zeros((n, 3))
        # step_one's row views of slot 0 (these arrays are only ever written in place)
        self._ee_vel_row, self._prev_ee_row = self.ee_vel[0], self._prev_ee[0]
        self._tip_row = self.core.tip_pos[0]
        self.traj_seeds = np.zeros(n, dtype=np.int64)
        self.shapes = [""] * n
        self.trajs: list = [None] * n
        self._reachable = np.ones((n, c.episode_steps + 1), dtype=bool)
        self._raw = np.zeros((n, base))
        self._all = np.arange(n)
        # Latency: the last obs_delay+1 observations and action_delay+1 actions per slot, newest
        # first; each slot reads the entry of its own delay (fixed, or drawn per episode).
        self._delayed = bool(c.obs_delay or c.action_delay)
        self._obs_hist = np.zeros((n, c.obs_delay + 1, base), dtype=np.float32)
        self._stack = np.zeros((n, c.obs_stack, base), dtype=np.float32)  # newest first
        self._act_hist = np.zeros((n, c.action_delay + 1, self.action_dim))
        self.obs_delay = np.full(n, c.obs_delay)
        self.action_delay = np.full(n, c.action_delay)
        # step_one's lean route: a lead with no action delay goes to the core's one-arm step
        # as Python floats (the lead is the action times max_lead, as _control computes it).
        self._lean_lead = n == 1 and self.core.lean and c.action == "lead" and not self._delayed
        self._plain_obs = not self._delayed and c.obs_stack == 1  # _observed() is the identity
        self._action_weighed = bool(c.w_action or c.w_action_change)  # step_one's terms
        # Peak-speed cap of drawn (training) trajectories; a curriculum raises it as it goes.
        self.speed_cap = c.max_peak_speed

    def _make_step(self) -> None:
        """What step_one's lean route leaves to be made when first read (_Deferred): the last
        step's prev_action and lead, fresh (1, 3) arrays, as step() makes them, and ee_vel and
        the last tip position written into their arrays. A single env reads neither (its
        info's lead is made from its own values): the two arrays and two writes a step cost it
        1-2 us in place, measured (docs/performance.md, the fourth pass)."""
        values, lead, ee_vel, ee = self._pending_step
        self._pending_step = None
        self._prev_action, self._lead = np.array([values]), np.array([lead])
        self._ee_vel_row[:], self._prev_ee_row[:] = ee_vel, ee

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
        if self.n == 1:  # step_one's, as Python bools
            self._reachable_row = self._reachable[0].tolist()
        self.prev_action[ids] = 0.0
        self.lead[ids] = 0.0
        self.ee_vel[ids] = 0.0
        self._prev_ee[ids] = core.tip_pos[ids]
        self.err_avg[ids] = 0.0
        obs = self.observe(ids)
        if self._delayed:
            if self.config.random_delay:
                for i in ids:
                    self.obs_delay[i] = self.rngs[i].integers(self.config.obs_delay + 1)
                    self.action_delay[i] = self.rngs[i].integers(self.config.action_delay + 1)
            self._act_hist[ids] = 0.0  # before the episode the lead was zero (classical)
            self._obs_hist[ids] = obs[ids, None, :]  # before it, the arm stood still
            obs = self._obs_hist[self._all, self.obs_delay]
        return self._stacked(obs, ids)

    def _stacked(self, obs: np.ndarray, reset_ids=None) -> np.ndarray:
        """The observation the policy gets: the last obs_stack observations, newest first; a
        slot just reset has seen only its first one (the arm stood still before it)."""
        if self.config.obs_stack == 1:
            return obs
        if reset_ids is not None:
            self._stack[reset_ids] = obs[reset_ids, None, :]
        else:
            self._stack[:, 1:] = self._stack[:, :-1]
            self._stack[:, 0] = obs
        return self._stack.reshape(self.n, -1).copy()

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
        if self._error_observed:
            source["tip_error"] = core.tip_pos - pos
        if self._avg_observed:
            source["tip_error_avg"] = self.err_avg
        for f, a, b in self.layout:
            raw[:, a:b] = source[f]
        if len(self._noisy):
            std = self._noise_std[self._noisy]
            for i in self._all if ids is None else ids:
                raw[i, self._noisy] += self.rngs[i].normal(0.0, std)
        return (raw * self._inv_scale).astype(np.float32)

    def step(self, actions: np.ndarray, discard=None):
        """One control step of every slot -> (obs, reward, terminated, truncated, info), where
        info holds (N, ...) arrays: distance, reward_terms, self_collision, collision_depth,
        reachable, lead, unstable. ``discard``: slots whose step the caller throws away (a
        vector env's next-step autoreset resets them at once): their generators do not
        advance, so their next episodes are those they would have had without this step."""
        action = self._checked(np.array(actions, dtype=np.float64).reshape(self.n,
                                                                           self.action_dim))
        core = self.core
        self._control(action)
        ee = core.tip_pos
        np.subtract(ee, self._prev_ee, out=self.ee_vel)
        self.ee_vel /= self.dt
        self._prev_ee[:] = ee
        now = core.target()  # (pos, vel, acc) after the step: the distance and the observation
        err = ee - now[0]
        dist = _distance(err)
        if self._avg_observed:  # avg += rate * (clip(err) - avg), step_one's order
            clip = self._avg_clip
            self.err_avg += self._avg_rate * (np.minimum(np.maximum(err, -clip), clip)
                                              - self.err_avg)
        unstable = core.unstable
        any_unstable = np.logical_or.reduce(unstable)
        terminated = (unstable | core.self_collision if self.config.terminate_on_collision
                      else unstable.copy())
        truncated = ~terminated & (core.step_count >= self.config.episode_steps)
        w, da = self._w, action - self.prev_action
        counts = core.time >= self.config.reward_after_s - 1e-9  # settled-only reward, if set
        terms = {
            "distance": np.where(counts, -w["distance"] * dist, 0.0),
            "tracking": np.where(counts, w["tracking"] * np.exp(-dist / self.config.tracking_scale),
                                 0.0),
            "action": -w["action"] * np.einsum("ij,ij->i", action, action),
            "action_change": -w["action_change"] * np.einsum("ij,ij->i", da, da),
            "collision": -w["collision"] * core.collision_depth,
            "alive": self._alive.copy(),
            "termination": np.where(terminated, -w["termination"], 0.0),
        }
        if any_unstable:  # a blown-up arm earns only its termination cost
            for k in REWARD_TERMS[:-1]:
                terms[k] = np.where(unstable, 0.0, terms[k])
        reward = sum(terms.values())
        self.prev_action = action
        ids = None if discard is None else np.setdiff1d(self._all, discard)
        obs = self._observed(self.observe(ids, target=now), unstable if any_unstable else None)
        k = np.minimum(core.step_count, self.config.episode_steps)
        info = {"distance": dist, "reward_terms": terms, "self_collision": core.self_collision,
                "collision_depth": core.collision_depth, "unstable": unstable,
                "reachable": self._reachable[self._all, k], "lead": self.lead}
        return obs, reward, terminated, truncated, info

    def step_one(self, action):
        """step() of a task of one slot (the single env), returning what a Gymnasium env
        returns: obs (obs_dim,), reward, terminated and truncated as Python scalars, and the
        info the single env reports (distance, reward_terms, self_collision, collision_depth,
        reachable, lead, and failure when terminated).

        The same numbers as step(), bit for bit (tests/test_vector.py checks it across the
        settings): the arithmetic on one slot's numbers is done in Python floats, which round
        exactly as numpy's elementwise operations do, and everything whose rounding depends on
        the routine (the IK's linear algebra, the norm's sum, einsum, exp) still goes through
        the same numpy calls as step(). For one arm a numpy call costs far more than the
        arithmetic in it, so this is what keeps a single env step near the cost of its physics.
        """
        if self.n != 1:
            raise ValueError(f"step_one is for a task of one slot; this one has {self.n}")
        c, core = self.config, self.core
        # (an array's own ravel: np.ravel's dispatch costs more than the copy out; a 1-D
        # array needs none)
        values = ((action if action.ndim == 1 else action.ravel()) if type(action) is np.ndarray
                  else np.ravel(action)).tolist()
        if len(values) != self.action_dim:
            raise ValueError(f"action must have {self.action_dim} values, got {len(values)}")
        if self._lean_lead:  # the 3-D lead, written out (a comprehension costs more)
            isfinite, (x0, x1, x2) = math.isfinite, values
            if not (isfinite(x0) and isfinite(x1) and isfinite(x2)):
                raise ValueError(f"action must be finite, got {np.ravel(action)} (trajectory "
                                 f"seed {self.traj_seeds[0]})")
            # np.clip, exactly: np.minimum(np.maximum(x, -1), 1) (no NaN gets here)
            values = [-1.0 if x0 < -1.0 else 1.0 if x0 > 1.0 else float(x0),
                      -1.0 if x1 < -1.0 else 1.0 if x1 > 1.0 else float(x1),
                      -1.0 if x2 < -1.0 else 1.0 if x2 > 1.0 else float(x2)]
            # (the action as an array only for the terms that take it; prev_action and lead
            # are made when first read, see _make_step)
            action = np.array([values]) if self._action_weighed else None
            # _control() on Python floats: lead = action * max_lead
            (v0, v1, v2), max_lead = values, c.max_lead
            lead = [v0 * max_lead, v1 * max_lead, v2 * max_lead]
            collision, depth, unstable = core.step_one(lead)
        else:
            if not all(map(math.isfinite, values)):
                raise ValueError(f"action must be finite, got {np.ravel(action)} (trajectory "
                                 f"seed {self.traj_seeds[0]})")
            values = [-1.0 if x < -1.0 else 1.0 if x > 1.0 else float(x) for x in values]
            action = np.array([values])
            self._control(action)
            collision, unstable = bool(core.self_collision[0]), bool(core.unstable[0])
            depth = float(core.collision_depth[0])
        # The 3-vectors' arithmetic written out (a comprehension costs more than its maths).
        # The last tip position: the last step's, while its arrays are still to be made.
        pending = self._pending_step
        p0, p1, p2 = self._prev_ee_row.tolist() if pending is None else pending[3]
        ee, dt = self._tip_row.tolist(), self.dt
        e0, e1, e2 = ee
        ee_vel = [(e0 - p0) / dt, (e1 - p1) / dt, (e2 - p2) / dt]
        step = core.step_count.item(0)
        k = min(step, c.episode_steps)  # the core's path index (its paths have one row more)
        path_pos, path_vel, path_acc = core.path_rows  # (Python rows: no numpy call per row)
        target = path_pos[k]
        t0, t1, t2 = target
        dx, dy, dz = e0 - t0, e1 - t1, e2 - t2
        dist = math.sqrt((dx * dx + dy * dy) + dz * dz)  # _distance() on Python floats
        if self._avg_observed:  # step()'s update on Python floats (a NaN stays a NaN as there)
            clip, rate = self._avg_clip, self._avg_rate
            avg = [a + rate * ((-clip if x < -clip else clip if x > clip else x) - a)
                   for a, x in zip(self.err_avg[0].tolist(), (dx, dy, dz), strict=True)]
            self.err_avg[0] = avg
        terminated = unstable or (collision and c.terminate_on_collision)
        truncated = not terminated and step >= c.episode_steps
        counts = step * dt >= self._reward_from
        w_dist, w_track, w_act, w_change, w_coll, w_alive, w_term = self._signed_w
        # A zero weight times anything finite is a zero of the weight's sign, so the numpy
        # calls behind a term whose weight is zero are skipped (the defaults weigh most so).
        e = np.exp(np.array([-dist / c.tracking_scale]))[0] if w_track else 1.0
        sq = np.einsum("ij,ij->i", action, action)[0] if w_act else 0.0
        da = action - self.prev_action if w_change else None
        dsq = np.einsum("ij,ij->i", da, da)[0] if w_change else 0.0
        if unstable:  # a blown-up arm earns only its termination cost
            terms = dict.fromkeys(REWARD_TERMS[:-1], 0.0)
            terms["termination"] = w_term if terminated else 0.0
        else:
            terms = {
                "distance": w_dist * dist if counts else 0.0,
                "tracking": float(w_track * e) if counts else 0.0,
                "action": float(w_act * sq),
                "action_change": float(w_change * dsq),
                "collision": w_coll * depth,
                "alive": w_alive,
                "termination": w_term if terminated else 0.0,
            }
        reward = sum(terms.values())
        if self._lean_lead:
            self._pending_step = (values, lead, ee_vel, ee)
        else:
            self.prev_action = action
            self._ee_vel_row[:], self._prev_ee_row[:] = ee_vel, ee
        # Every feature's values (in _SOURCES' order), the observed ones picked in the
        # layout's order and chained: no dict of them, no list in between.
        joints = self._joints_observed
        source = (ee, ee_vel, target, path_vel[k], path_acc[k],
                  core.qpos[0].tolist() if joints else None,
                  core.qvel[0].tolist() if joints else None,
                  values, (dx, dy, dz), avg if self._avg_observed else None)
        raw = chain.from_iterable(self._pick(source))
        if len(self._noisy):
            raw = list(raw)
            noise = self.rngs[0].normal(0.0, self._noise_std[self._noisy]).tolist()
            for j, v in zip(self._noisy.tolist(), noise, strict=True):
                raw[j] += v
        # raw * inv_scale to float32 (fromiter: no list in between, and cheaper than np.array)
        obs = np.fromiter(map(mul, raw, self._inv_scale_list), np.float32, self._base_dim)
        if not self._plain_obs or unstable:
            obs = self._observed(obs[None], core.unstable if unstable else None)[0]
        info = {"distance": dist, "reward_terms": terms, "self_collision": collision,
                "collision_depth": depth, "reachable": self._reachable_row[k],
                "lead": np.array(lead) if self._lean_lead else self.lead[0].copy()}
        if terminated:
            info["failure"] = "unstable" if unstable else "self_collision"
        return obs, reward, terminated, truncated, info

    def _checked(self, action: np.ndarray) -> np.ndarray:
        """Finite actions, clipped to [-1, 1] in place; a NaN or infinity is a clear error."""
        finite = np.isfinite(action)
        if not np.logical_and.reduce(finite, axis=None):
            bad = np.flatnonzero(~finite.all(axis=1))
            raise ValueError(f"action must be finite, got {action[bad[0]]} (trajectory seed "
                             f"{self.traj_seeds[bad[0]]})")
        return np.minimum(np.maximum(action, -1.0, out=action), 1.0, out=action)  # np.clip

    def _control(self, action: np.ndarray) -> None:
        """Apply the (checked) actions: the action delay, then one control step of the core."""
        core = self.core
        applied = action
        if self._delayed:
            self._act_hist[:, 1:] = self._act_hist[:, :-1]
            self._act_hist[:, 0] = action
            applied = self._act_hist[self._all, self.action_delay]
        kind = self.config.action
        if kind == "lead":
            self.lead = applied * self.config.max_lead
            core.step(self.lead)
        elif kind == "joint":
            core.step(joint_offset=applied * self.config.max_joint_offset)
        else:  # joint_target, no IK: -1 the lower limit, 0 the home pose, +1 the upper limit
            lo, hi = core.joint_limits
            home = core.home
            core.step(joint_goal=home + np.where(applied < 0, home - lo, hi - home) * applied)

    def _observed(self, obs: np.ndarray, unstable: np.ndarray | None) -> np.ndarray:
        """What the policy sees of this step's (N, base) observations: the observation delay,
        zeros for blown-up slots (``unstable``; None when there are none), then stacking."""
        if self._delayed:
            self._obs_hist[:, 1:] = self._obs_hist[:, :-1]
            self._obs_hist[:, 0] = obs
            obs = self._obs_hist[self._all, self.obs_delay]
        if unstable is not None:
            obs[unstable] = 0.0  # never hand NaNs to the learner
        return self._stacked(obs)


def _distance(d: np.ndarray) -> np.ndarray:
    """|d| of each row of an (N, 3) array: np.linalg.norm(d, axis=1), which sums the squares
    in this order (checked on millions of rows), written out elementwise so that step_one's
    Python floats give the same numbers by construction."""
    return np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])


def failure_of(info: dict, i: int, terminated: bool) -> str | None:
    if not terminated:
        return None
    return "unstable" if info["unstable"][i] else "self_collision"
