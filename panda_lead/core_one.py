"""`ArmOne`: the single env's arm, `ArmBatch` specialised to one arm for speed. Deletable.

The control law is core.py's `ArmBatch` and nothing here changes it: `ArmOne` is the same arm
on another backend, one plain MjData stepped by mj_step (Batch documents itself bit-identical
to exactly that loop; its per-call costs, argument checks, handing the call to its thread pool
and copying the bound fields out, were the largest part of a single env's step: a one-arm
Batch.jac ~25 us, mj_jac itself ~3 us), plus `step_one`, the law's lead step for one arm on
Python floats, for a fraction of the batch's numpy calls.

Held to the batch bit for bit by tests/test_core.py (test_one_arm_is_a_row_of_a_batch_bit_for_bit,
test_one_arm_contacts_come_from_the_sensor_history_as_from_a_read_after_each_substep,
test_the_single_env_takes_the_fast_path), tests/test_batched.py (the single env against a row
of the vector env, and the reference single env LeadTask(1) against this one) and
tests/test_vector.py (every setting's single envs against the native vector env).

Delete this file and task_one.py, and change the one line in env.py that picks
``LeadTaskOne`` to ``LeadTask``: the single env then runs the reference ``ArmBatch(1)``, the
same episodes, at roughly 3x its raw physics instead of 2x (docs/performance.md).
"""

from __future__ import annotations

import math
from operator import itemgetter, sub

import mujoco
import numpy as np

from .core import (
    _FLOOR_FOUND,
    _SELF_DIST,
    _SELF_FOUND,
    _UNSTABLE_WARNINGS,
    CONTROL_SUBSTEPS,
    ArmBatch,
)
from .ikconfig import DEFAULT_IK, N_JOINTS, IKConfig

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
    """np.linalg.solve(a, b) into ``out`` without its Python-level checks for a singular or
    non-finite system (for one arm they cost more than the solve): the same numbers. The
    caller sees a non-finite solution and redoes it with np.linalg.solve (see _ik_list)."""
    if _solve_gufunc is None:
        out[...] = np.linalg.solve(a, b)
        return out
    return _solve_gufunc(a, b, out=out)  # (float64 operands: its float64 loop, as solve's)


class _Deferred:
    """An attribute (an array) that a single env's step leaves to be made when first read:
    stored in ``_<name>``, made by the method ``make`` while the attribute ``pending`` is not
    None (a set makes it first too, so that nothing pending is lost). ArmOne's flags and
    q_goal (made from what step_one leaves), LeadTaskOne's prev_action, lead and ee_vel (from
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


class ArmOne(ArmBatch):
    """`ArmBatch` of one arm on a plain MjData (no collision-aware IK: its Clearance reads a
    batch's bound kinematics). ``step`` and ``ik`` are ArmBatch's; a lead step (no joint
    offset or goal, the IK once per control step) goes through ``step_one``, the same numbers
    on Python floats. Held to the batch by the tests named in core_one.py's docstring."""

    self_collision = _Deferred("_pending_flags", "_make_flags")
    collision_depth = _Deferred("_pending_flags", "_make_flags")
    floor_contact = _Deferred("_pending_flags", "_make_flags")
    unstable = _Deferred("_pending_flags", "_make_flags")
    q_goal = _Deferred("_pending_goal", "_make_goal")

    def __init__(self, n: int = 1, ik: IKConfig = DEFAULT_IK, substeps: int = CONTROL_SUBSTEPS,
                 nthread: int = 0):
        if n != 1:
            raise ValueError(f"ArmOne is one arm; use ArmBatch for {n}")
        if ik.clearance > 0:
            raise ValueError("ArmOne has no collision-aware IK (ik.clearance needs ArmBatch)")
        self._pending_flags = self._pending_goal = None  # (see _Deferred)
        self.path_rows = None  # the three paths as lists of rows (_set_paths)
        super().__init__(1, ik, substeps, nthread)
        # Row views made once for step_one and _ik_list: every MjData attribute access builds
        # a new array object (about 0.1 us each, a few dozen per step).
        self._lo_list, self._hi_list = self._lo.tolist(), self._hi.tolist()
        self._home_list = self._home.tolist()
        self._rhs_err_row = self._rhs_err[0]
        self._rhs_pull = self._rhs[0, 1:2]  # (1, 3, 1): J times the pull
        self._skew_flat = self._skew[0].reshape(9)
        self._old_tip_row = self._old_tip[0]
        # The arm's Jacobian twice (views), so that J J^T comes out once per regulariser and
        # adds to them without broadcasting (which costs a small numpy call more than the sum
        # itself). Each matrix of a stack is computed on its own: the same numbers as ik()'s.
        self._jac_arm2 = np.broadcast_to(self._jac_arm[:1], (2, 3, N_JOINTS))
        self._jac_arm2_t = self._jac_arm2.transpose(0, 2, 1)

    @property
    def lean(self) -> bool:
        """Whether a lead step runs step_one: the IK once per control step."""
        return not self.ik_config.substep_ik

    # --- the simulation: one MjData ---------------------------------------------------------
    def _bind(self, nthread: int) -> None:
        m = self.model
        self.batch = None
        self._data = d = mujoco.MjData(m)
        mocap = m.body("target").mocapid[0]
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
        self._sensordata = d.sensordata
        self._qpos_row, self._ctrl_row = d.qpos[:N_JOINTS], d.ctrl[:N_JOINTS]
        self._tip_row, self._mocap_row = d.site_xpos[self._tip], d.mocap_pos[mocap]
        # Operands and outputs of _ik_list's numpy calls, made once. The posture pull is
        # written into a column; J^T times each system's solution into a buffer whose flat
        # view gives the 14 numbers in one cheap tolist() (a contiguous buffer of the
        # result's shape is what the call would allocate: the same numbers).
        self._pull_col = np.zeros((1, N_JOINTS, 1))
        self._pull_flat = self._pull_col.reshape(-1)
        self._steps = np.zeros((2, N_JOINTS, 1))
        self._steps_flat = self._steps.reshape(-1)
        self._jjt2, self._systems = np.zeros((2, 3, 3)), np.zeros((2, 3, 3))
        self._solutions = np.zeros((2, 3, 1))
        self._moved = np.zeros((1, 3, m.nv))  # [b - a]x J_r (_end_of_step_kinematics)
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

    def _reset_sims(self, ids: np.ndarray) -> None:
        mujoco.mj_resetDataKeyframe(self.model, self._data, self._home_key)

    def _forward(self, ids: np.ndarray) -> None:
        mujoco.mj_forward(self.model, self._data)

    def _physics(self, out: np.ndarray) -> np.ndarray:
        out[0] = self._physics_rows(out.shape[1])[0]
        return out

    def _physics_rows(self, nstep: int) -> tuple[list[list[float]], list[int]]:
        """The arm's substeps on its MjData: the sensors after each (nstep rows) and all the
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

    def _unstable_warnings(self) -> tuple[int, int, int, int]:
        """The four counters of ArmBatch's, as Python ints (what _flags_lean compares)."""
        return _unstable_of(self._warning_number.tolist())

    def warning_counts(self) -> np.ndarray:
        return self._warning_number[None].copy()

    def _kinematics_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A scratch MjData's kinematics and mj_jac: Batch.forward(POS) and Batch.jac's."""
        if self._scratch is None:
            self._scratch = mujoco.MjData(self.model)
        d = self._scratch
        d.qpos[:N_JOINTS] = q[0]
        mujoco.mj_kinematics(self.model, d)
        tip = d.site_xpos[None, self._tip].copy()
        return self._jacobians(d, tip)[0].copy(), tip

    def _jacobians(self, d: mujoco.MjData, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (1, 3, nv) tip-body Jacobians at a world point, as Batch.jac computes them:
        mj_kinematics and mj_comPos from the state, then mj_jac (into reused buffers)."""
        m = self.model
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jac(m, d, self._jacp_row, self._jacr_row, point[0], self._tip_body)
        return self._jacp, self._jacr

    def _tip_jac(self, ids: np.ndarray | None = None) -> None:
        self._jac[:] = self._jacobians(self._data, self.tip_pos)[0]

    def _end_of_step_kinematics(self) -> None:
        """ArmBatch's on row views; the MjData's tip is current at once (no forward(NONE))."""
        m, d, old = self.model, self._data, self._old_tip_row
        old[:] = self._tip_row
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_jac(m, d, self._jacp_row, self._jacr_row, old, self._tip_body)
        r0, r1, r2 = map(sub, self._tip_row.tolist(), old.tolist())  # b - a
        self._skew_flat[:] = (0.0, -r2, r1, r2, 0.0, -r0, -r1, r0, 0.0)
        np.subtract(self._jacp, np.matmul(self._skew, self._jacr, out=self._moved),
                    out=self._jac)

    def get_data(self, i: int = 0, data: mujoco.MjData | None = None) -> mujoco.MjData:
        if i != 0:
            raise IndexError(f"arm {i} of 1")
        if data is None:
            data = mujoco.MjData(self.model)
        mujoco.mj_copyData(data, self.model, self._data)
        return data

    # --- state -------------------------------------------------------------------------------
    def reset(self, ids=None, trajs=None, n_steps: int = 0, qpos: np.ndarray | None = None):
        super().reset(ids, trajs, n_steps, qpos)
        self._flags_raw = None  # (_flags_lean's record of the counters, as bytes)

    def _set_paths(self, ids: np.ndarray, trajs, n_steps: int) -> None:
        super()._set_paths(ids, trajs, n_steps)
        # step_one's and LeadTaskOne's: Python rows, one index each (not a tolist per step)
        self.path_rows = (self.target_pos[0].tolist(), self.target_vel[0].tolist(),
                          self.target_acc[0].tolist())

    # --- control: the lead step on Python floats --------------------------------------------
    def step(self, lead: np.ndarray | None = None, joint_offset: np.ndarray | None = None,
             joint_goal: np.ndarray | None = None, off_itself: np.ndarray | None = None
             ) -> None:
        """ArmBatch.step; a lead step (when ``lean``) through step_one."""
        if self.lean and joint_goal is None and joint_offset is None:
            self.step_one(None if lead is None else np.broadcast_to(lead, (1, 3))[0].tolist())
            return
        super().step(lead, joint_offset, joint_goal, off_itself)

    def step_one(self, lead: list[float] | None = None) -> tuple[bool, float, bool]:
        """step(lead) of the arm (when ``lean``), the lead as Python floats: the same numbers
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
        q = self._ik_list(target, self.ik_config.iters)
        self._ctrl_row[:] = q
        self._pending_goal = q  # q_goal: np.array([q]) when first read (_Deferred)
        found, floor = self._substeps_one()
        self.step_count[0] = k + 1
        self._mocap_row[:] = path[min(k + 1, last)]
        return self._flags_lean(found, floor)

    def _flags(self, sensors: np.ndarray) -> None:
        """ArmBatch._flags of the arm's recorded rows (the steps step_one does not take)."""
        self._flags_one(sensors[0].tolist(), self._warning_number.tolist())

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

    def _ik_list(self, target: list[float], iters: int) -> list[float]:
        """ik(target) of the arm, on Python floats, warm-started from the measured angles: the
        same numbers. The elementwise arithmetic is
        done on Python floats (numpy's elementwise operations round exactly as Python's do, and
        the operands and their order are ik()'s); the linear algebra goes through the numpy
        routines ik() calls, on matrices of the same shapes and layouts (a stack's matrices are
        each computed on their own, so dropping ik()'s leading axis of one arm changes no
        number), into preallocated outputs. For one arm each numpy call costs more than the
        arithmetic in it, so this path makes as few as it can: five per iteration."""
        cfg = self.ik_config
        gain, cap = cfg.nullspace_gain, cfg.max_step
        q = self._qpos_row.tolist()
        rhs = self._rhs[0]  # (2, 3, 1): the tip error e, and J times the posture pull
        for i in range(iters):
            if i == 0:
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
            j0, j1, j2, j3, j4, j5, j6 = q
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
                if not math.isfinite(sum(steps)):  # singular or not finite: ik()'s own solve
                    np.matmul(jac_t, np.linalg.solve(systems, rhs), out=self._steps)
                    steps = self._steps_flat.tolist()
                # dq = step_0 + (pull - step_1)
                s0, s1, s2, s3, s4, s5, s6, t0, t1, t2, t3, t4, t5, t6 = steps
                d0, d1, d2, d3 = s0 + (p0 - t0), s1 + (p1 - t1), s2 + (p2 - t2), s3 + (p3 - t3)
                d4, d5, d6 = s4 + (p4 - t4), s5 + (p5 - t5), s6 + (p6 - t6)
            else:  # ik()'s calls (the default gain is not zero)
                a = (jac_t @ np.linalg.solve(jac @ jac_t + self._damp3, rhs[:1])).tolist()[0]
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
