"""`LeadTaskOne`: the single env's task, `LeadTask` of one slot specialised for speed. Deletable.

The control step, the reward and the observation are task.py's `LeadTask.step`; this file
changes none of them. It runs the task on core_one.py's `ArmOne` and, for a lead action
without action delay (the single env's usual case), steps through `step_one` below: the same
numbers as `LeadTask.step`, bit for bit, with one slot's arithmetic done in Python floats,
which round exactly as numpy's elementwise operations do, while everything whose rounding
depends on the routine (the IK's linear algebra, einsum, exp) still goes through the numpy
calls `LeadTask.step` makes. For one arm a numpy call costs far more than the arithmetic in
it, so this is what keeps a single env step near the cost of its physics (docs/performance.md,
"The single env"). Every other setting (joint actions, delays) takes `LeadTask.step_one`, the
reference step itself.

Held to `LeadTask` bit for bit by tests/test_batched.py
(test_the_fast_single_task_is_the_reference_bit_for_bit,
test_the_single_envs_deferred_arrays_are_the_batchs, and the single env against a row of the
vector env), tests/test_vector.py (every setting's single envs against the native vector env:
noise, weights, settled-only reward, ragged ends, delays, stacking, joint actions, substep IK,
clearance) and tests/test_core.py (ArmOne, see core_one.py).

To delete: remove this file and core_one.py, and in env.py import ``LeadTask as SingleTask``
from task.py instead of ``LeadTaskOne``.
"""

from __future__ import annotations

import math
from itertools import chain
from operator import itemgetter, mul

import numpy as np

from .config import REWARD_TERMS, EnvConfig, failure_label
from .core import ArmBatch
from .core_one import ArmOne, _Deferred
from .task import LeadTask

# step_one's order of the observation features (its tuple of their values): the features the
# lean route builds (recent_actions is LeadTask.step()'s alone)
LEAN_FEATURES = ("ee_pos", "ee_vel", "target_pos", "target_vel", "target_acc", "joint_pos",
            "joint_vel", "prev_action", "tip_error", "tip_error_avg", "target_preview",
            "preview_jerk", "installation")


class LeadTaskOne(LeadTask):
    """`LeadTask` of one slot on `ArmOne` (`ArmBatch(1)` with the collision-aware IK, which
    needs the batch), whose ``step_one`` is the single env's fast step. Held to LeadTask by the
    tests named in task_one.py's docstring."""

    prev_action = _Deferred("_pending_step", "_make_step")
    lead = _Deferred("_pending_step", "_make_step")
    ee_vel = _Deferred("_pending_step", "_make_step")
    _prev_ee = _Deferred("_pending_step", "_make_step")

    def __init__(self, config: EnvConfig, n: int = 1, nthread: int = 0):
        if n != 1:
            raise ValueError(f"LeadTaskOne is a task of one slot; use LeadTask for {n}")
        self._pending_step = None  # (see _make_step)
        super().__init__(config, 1, nthread)
        c = self.config
        self._inv_scale_list = self._inv_scale.tolist()
        self._base_dim = self.layout[-1][2]  # one observation's size
        # the observed features' positions in step_one's tuple of every feature
        at = [LEAN_FEATURES.index(f) for f in self._features if f in LEAN_FEATURES]
        self._pick = itemgetter(*at) if len(at) > 1 else lambda source: (source[at[0]],)
        self._joints_observed = bool({"joint_pos", "joint_vel"} & set(self._features))
        # the weights, signed as step_one's terms use them (one unpack, not a dict lookup each)
        self._signed_w = (-self._w["distance"], self._w["tracking"], -self._w["action"],
                          -self._w["action_change"], -self._w["collision"], self._w["alive"],
                          -self._w["termination"])  # (limit: not on the lean route)
        self._reward_from = c.reward_after_s - 1e-9  # step()'s threshold on the time
        # row views of slot 0 (these arrays are only ever written in place)
        self._ee_vel_row, self._prev_ee_row = self.ee_vel[0], self._prev_ee[0]
        self._tip_row = self.core.tip_pos[0]
        # The lean route: a lead with no action delay goes to the core's one-arm step as
        # Python floats (the lead is the action times max_lead, as _control computes it).
        self._lean_lead = (isinstance(self.core, ArmOne) and self.core.lean
                           and c.action == "lead" and not self._delayed
                           and not c.lead_filter_hz and not c.noisy_lead_filter_hz
                           and set(c.obs_features) <= set(LEAN_FEATURES)
                           and not c.target_delay
                           and not c.noisy_ik_target and not c.target_filter
                           and not c.arm_filter and not c.feedforward and not c.w_limit
                           and not c.repetitive_gain and not c.follow_plan)
        self._plain_obs = not self._delayed and c.obs_stack == 1  # _observed() is the identity
        self._action_weighed = bool(c.w_action or c.w_action_change)
        self._offset_rows = self._jerk_rows = None  # the preview's rows (reset sets them)
        # the noise's channels as Python ints (LeadTask._set_up_noise)
        self._noisy_list, self._noisy_obs_list = self._noisy.tolist(), self._noisy_obs.tolist()
        self._reading_pairs = list(zip(*(c.tolist() for c in self._reading_cols), strict=True))

    def _new_core(self, n: int, nthread: int) -> ArmBatch:
        if self.config.ik.clearance > 0:
            return ArmBatch(1, self.config.ik, nthread=nthread)
        return ArmOne(1, self.config.ik)

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

    def reset(self, ids=None, traj_seeds=None, shapes=None) -> np.ndarray:
        obs = super().reset(ids, traj_seeds, shapes)
        self._reachable_row = self._reachable[0].tolist()  # step_one's, as Python bools
        if self._preview_observed:  # the preview's rows, as Python floats (LeadTask's values)
            rows = {f: r[0].tolist() for f, r in self._preview.items()}
            self._offset_rows = rows.get("target_preview")
            self._jerk_rows = rows.get("preview_jerk")
        return obs

    def step_one(self, action):
        """LeadTask.step_one, the same numbers and types, the lean route on Python floats (see
        task_one.py's docstring); any other setting takes LeadTask.step_one itself."""
        if not self._lean_lead:
            return super().step_one(action)
        c, core = self.config, self.core
        # (an array's own ravel: np.ravel's dispatch costs more than the copy out; a 1-D
        # array needs none)
        values = ((action if action.ndim == 1 else action.ravel()) if type(action) is np.ndarray
                  else np.ravel(action)).tolist()
        if len(values) != self.action_dim:
            raise ValueError(f"action must have {self.action_dim} values, got {len(values)}")
        # the 3-D lead, written out (a comprehension costs more)
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
        noise = reading = None
        if self._noisy_list:  # this step's draw, first (LeadTask._draw_noise):
            std = (self._noisy_std * self.noise_scale[0] if c.random_noise
                   else self._noisy_std)  # (_draw_noise's)
            drawn = self.rngs[0].normal(0.0, std)  # the average takes the measured error
            self._noise[0, self._noisy] = drawn
            noise = self._noise[0].tolist()
            if self._error_noisy:  # the tip reading's noise minus the target reading's
                reading = [noise[a] - noise[b] for a, b in self._reading_pairs]
        if self._avg_observed:  # step()'s update on Python floats (a NaN stays a NaN as there)
            clip, rate = self._avg_clip, self._avg_rate
            seen = (dx, dy, dz) if reading is None else (dx + reading[0], dy + reading[1],
                                                         dz + reading[2])
            avg = [a + rate * ((-clip if x < -clip else clip if x > clip else x) - a)
                   for a, x in zip(self.err_avg[0].tolist(), seen, strict=True)]
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
                "limit": 0.0,
                "alive": w_alive,
                "termination": w_term if terminated else 0.0,
            }
        reward = sum(terms.values())
        self._pending_step = (values, lead, ee_vel, ee)
        # Every feature's values (in LEAN_FEATURES' order), the observed ones picked in the
        # layout's order and chained: no dict of them, no list in between.
        joints = self._joints_observed
        source = (ee, ee_vel, target, path_vel[k], path_acc[k],
                  core.qpos[0].tolist() if joints else None,
                  core.qvel[0].tolist() if joints else None,
                  values, (dx, dy, dz), avg if self._avg_observed else None,
                  self._offset_rows[k] if self._offset_rows is not None else None,
                  self._jerk_rows[k] if self._jerk_rows is not None else None,
                  self._installation[0].tolist() if self._installation_cols is not None
                  else None)
        raw = chain.from_iterable(self._pick(source))
        if noise is not None:  # observe()'s order: each column's own draw, then the readings'
            raw = list(raw)
            for j in self._noisy_obs_list:
                raw[j] += noise[j]
            if reading is not None and self._error_cols is not None:
                for j, v in zip(self._error_cols.tolist(), reading, strict=True):
                    raw[j] += v
        # raw * inv_scale to float32 (fromiter: no list in between, and cheaper than np.array)
        obs = np.fromiter(map(mul, raw, self._inv_scale_list), np.float32, self._base_dim)
        if not self._plain_obs or unstable:
            obs = self._observed(obs[None], core.unstable if unstable else None)[0]
        info = {"distance": dist, "reward_terms": terms, "self_collision": collision,
                "collision_depth": depth, "reachable": self._reachable_row[k],
                "lead": np.array(lead)}
        if terminated:
            info["failure"] = failure_label(unstable)
        return obs, reward, terminated, truncated, info

