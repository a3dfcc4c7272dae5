"""`LeadTask`: N episodes of the lead task on one `ArmBatch`, the code every env runs.

The single env (env.py), Gymnasium's vector env (vector.py) and SB3's VecEnv (sb3_vecenv.py)
are thin views over it, which is why their episodes are bit-identical for the same trajectory
seeds. `LeadTask.step` is the one definition of the control step, the reward and the
observation; task_one.py's `LeadTaskOne` (the single env's fast path) is a specialisation of
it held to it bit for bit by tests, which nothing here knows of.
"""

from __future__ import annotations

import numpy as np

from . import kalman, online, trajectory
from .config import (
    LIMIT_FEASIBLE_ACC,
    LIMIT_FROM_S,
    OBS_SCALE,
    PATH_FEATURES,
    RECENT_ACTIONS,
    REWARD_TERMS,
    EnvConfig,
    action_dim,
    failure_of,
    obs_layout,
)
from .core import ArmBatch
from .limits import JOINT_ACC
from .seeds import TRAIN_SEED_HIGH, TRAIN_SEED_LOW
from .trajectory import reachable


class LeadTask:
    """N episodes of the lead task on one `ArmBatch`: the code both envs run.

    ``rngs[i]`` is episode slot i's generator: it draws slot i's training trajectories and its
    observation noise, so a slot's episodes depend on its own stream alone.
    """

    def __init__(self, config: EnvConfig, n: int, nthread: int = 0):
        self.config = c = config
        self.n = n
        self.layout = obs_layout(c.obs_features)
        self.core = self._new_core(n, nthread)  # ArmBatch(n, config.ik)
        self.dt = self.core.dt
        base = self.layout[-1][2]  # one observation; obs_stack of them are stacked
        self.obs_dim = base * c.obs_stack
        self._inv_scale = np.ones(base)
        for f, a, b in self.layout:
            self._inv_scale[a:b] = 1.0 / OBS_SCALE[f]
        self._features = [f for f, _, _ in self.layout]
        self._error_observed = "tip_error" in self._features
        # tip_error_avg: a running average of the clipped tip error (EnvConfig.error_avg_*),
        # updated only when it is observed
        self._avg_observed = "tip_error_avg" in self._features
        self._set_up_noise(base)
        self.err_avg = np.zeros((n, 3))
        # target_preview, preview_jerk: each slot's path ahead at every step of its episode,
        # computed from its trajectory at its reset (the path ahead runs past the episode's end)
        self._preview = {f: np.zeros((n, c.episode_steps + 1, 3 * len(c.preview_times)))
                         for f in PATH_FEATURES if f in self._features}
        self._preview_observed = bool(self._preview)
        self._avg_rate, self._avg_clip = self.dt / c.error_avg_time, c.error_avg_clip
        self._w = {k: getattr(c, f"w_{k}") for k in REWARD_TERMS}
        self._alive = np.full(n, self._w["alive"])
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.action_dim = action_dim(c.action)
        self.prev_action = np.zeros((n, self.action_dim))
        # recent_actions: the last actions, newest first, and their observed columns
        self._recent = np.zeros((n, RECENT_ACTIONS, self.action_dim))
        self._recent_cols = next((slice(a, b) for f, a, b in self.layout
                                  if f == "recent_actions"), None)
        # plan_weight: the planner's hand's share of the next goal (set up with the hand below)
        self._plan_weight_cols = next((slice(a, b) for f, a, b in self.layout
                                       if f == "plan_weight"), None)
        # what the controller knows when it acts, never late: its own actions and its hand
        self._undelayed_cols = [c for c in (self._recent_cols, self._plan_weight_cols)
                                if c is not None]
        self.lead = np.zeros((n, 3))
        self.ee_vel = np.zeros((n, 3))
        self._prev_ee = np.zeros((n, 3))
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
        self.target_delay = np.full(n, c.target_delay)  # the target camera's, per slot
        self.noise_scale = np.ones(n)  # each slot's episode's share of obs_noise (random_noise)
        self._goal_hist = np.zeros((n, 2, 7))  # the last two joint goals (w_limit's term)
        self._no_limit = np.zeros(n)  # the limit term when w_limit is 0: made once, read-only
        self._no_limit.flags.writeable = False
        # limit_lead_only: the zero lead's last two goals, and the slots whose path the term
        # leaves out (set at each reset)
        self._ref_hist = np.zeros((n, 2, 7)) if c.limit_lead_only else None
        self._ref_goal = None  # (set each step before the core's, under limit_lead_only)
        self._limit_off = np.ones(n, bool) if c.limit_lead_only else None
        # the installation feature: each slot's latencies and target noise (config.OBS_SCALE)
        self._installation = np.zeros((n, 4))
        self._installation_cols = next((slice(a, b) for f, a, b in self.layout
                                        if f == "installation"), None)
        self._set_installation(self._all)
        # Peak-speed cap of drawn (training) trajectories; a curriculum raises it as it goes.
        self.speed_cap = c.max_peak_speed
        # noisy_ik_target: the observed target_pos reading's columns, and the latest reading
        self._target_cols = next((slice(a, b) for f, a, b in self.layout if f == "target_pos"),
                                 None)
        self._target_reading = np.zeros((n, 3))
        # The tracker's Kalman filter (EnvConfig.target_filter) and the same filter on the
        # tip's readings (EnvConfig.arm_filter): each slot's estimate, started from the
        # reading at a reset; under random_noise, the gain of each episode's noise level
        cols = {f: slice(a, b) for f, a, b in self.layout}
        self._filters = []
        for on, features, sign in ((c.target_filter, ("target_pos", "target_vel", "target_acc"),
                                    -1.0), (c.arm_filter, ("ee_pos", "ee_vel"), 1.0)):
            if on:
                self._filters.append(kalman.ReadingFilter(
                    [cols[f] for f in features], sign, self.dt,
                    [c.obs_noise.get(f, 0.0) for f in features], n, c.random_noise))
        self._filter_error_cols = cols.get("tip_error")
        # The feedforward rival under the lead (EnvConfig.feedforward): each slot's planned
        # path and servo goals, recomputed for the slots that reset
        self._feedforward = None
        if c.feedforward:
            from . import controllers, preview

            self._feedforward = preview._PathCache(
                max(controllers.FEEDFORWARD_TAU, controllers.FEEDFORWARD_TAU_IK),
                joint_path=True, clip=controllers.FEEDFORWARD_CLIP)
            self._ff_settings = (controllers.FEEDFORWARD_TAU / self.dt,
                                 controllers.FEEDFORWARD_TAU_IK / self.dt,
                                 controllers.FEEDFORWARD_GAIN)
        # The plan followed where the arm can (EnvConfig.follow_plan): each slot's planned
        # joint goals, and whether its whole episode is followable, once per reset
        self._plan = None
        if c.follow_plan:
            from . import controllers, preview

            self._plan = self._feedforward or preview._PathCache(0.0, joint_path=True, clip=True)
            self._handover = controllers.PLAN_HANDOVER
            self._handover_weight = preview.handover_weight
            # which slots' goal the damper projects: the feedforward's goal always (as the
            # core does), the IK's own only once handed over (the IK projected it already)
            self._every_slot = np.ones(n, dtype=bool) if self._feedforward is not None else None
        # The lap-to-lap correction in the loop (EnvConfig.repetitive_gain): online.py's law,
        # the one a trained lead is played with
        self._corrector = None
        self._correction_observed = "repetitive_correction" in self._features
        if c.repetitive_gain:
            self._corrector = online.Corrector(online.OnlineCorrection(
                "repetitive", c.repetitive_gain, c.repetitive_advance, c.repetitive_smooth))
        # The lead's low-pass (EnvConfig.lead_filter_hz): the share of the way it moves per step
        # (noisy_lead_filter_hz: the slots whose episode is noisy, set at each reset)
        hz = c.lead_filter_hz or (c.noisy_lead_filter_hz if any(c.obs_noise.values()) else 0)
        self._lead_alpha = 1.0 - np.exp(-2 * np.pi * hz * self.dt) if hz > 0 else None
        self._lead_smoothed = (np.ones(n, bool) if c.noisy_lead_filter_hz and self._lead_alpha
                               else None)

    def _set_up_noise(self, base: int) -> None:
        """The sensors' noise (EnvConfig.obs_noise). Each feature gets its own Gaussian draw,
        except the tip error, which is computed from two readings, the tip's (ee_pos's noise)
        and the target's (target_pos's): it carries the difference of their draws, plus its
        own draw if obs_noise gives tip_error one, and tip_error_avg averages that measured
        error. A reading's draw is its observed columns' or, when that position is not
        observed, one of 3 hidden channels after the observation's (tip at base, target at
        base + 3). One draw per slot and step, from the slot's generator, over the channels
        whose std is not zero."""
        c, cols = self.config, {f: np.arange(a, b) for f, a, b in self.layout}
        std = np.zeros(base + 6)
        for f, a, b in self.layout:
            std[a:b] = c.obs_noise.get(f, 0.0)
        uses_error = self._error_observed or self._avg_observed
        self._reading_cols = []  # the tip's, then the target's
        for k, f in enumerate(("ee_pos", "target_pos")):
            hidden = np.arange(base + 3 * k, base + 3 * k + 3)
            self._reading_cols.append(cols.get(f, hidden))
            if uses_error and f not in cols:
                std[hidden] = c.obs_noise.get(f, 0.0)
        self._noisy = np.flatnonzero(std)  # the channels drawn, and their stds
        self._noisy_std = std[self._noisy]
        self._noisy_obs = self._noisy[self._noisy < base]  # of them, the observation's columns
        self._noise = np.zeros((self.n, base + 6))  # each slot's latest draw
        self._error_noisy = uses_error and bool(std[self._reading_cols[0]].any()
                                                or std[self._reading_cols[1]].any())
        self._error_cols = cols.get("tip_error")
        # what an online correction reads under noise (error_reading_noise): the reading noisy
        # in the config but never drawn here would make its measured error exact
        self._unread = [f for f, rc in zip(("ee_pos", "target_pos"), self._reading_cols,
                                           strict=True)
                        if c.obs_noise.get(f) and not np.isin(rc, self._noisy).all()]
        self._reading_noisy = bool(c.obs_noise.get("ee_pos") or c.obs_noise.get("target_pos"))

    def _draw_noise(self, ids) -> None:
        """Slots ``ids``' noise for this step (all when None), into self._noise."""
        scaled = self.config.random_noise
        for i in self._all if ids is None else ids:
            std = self._noisy_std * self.noise_scale[i] if scaled else self._noisy_std
            self._noise[i, self._noisy] = self.rngs[i].normal(0.0, std)

    def _reading_noise(self) -> np.ndarray:
        """(N, 3) the measured tip error's noise: the tip reading's minus the target's."""
        tip, target = self._reading_cols
        return self._noise[:, tip] - self._noise[:, target]

    def error_reading_noise(self) -> np.ndarray | float:
        """(N, 3) the noise of the latest measured tip error target - tip (the target reading's
        draw minus the tip reading's; the same draws the observation carries), 0.0 without
        noise on either reading. What an online correction reads under noise (online.py)."""
        if not self._reading_noisy:
            return 0.0
        if self._unread:
            raise ValueError(f"the env draws no noise for the {self._unread[0]} reading (observe "
                             f"{self._unread[0]} or tip_error): the measured error would be exact")
        return -self._reading_noise()

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
        self._goal_hist[ids] = core.q_goal[ids, None]
        if self._ref_hist is not None:
            self._ref_hist[ids] = core.q_goal[ids, None]
        self._reachable[ids] = reachable(core.target_pos[ids])
        if self._preview_observed:
            self._set_preview(ids)
        if self._feedforward is not None:  # the new episodes' planned paths, once per reset
            self._feedforward.update(self)
        if self._plan is not None:
            self._plan.update(self)  # (a no-op when it is the feedforward's own cache)
        self.prev_action[ids] = 0.0
        self._recent[ids] = 0.0
        self.lead[ids] = 0.0
        self.ee_vel[ids] = 0.0
        self._prev_ee[ids] = core.tip_pos[ids]
        self.err_avg[ids] = 0.0
        nominal = self._draw_nominal(ids)
        if self.config.random_noise:  # (drawn only when asked: other settings' streams stay)
            for i in ids:
                self.noise_scale[i] = self.rngs[i].uniform()
            self.noise_scale[nominal] = 0.0
        undelayed = self._draw_split(ids, nominal)
        if self._lead_smoothed is not None:  # the lead's low-pass in the noisy episodes only
            self._lead_smoothed[ids] = self.noise_scale[ids] > 0
        if self._limit_off is not None:  # a path no controller runs within the limits
            self._limit_off[ids] = [self.trajs[i].peak_acc > LIMIT_FEASIBLE_ACC for i in ids]
        for reading_filter in self._filters:  # (the filter of each episode's noise level)
            reading_filter.restart(ids, self.noise_scale[ids])
        self._set_installation(ids)
        obs = self.observe(ids)
        if self.config.random_delay and self.config.target_delay:
            for i in ids:
                self.target_delay[i] = self.rngs[i].integers(self.config.target_delay + 1)
        if self._delayed and self.config.random_delay:
            for i in ids:
                self.obs_delay[i] = self.rngs[i].integers(self.config.obs_delay + 1)
                self.action_delay[i] = self.rngs[i].integers(self.config.action_delay + 1)
        for quiet in (nominal, undelayed):  # the nominal installation, and noise alone
            if len(quiet):  # (no delay of any kind)
                self.obs_delay[quiet] = self.action_delay[quiet] = 0
                self.target_delay[quiet] = 0
        if self._installation_cols is not None and self.config.random_delay:
            # (the delays are drawn after the first observation, whose other columns keep
            # their streams; its installation columns get this episode's)
            self._set_installation(ids)
            cols = self._installation_cols
            obs[ids, cols] = (self._installation[ids] * self._inv_scale[cols]).astype(np.float32)
        if self._delayed:
            self._act_hist[ids] = 0.0  # before the episode the lead was zero (classical)
            self._obs_hist[ids] = obs[ids, None, :]  # before it, the arm stood still
            obs = self._obs_hist[self._all, self.obs_delay]
        return self._stacked(obs, ids)

    def _draw_nominal(self, ids) -> np.ndarray:
        """Of slots ``ids``, those whose new episode is the nominal installation (no delay, no
        noise; EnvConfig.nominal_share), drawn from each slot's stream only when asked."""
        share = self.config.nominal_share
        if not share:
            return np.zeros(0, dtype=np.int64)
        return np.array([i for i in ids if self.rngs[i].uniform() < share], dtype=np.int64)

    def _draw_split(self, ids, nominal) -> np.ndarray:
        """Under split_conditions, of slots ``ids`` not drawn ``nominal``: a third keep their
        noise and lose their delays (returned), a third lose their noise (set here) and keep
        their delays, a third keep both; drawn from each slot's stream only when asked."""
        if not self.config.split_conditions:
            return np.zeros(0, dtype=np.int64)
        skip = set(np.asarray(nominal).tolist())
        kinds = {i: self.rngs[i].integers(3) for i in ids if i not in skip}
        self.noise_scale[[i for i, k in kinds.items() if k == 1]] = 0.0  # latency alone
        return np.array([i for i, k in kinds.items() if k == 0], dtype=np.int64)

    def _set_installation(self, ids) -> None:
        """Slots ``ids``' installation rows: their delays and their target reading's noise."""
        c, inst = self.config, self._installation
        inst[ids, 0], inst[ids, 1] = self.obs_delay[ids], self.action_delay[ids]
        inst[ids, 2] = self.target_delay[ids]
        noise_cm = 100.0 * c.obs_noise.get("target_pos", 0.0)
        inst[ids, 3] = noise_cm * (self.noise_scale[ids] if c.random_noise else 1.0)

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

    def _set_preview(self, ids) -> None:
        """The preview's rows for slots ``ids`` at every step's time t, h in preview_times, from
        each slot's trajectory (defined for every t >= 0): target_preview p(t + h) - p(t),
        preview_jerk 6 (p(t + h) - p - v h - a h^2 / 2) / h^3 (config.OBS_SCALE)."""
        times = np.arange(self.config.episode_steps + 1) * self.dt
        offsets, jerks = self._preview.get("target_preview"), self._preview.get("preview_jerk")
        for i in ids:
            if jerks is not None:  # the Taylor guess's terms, once per slot
                p, v, a = self.trajs[i].at(times)[:3]
            for j, h in enumerate(self.config.preview_times):
                ahead = self.trajs[i].at(times + h)[0]
                if offsets is not None:
                    offsets[i, :, 3 * j:3 * j + 3] = ahead - self.core.target_pos[i]
                if jerks is not None:
                    jerks[i, :, 3 * j:3 * j + 3] = 6.0 * (ahead - (p + v * h + 0.5 * a * h * h)
                                                          ) / h ** 3

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

    def observe(self, ids=None, target=None, drawn=False) -> np.ndarray:
        """The (scaled, float32) observation of every slot; noise is drawn for slots ``ids``
        only (default all): a slot's generator advances only when its observation is used.
        ``target``: the core's current (pos, vel, acc), when the caller already has it;
        ``drawn``: this step's noise of slots ``ids`` is drawn already (step() draws it first,
        for tip_error_avg)."""
        core, raw = self.core, self._raw
        if self.config.target_delay:
            pos, vel, acc = self.known_target()
        else:
            pos, vel, acc = core.target() if target is None else target
        source = {"ee_pos": core.tip_pos, "ee_vel": self.ee_vel, "target_pos": pos,
                  "target_vel": vel, "target_acc": acc, "joint_pos": core.qpos,
                  "joint_vel": core.qvel, "prev_action": self.prev_action}
        if self._recent_cols is not None:
            source["recent_actions"] = self._recent.reshape(self.n, -1)
        if self._error_observed:
            source["tip_error"] = core.tip_pos - pos
        if self._plan_weight_cols is not None:  # (the weight _plan_goal gives the next goal;
            source["plan_weight"] = 0.0 if self._plan is None else self._handover_weight(
                core.time, self._handover, self._plan.followable)[:, None]  # none: no hand)
        if self._avg_observed:
            source["tip_error_avg"] = self.err_avg
        if self._installation_cols is not None:
            source["installation"] = self._installation
        if self._correction_observed:  # this step's correction (_control adds the same: the
            source["repetitive_correction"] = (  # law is idempotent); none: 0
                self._corrector(self) if self._corrector is not None else 0.0)
        if self._preview_observed:
            k = np.minimum(np.maximum(core.step_count - self.target_delay, 0),
                           self.config.episode_steps)
            for f, rows in self._preview.items():
                source[f] = rows[self._all, k]
        for f, a, b in self.layout:
            raw[:, a:b] = source[f]
        if len(self._noisy):
            if not drawn:
                self._draw_noise(ids)
            noisy, errs = self._noisy_obs, self._error_cols
            errs = errs if self._error_noisy else None
            if ids is None:  # every slot (a step without resets): no index arrays to build
                raw[:, noisy] += self._noise[:, noisy]
                if errs is not None:
                    raw[:, errs] += self._reading_noise()
            else:
                raw[np.ix_(ids, noisy)] += self._noise[np.ix_(ids, noisy)]
                if errs is not None:
                    raw[np.ix_(ids, errs)] += self._reading_noise()[ids]
        for reading_filter in self._filters:
            reading_filter.apply(raw, self._all if ids is None else ids,
                                 self._filter_error_cols)
        if self.config.noisy_ik_target:  # the reading the IK aims at until the next one,
            rows = self._all if ids is None else ids  # of the slots observed (noise drawn)
            self._target_reading[rows] = raw[rows, self._target_cols]
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
        observed = None if discard is None else np.setdiff1d(self._all, discard)
        drawn = self._avg_observed and self._error_noisy
        if self._avg_observed:  # avg += rate * (clip(err) - avg), step_one's order
            clip = self._avg_clip
            seen = err if not self.config.target_delay else ee - self.known_target()[0]
            if self._error_noisy:  # the measured error: this step's noise drawn first
                self._draw_noise(observed)
                seen = seen + self._reading_noise()
            self.err_avg += self._avg_rate * (np.minimum(np.maximum(seen, -clip), clip)
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
            "limit": self._limit_term(core) if w["limit"] else self._no_limit,
            "alive": self._alive.copy(),
            "termination": np.where(terminated, -w["termination"], 0.0),
        }
        if any_unstable:  # a blown-up arm earns only its termination cost
            for k in REWARD_TERMS[:-1]:
                terms[k] = np.where(unstable, 0.0, terms[k])
        reward = sum(terms.values())
        self.prev_action = action
        if self._recent_cols is not None:
            self._recent[:, 1:] = self._recent[:, :-1]
            self._recent[:, 0] = action
        obs = self._observed(self.observe(observed, target=now, drawn=drawn),
                             unstable if any_unstable else None)
        k = np.minimum(core.step_count, self.config.episode_steps)
        info = {"distance": dist, "reward_terms": terms, "self_collision": core.self_collision,
                "collision_depth": core.collision_depth, "unstable": unstable,
                "reachable": self._reachable[self._all, k], "lead": self.lead}
        return obs, reward, terminated, truncated, info

    def _limit_term(self, core) -> np.ndarray:
        """-w_limit * the joint goals' clipped acceleration excess (EnvConfig.w_limit): the
        second difference of this step's goal and the two before (none before the third step
        of an episode, and none before LIMIT_FROM_S); under limit_lead_only, minus the zero
        lead's, on the paths a Panda could run."""
        k = core.step_count
        excess = _acceleration_excess(self._goal_hist, core.q_goal, self.dt)
        counts = (k >= 3) & (core.time >= LIMIT_FROM_S - 1e-9)
        if self._ref_hist is not None:
            excess -= _acceleration_excess(self._ref_hist, self._ref_goal, self.dt)
            counts &= ~self._limit_off
        return np.where(counts, -self._w["limit"] * excess, 0.0)

    def _new_core(self, n: int, nthread: int) -> ArmBatch:
        """The arms the task runs on."""
        return ArmBatch(n, self.config.ik, nthread=nthread)

    def step_one(self, action):
        """step() of a task of one slot (the single env), returning what a Gymnasium env
        returns: obs (obs_dim,), reward, terminated and truncated as Python scalars, and the
        info the single env reports (distance, reward_terms, self_collision, collision_depth,
        reachable, lead, and failure when terminated): slot 0 of step()'s."""
        if self.n != 1:
            raise ValueError(f"step_one is for a task of one slot; this one has {self.n}")
        action = np.asarray(action)
        if action.size != self.action_dim:
            raise ValueError(f"action must have {self.action_dim} values, got {action.size}")
        obs, reward, terminated, truncated, info = self.step(action)
        info = {"distance": float(info["distance"][0]),
                "reward_terms": {k: float(v[0]) for k, v in info["reward_terms"].items()},
                "self_collision": bool(info["self_collision"][0]),
                "collision_depth": float(info["collision_depth"][0]),
                "reachable": bool(info["reachable"][0]), "lead": info["lead"][0].copy(),
                **({"failure": failure_of(info, 0, True)} if terminated[0] else {})}
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), info

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
        # The target camera: the IK aims at the known (old) target, moved there by a shift
        # added to what the core aims at (the core's target is the true one)
        # (noisy_ik_target: at the observed reading of it, noise and all)
        if self.config.noisy_ik_target:
            shift = self._target_reading - core.target()[0]
        elif self.config.target_delay:
            shift = self.known_target()[0] - core.target()[0]
        else:
            shift = None
        if kind == "lead":
            if self._corrector is not None:
                applied = online.corrected_action(applied, self._corrector(self),
                                           self.config.max_lead).astype(np.float64)
            if self._lead_alpha is None:
                self.lead = applied * self.config.max_lead
            else:  # a new array: info["lead"] of the last step is not written over
                goal = applied * self.config.max_lead
                lead = self.lead + self._lead_alpha * (goal - self.lead)
                self.lead = (lead if self._lead_smoothed is None
                             else np.where(self._lead_smoothed[:, None], lead, goal))
            if self._plan is not None:
                core.step(*self._plan_goal(shift))
            elif self._feedforward is not None:
                core.step(*self._feedforward_step(self.lead))
            else:
                if self._ref_hist is not None:  # limit_lead_only: the zero lead's goal first
                    aim = core.target()[0]  # (a copy: the shift may be added in place)
                    if shift is not None:
                        aim += shift
                    self._ref_goal = core.ik(aim)
                core.step(self.lead if shift is None else self.lead + shift)
        elif kind == "joint":
            core.step(lead=shift, joint_offset=applied * self.config.max_joint_offset)
        else:  # joint_target, no IK: -1 the lower limit, 0 the home pose, +1 the upper limit
            lo, hi = core.joint_limits
            home = core.home
            core.step(joint_goal=home + np.where(applied < 0, home - lo, hi - home) * applied)

    def _plan_goal(self, shift: np.ndarray | None) -> tuple:
        """EnvConfig.follow_plan's core.step arguments: the joint goal the core would command
        for the lead (the feedforward's under EnvConfig.feedforward), handed over to the plan's
        goal half a control period ahead on the followable slots
        (preview.make_planned_feedforward's law); under ik.clearance, the damper projects what
        the core would have projected (the feedforward's goal, every handed-over goal) and
        leaves the IK's own goal as the IK left it."""
        core = self.core
        if self._feedforward is not None:
            lead, offset = self._feedforward_step(self.lead)
            goal = core.ik(core.target()[0] + lead) + offset
        else:
            goal = core.ik(core.target()[0] + (self.lead if shift is None else self.lead + shift))
        w = self._handover_weight(core.time, self._handover, self._plan.followable)
        if w.any():
            row = self._plan.at(self._plan.goal, self, 0.5)
            goal = goal + w[:, None] * (row[..., 0] + row[..., 1] - goal)
        return None, None, goal, w > 0 if self._every_slot is None else self._every_slot

    def _feedforward_step(self, lead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The core's (lead, joint offset) under EnvConfig.feedforward: the IK aimed at the
        planned target tau_ik ahead plus the lead, the servo correction tau ahead added to
        its goal (preview.make_feedforward's law, the lead on top)."""
        cache, (ahead, ahead_ik, gain) = self._feedforward, self._ff_settings
        aim = cache.at(cache.pos, self, ahead_ik) - cache.at(cache.pos, self, 0.0)
        return lead + aim, gain * cache.at(cache.goal, self, ahead)[..., 1]

    def known_target(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos, vel, acc) of the target the controller knows, (N, 3) each: the true target
        of EnvConfig.target_delay steps ago (each slot's own, drawn per episode under
        random_delay; the episode's first while there is none older)."""
        core = self.core
        k = np.maximum(np.minimum(core.step_count, core.target_pos.shape[1] - 1)
                       - self.target_delay, 0)
        i = self._all
        return core.target_pos[i, k], core.target_vel[i, k], core.target_acc[i, k]

    def _observed(self, obs: np.ndarray, unstable: np.ndarray | None) -> np.ndarray:
        """What the policy sees of this step's (N, base) observations: the observation delay,
        zeros for blown-up slots (``unstable``; None when there are none), then stacking."""
        if self._delayed:
            self._obs_hist[:, 1:] = self._obs_hist[:, :-1]
            self._obs_hist[:, 0] = obs
            obs = self._obs_hist[self._all, self.obs_delay]  # (a copy: fancy indexing)
            for cols in self._undelayed_cols:  # its own actions and its hand are not late
                obs[:, cols] = self._obs_hist[:, 0, cols]
        if unstable is not None:
            obs[unstable] = 0.0  # never hand NaNs to the learner
        return self._stacked(obs)


def _distance(d: np.ndarray) -> np.ndarray:
    """|d| of each row of an (N, 3) array: np.linalg.norm(d, axis=1), which sums the squares
    in this order (checked on millions of rows), written out elementwise so that task_one.py's
    Python floats give the same numbers by construction."""
    return np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])


def _acceleration_excess(history: np.ndarray, goal: np.ndarray, dt: float) -> np.ndarray:
    """Per slot, the joints' summed acceleration excess of ``goal`` after the two goals in
    ``history`` (newest first): |second difference| / limits.JOINT_ACC - 1, clipped to [0, 1]
    per joint. Shifts ``goal`` into ``history``."""
    acc = (goal - 2 * history[:, 0] + history[:, 1]) / dt ** 2
    history[:, 1] = history[:, 0]
    history[:, 0] = goal
    return np.minimum(np.maximum(np.abs(acc) / JOINT_ACC - 1.0, 0.0), 1.0).sum(axis=1)
