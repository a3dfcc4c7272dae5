"""`EnvConfig`: every setting of PandaLead-v0 in one typed, frozen config, and the observation
layout it selects. Sidecars store it whole; the command line sets it as ``--env.max-lead 0.1``;
presets are values of it.
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

from . import trajectory
from .errors import UserError, check_typed_fields, did_you_mean
from .ikconfig import N_JOINTS, IKConfig

OBS_FEATURES = {
    "ee_pos": 3, "ee_vel": 3, "target_pos": 3, "target_vel": 3, "target_acc": 3,
    "joint_pos": N_JOINTS, "joint_vel": N_JOINTS, "prev_action": 3, "tip_error": 3,
    "tip_error_avg": 3,
    "target_preview": 18,  # PREVIEW_POINTS future target offsets (EnvConfig.preview_times)
    "preview_jerk": 18,  # the same points as what the Taylor guess misses (see OBS_SCALE)
    "installation": 4,  # what the installation's engineer knows: latencies and noise (OBS_SCALE)
    "recent_actions": 18,  # RECENT_ACTIONS of the policy's own last actions, never delayed
    "repetitive_correction": 3,  # the in-loop lap-to-lap correction's present value (m)
    "plan_weight": 1,  # the planner's hand's share of the joint goal (EnvConfig.follow_plan)
}
# recent_actions: the policy's last actions, newest first. Under k steps of latency each way a
# lead's observation is k steps old and its action lands k steps late, so the last 2k actions
# are what the delayed system needs to be Markov again (issue 36); 2 x 3 steps at most here.
RECENT_ACTIONS = 6
# Features the controller knows rather than measures: never noisy
KNOWN_FEATURES = ("installation", "recent_actions", "repetitive_correction", "plan_weight")
# The features that show the planned path ahead: a model observing one "knows the planned path"
# (issue 37), a labelled variant never ranked with the causal ones.
PATH_FEATURES = ("target_preview", "preview_jerk")


def knows_path(env) -> bool:
    """Whether a controller on env ``env`` (an EnvConfig, a sidecar's env dict, or observation
    features alone) knows the planned path ahead: it observes a PATH_FEATURES feature, or
    its env runs the model-based feedforward (EnvConfig.feedforward), follows the plan where
    the arm can (EnvConfig.follow_plan) or runs the lap-to-lap correction
    (EnvConfig.repetitive_gain, which knows each path's lap time) with its lead."""
    if isinstance(env, dict):
        features = env.get("obs_features")
        feedforward = (env.get("feedforward", False) or env.get("follow_plan", False)
                       or env.get("repetitive_gain", 0.0))
    elif hasattr(env, "obs_features"):
        features = env.obs_features
        feedforward = env.feedforward or env.follow_plan or env.repetitive_gain
    else:
        features, feedforward = env, False
    return bool(feedforward) or any(f in PATH_FEATURES for f in features or ())


# Each feature is divided by a fixed scale so that every input of the policy is of order one
# (velocities peak near 2.5 m/s, accelerations near 30 m/s^2): a fixed scale needs no running
# statistics to save beside a model, unlike VecNormalize.
OBS_SCALE = {
    "ee_pos": 1.0, "ee_vel": 2.5, "target_pos": 1.0, "target_vel": 2.5, "target_acc": 30.0,
    "joint_pos": 1.0, "joint_vel": 2.5, "prev_action": 1.0,
    # The tip's error (tip - target) is what the lead must cancel, to millimetres. From ee_pos
    # and target_pos alone the network must subtract two inputs of order 0.5 exactly, and any
    # mismatch of the two weights is a bias that grows with the position; observed directly,
    # at a 5 cm scale, a millimetre is 0.02 of an input.
    "tip_error": 0.05,
    # A running average of the tip's error (EnvConfig.error_avg_time, clipped per axis at
    # error_avg_clip): the slow bias a memoryless policy cannot see in one error sample, what
    # a PID's integral term acts on. At a 1 cm scale a millimetre of bias is 0.1 of an input.
    "tip_error_avg": 0.01,
    # The planned path ahead (issue 37; a variant that KNOWS THE PLANNED PATH, never mixed
    # with the causal results): the target's future positions p(t + h) - p(t), h in
    # EnvConfig.preview_times; 0.3 s ahead at 2.5 m/s is 0.75 m, so 0.1 m keeps them of order 1.
    "target_preview": 0.1,
    # The same path ahead as what the present target's Taylor guess misses, per look-ahead h:
    # 6 (p(t + h) - p - v h - a h^2 / 2) / h^3, the path's mean jerk over the next h seconds
    # (m/s^3). The raw offsets span 1 mm to 0.6 m over 0.02-0.2 s (training trajectories'
    # 99.9th percentile), and what the policy cannot already read from the present target's
    # velocity and acceleration is the smallest part of them; divided by h^3 every look-ahead
    # is of one order (0.02-0.3 s, 128 training episodes of 2 s: median 15-18 m/s^3, 95th
    # percentile 185-290, 99.9th 310-640), hence a 250 m/s^3 scale.
    "preview_jerk": 250.0,
    # What an engineer knows of the installation and hands every rival (the predicting lead
    # reads the latency, the Kalman filter the sensors' noise): the slot's obs_delay,
    # action_delay and target_delay (control steps) and its target reading's noise std (cm),
    # as drawn for the episode. Known, not measured: never noisy. 0-3 steps / 0-2 cm at 3.
    "installation": 3.0,
    # The policy's own last actions (RECENT_ACTIONS, newest first), in [-1, 1] as it sent them.
    # The lead's computer knows what it sent when it sent it: unlike every other feature this
    # one skips the observation delay (and is never noisy).
    "recent_actions": 1.0,
    # The lap-to-lap correction the env adds to this step's lead (EnvConfig.repetitive_gain),
    # computed by the controller from the errors of the last lap (known, not measured): what
    # the policy's lead is added to (0 without one). Centimetres, so tip_error's scale.
    "repetitive_correction": 0.05,
    # The planner's hand's weight in this step's joint goal (EnvConfig.follow_plan): 0 where
    # the lead's goal is commanded (always, without the hand), 1 where the plan holds the arm
    # and the lead's action changes nothing. The controller's own choice, known when it is
    # made: never noisy, never late. A policy that observes it learns only from the steps its
    # action reaches the arm (training.fast_ppo: the policy loss leaves out those at 1).
    "plan_weight": 1.0,
}
PREVIEW_POINTS = 6  # target_preview's future points (its size is fixed: 3 per point)
# The observation layouts of the reference ladder (the presets build on them).
OBS_12 = ("ee_pos", "ee_vel", "target_pos", "target_vel")
OBS_15 = OBS_12 + ("target_acc",)
OBS_29 = OBS_15 + ("joint_pos", "joint_vel")
DEFAULT_OBS = OBS_15
REWARD_TERMS = ("distance", "tracking", "action", "action_change", "collision", "limit",
                "alive", "termination")
LIMIT_FROM_S = 0.5  # the limit term, as the arm's check (studies/deploy.py), skips the swing
# limit_lead_only: the paths whose peak acceleration passes this are left out of the limit
# term (no controller was accepted above 6.5 m/s^2 on 300 tuning and selection paths)
LIMIT_FEASIBLE_ACC = 10.0


def failure_label(unstable: bool) -> str:
    """The one name of each way an episode can end early (rollout files, infos and tables use
    it): a blown-up simulation, else the self-collision the config terminates on."""
    return "unstable" if unstable else "self_collision"


def failure_of(info: dict, i: int, terminated: bool) -> str | None:
    """Why episode i of a task step's ``info`` ended early (None if it did not): its label."""
    if not terminated:
        return None
    return failure_label(bool(info["unstable"][i]))


ACTIONS = {"lead": 3, "joint": N_JOINTS, "joint_target": N_JOINTS}
# Settings that are mappings: a command line sets some of their keys (EnvConfig.merged).
MAPPINGS = ("obs_noise", "ik")
MAX_REWARD_WEIGHT = 1e6
MAX_EPISODE_STEPS = 100_000  # 1,000 s: beyond it an episode's precomputed path is a typo


def action_dim(action: str) -> int:
    """The action's size: a 3-D Cartesian lead, or one value per joint."""
    return ACTIONS[action]


def check_features(features) -> tuple[str, ...]:
    """Validate a feature selection and put it in the canonical order."""
    try:  # a hand-edited sidecar may hold 5 or null here
        features = (features,) if isinstance(features, str) else tuple(features)
    except TypeError:
        raise UserError(f"obs_features must be a list of feature names, not {features!r}"
                        ) from None
    for f in features:
        if not isinstance(f, str):
            raise UserError(f"obs_features must be a list of feature names, not {f!r} in it")
        if f not in OBS_FEATURES:
            raise UserError(f"unknown observation feature {f!r}" + did_you_mean(f, OBS_FEATURES))
    if not features:
        raise UserError("the observation needs at least one feature")
    return tuple(f for f in OBS_FEATURES if f in features)


def check_preview_times(times) -> tuple[float, ...]:
    """PREVIEW_POINTS increasing look-aheads in (0, 1] s, as a tuple of floats."""
    try:
        times = tuple(float(t) for t in times)
    except (TypeError, ValueError):
        raise UserError(f"preview_times must be {PREVIEW_POINTS} numbers of seconds, got "
                        f"{times!r}") from None
    if (len(times) != PREVIEW_POINTS or not all(0 < t <= 1 for t in times)
            or any(b <= a for a, b in zip(times, times[1:], strict=False))):
        raise UserError(f"preview_times must be {PREVIEW_POINTS} increasing look-aheads in "
                        f"(0, 1] s, got {list(times)}")
    return times


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
    w_limit: float = 0.0
    """Weight of -(the commanded joint goals' acceleration over the Panda's limit), per joint
    the excess (|second difference of the 100 Hz goals| / limits.JOINT_ACC - 1) clipped to
    [0, 1] and summed, from 0.5 s on (the swing from home is left out, as the arm's check
    leaves it). Saturating: a path no controller can run within the limits pushes no gradient;
    one near them is pushed under."""
    limit_lead_only: bool = False
    """Charge w_limit's term for what the lead changes, and only where a Panda could run the path
    at all: per joint, the excess of the commanded goals minus the excess of the goals the IK
    would command with a zero lead (a second IK solve each step, from the same measured angles
    at the same aim point), on paths whose peak acceleration is at most LIMIT_FEASIBLE_ACC;
    zero elsewhere. The plain term is mostly out of the lead's reach: under 1 cm of noise the
    IK chasing the noisy target jitters every controller's goals far over the limits (an excess
    of ~590 a 2 s episode against ~40 without), and on 300 tuning and selection paths no
    controller was accepted on one whose peak acceleration passed 6.5 m/s^2 (docs/deploy.md).
    A lead that calms the goals below the zero lead's earns the difference back."""
    w_alive: float = 0.0
    """Bonus per step."""
    w_termination: float = 0.0
    """Penalty on the step that terminates (self-collision when terminating on it, instability)."""
    terminate_on_collision: bool = False
    """End the episode (terminated) on a self-collision."""
    obs_noise: dict[str, float] = field(default_factory=dict)
    """Gaussian noise std per observation feature, in the feature's unit (m, m/s, m/s^2, rad);
    tip_error (and tip_error_avg's input) is the tip reading minus the target reading, so it
    carries ee_pos's and target_pos's noise (docs/env.md)."""
    ik: IKConfig = field(default_factory=IKConfig)
    """The classical IK's settings (core.IKConfig): --env.ik.damping, --env.ik.clearance, ..."""
    obs_delay: int = 0
    """Observation latency in control steps (10 ms each): the policy sees the state of k steps ago."""
    action_delay: int = 0
    """Action latency in control steps: the lead applied now is the action chosen k steps ago."""
    random_delay: bool = False
    """Draw each episode's delays uniformly from 0..obs_delay and 0..action_delay (and
    0..target_delay when that is set)."""
    target_delay: int = 0
    """The target camera: the target the controller knows is k control steps old, for the IK's
    aim point and for every target feature observed (target_*, the tip error and its average,
    the preview), for every controller, the classical one included. Tracking is still measured
    against the true target. (obs_delay and action_delay instead delay the lead's channel.)"""
    random_noise: bool = False
    """Scale each episode's observation noise (obs_noise, every channel alike) by a factor drawn
    uniformly from [0, 1]: training over every noise level up to obs_noise's, from none."""
    nominal_share: float = field(default=0.0, metadata={"range": (0.0, 1.0)})
    """Under random_delay / random_noise: the share of episodes drawn as the nominal
    installation, no delay and no noise. Drawn uniformly, three delays of 0-3 steps are all
    zero in 1 episode of 64: the condition the arm is most often run in is the one training
    sees least."""
    split_conditions: bool = False
    """Under random_delay and random_noise: each episode not drawn nominal is delayed only,
    noisy only, or both, with equal odds, instead of always both. The deployment table's rows
    test latency without noise and noise without latency; drawn together, latency without
    noise reaches the policy only in the episodes whose noise factor happens to be near zero."""
    noisy_ik_target: bool = False
    """The IK aims at the target as measured: the latest observation's (noisy) target_pos
    reading, not the true target, so that observation noise reaches the classical controller
    too (one tracker measures the target for everything). Needs target_pos observed."""
    target_filter: bool = False
    """The tracker's Kalman filter on the target readings (panda_lead/kalman.py, the filtered
    analytic lead's own, tuned on the tuning seeds): the observed target_pos, target_vel and
    target_acc are its estimates, the tip error is the tip reading minus the estimated
    position, and under noisy_ik_target the IK aims at the estimate. Its gain is set by
    obs_noise (the installation's sensors; under random_noise, their full level); with no
    noise it passes the readings through. tip_error_avg keeps averaging the raw measured
    error (the average is a filter of its own). Needs the three target features observed."""
    arm_filter: bool = False
    """The same Kalman filter on the tip's readings (panda_lead/kalman.py, position and
    velocity measured, acceleration not): the observed ee_pos and ee_vel are its estimates and
    the tip error is the estimated tip minus the target (reading or, with target_filter, its
    estimate). The IK reads the joints, not these, so only what a lead observes changes. Its
    gain is set by obs_noise as target_filter's; with no noise it passes the readings
    through. Needs ee_pos and ee_vel observed."""
    feedforward: bool = False
    """The model-based feedforward rival under the lead (issue 37; knows the planned path):
    the IK aims FEEDFORWARD_TAU_IK ahead on the planned path plus the lead, and the joint goal
    gets the servo correction of the planned joint path FEEDFORWARD_TAU ahead
    (controllers.make_feedforward's settings, tuned on the tuning seeds). With a zero lead
    this is the feedforward rival; a policy on it learns a residual. Needs action "lead"; not
    with target_delay or noisy_ik_target (the plan is known, not measured)."""
    follow_plan: bool = False
    """The planner's hand (issue 37; knows the planned path): an episode whose whole planned
    path the arm can follow (no motor asked for more than its force range, no goal past a
    joint limit: preview._PathCache.within) hands its joint goal over from the lead's to the
    plan's own (the feedforward's planned joint path and servo correction, read half a control
    period ahead), by a smoothstep over controllers.PLAN_HANDOVER; an episode the arm cannot
    follow keeps the lead throughout. With a zero lead on the feedforward env this is the
    feedforward_plan rival. Under ik.clearance the plan is the collision-aware IK's path and
    every handed-over goal passes the damper. Needs action "lead"; not with ik.substep_ik or
    limit_lead_only."""
    repetitive_gain: float = field(default=0.0, metadata={"range": (0.0, 2.0)})
    """The lap-to-lap (repetitive) correction in the loop, added to the policy's lead each
    control step (panda_lead/online.py, the law studies/online_correction.py plays on top of a
    trained lead): c(t) = Q[c(t - T) + k e(t - T + advance)] with this gain k, T each path's
    lap time (so it knows the planned path). A policy trained with it learns the lead that
    works beside it. Needs action "lead" and the world without noise or latency. 0: none."""
    repetitive_advance: int = field(default=15, metadata={"range": (0, 50)})
    """The in-loop repetitive correction's phase lead (control steps; repetitive_gain > 0)."""
    repetitive_smooth: int = field(default=0, metadata={"range": (0, 20)})
    """The in-loop repetitive correction's low-pass half-width (control steps)."""
    lead_filter_hz: float = field(default=0.0, metadata={"range": (0.0, 1000.0)})
    """A first-order low-pass on the applied lead, in the loop (cutoff in Hz; 0: none), like
    libfranka's 100 Hz filter on the robot's commands but on the lead alone: the lead moves
    1 - exp(-2 pi f dt) of the way to the action's each control step (from 0 at reset), so a
    policy trained with it learns to act through it."""
    noisy_lead_filter_hz: float = field(default=0.0, metadata={"range": (0.0, 1000.0)})
    """The same low-pass on the lead, in the episodes whose sensors are noisy only (obs_noise
    non-zero; under random_noise, the episodes not drawn noise-free); where the readings are
    exact the lead passes unfiltered, bit for bit. A gain scheduled on the installation's
    noise, as the tracker's Kalman gain is (target_filter): a noisy camera's lead is smoothed,
    an exact one's is not delayed. A trade under noise (precision for calm; `studies/deploy.py
    --tune-lead-filter` prints a model's frontier); not with lead_filter_hz. 0: none."""
    preview_times: tuple[float, ...] = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3)
    """The `target_preview` observation's look-aheads (s; 6 increasing, in (0, 1]): it holds
    the target's future positions p(t + h) - p(t), what a controller that knows the planned
    path sees (a labelled variant: "knows the planned path")."""
    obs_stack: int = field(default=1, metadata={"range": (1, 16)})
    """Observe the last k observations, newest first (frame stacking inside the env; the
    observation is k times as long); 1: the current one only."""
    reward_after_s: float = field(default=0.0, metadata={"range": (0.0, 10.0)})
    """The distance and tracking terms count only from this time on (s): 0.5 rewards settled
    tracking alone (the swing from the home pose is no lead's to improve); 0: every step."""
    action: Literal["lead", "joint", "joint_target"] = "lead"
    """lead: the action is a Cartesian lead added to the IK target (3-D); joint: a residual
    added to the IK's joint goal (7-D, one per joint; it can move the elbow, a lead cannot);
    joint_target: the joint goals themselves (7-D, no IK at all; -1 is a joint's lower limit,
    0 its home angle, +1 its upper limit, linear in between)."""
    max_joint_offset: float = 0.2
    """With action "joint": the joint-goal offset (rad) at action +-1."""
    error_avg_time: float = field(default=0.3, metadata={"range": (0.01, 100.0)})
    """Time constant (s) of the `tip_error_avg` observation: each step it moves dt/this of
    the way towards the newest (clipped) tip error; 0 at the start of an episode."""
    error_avg_clip: float = field(default=0.02, metadata={"range": (1e-4, 1.0)})
    """Per-axis clip (m) of the tip error fed to `tip_error_avg`, so that the swing from the
    home pose (tens of cm) does not fill the average for seconds."""
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
        for known in KNOWN_FEATURES:
            if known in self.obs_noise:
                raise UserError(f"obs_noise: the {known} feature is known, not measured: it "
                                "takes no noise")
        set_("obs_noise", {f: float(v) for f, v in self.obs_noise.items()})
        set_("preview_times", check_preview_times(self.preview_times))
        set_("ik", IKConfig.from_dict(self.ik))
        check_typed_fields(self)
        for name in REWARD_TERMS:  # bounded: a weight of 1e308 makes every loss infinite
            w = getattr(self, f"w_{name}")
            if abs(w) > MAX_REWARD_WEIGHT:
                raise UserError(f"w_{name} must be within +-{MAX_REWARD_WEIGHT:g}, got {w!r}")
        if self.max_lead < 0:
            raise UserError(f"max_lead must be >= 0, got {self.max_lead}")
        if not 1 <= self.episode_steps <= MAX_EPISODE_STEPS:
            raise UserError(f"episode_steps must be 1..{MAX_EPISODE_STEPS:,}, got "
                            f"{self.episode_steps}")
        if not (0 <= self.obs_delay <= 50 and 0 <= self.action_delay <= 50):
            raise UserError(f"obs_delay and action_delay must be 0..50 steps, got "
                            f"{self.obs_delay}, {self.action_delay}")
        if self.noisy_ik_target and "target_pos" not in self.obs_features:
            raise UserError("noisy_ik_target aims the IK at the observed target_pos reading: "
                            "observe target_pos")
        if self.target_filter and not {"target_pos", "target_vel", "target_acc"} <= set(
                self.obs_features):
            raise UserError("target_filter estimates the target from its position, velocity and "
                            "acceleration readings: observe target_pos, target_vel and target_acc")
        if self.arm_filter and not {"ee_pos", "ee_vel"} <= set(self.obs_features):
            raise UserError("arm_filter estimates the tip from its position and velocity "
                            "readings: observe ee_pos and ee_vel")
        if self.limit_lead_only and not (self.w_limit and self.action == "lead"
                                         and not self.feedforward and not self.ik.substep_ik):
            raise UserError("limit_lead_only charges w_limit's term for what the lead changes: "
                            "it needs w_limit > 0, action 'lead', no feedforward and no "
                            "ik.substep_ik")
        if self.nominal_share and not (self.random_delay or self.random_noise):
            raise UserError("nominal_share is the share of randomised episodes drawn nominal: "
                            "it needs random_delay or random_noise")
        if self.split_conditions and not (self.random_delay and self.random_noise):
            raise UserError("split_conditions draws an episode's latency and noise apart: it "
                            "needs random_delay and random_noise")
        if self.feedforward and (self.action != "lead" or self.target_delay
                                 or self.noisy_ik_target):
            raise UserError("feedforward puts the feedforward rival under a Cartesian lead: "
                            "it needs action 'lead', and no target_delay or noisy_ik_target")
        if self.follow_plan and (self.action != "lead" or self.ik.substep_ik
                                 or self.limit_lead_only):
            raise UserError("follow_plan hands a Cartesian lead's joint goal over to the plan: "
                            "it needs action 'lead', and no ik.substep_ik or limit_lead_only")
        if self.repetitive_gain and (
                self.action != "lead" or any(self.obs_noise.values()) or self.obs_delay
                or self.action_delay or self.target_delay or self.random_delay
                or self.random_noise or self.noisy_ik_target):
            raise UserError("repetitive_gain runs the lap-to-lap correction on the true tip and "
                            "target: it needs action 'lead' and no noise or latency")
        if not 0 <= self.target_delay <= 50:
            raise UserError(f"target_delay must be 0..50 steps, got {self.target_delay}")
        if self.action not in ACTIONS:
            raise UserError(f"unknown action {self.action!r}" + did_you_mean(self.action, ACTIONS))
        if self.action != "lead" and "recent_actions" in self.obs_features:
            raise UserError("recent_actions holds 3-D leads; it cannot be observed with "
                            f"action {self.action!r}")
        if self.action != "lead" and "prev_action" in self.obs_features:
            raise UserError("prev_action is a 3-D lead feature; it cannot be observed with "
                            f"action {self.action!r}")
        if self.max_joint_offset < 0:
            raise UserError(f"max_joint_offset must be >= 0, got {self.max_joint_offset}")
        if self.max_peak_speed is not None:
            cap = self.max_peak_speed
            if isinstance(cap, bool) or not isinstance(cap, int | float) or not cap > 0.25:
                raise UserError(f"max_peak_speed must be a speed above 0.25 m/s, got {cap!r}")
            set_("max_peak_speed", float(cap))
        if self.lead_filter_hz and self.noisy_lead_filter_hz:
            raise UserError("lead_filter_hz filters the lead always, noisy_lead_filter_hz under "
                            "noise only: set one of them")
        if self.tracking_scale <= 0:
            raise UserError(f"tracking_scale must be > 0, got {self.tracking_scale}")

    @classmethod
    def from_dict(cls, settings: dict) -> EnvConfig:
        """From a sidecar or keyword arguments; an unknown name is one clear error. Sidecars
        written before the IK settings were nested (ik_iters, ik_clearance) read the same."""
        if not isinstance(settings, dict):
            raise UserError(f"env settings must be a mapping, got {type(settings).__name__}")
        settings = dict(settings)
        legacy = {k[3:]: settings.pop(k) for k in ("ik_iters", "ik_clearance") if k in settings}
        if legacy:
            ik = settings.get("ik", {})
            ik = dataclasses.asdict(ik) if isinstance(ik, IKConfig) else ik
            settings["ik"] = {**legacy, **ik} if isinstance(ik, dict) else ik
        names = [f.name for f in dataclasses.fields(cls)]
        for k in settings:
            if k not in names:
                raise UserError(f"unknown env setting {k!r}" + did_you_mean(k, names))
        return cls(**settings)

    def replace(self, **changes) -> EnvConfig:
        """A copy with ``changes``, each replacing the setting whole."""
        return self.from_dict({**self.to_dict(), **changes})

    def without_correction(self) -> EnvConfig:
        """This env without the in-loop lap-to-lap correction (repetitive_gain 0, its feature
        no longer observed): where a baseline plays, or the oracle replays corrected leads."""
        if not self.repetitive_gain:
            return self
        return self.replace(repetitive_gain=0.0, obs_features=tuple(
            f for f in self.obs_features if f != "repetitive_correction"))

    def merged(self, overrides: dict) -> EnvConfig:
        """A copy with ``overrides`` applied the way a command line means them: a mapping
        setting (obs_noise, ik) gets the keys given and keeps its others; the rest replace."""
        d = self.to_dict()
        for k, v in overrides.items():
            d[k] = {**d[k], **v} if k in MAPPINGS and isinstance(v, dict) else v
        return self.from_dict(d)

    def to_dict(self) -> dict:
        """JSON-friendly (lists for tuples): what sidecars and config.json hold."""
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


@cache
def config_docs(cls=None) -> dict[str, str]:
    """Each field's docstring (the string under it) of a config class (default EnvConfig),
    read from the source."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls or EnvConfig)))
    body, docs = tree.body[0].body, {}
    for a, b in zip(body, body[1:], strict=False):
        documented = isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant)
        if isinstance(a, ast.AnnAssign) and documented:
            docs[a.target.id] = " ".join(str(b.value.value).split())
    return docs


def arguments_table() -> str:
    """The env docstring's arguments table, made from EnvConfig (so it cannot drift); a nested
    config's fields get a row each (ik.damping, ...)."""
    rows = ["| name | type | default | meaning |", "|---|---|---|---|"]

    def add(cls, defaults, prefix: str) -> None:
        docs = config_docs(cls)
        for f in dataclasses.fields(cls):
            value = getattr(defaults, f.name)
            if dataclasses.is_dataclass(value):
                add(type(value), value, f"{prefix}{f.name}.")
                continue
            cells = (prefix + f.name, str(f.type), repr(value), docs[f.name])
            rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")

    add(EnvConfig, EnvConfig(), "")
    return "\n".join(rows)


def as_config(config: EnvConfig | dict | None, overrides: dict) -> EnvConfig:
    if config is None:
        return EnvConfig.from_dict(overrides)
    base = config if isinstance(config, EnvConfig) else EnvConfig.from_dict(config)
    return base.replace(**overrides) if overrides else base
