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

The simulation is reached through a handful of methods (`_bind`, `_reset_sims`, `_forward`,
`_physics`, `_end_of_step_kinematics`, `_tip_jac`, `_kinematics_at`, the warning counters,
`get_data`), which is all a specialisation on another backend overrides: core_one.py's
`ArmOne`, the single env's one arm on a plain MjData, is such a subclass and nothing here
knows of it.
"""

from __future__ import annotations

import importlib.util
from functools import cache
from pathlib import Path

import mujoco  # (panda_lead/__init__.py chose the GL backend before this first import)
import mujoco.batch
import numpy as np

from .clearance import Clearance
from .ikconfig import DEFAULT_IK, N_JOINTS, IKConfig
from .paths import shipped

__all__ = ["ArmBatch", "IKConfig", "N_JOINTS", "CONTROL_SUBSTEPS", "analytic_lead",
           "control_dt", "home_qpos", "load_model"]  # (IKConfig, N_JOINTS: from ikconfig.py)

ASSETS = shipped("assets")
SCENE_XML = ASSETS / "scene.xml"
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


class ArmBatch:
    """N Pandas and their controller: ``step(lead)`` is one 100 Hz control step of all of them.

    State is per arm, in (N, ...) arrays: ``tip_pos``, ``qpos``, ``qvel`` (live views, updated
    in place by each step: copy to keep), ``step_count``, and after each step the flags
    ``self_collision``, ``collision_depth`` (m), ``floor_contact`` and ``unstable``. Each arm
    plays its own target path, precomputed at its reset (positions, velocities, accelerations
    at every control step), so a step does no trajectory maths.
    """

    def __init__(self, n: int, ik: IKConfig = DEFAULT_IK, substeps: int = CONTROL_SUBSTEPS,
                 nthread: int = 0):
        if n < 1:
            raise ValueError(f"an ArmBatch needs at least one arm, got n={n}")
        self.model = m = load_model()
        self.n = n
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
        self._rhs = np.zeros((n, 2, 3, 1))
        self._rhs_err = self._rhs[:, 0, :, 0]
        self._bind(nthread)
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
        # The tip's Jacobian at the current state, rewritten in place, and its arm columns
        # (and their transpose) as views made once.
        self._jac = np.zeros((n, 3, m.nv))
        self._jac_arm = self._jac[:, :, :N_JOINTS]
        self._jac_arm_t = self._jac_arm.transpose(0, 2, 1)
        self._old_tip = np.zeros((n, 3))
        self._scratch = None  # a second batch for IK iterations away from the measured q
        self._scratch_clearance = None  # ... and its collision-aware IK (ik.clearance only)
        self.target_pos = self.target_vel = self.target_acc = None
        self._fine_pos = None  # the target at every substep (substep_ik only)
        self.reset()

    # --- the simulation: a mujoco.batch.Batch of N ------------------------------------------
    def _bind(self, nthread: int) -> None:
        """Make the simulations and bind the live (N, ...) views the control law reads and
        writes: qpos, qvel, tip_pos, _ctrl, _mocap (the target marker)."""
        m = self.model
        self.batch = b = mujoco.batch.Batch(m, nsim=self.n, nthread=nthread, persistent=True)
        # Live (N, ...) views into the batch (bound once; the batch never moves them).
        self.qpos = b.bind("qpos")[:, :N_JOINTS]
        self.qvel = b.bind("qvel")[:, :N_JOINTS]
        self._ctrl = b.bind("ctrl")
        self._mocap = b.bind("mocap_pos")[:, m.body("target").mocapid[0]]
        self.tip_pos = b.bind("site_xpos")[:, self._tip]

    def _reset_sims(self, ids: np.ndarray) -> None:
        """Arms ``ids`` back to the home keyframe (no kinematics yet)."""
        self.batch.reset(ids, keyframe=self._home_key, stage=mujoco.mjtStage.mjSTAGE_NONE)

    def _forward(self, ids: np.ndarray) -> None:
        """Every derived quantity of arms ``ids`` from their state (mj_forward)."""
        self.batch.forward(ids)

    def _physics(self, out: np.ndarray) -> np.ndarray:
        """Every arm's physics substeps, (N, nstep, nsensordata) ``out`` recording the sensors
        after each; returns out. An arm whose warning counters rise stops stepping, and its
        remaining records repeat its last ones (Batch.rollout)."""
        return self.batch.rollout(out.shape[1], record=("sensordata",),
                                  out={"sensordata": out})["sensordata"]

    def _unstable_warnings(self) -> np.ndarray:
        """(N, 4) counters of MuJoCo's bad qpos, qvel, qacc and ctrl warnings (a copy)."""
        return self.batch.warning[:, _UNSTABLE_WARNINGS, 1]

    def warning_counts(self) -> np.ndarray:
        """(N, mjNWARNING) counters of every MuJoCo warning of each arm (a copy)."""
        return self.batch.warning[:, :, 1].copy()

    def _kinematics_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip Jacobians and positions at joint angles q, from a scratch batch (state untouched)."""
        if self._scratch is None:
            self._scratch = mujoco.batch.Batch(self.model, nsim=self.n,
                                               nthread=self.batch.nthread, persistent=True)
            self._scratch_qpos = self._scratch.bind("qpos")
            self._scratch_tip = self._scratch.bind("site_xpos")[:, self._tip]
            # The collision-aware IK away from the measured angles (a planned joint path, the
            # feedforward rival's) reads the capsules where q puts them, not where the arm is.
            self._scratch_clearance = (Clearance(self.model, self._scratch, N_JOINTS,
                                                 self.ik_config.clearance)
                                       if self.ik_config.clearance > 0 else None)
        self._scratch_qpos[:, :N_JOINTS] = q
        self._scratch.forward(stage=mujoco.mjtStage.mjSTAGE_POS)
        jac, _ = self._scratch.jac(self._tip_body, self._scratch_tip)
        return jac, self._scratch_tip.copy()

    def _tip_jac(self, ids: np.ndarray | None = None) -> None:
        """The tip's position Jacobian at each arm's current state, (N, 3, nv), for the next IK."""
        if ids is None or len(ids) == self.n:
            self._jac[:] = self.batch.jac(self._tip_body, self.tip_pos)[0]
        else:
            self._jac[ids] = self.batch.jac(self._tip_body, self.tip_pos[ids], ids=ids)[0]

    def _end_of_step_kinematics(self) -> None:
        """Tip positions and Jacobians of the state the substeps ended in, from one kinematics
        pass: `jac` at the old tip positions (it runs mj_kinematics and mj_comPos), then
        `forward(stage=NONE)`, which computes nothing but copies those kinematics into the bound
        tip position, then the Jacobian moved from the old point a to the new tip b."""
        old_tip = self._old_tip
        np.copyto(old_tip, self.tip_pos)
        jacp, jacr = self.batch.jac(self._tip_body, old_tip)
        self.batch.forward(stage=_STAGE_NONE)
        # The velocity of point b on the tip body is v_a + w x (b - a): J_b = J_a - [b - a]x J_r,
        # [r]x = [[0, -r2, r1], [r2, 0, -r0], [-r1, r0, 0]], written in one indexed assignment.
        r = self.tip_pos - old_tip
        self._skew.reshape(self.n, 9)[:, _SKEW_AT] = r[:, _SKEW_OF] * _SKEW_SIGN
        np.subtract(jacp, self._skew @ jacr, out=self._jac)

    def get_data(self, i: int = 0, data: mujoco.MjData | None = None) -> mujoco.MjData:
        """Arm i's whole MjData (for rendering, the viewer and inspection): a copy."""
        return self.batch.get_data(i, data)

    # --- state -----------------------------------------------------------------------------
    def reset(self, ids=None, trajs=None, n_steps: int = 0, qpos: np.ndarray | None = None):
        """Restore every piece of state of arms ``ids`` (default all): arm, actuator goals, IK
        warm start, target path and marker, clock, flags. ``trajs``: one trajectory per id."""
        ids = self._arange if ids is None else np.asarray(ids, dtype=np.int64).reshape(-1)
        self._reset_sims(ids)
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
        self._forward(ids)
        self._warnings = self._unstable_warnings()
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
        i, k = self._arange, self._path_index()
        return self.target_pos[i, k], self.target_vel[i, k], self.target_acc[i, k]

    def _path_index(self) -> np.ndarray:
        """Each arm's row of its path: its step, held at the last row if stepped past it (a
        vector env steps a finished arm once before resetting it)."""
        return np.minimum(self.step_count, self.target_pos.shape[1] - 1)

    def _target_pos_now(self) -> np.ndarray:
        """Each arm's target position now, (N, 3): target()[0] without the rest."""
        return self.target_pos[self._arange, self._path_index()]

    # --- control ---------------------------------------------------------------------------
    def ik(self, target: np.ndarray, q0: np.ndarray | None = None, iters: int | None = None
           ) -> np.ndarray:
        """DLS IK for every arm's tip, (N, 3) targets -> (N, 7) joint goals, warm-started from
        q0 (default: the measured angles, whose kinematics are current). Under ik.clearance
        every iteration's step is projected with the capsules where that iteration starts."""
        cfg = self.ik_config
        iters = cfg.iters if iters is None else iters
        q = (self.qpos if q0 is None else np.broadcast_to(q0, (self.n, N_JOINTS))).copy()
        for i in range(iters):
            if i == 0 and q0 is None:
                jac, jac_t, tip = self._jac_arm, self._jac_arm_t, self.tip_pos
                clearance = self._clearance
            else:
                jac, tip = self._kinematics_at(q)
                jac = jac[:, :, :N_JOINTS]
                jac_t = jac.transpose(0, 2, 1)
                clearance = self._scratch_clearance
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
            if clearance is not None:
                dq = clearance.project(dq)
            # Cap the step at max_step (infinity norm). Under the cap the factor is exactly 1,
            # so the multiplication is skipped then (the usual case; same numbers).
            peak = np.maximum.reduce(np.abs(dq), axis=1, keepdims=True)
            if not np.logical_and.reduce(peak <= cfg.max_step, axis=None):
                dq *= np.minimum(1.0, cfg.max_step / np.maximum(peak, 1e-300))
            q += dq
            np.minimum(np.maximum(q, self._lo, out=q), self._hi, out=q)  # np.clip, cheaper
        return q


    def step(self, lead: np.ndarray | None = None, joint_offset: np.ndarray | None = None,
             joint_goal: np.ndarray | None = None, off_itself: np.ndarray | None = None
             ) -> None:
        """One control step of every arm: IK on (target + lead), plus an optional joint-goal
        offset (rad, kept inside the joint limits), then the PD for the substeps. With
        ``joint_goal`` (rad) the IK is skipped: the goal goes to the PD as it is (clipped to
        the limits; under ik.clearance projected by the damper, on the slots ``off_itself``
        marks when given: a goal the IK already projected is not projected twice). With
        ``ik.substep_ik`` the IK is solved before every substep instead, on the target at that
        instant, the lead held."""
        if self.target_pos is None:
            raise RuntimeError("ArmBatch.step before any target path: call "
                               "reset(trajs=[...], n_steps=N) first")
        if joint_goal is not None:
            if off_itself is None or self._clearance is None:
                projected = self._off_itself(joint_goal)
            elif off_itself.any():  # (the damper's projection is not cheap: only when asked)
                projected = np.where(off_itself[:, None], self._off_itself(joint_goal),
                                     joint_goal)
            else:
                projected = joint_goal
            self.q_goal = np.clip(projected, self._lo, self._hi)
        elif self.ik_config.substep_ik:
            sensors = self._substep_ik_step(lead, joint_offset)
        else:
            target = self._target_pos_now()
            self.q_goal = self.ik(target if lead is None else target + lead)
            if joint_offset is not None:
                self.q_goal = np.clip(self._off_itself(self.q_goal + joint_offset), self._lo,
                                      self._hi)
        if joint_goal is not None or not self.ik_config.substep_ik:
            self._ctrl[:, :N_JOINTS] = self.q_goal
            sensors = self._physics(self._contacts["sensordata"])
            self._end_of_step_kinematics()
        self.step_count += 1
        self._mocap[:] = self._target_pos_now()
        self._flags(sensors)

    def _off_itself(self, goal: np.ndarray) -> np.ndarray:
        """A joint goal set around the IK (a joint offset on its solution, or a goal that skips
        it: the feedforward rival's servo correction) under ik.clearance: its step from the
        measured angles projected as the IK's own steps are, so the damper sees the whole
        command; without a clearance the goal as it is."""
        if self._clearance is None:
            return goal
        return self.qpos + self._clearance.project(goal - self.qpos)

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
                self.q_goal = np.clip(self._off_itself(self.q_goal + joint_offset), self._lo,
                                      self._hi)
            self._ctrl[:, :N_JOINTS] = self.q_goal
            sensors[:, j] = self._physics(one)[:, 0]
            self._end_of_step_kinematics()
        return sensors

    def _flags(self, sensors: np.ndarray) -> None:
        """The step's flags from the contact sensors recorded after every substep (any touch
        in the step counts) and from MuJoCo's warning counters: MuJoCo resets a simulation
        itself on a NaN/huge position, velocity, acceleration or control (and only warns), so
        a rise in those counters marks the arm unstable."""
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

    # --- inspection --------------------------------------------------------------------------
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
