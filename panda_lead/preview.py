"""What a controller that knows the planned path can do with it: the classical rivals of a lead
that sees the path ahead (issue 37). They read each arm's whole target path from its
trajectory (``task.trajs``: defined for every t >= 0, so also past the episode's end) and
none learns anything; their knobs are tuned on the tuning seeds (studies/preview_rivals.py).

- **future target**: the IK aims at the exact future target p(t + tau) instead of the
  analytic lead's Taylor guess p(t) + v tau + a tau^2 / 2 (a Cartesian lead p(t + tau) - p(t)).
- **model-based feedforward**: inverts the simulated joint servos on the desired joint path.
  The desired path q_d(t) is the IK (the core's own DLS with its posture pull, iterated to
  convergence, warm-started along the path) of the planned target path; its velocity and
  acceleration are its numerical derivatives. Each MJCF position actuator pushes
  kp (u - q) - kv qd, so the goal u that makes q_d a solution of the arm's dynamics is

      u = q_d + (M(q_d) qdd_d + c(q_d, qd_d) + d qd_d + kv qd_d) / kp

  where M qdd + c + d qd is MuJoCo's inverse dynamics (mj_inverse: the mass matrix with the
  joints' armature, the Coriolis and centrifugal forces, the joints' damping d) and kp, kv are
  read from the compiled actuators. Every link has gravcomp="1" (assets/panda.xml): gravity is
  cancelled by a passive force, which mj_inverse already subtracts, so it is not counted
  twice. The goal goes to the PD through the core's joint-goal path (action "joint_target").
  The desired angle that goal is added to is, by default, the core's own one-step IK from the
  measured arm towards p(t + tau_ik) (what the core would command, aimed ahead: it keeps the
  Cartesian feedback; on the 50 tuning seeds 3.14 cm against 3.65 for q_d alone:
  results/studies/preview/rivals_tuning.md). The correction is clipped to what each motor
  can push (its MJCF forcerange, given the damping force kv qd it must also overcome): where
  the planned path asks for more (fast circles near the workspace's edge) an unclipped goal
  only winds the PD up (2.13 cm against 2.77 on the tuning seeds).
- **the feedforward that follows its plan** (feedforward_plan): where the arm can follow the
  whole plan, its own joint goals open-loop; elsewhere the feedforward above
  (make_planned_feedforward). EnvConfig.follow_plan puts the same handover under any lead.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .core import N_JOINTS
from .online import smooth_ramp

# How many converging IK iterations the desired joint path gets per control step (warm-started
# from the previous step's solution; the first step from home gets FIRST_IK_ITERS).
PATH_IK_ITERS = 8
FIRST_IK_ITERS = 100


class _PathCache:
    """Each slot's planned path at every control step from 0 to the episode's end plus
    ``horizon_s`` seconds, recomputed for the slots whose trajectory changed (a reset). With
    ``joint_path``, also its servo goals, ``within`` (N, rows): whether each step of the plan
    asks no more than the motors can push and keeps the goal inside the joint limits, and
    ``followable`` (N,): whether every step of the episode (0 to its last) is within."""

    def __init__(self, horizon_s: float, joint_path: bool = False, clip: bool = False):
        self.horizon_s = float(horizon_s)
        self.clip = clip
        self.joint_path = joint_path
        self.trajs: list = []
        self.pos = self.goal = self.within = self.followable = None

    def update(self, task) -> None:
        n, dt = task.n, task.dt
        rows = task.config.episode_steps + 3 + int(np.ceil(self.horizon_s / dt))
        if self.pos is None or self.pos.shape[:2] != (n, rows):
            self.trajs = [None] * n
            self.pos = np.zeros((n, rows, 3))
            self.goal = np.zeros((n, rows, N_JOINTS, 2)) if self.joint_path else None
            self.within = np.ones((n, rows), dtype=bool) if self.joint_path else None
            self.followable = np.ones(n, dtype=bool) if self.joint_path else None
        stale = [i for i in range(n) if self.trajs[i] is not task.trajs[i]]
        if not stale:
            return
        times = np.arange(rows) * dt
        for i in stale:
            self.pos[i] = task.trajs[i].at(times)[0]
            self.trajs[i] = task.trajs[i]
        if self.joint_path:
            within = np.empty((len(stale), rows), dtype=bool)
            self.goal[stale] = servo_goals(task.core, self.pos, dt, self.clip, slots=stale,
                                           within=within)
            self.within[stale] = within
            self.followable[stale] = within[:, :task.config.episode_steps + 1].all(axis=1)

    def at(self, array: np.ndarray, task, offset_steps: float) -> np.ndarray:
        """Each slot's row at its step + offset_steps (linear between rows), (N, ...)."""
        k = np.minimum(task.core.step_count, array.shape[1] - 1) + offset_steps
        lo = np.minimum(np.floor(k).astype(np.int64), array.shape[1] - 1)
        hi = np.minimum(lo + 1, array.shape[1] - 1)
        w = (k - lo).reshape(-1, *([1] * (array.ndim - 2)))
        i = np.arange(array.shape[0])
        return (1 - w) * array[i, lo] + w * array[i, hi]


def desired_joint_path(core, pos: np.ndarray) -> np.ndarray:
    """(N, T, 7) joint path: the core's IK of every arm's target path pos (N, T, 3), converged
    step by step (each step warm-started from the previous step's solution)."""
    q = np.empty(pos.shape[:2] + (N_JOINTS,))
    prev = np.broadcast_to(core.home, (core.n, N_JOINTS)).copy()
    for k in range(pos.shape[1]):
        prev = core.ik(pos[:, k], q0=prev, iters=FIRST_IK_ITERS if k == 0 else PATH_IK_ITERS)
        q[:, k] = prev
    return q


def servo_goals(core, pos: np.ndarray, dt: float, clip_to_motors: bool = False,
                slots=None, within: np.ndarray | None = None) -> np.ndarray:
    """(N, T, 7, 2) PD goals that make the desired joint path of ``pos`` a solution of the
    simulated arm's dynamics (the module's formula), from MuJoCo's inverse dynamics: the path
    and the correction added to it. ``slots``: only those arms' rows (a vector env resets one
    slot at a time; the batched IK costs about the same for all, the inverse dynamics, one
    mj_inverse per arm and step, do not). ``within``: an (N, T) bool array filled with
    whether each step's unclipped goal is one the arm can follow (every motor's force inside
    its forcerange, every goal inside the joint limits)."""
    m = core.model
    q = desired_joint_path(core, pos)
    if slots is not None:
        q = q[np.asarray(slots, dtype=np.int64)]
    qd = np.gradient(q, dt, axis=1)
    qdd = np.gradient(qd, dt, axis=1)
    kp = m.actuator_gainprm[:N_JOINTS, 0]
    kv = -m.actuator_biasprm[:N_JOINTS, 2]
    force = np.empty_like(q)
    d = mujoco.MjData(m)
    for i in range(q.shape[0]):
        for k in range(q.shape[1]):
            d.qpos[:N_JOINTS], d.qvel[:N_JOINTS], d.qacc[:N_JOINTS] = q[i, k], qd[i, k], qdd[i, k]
            mujoco.mj_inverse(m, d)
            force[i, k] = d.qfrc_inverse[:N_JOINTS]
    correction = force + kv * qd
    limit = m.actuator_forcerange[:N_JOINTS, 1]
    if within is not None:
        lo, hi = core.joint_limits
        goal = q + correction / kp
        within[...] = ((np.abs(force) <= limit) & (goal >= lo) & (goal <= hi)).all(axis=-1)
    if clip_to_motors:  # no more than the motor can push: |kp (u - q) - kv qd| <= forcerange
        correction = np.clip(correction, kv * qd - limit, kv * qd + limit)
    return np.stack([q, correction / kp], axis=-1)  # (N, T, 7, 2): path, correction


def make_future_target(tau: float):
    """A Cartesian lead that aims the IK at the exact future target: p(t + tau) - p(t)."""
    cache = _PathCache(tau)

    def act(obs, task) -> np.ndarray:
        if task.config.action != "lead":
            raise ValueError("the future-target lead is a Cartesian lead: it needs action 'lead'")
        max_lead = task.config.max_lead
        if max_lead == 0:
            return np.zeros((task.n, 3), dtype=np.float32)
        cache.update(task)
        lead = cache.at(cache.pos, task, tau / task.dt) - cache.at(cache.pos, task, 0.0)
        return np.clip(lead / max_lead, -1.0, 1.0).astype(np.float32)

    return act


def make_feedforward(tau: float, gain: float = 1.0, tau_ik: float | None = 0.01,
                     clip: bool = False):
    """Joint goals = gain x (servo correction)(t + tau) plus, for the desired angle, the core's
    own one-step IK from the measured arm towards the future target p(t + tau_ik) (so the goal
    keeps the core's Cartesian feedback), or with ``tau_ik`` None the planned joint path
    q_d(t + tau) itself (pure feedforward, joint feedback only). Played as joint_target
    actions (the core's joint goal; the core's IK step is skipped, this one replaces it)."""
    goal = _feedforward_goal(tau, gain, tau_ik, clip)

    def act(obs, task) -> np.ndarray:
        if task.config.action != "joint_target":
            raise ValueError("the model-based feedforward commands joint goals: it needs "
                             "action 'joint_target'")
        return joint_target_action(task.core, goal(task))

    return act


def _feedforward_goal(tau: float, gain: float, tau_ik: float | None, clip: bool,
                      cache: _PathCache | None = None):
    """make_feedforward's joint goal (rad, (N, 7)) as a function of the task; ``cache`` (one
    with joint_path, clip as given) is shared with a caller that reads the plan too."""
    cache = cache or _PathCache(max(tau, tau_ik or 0.0), joint_path=True, clip=clip)

    def goal(task) -> np.ndarray:
        cache.update(task)
        row = cache.at(cache.goal, task, tau / task.dt)
        if tau_ik is None:
            angle = row[..., 0]
        else:
            angle = task.core.ik(cache.at(cache.pos, task, tau_ik / task.dt))
        return angle + gain * row[..., 1]

    return goal


def make_planned_feedforward(handover: tuple[float, float], fallback: dict,
                             ahead_s: float | None = None):
    """The feedforward that follows its plan: wherever the whole planned path of an episode is
    one the arm can follow (``_PathCache.within`` at every step up to the episode's end), the
    joint goal is the plan's own, q_d + (servo correction) at full gain, open-loop in Cartesian
    space (the joint PD its only feedback), taken half a control period ahead: the goal is
    held for the whole period (zero-order hold), so the plan's mid-period goal is the one it
    stands for. The episode starts in ``make_feedforward(**fallback)``'s form, which moves the
    arm from home onto the path with Cartesian feedback, and hands over to the plan by a
    smoothstep from ``handover[0]`` s over ``handover[1]`` s; a plan the arm cannot follow
    (a fast circle near the workspace's edge asks more than the motors can push) keeps the
    fallback throughout. Why: on the tuning seeds, followed from the start wherever the arm
    can, the plan settles to 0.13 cm on the median trajectory against 0.30 for the fallback
    (results/studies/preview/rivals_tuning_plan.md); where it asks for the impossible it has
    no way back to the path. ``ahead_s``:
    how far ahead the plan is read (default half a control period; tuning only)."""
    start, ramp = (float(x) for x in handover)
    if start < 0 or ramp < 0:
        raise ValueError(f"handover start and ramp must be >= 0 s, not {handover}")
    # one cache for both: clipped as the fallback asks, which changes no row of a followable
    # episode (nothing there exceeds a motor's force range)
    cache = _PathCache(max(fallback["tau"], fallback.get("tau_ik") or 0.0), joint_path=True,
                       clip=fallback.get("clip", False))
    fallback_goal = _feedforward_goal(**fallback, cache=cache)

    def act(obs, task) -> np.ndarray:
        if task.config.action != "joint_target":
            raise ValueError("the plan-following feedforward commands joint goals: it needs "
                             "action 'joint_target'")
        cache.update(task)
        row = cache.at(cache.goal, task, 0.5 if ahead_s is None else ahead_s / task.dt)
        planned = row[..., 0] + row[..., 1]
        back = fallback_goal(task)
        w = handover_weight(task.core.time, (start, ramp), cache.followable)[:, None]
        return joint_target_action(task.core, (1.0 - w) * back + w * planned)

    return act


def handover_weight(time: np.ndarray, handover: tuple[float, float],
                    followable: np.ndarray) -> np.ndarray:
    """(N,) the plan's weight in the joint goal at each slot's time: a smoothstep from
    handover[0] s over handover[1] s (a step at handover[0] when the ramp is 0), 0 where the
    plan is not followable."""
    return np.where(followable, smooth_ramp(time, *handover), 0.0)


def joint_target_action(core, goal: np.ndarray) -> np.ndarray:
    """The joint_target action whose goal is ``goal`` (task._control's map inverted: -1 the
    lower limit, 0 home, +1 the upper limit), clipped to the limits."""
    lo, hi = core.joint_limits
    home = core.home
    goal = np.clip(goal, lo, hi)
    action = np.where(goal < home, (goal - home) / (home - lo), (goal - home) / (hi - home))
    return np.clip(action, -1.0, 1.0).astype(np.float32)
