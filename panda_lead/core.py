"""The IK+PD core, batched: N Panda arms in one `mujoco.batch.Batch`, one control law for all.

Every controller in this repo runs on `ArmBatch`: damped-least-squares IK on the tip site's
position Jacobian, warm-started from the measured joint angles, feeding MuJoCo position
actuators (a joint PD at the 500 Hz physics rate) with gravity compensation on every link.
The classical controller is this core with a zero lead; the analytic-lead baseline adds
``v*tau + a*tau^2/2``; the learned policy adds its own lead. Nothing else differs.

Why batched: MuJoCo's Batch steps all N simulations on its own threads with the GIL released,
and the IK below is a handful of numpy calls over (N, 3, 7) arrays, so one process keeps every
core busy and the per-env Python cost is paid once per batch, not once per env. Batch steps
each simulation exactly as a loop of mj_step would, at any thread count, and the numpy maths
is row by row, so an arm's episode is the same whether it runs alone (N=1) or among many.

Why IK runs once per control step (100 Hz) and not at 500 Hz: the IK target only changes when
the lead (an action) or the sampled target changes, both at the control rate; between those
the PD converges on the joint goal. One DLS iteration from the measured angles is the default.

Call order per control step (`ArmBatch.step`): IK from the current kinematics -> write the
joint goals to ctrl -> `Batch.rollout` of the substeps, recording the contact sensors after
each substep (so a touch in any substep counts) -> `Batch.jac` at the state the step ends in,
which runs only the kinematics (a `forward(stage=POS)` would also redo collision detection and
the mass matrix, which the next substep recomputes anyway: 3-5 us per arm, measured), and
`forward(stage=NONE)` to copy those kinematics into the bound tip position -> move the target
marker. The Jacobian is taken at the old tip and moved to the new one exactly (J_p(b) =
J_p(a) - [b - a]x J_r), so the next IK needs no kinematics of its own.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
from dataclasses import dataclass, field
from functools import cache
from operator import itemgetter, sub
from pathlib import Path

import mujoco  # (panda_lead/__init__.py chose the GL backend before this first import)
import mujoco.batch
import numpy as np

from .clearance import Clearance
from .errors import UserError, check_typed_fields, did_you_mean
from .paths import shipped

ASSETS = shipped("assets")
SCENE_XML = ASSETS / "scene.xml"
N_JOINTS = 7
CONTROL_SUBSTEPS = 5  # physics steps per control step: 500 Hz physics (MJCF timestep), 100 Hz control


def _mesh_assets() -> dict[str, bytes]:
    """Franka link meshes from the gymnasium-robotics package (no mesh is copied into this repo)."""
    spec = importlib.util.find_spec("gymnasium_robotics")  # locate without importing it
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("gymnasium-robotics is not installed; run `uv sync`")
    root = Path(spec.submodule_search_locations[0])
    meshes = root / "envs" / "assets" / "kitchen_franka" / "franka_assets" / "meshes"
    files = {f"link{i}.stl": meshes / "visual" / f"link{i}.stl" for i in range(8)}
    files["hand.stl"] = meshes / "visual" / "hand.stl"
    files["finger.stl"] = meshes / "collision" / "finger.stl"
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise RuntimeError(f"Franka meshes not found in gymnasium-robotics: {missing[0]}")
    return {name: path.read_bytes() for name, path in files.items()}


@cache
def load_model() -> mujoco.MjModel:
    """The scene with the Panda, compiled once per process (compiling the meshes takes ~0.3 s)."""
    return mujoco.MjModel.from_xml_path(str(SCENE_XML), _mesh_assets())


@cache
def home_qpos() -> np.ndarray:
    """The arm's home pose: the MJCF keyframe "home" (Franka's ready pose)."""
    m = load_model()
    q = m.key("home").qpos[:N_JOINTS].copy()
    q.flags.writeable = False
    return q


def control_dt(substeps: int = CONTROL_SUBSTEPS) -> float:
    """Seconds per control step: the MJCF physics timestep times the substeps."""
    return float(load_model().opt.timestep) * substeps


def analytic_lead(vel: np.ndarray, acc: np.ndarray, tau: float, max_lead: float) -> np.ndarray:
    """Second-order extrapolation of the target over tau seconds, clipped like the RL lead."""
    return np.clip(vel * tau + 0.5 * acc * tau * tau, -max_lead, max_lead)


@dataclass(frozen=True)
class IKConfig:
    """The classical controller's IK, every knob of it (EnvConfig.ik; ``--env.ik.damping``)."""

    damping: float = field(default=0.05, metadata={"range": (0.0, 10.0)})
    """DLS damping lambda (m): keeps steps finite near singularities and out-of-reach targets."""
    iters: int = field(default=1, metadata={"range": (1, 100)})
    """DLS iterations per IK solve, each from the last (the first from the measured angles)."""
    nullspace_gain: float = field(default=0.1, metadata={"range": (0.0, 1.0)})
    """Pull towards the home posture in the Jacobian's null space, so the elbow does not drift."""
    max_step: float = field(default=0.5, metadata={"range": (1e-6, 10.0)})
    """Largest joint change per iteration (rad, infinity norm)."""
    limit_margin: float = field(default=0.02, metadata={"range": (0.0, 0.5)})
    """Joint goals stay this far (rad) inside the joint limits."""
    clearance: float = field(default=0.0, metadata={"range": (0.0, 0.2)})
    """Collision-aware IK: keep the arm's collision capsules this far apart (m; e.g. 0.02) by a
    velocity damper on the IK step (clearance.py); 0: off, the plain IK. Needs iters 1."""
    substep_ik: bool = False
    """Solve the IK before every physics substep (500 Hz) on the target at that instant, the
    lead held over the control step, instead of once per control step (100 Hz): the reference
    work's rate, for an apples-to-apples baseline. Five times the IK work per step."""

    def __post_init__(self):
        check_typed_fields(self, "ik.")
        if self.clearance > 0 and self.iters != 1:
            raise UserError(f"ik.clearance needs ik.iters 1, got clearance {self.clearance} "
                            f"with iters {self.iters}")

    @classmethod
    def from_dict(cls, settings) -> IKConfig:
        if isinstance(settings, IKConfig):
            return settings
        if not isinstance(settings, dict):
            raise UserError(f"ik must be a mapping of IK settings, got {settings!r}")
        names = [f.name for f in dataclasses.fields(cls)]
        for k in settings:
            if k not in names:
                raise UserError(f"unknown IK setting {k!r}" + did_you_mean(k, names))
        return cls(**settings)


_STAGE_NONE = mujoco.mjtStage.mjSTAGE_NONE
# The cross-product matrix [r]x, flattened: entries (0,1) (0,2) (1,2) (1,0) (2,0) (2,1) hold
# -r2, r1, -r0, r2, -r1, r0.
_SKEW_AT = np.array([1, 2, 5, 3, 6, 7])
_SKEW_OF = np.array([2, 1, 0, 2, 1, 0])
_SKEW_SIGN = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])
# Sensor layout (assets/scene.xml): self_contact (found, mindist), floor_contact (found).
_SELF_FOUND, _SELF_DIST, _FLOOR_FOUND = 0, 1, 2
_UNSTABLE_WARNINGS = [int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS,
                                       mujoco.mjtWarning.mjWARN_BADQVEL,
                                       mujoco.mjtWarning.mjWARN_BADQACC,
                                       mujoco.mjtWarning.mjWARN_BADCTRL)]
_unstable_of = itemgetter(*_UNSTABLE_WARNINGS)  # those four of a list of all the counters
_POSITIVE = (0.0).__lt__  # x > 0 as a function (False for a NaN, as the comparison)
_TRUE1, _FALSE1 = np.ones(1, dtype=bool), np.zeros(1, dtype=bool)  # (copied, never handed out)
# What _substeps_one saves before a control step, to replay it on the rare path: every input
# of mj_step (time, qpos, qvel, warm start, ctrl, applied forces, mocap, sensor history, ...).
_SAVED_STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION)


try:  # the gufunc np.linalg.solve calls, which solves each matrix of a stack with LAPACK
    from numpy.linalg._umath_linalg import solve as _solve_gufunc
except ImportError:  # (a private name: should numpy move it, the public function does)
    _solve_gufunc = None


def _solve_unchecked(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> np.ndarray:
    """_solve without the check for a singular or non-finite system (see _ik_list), into
    ``out``."""
    if _solve_gufunc is None:
        out[...] = np.linalg.solve(a, b)
        return out
    return _solve_gufunc(a, b, out=out)  # (float64 operands: its float64 loop, as solve's)


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.linalg.solve(a, b) for float64 stacks, the same numbers, without its Python-level
    checks: for one arm they cost more than the solve (about half the IK's numpy overhead).
    A singular or non-finite system goes through np.linalg.solve itself, which raises
    LinAlgError for a singular one as ik() does (after a RuntimeWarning from the first try)."""
    if _solve_gufunc is None:
        return np.linalg.solve(a, b)
    x = _solve_gufunc(a, b, signature="dd->d")
    if not math.isfinite(np.add.reduce(x, axis=None)):
        return np.linalg.solve(a, b)
    return x


class _Deferred:
    """An attribute (an array) that a single env's step leaves to be made when first read:
    stored in ``_<name>``, made by the method ``make`` while the attribute ``pending`` is not
    None (a set makes it first too, so that nothing pending is lost). ArmBatch's flags and
    q_goal (made from what step_one leaves), LeadTask's prev_action, lead and ee_vel (from
    what its step_one leaves): a single env reads the Python values these steps return."""

    def __init__(self, pending: str, make: str):
        self._pending, self._make = pending, make

    def __set_name__(self, owner, name: str) -> None:
        self._attr = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        if getattr(obj, self._pending) is not None:
            getattr(obj, self._make)()
        return obj.__dict__[self._attr]

    def __set__(self, obj, value) -> None:
        if getattr(obj, self._pending) is not None:
            getattr(obj, self._make)()
        obj.__dict__[self._attr] = value


class ArmBatch:
    """N Pandas and their controller: ``step(lead)`` is one 100 Hz control step of all of them.

    State is per arm, in (N, ...) arrays: ``tip_pos``, ``qpos``, ``qvel`` (live views, updated
    in place by each step: copy to keep), ``step_count``, and after each step the flags
    ``self_collision``, ``collision_depth`` (m), ``floor_contact`` and ``unstable``. Each arm
    plays its own target path, precomputed at its reset (positions, velocities, accelerations
    at every control step), so a step does no trajectory maths.
    """

    self_collision = _Deferred("_pending_flags", "_make_flags")
    collision_depth = _Deferred("_pending_flags", "_make_flags")
    floor_contact = _Deferred("_pending_flags", "_make_flags")
    unstable = _Deferred("_pending_flags", "_make_flags")
    q_goal = _Deferred("_pending_goal", "_make_goal")

    def __init__(self, n: int, ik: IKConfig = IKConfig(), substeps: int = CONTROL_SUBSTEPS,
                 nthread: int = 0):
        if n < 1:
            raise ValueError(f"an ArmBatch needs at least one arm, got n={n}")
        self.model = m = load_model()
        self.n = n
        self._pending_flags = self._pending_goal = None  # (see _Deferred)
        self.ik_config = ik
        self.substeps = int(substeps)
        self.dt = control_dt(self.substeps)
        self._home_key = m.key("home").id
        self._tip = m.site("tip").id
        self._tip_body = int(m.site_bodyid[self._tip])
        self._lo = m.jnt_range[:N_JOINTS, 0] + ik.limit_margin
        self._hi = m.jnt_range[:N_JOINTS, 1] - ik.limit_margin
        self._home = home_qpos()
        self._damp3 = np.eye(3) * ik.damping**2
        self._eps3 = np.eye(3) * 1e-10
        self._regularisers = np.stack([self._damp3, self._eps3])  # (2, 3, 3), see ik()
        self._lo_list, self._hi_list = self._lo.tolist(), self._hi.tolist()  # for _ik_list
        self._home_list = self._home.tolist()
        self._rhs = np.zeros((n, 2, 3, 1))
        self._rhs_err = self._rhs[:, 0, :, 0]
        self._rhs_err_row = self._rhs_err[0]  # arm 0's, for _ik_list
        self._rhs_pull = self._rhs[0, 1:2]  # (1, 3, 1): J times the pull, for _ik_list
        mocap = m.body("target").mocapid[0]
        # One arm (the single env) runs on a plain MjData stepped by mj_step: Batch documents
        # itself bit-identical to exactly that loop, and its per-call costs (argument checks,
        # handing the call to its thread pool, copying the bound fields out) were the largest
        # part of a single env's step (a one-arm Batch.jac: ~25 us, mj_jac itself: ~3 us).
        # The collision-aware IK reads the batch's bound kinematics, so it keeps the batch.
        if n == 1 and ik.clearance == 0:
            self.batch = None
            self._data = d = mujoco.MjData(m)
            # (1, ...) views of the MjData: the same shapes as a batch's, always current.
            self.qpos = d.qpos[None, :N_JOINTS]
            self.qvel = d.qvel[None, :N_JOINTS]
            self._ctrl = d.ctrl[None]
            self._mocap = d.mocap_pos[None, mocap]
            self.tip_pos = d.site_xpos[None, self._tip]
            self._warning_number = d.warning.number  # live view of the warning counters
            self._jacp = np.zeros((1, 3, m.nv))
            self._jacr = np.zeros((1, 3, m.nv))
            self._jacp_row, self._jacr_row = self._jacp[0], self._jacr[0]
            # Row views made once for step_one: every MjData attribute access builds a new
            # array object (about 0.1 us each, a few dozen per step).
            self._sensordata = d.sensordata
            self._qpos_row, self._ctrl_row = d.qpos[:N_JOINTS], d.ctrl[:N_JOINTS]
            self._ctrl_goal = self._ctrl[:, :N_JOINTS]
            self._tip_row, self._mocap_row = d.site_xpos[self._tip], d.mocap_pos[mocap]
            # Operands and outputs of _ik_list's numpy calls, made once. The posture pull is
            # written into a column; J^T times each system's solution into a buffer whose flat
            # view gives the 14 numbers in one cheap tolist() (a contiguous buffer of the
            # result's shape is what the call would allocate: the same numbers).
            self._pull_col = np.zeros((1, N_JOINTS, 1))
            self._pull_flat = self._pull_col.reshape(-1)
            self._steps = np.zeros((2, N_JOINTS, 1))
            self._jjt2, self._systems = np.zeros((2, 3, 3)), np.zeros((2, 3, 3))
            self._solutions = np.zeros((2, 3, 1))
            self._moved = np.zeros((1, 3, m.nv))  # [b - a]x J_r (_end_of_step_kinematics)
            self._steps_flat = self._steps.reshape(-1)
            # For _substeps_one: the state saved before each control step; the warning
            # counters with their last-info words, as one int32 view of MuJoCo's
            # {lastinfo, number} records (saved and compared as bytes); the sensor history
            # (assets/scene.xml: nsample = the substeps), used when it holds one control step.
            self._saved = np.zeros(mujoco.mj_stateSize(m, _SAVED_STATE))
            lastinfo = d.warning.lastinfo
            self._warning_raw = np.lib.stride_tricks.as_strided(
                lastinfo, (2 * len(lastinfo),), (lastinfo.itemsize,))
            self._history = d.history
            nsample, adr = m.sensor_history[:, 0], m.sensor_historyadr
            self._history_rows = bool((nsample == self.substeps).all()) and m.nsensor == 2
            if self._history_rows:  # where each contact sensor's values start in d.history
                self._history_at = [int(a) + 2 + int(k) for a, k in zip(adr, nsample, strict=True)]
        else:
            self._data = None
            self.batch = b = mujoco.batch.Batch(m, nsim=n, nthread=nthread, persistent=True)
            # Live (N, ...) views into the batch (bound once; the batch never moves them).
            self.qpos = b.bind("qpos")[:, :N_JOINTS]
            self.qvel = b.bind("qvel")[:, :N_JOINTS]
            self._ctrl = b.bind("ctrl")
            self._mocap = b.bind("mocap_pos")[:, mocap]
            self.tip_pos = b.bind("site_xpos")[:, self._tip]
        self._contacts = {"sensordata": np.zeros((n, self.substeps, m.nsensordata))}
        self._arange = np.arange(n)
        self.step_count = np.zeros(n, dtype=np.int64)
        self.self_collision = np.zeros(n, dtype=bool)
        self.collision_depth = np.zeros(n)
        self.floor_contact = np.zeros(n, dtype=bool)
        self.unstable = np.zeros(n, dtype=bool)
        self.q_goal = np.tile(self._home, (n, 1))
        # Collision-aware IK binds more kinematics (copied out after every batch call), so
        # only when it is on.
        self._clearance = (Clearance(m, self.batch, N_JOINTS, ik.clearance) if ik.clearance > 0
                           else None)
        self._skew = np.zeros((n, 3, 3))  # cross-product matrices, rewritten every step
        self._skew_flat = self._skew[0].reshape(9)  # arm 0's, flat (one arm: one assignment)
        # The tip's Jacobian at the current state, rewritten in place, and its arm columns
        # (and their transpose) as views made once.
        self._jac = np.zeros((n, 3, m.nv))
        self._jac_arm = self._jac[:, :, :N_JOINTS]
        self._jac_arm_t = self._jac_arm.transpose(0, 2, 1)
        # For _ik_list: the arm's Jacobian twice (views), so that J J^T comes out once per
        # regulariser and adds to them without broadcasting (which costs a small numpy call
        # more than the sum itself). Each matrix of a stack is computed on its own: the same
        # numbers as ik()'s J J^T.
        self._jac_arm2 = np.broadcast_to(self._jac_arm[:1], (2, 3, N_JOINTS))
        self._jac_arm2_t = self._jac_arm2.transpose(0, 2, 1)
        self._old_tip = np.zeros((n, 3))
        self._old_tip_row = self._old_tip[0]
        self._scratch = None  # a second batch for IK iterations away from the measured q
        self.target_pos = self.target_vel = self.target_acc = None
        self.path_rows = None  # one arm: the three paths as lists of rows (_set_paths)
        self._fine_pos = None  # the target at every substep (substep_ik only)
        self.reset()

    # --- state -----------------------------------------------------------------------------
    def reset(self, ids=None, trajs=None, n_steps: int = 0, qpos: np.ndarray | None = None):
        """Restore every piece of state of arms ``ids`` (default all): arm, actuator goals, IK
        warm start, target path and marker, clock, flags. ``trajs``: one trajectory per id."""
        ids = self._arange if ids is None else np.asarray(ids, dtype=np.int64).reshape(-1)
        if self.batch is None:
            mujoco.mj_resetDataKeyframe(self.model, self._data, self._home_key)
        else:
            self.batch.reset(ids, keyframe=self._home_key, stage=mujoco.mjtStage.mjSTAGE_NONE)
        q0 = self._home if qpos is None else np.asarray(qpos, dtype=float)
        self.qpos[ids] = q0
        self._ctrl[ids, :N_JOINTS] = q0
        self.q_goal[ids] = q0
        self.step_count[ids] = 0
        for flag in (self.self_collision, self.collision_depth, self.floor_contact, self.unstable):
            flag[ids] = 0
        if trajs is not None:
            self._set_paths(ids, trajs, n_steps)
            self._mocap[ids] = self.target_pos[ids, 0]
        if self.batch is None:
            mujoco.mj_forward(self.model, self._data)
        else:
            self.batch.forward(ids)
        self._warnings = self._unstable_warnings()
        self._flags_raw = None  # (_flags_lean's record of the counters, as bytes)
        self._tip_jac(ids)

    def _set_paths(self, ids: np.ndarray, trajs, n_steps: int) -> None:
        steps = n_steps + 1
        if self.target_pos is None or self.target_pos.shape[1] != steps:
            if self.target_pos is not None and len(ids) != self.n:
                raise ValueError(f"every arm's path has {self.target_pos.shape[1] - 1} steps; "
                                 f"reset all arms to change it to {n_steps}")
            self.target_pos, self.target_vel, self.target_acc = (
                np.zeros((self.n, steps, 3)) for _ in range(3))
        times = np.arange(steps) * self.dt
        for i, traj in zip(ids, trajs, strict=True):
            pos, vel, acc = traj.at(times)
            self.target_pos[i], self.target_vel[i], self.target_acc[i] = pos, vel, acc
        if self.n == 1:  # for the one-slot steps: Python rows, one index each (not a tolist)
            self.path_rows = (self.target_pos[0].tolist(), self.target_vel[0].tolist(),
                              self.target_acc[0].tolist())
        if self.ik_config.substep_ik:  # the target at every physics substep, for the IK there
            fine = n_steps * self.substeps + 1
            if self._fine_pos is None or self._fine_pos.shape[1] != fine:
                self._fine_pos = np.zeros((self.n, fine, 3))
            fine_times = np.arange(fine) * (self.dt / self.substeps)
            for i, traj in zip(ids, trajs, strict=True):
                self._fine_pos[i] = traj.at(fine_times)[0]

    @property
    def home(self) -> np.ndarray:
        """The home pose's joint angles (rad), read-only."""
        return self._home

    @property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) joint goals the controller may command (rad): the MJCF limits less the
        IK's margin."""
        return self._lo, self._hi

    @property
    def time(self) -> np.ndarray:
        return self.step_count * self.dt

    def target(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos, vel, acc) of every arm's target now, (N, 3) each (copies)."""
        if self.n == 1:  # plain indexing (a copy): cheaper than index arrays for one arm
            k = min(int(self.step_count[0]), self.target_pos.shape[1] - 1)
            return (self.target_pos[:, k].copy(), self.target_vel[:, k].copy(),
                    self.target_acc[:, k].copy())
        i, k = self._arange, self._path_index()
        return self.target_pos[i, k], self.target_vel[i, k], self.target_acc[i, k]

    def _path_index(self) -> np.ndarray:
        """Each arm's row of its path: its step, held at the last row if stepped past it (a
        vector env steps a finished arm once before resetting it)."""
        return np.minimum(self.step_count, self.target_pos.shape[1] - 1)

    def _target_pos_now(self) -> np.ndarray:
        """Each arm's target position now, (N, 3): target()[0] without the rest."""
        if self.n == 1:
            return self.target_pos[:, min(int(self.step_count[0]), self.target_pos.shape[1] - 1)]
        return self.target_pos[self._arange, self._path_index()]

    # --- control ---------------------------------------------------------------------------
    def ik(self, target: np.ndarray, q0: np.ndarray | None = None, iters: int | None = None
           ) -> np.ndarray:
        """DLS IK for every arm's tip, (N, 3) targets -> (N, 7) joint goals, warm-started from
        q0 (default: the measured angles, whose kinematics are current)."""
        cfg = self.ik_config
        iters = cfg.iters if iters is None else iters
        if self.batch is None:
            target = np.broadcast_to(target, (1, 3))[0].tolist()
            q0 = None if q0 is None else np.broadcast_to(q0, (1, N_JOINTS))[0].tolist()
            return np.array([self._ik_list(target, q0, iters)])
        q = (self.qpos if q0 is None else np.broadcast_to(q0, (self.n, N_JOINTS))).copy()
        for i in range(iters):
            if i == 0 and q0 is None:
                jac, jac_t, tip = self._jac_arm, self._jac_arm_t, self.tip_pos
            else:
                jac, tip = self._kinematics_at(q)
                jac = jac[:, :, :N_JOINTS]
                jac_t = jac.transpose(0, 2, 1)
            # Damped step J^T (J J^T + l^2 I)^-1 e, and the posture pull projected by the exact
            # null-space projector I - J^T (J J^T)^-1 J (a damped projector would leak the pull
            # into the tip position and bias the solution by centimetres near singularities).
            # The two 3x3 systems are independent, so one stacked solve does both (LAPACK
            # solves each matrix of a stack on its own: the same numbers as two calls, for
            # half the numpy overhead, which is most of the cost for a few arms).
            jjt = jac @ jac_t
            rhs = self._rhs  # (N, 2, 3, 1): the tip error e, and J times the posture pull
            np.subtract(target, tip, out=self._rhs_err)
            if cfg.nullspace_gain:
                pull = cfg.nullspace_gain * (self._home - q)
                rhs[:, 1] = jac @ pull[:, :, None]
                steps = jac_t[:, None] @ np.linalg.solve(jjt[:, None] + self._regularisers, rhs)
                dq = steps[:, 0, :, 0]
                dq += pull - steps[:, 1, :, 0]
            else:
                dq = (jac_t @ np.linalg.solve(jjt + self._damp3, rhs[:, 0]))[:, :, 0]
            if self._clearance is not None:
                dq = self._clearance.project(dq)
            # Cap the step at max_step (infinity norm). Under the cap the factor is exactly 1,
            # so the multiplication is skipped then (the usual case; same numbers).
            peak = np.maximum.reduce(np.abs(dq), axis=1, keepdims=True)
            if not np.logical_and.reduce(peak <= cfg.max_step, axis=None):
                dq *= np.minimum(1.0, cfg.max_step / np.maximum(peak, 1e-300))
            q += dq
            np.minimum(np.maximum(q, self._lo, out=q), self._hi, out=q)  # np.clip, cheaper
        return q

    def _ik_list(self, target: list[float], q0: list[float] | None, iters: int) -> list[float]:
        """ik() for one arm, on Python floats: the same numbers. The elementwise arithmetic is
        done on Python floats (numpy's elementwise operations round exactly as Python's do, and
        the operands and their order are ik()'s); the linear algebra goes through the numpy
        routines ik() calls, on matrices of the same shapes and layouts (a stack's matrices are
        each computed on their own, so dropping ik()'s leading axis of one arm changes no
        number), into preallocated outputs. For one arm each numpy call costs more than the
        arithmetic in it, so this path makes as few as it can: five per iteration."""
        cfg = self.ik_config
        gain, cap = cfg.nullspace_gain, cfg.max_step
        q = self._qpos_row.tolist() if q0 is None else q0
        rhs = self._rhs[0]  # (2, 3, 1): the tip error e, and J times the posture pull
        for i in range(iters):
            if i == 0 and q0 is None:
                jac, jac_t, tip = self._jac_arm, self._jac_arm_t, self._tip_row.tolist()
                jac2, jac2_t = self._jac_arm2, self._jac_arm2_t
            else:
                jac, tip_pos = self._kinematics_at(np.array([q]))
                jac = jac[:, :, :N_JOINTS]
                jac_t = jac.transpose(0, 2, 1)
                tip = tip_pos[0].tolist()
                jac2 = np.broadcast_to(jac, (2, 3, N_JOINTS))
                jac2_t = jac2.transpose(0, 2, 1)
            # The 7-vectors' arithmetic is written out joint by joint: Python 3.11 builds and
            # calls a function for every comprehension, and a zip or map of a few 7-vectors
            # costs more than the arithmetic in it (this tail took 2.7 us as comprehensions
            # and maps, 0.8 us written out; the operations and their order are ik()'s).
            j0, j1, j2, j3, j4, j5, j6 = q  # (q0 is the argument)
            (a0, a1, a2), (b0, b1, b2) = target, tip
            self._rhs_err_row[:] = (a0 - b0, a1 - b1, a2 - b2)
            if gain:
                h0, h1, h2, h3, h4, h5, h6 = self._home_list
                pull = [gain * (h0 - j0), gain * (h1 - j1), gain * (h2 - j2), gain * (h3 - j3),
                        gain * (h4 - j4), gain * (h5 - j5), gain * (h6 - j6)]  # gain * (home - q)
                self._pull_flat[:] = pull
                p0, p1, p2, p3, p4, p5, p6 = pull
                np.matmul(jac, self._pull_col, out=self._rhs_pull)
                # (2, 3, 3): J J^T + each, into buffers (a fresh array costs more than the
                # copy into it: the same numbers)
                systems = np.add(np.matmul(jac2, jac2_t, out=self._jjt2), self._regularisers,
                                 out=self._systems)
                # The solve without _solve's finiteness check (a numpy reduction): a non-finite
                # solution gives a non-finite product, which the sum of its values shows.
                np.matmul(jac_t, _solve_unchecked(systems, rhs, self._solutions), out=self._steps)
                steps = self._steps_flat.tolist()
                if not math.isfinite(sum(steps)):  # _solve's fallback (see there)
                    np.matmul(jac_t, np.linalg.solve(systems, rhs), out=self._steps)
                    steps = self._steps_flat.tolist()
                # dq = step_0 + (pull - step_1)
                s0, s1, s2, s3, s4, s5, s6, t0, t1, t2, t3, t4, t5, t6 = steps
                d0, d1, d2, d3 = s0 + (p0 - t0), s1 + (p1 - t1), s2 + (p2 - t2), s3 + (p3 - t3)
                d4, d5, d6 = s4 + (p4 - t4), s5 + (p5 - t5), s6 + (p6 - t6)
            else:
                self._rhs_err_row[:] = (a0 - b0, a1 - b1, a2 - b2)
                a = (jac_t @ _solve(jac @ jac_t + self._damp3, rhs[:1])).tolist()[0]
                ((d0,), (d1,), (d2,), (d3,), (d4,), (d5,), (d6,)) = a
            # Over the cap or NaN: ik()'s own calls. (Every |d| <= cap, written as two
            # comparisons, which a NaN fails: under the cap every value is finite.)
            m = -cap
            if not (m <= d0 <= cap and m <= d1 <= cap and m <= d2 <= cap and m <= d3 <= cap
                    and m <= d4 <= cap and m <= d5 <= cap and m <= d6 <= cap):
                d = np.array([[d0, d1, d2, d3, d4, d5, d6]])
                d *= np.minimum(1.0, cap / np.maximum(np.maximum.reduce(np.abs(d), axis=1,
                                                                        keepdims=True), 1e-300))
                d0, d1, d2, d3, d4, d5, d6 = d[0].tolist()
            # np.clip(q + dq, lo, hi) as ik() computes it, np.minimum(np.maximum(.., lo), hi):
            # a NaN fails both comparisons and stays, as numpy's maximum and minimum keep it
            # (lo < hi, so hi wins over lo).
            x0, x1, x2, x3, x4, x5, x6 = j0 + d0, j1 + d1, j2 + d2, j3 + d3, j4 + d4, j5 + d5, j6 + d6
            l0, l1, l2, l3, l4, l5, l6 = self._lo_list
            u0, u1, u2, u3, u4, u5, u6 = self._hi_list
            q = [u0 if x0 > u0 else l0 if x0 < l0 else x0, u1 if x1 > u1 else l1 if x1 < l1 else x1,
                 u2 if x2 > u2 else l2 if x2 < l2 else x2, u3 if x3 > u3 else l3 if x3 < l3 else x3,
                 u4 if x4 > u4 else l4 if x4 < l4 else x4, u5 if x5 > u5 else l5 if x5 < l5 else x5,
                 u6 if x6 > u6 else l6 if x6 < l6 else x6]
        return q

    def _kinematics_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip Jacobians and positions at joint angles q, from a scratch batch (state untouched)."""
        if self.batch is None:  # one arm: a scratch MjData, the same kinematics and mj_jac
            if self._scratch is None:
                self._scratch = mujoco.MjData(self.model)
            d = self._scratch
            d.qpos[:N_JOINTS] = q[0]
            mujoco.mj_kinematics(self.model, d)
            tip = d.site_xpos[None, self._tip].copy()
            return self._jacobians(d, tip)[0].copy(), tip
        if self._scratch is None:
            self._scratch = mujoco.batch.Batch(self.model, nsim=self.n,
                                               nthread=self.batch.nthread, persistent=True)
            self._scratch_qpos = self._scratch.bind("qpos")
            self._scratch_tip = self._scratch.bind("site_xpos")[:, self._tip]
        self._scratch_qpos[:, :N_JOINTS] = q
        self._scratch.forward(stage=mujoco.mjtStage.mjSTAGE_POS)
        jac, _ = self._scratch.jac(self._tip_body, self._scratch_tip)
        return jac, self._scratch_tip.copy()

    def _jacobians(self, d: mujoco.MjData, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One arm's (1, 3, nv) tip-body Jacobians at a world point, as Batch.jac computes them:
        mj_kinematics and mj_comPos from the state, then mj_jac (into reused buffers)."""
        m = self.model
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jac(m, d, self._jacp_row, self._jacr_row, point[0], self._tip_body)
        return self._jacp, self._jacr

    def _tip_jac(self, ids: np.ndarray | None = None) -> None:
        """The tip's position Jacobian at each arm's current state, (N, 3, nv), for the next IK."""
        if self.batch is None:
            self._jac[:] = self._jacobians(self._data, self.tip_pos)[0]
        elif ids is None or len(ids) == self.n:
            self._jac[:] = self.batch.jac(self._tip_body, self.tip_pos)[0]
        else:
            self._jac[ids] = self.batch.jac(self._tip_body, self.tip_pos[ids], ids=ids)[0]

    def _end_of_step_kinematics(self) -> None:
        """Tip positions and Jacobians of the state the substeps ended in, from one kinematics
        pass: `jac` at the old tip positions (it runs mj_kinematics and mj_comPos), then
        `forward(stage=NONE)`, which computes nothing but copies those kinematics into the bound
        tip position, then the Jacobian moved from the old point a to the new tip b."""
        old_tip = self._old_tip
        # The velocity of point b on the tip body is v_a + w x (b - a): J_b = J_a - [b - a]x J_r,
        # [r]x = [[0, -r2, r1], [r2, 0, -r0], [-r1, r0, 0]].
        if self.batch is None:  # _jacobians() on row views; the MjData's tip is current at once
            m, d, old = self.model, self._data, self._old_tip_row
            old[:] = self._tip_row
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jac(m, d, self._jacp_row, self._jacr_row, old, self._tip_body)
            r0, r1, r2 = map(sub, self._tip_row.tolist(), old.tolist())  # b - a
            self._skew_flat[:] = (0.0, -r2, r1, r2, 0.0, -r0, -r1, r0, 0.0)
            np.subtract(self._jacp, np.matmul(self._skew, self._jacr, out=self._moved),
                        out=self._jac)
            return
        np.copyto(old_tip, self.tip_pos)
        jacp, jacr = self.batch.jac(self._tip_body, old_tip)
        self.batch.forward(stage=_STAGE_NONE)
        r = self.tip_pos - old_tip  # written in one indexed assignment:
        self._skew.reshape(self.n, 9)[:, _SKEW_AT] = r[:, _SKEW_OF] * _SKEW_SIGN
        np.subtract(jacp, self._skew @ jacr, out=self._jac)

    def step(self, lead: np.ndarray | None = None, joint_offset: np.ndarray | None = None,
             joint_goal: np.ndarray | None = None) -> None:
        """One control step of every arm: IK on (target + lead), plus an optional joint-goal
        offset (rad, kept inside the joint limits), then the PD for the substeps. With
        ``joint_goal`` (rad) the IK is skipped: the goal goes to the PD as it is (clipped to
        the limits). With ``ik.substep_ik`` the IK is solved before every substep instead, on
        the target at that instant, the lead held."""
        if self.target_pos is None:
            raise RuntimeError("ArmBatch.step before any target path: call "
                               "reset(trajs=[...], n_steps=N) first")
        if self.lean and joint_goal is None and joint_offset is None:
            self.step_one(None if lead is None else np.broadcast_to(lead, (1, 3))[0].tolist())
            return
        if joint_goal is not None:
            self.q_goal = np.clip(joint_goal, self._lo, self._hi)
        elif self.ik_config.substep_ik:
            sensors = self._substep_ik_step(lead, joint_offset)
        else:
            target = self._target_pos_now()
            self.q_goal = self.ik(target if lead is None else target + lead)
            if joint_offset is not None:
                self.q_goal = np.clip(self.q_goal + joint_offset, self._lo, self._hi)
        if joint_goal is not None or not self.ik_config.substep_ik:
            self._ctrl[:, :N_JOINTS] = self.q_goal
            sensors = self._physics(self._contacts["sensordata"])
            self._end_of_step_kinematics()
        self.step_count += 1
        self._mocap[:] = self._target_pos_now()
        self._flags(sensors)

    @property
    def lean(self) -> bool:
        """Whether step_one() runs: one arm on a plain MjData, the IK once per control step."""
        return self.batch is None and not self.ik_config.substep_ik

    def step_one(self, lead: list[float] | None = None) -> tuple[bool, float, bool]:
        """step(lead) of one arm (when ``lean``), the lead as Python floats: the same numbers
        as step() on Python floats (see _ik_list), for a fraction of its numpy calls; returns
        the step's (self_collision, collision_depth, unstable) of arm 0 as Python values."""
        if self.target_pos is None:
            raise RuntimeError("ArmBatch.step before any target path: call "
                               "reset(trajs=[...], n_steps=N) first")
        k, path = self.step_count.item(0), self.path_rows[0]
        last = len(path) - 1
        target = path[min(k, last)]  # _target_pos_now()
        if lead is not None:  # target + lead (written out: cheaper than a map)
            (t0, t1, t2), (l0, l1, l2) = target, lead
            target = [t0 + l0, t1 + l1, t2 + l2]
        q = self._ik_list(target, None, self.ik_config.iters)
        self._ctrl_row[:] = q
        self._pending_goal = q  # q_goal: np.array([q]) when first read (_Deferred)
        found, floor = self._substeps_one()
        self.step_count[0] = k + 1
        self._mocap_row[:] = path[min(k + 1, last)]
        return self._flags_lean(found, floor)

    def _flags(self, sensors: np.ndarray) -> None:
        """The step's flags from the contact sensors recorded after every substep (any touch
        in the step counts) and from MuJoCo's warning counters: MuJoCo resets a simulation
        itself on a NaN/huge position, velocity, acceleration or control (and only warns), so
        a rise in those counters marks the arm unstable."""
        if self.batch is None:
            self._flags_one(sensors[0].tolist(), self._warning_number.tolist())
            return
        warnings = self._unstable_warnings()
        # (a ufunc's reduce is what .any() and .max() call, without their wrappers)
        found = sensors[:, :, _SELF_FOUND] > 0
        self.self_collision = np.logical_or.reduce(found, axis=1)
        self.collision_depth = np.maximum.reduce(
            np.where(found, -sensors[:, :, _SELF_DIST], 0.0), axis=1)
        self.floor_contact = np.logical_or.reduce(sensors[:, :, _FLOOR_FOUND] > 0, axis=1)
        self.unstable = (np.logical_or.reduce(warnings != self._warnings, axis=1)
                         | ~np.logical_and.reduce(np.isfinite(self.qpos), axis=1))
        self._warnings = warnings

    def _flags_one(self, rows: list[list[float]], counters: list[int]
                   ) -> tuple[bool, float, bool]:
        """_flags() of one arm from Python values (see _ik_list): ``rows``, the sensors after
        each substep, ``counters``, all the warning counters now. Returns (self_collision,
        collision_depth, unstable) as Python values; the flags' (1,) arrays are made when
        first read (_Deferred)."""
        found = [x for row in rows for x in row[_SELF_FOUND:_SELF_DIST + 1]]
        return self._flags_lean(found, [row[_FLOOR_FOUND] for row in rows], counters)

    def _flags_lean(self, found: list[float], floor: list[float],
                    counters: list[int] | None = None) -> tuple[bool, float, bool]:
        """_flags_one() from the self-contact sensor's (found, distance) pairs of every
        substep, flat, and the floor sensor's found values; ``counters`` default to the
        warning counters now."""
        touched = any(map(_POSITIVE, found[0::2]))  # (any found > 0, as _flags())
        floor = any(map(_POSITIVE, floor))
        if counters is None:  # unchanged counters (as bytes) since the last flags: no rise
            raw = self._warning_raw.tobytes()
            if raw == self._flags_raw:
                warnings = self._warnings
            else:
                warnings, self._flags_raw = _unstable_of(self._warning_number.tolist()), raw
        else:
            warnings, self._flags_raw = _unstable_of(counters), None
        # every qpos finite: a finite sum says so; a non-finite one may be an overflow
        qpos = self._qpos_row.tolist()
        unstable = (warnings != self._warnings
                    or not (math.isfinite(sum(qpos)) or all(map(math.isfinite, qpos))))
        self._warnings = warnings
        if touched:  # _flags()'s own calls (numpy's maximum keeps a NaN; max() may not)
            pairs = np.array([found]).reshape(1, -1, 2)
            depths = np.maximum.reduce(np.where(pairs[:, :, 0] > 0, -pairs[:, :, 1], 0.0),
                                       axis=1)
            depth = float(depths[0])
        else:  # without a touch every substep's depth is 0.0, and so is the maximum
            depths, depth = None, 0.0
        # The flags' (1,) arrays are made when first read (_Deferred): a single env reads
        # the Python values returned here.
        self._pending_flags = (touched, depths, floor, unstable)
        return touched, depth, unstable

    def _make_goal(self) -> None:
        """q_goal from step_one's joint goals: (1, 7), the float64s it wrote to ctrl."""
        self._q_goal, self._pending_goal = np.array([self._pending_goal]), None

    def _make_flags(self) -> None:
        """The flags' fresh (1,) arrays from _flags_lean's values, as _flags() makes them
        (copies: cheaper than np.array)."""
        touched, depths, floor, unstable = self._pending_flags
        self._pending_flags = None
        self._self_collision = (_TRUE1 if touched else _FALSE1).copy()
        self._collision_depth = np.zeros(1) if depths is None else depths
        self._floor_contact = (_TRUE1 if floor else _FALSE1).copy()
        self._unstable = (_TRUE1 if unstable else _FALSE1).copy()

    def _physics(self, out: np.ndarray) -> np.ndarray:
        """Every arm's physics substeps, (N, nstep, nsensordata) ``out`` recording the sensors
        after each; returns out."""
        if self.batch is not None:
            return self.batch.rollout(out.shape[1], record=("sensordata",),
                                      out={"sensordata": out})["sensordata"]
        out[0] = self._physics_rows(out.shape[1])[0]
        return out

    def _substeps_one(self) -> tuple[list[float], list[float]]:
        """step_one's substeps and end-of-step kinematics: ``_physics_rows(substeps)`` then
        ``_end_of_step_kinematics()``, the same numbers in fewer Python calls. Returns the
        self-contact sensor's (found, distance) after each substep, flat, and the floor
        sensor's found after each (in the same order, not necessarily the substeps').

        The substeps run in one ``mj_step(m, d, n)``, and each substep's contact sensors come
        from MuJoCo's sensor history (the last n readings: assets/scene.xml), not from a read
        and a check of the warning counters after every substep. But ``Batch.rollout`` stops an
        arm at the substep its warning counters rise (MuJoCo resets a simulation that goes bad
        and steps on), which one call cannot do: when the counters moved, the state saved
        before the call and the counters are restored and the substeps replayed one by one, as
        ``_physics_rows`` does (MuJoCo then prints the warning's first-time message twice).
        """
        m, d, raw, n = self.model, self._data, self._warning_raw, self.substeps
        start = raw.tobytes()
        if self._history_rows:
            mujoco.mj_getState(m, d, self._saved, _SAVED_STATE)
            mujoco.mj_step(m, d, n)
            if raw.tobytes() == start:
                history = self._history.tolist()
                self._end_of_step_kinematics()
                # Each sensor's ring buffer is [user, cursor, n times, n values]: after n
                # insertions its n values are this call's, in an order set by the cursor, which
                # the flags (any touch, deepest touch) do not depend on.
                (v0, v1) = self._history_at
                return history[v0:v0 + 2 * n], history[v1:v1 + n]
            mujoco.mj_setState(m, d, self._saved, _SAVED_STATE)
            raw[:] = np.frombuffer(start, raw.dtype)
        rows, _ = self._physics_rows(n)
        self._end_of_step_kinematics()
        return ([x for row in rows for x in row[_SELF_FOUND:_SELF_DIST + 1]],
                [row[_FLOOR_FOUND] for row in rows])

    def _physics_rows(self, nstep: int) -> tuple[list[list[float]], list[int]]:
        """One arm's substeps on its MjData: the sensors after each (nstep rows) and all the
        warning counters after the last, as Python values."""
        m, d, sensordata, counters = self.model, self._data, self._sensordata, self._warning_number
        mj_step, record = mujoco.mj_step, sensordata.tolist
        start = counters.tobytes()  # (compared as bytes: cheaper than a list each substep)
        rows = []
        for j in range(nstep):
            mj_step(m, d)
            rows.append(record())
            # As Batch.rollout: an arm whose warning counters rise stops stepping, and its
            # remaining records repeat its last ones.
            if counters.tobytes() != start:
                rows += rows[-1:] * (nstep - 1 - j)
                break
        return rows, counters.tolist()

    def _unstable_warnings(self) -> np.ndarray | list[int]:
        """(N, 4) counters of MuJoCo's bad qpos, qvel, qacc and ctrl warnings (a copy); for one
        arm a tuple of the four."""
        if self.batch is None:
            return _unstable_of(self._warning_number.tolist())
        return self.batch.warning[:, _UNSTABLE_WARNINGS, 1]

    def warning_counts(self) -> np.ndarray:
        """(N, mjNWARNING) counters of every MuJoCo warning of each arm (a copy)."""
        if self.batch is None:
            return self._warning_number[None].copy()
        return self.batch.warning[:, :, 1].copy()

    def _substep_ik_step(self, lead, joint_offset) -> np.ndarray:
        """The substeps of one control step, each after an IK on the target at its start time
        (the fine path); returns the contact sensors recorded after each substep."""
        sensors = self._contacts["sensordata"]
        one = np.zeros((self.n, 1, sensors.shape[2]))
        fine = self._fine_pos
        base = np.minimum(self.step_count * self.substeps, fine.shape[1] - 1)
        for j in range(self.substeps):
            target = fine[self._arange, np.minimum(base + j, fine.shape[1] - 1)]
            self.q_goal = self.ik(target if lead is None else target + lead)
            if joint_offset is not None:
                self.q_goal = np.clip(self.q_goal + joint_offset, self._lo, self._hi)
            self._ctrl[:, :N_JOINTS] = self.q_goal
            sensors[:, j] = self._physics(one)[:, 0]
            self._end_of_step_kinematics()
        return sensors

    # --- inspection --------------------------------------------------------------------------
    def get_data(self, i: int = 0, data: mujoco.MjData | None = None) -> mujoco.MjData:
        """Arm i's whole MjData (for rendering, the viewer and inspection): a copy."""
        if self.batch is not None:
            return self.batch.get_data(i, data)
        if not 0 <= i < self.n:
            raise IndexError(f"arm {i} of {self.n}")
        if data is None:
            data = mujoco.MjData(self.model)
        mujoco.mj_copyData(data, self.model, self._data)
        return data

    def contact_pairs(self, i: int = 0) -> list[tuple[str, str, float]]:
        """Which arm bodies of arm i touch each other now, and how deep (m). For tests."""
        m = self.model
        d = self.get_data(i)
        mujoco.mj_forward(m, d)
        pairs = []
        for c in d.contact[: d.ncon]:
            b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
            if b1 != 0 and b2 != 0:  # every collision geom but the floor belongs to the arm
                pairs.append((m.body(b1).name, m.body(b2).name, float(-c.dist)))
        return pairs
