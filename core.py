"""The shared IK+PD core, and the classical baselines built on it.

Every controller in this repo runs on `ArmCore`: damped-least-squares IK on the tip site's
position Jacobian, warm-started from the current joint angles, feeding MuJoCo position
actuators (a joint PD at the 500 Hz physics rate) with gravity compensation on every link.
The classical controller is this core with a zero lead; the analytic-lead baseline adds
``v*tau + a*tau^2/2``; the learned policy adds its own lead. Nothing else differs.

Why IK runs once per control step (100 Hz) and not at 500 Hz: the IK target only changes when
the lead (an action) or the sampled target changes, both at the control rate; between those
the PD converges on the joint goal. A second DLS iteration per control step buys little
(see README), so one iteration from the measured joint angles is the default.

The classical baseline's command line is the thin script ``ikpd.py``; nothing here imports
anything above this module.
"""

from __future__ import annotations

import importlib.util
import math
import os
from dataclasses import dataclass
from pathlib import Path

if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    import ctypes.util

    # Headless: offscreen rendering through EGL, where the EGL library exists (MuJoCo reads
    # this once, at import; a machine without EGL can still simulate, just not render).
    if ctypes.util.find_library("EGL"):
        os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import trajectory  # noqa: E402

ASSETS = Path(__file__).resolve().parent / "assets"
SCENE_XML = ASSETS / "scene.xml"
N_JOINTS = 7
HOME_QPOS = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
CONTROL_SUBSTEPS = 5  # 500 Hz physics, 100 Hz control
# A target is reachable when it is inside the reach sphere and above the floor margin (the
# geometry lives in trajectory.py, which samples against it; the sphere's radius is measured:
# max |tip - shoulder| over 20k random configurations is 0.947 m) and not inside the base
# column, which the tip cannot enter without the arm folding into itself.
BASE_COLUMN_RADIUS, BASE_COLUMN_TOP = 0.12, 0.30


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


_MODEL_CACHE: dict[str, mujoco.MjModel] = {}


def load_model() -> mujoco.MjModel:
    """The scene with the Panda, compiled once per process (compiling the meshes takes ~0.3 s)."""
    if "scene" not in _MODEL_CACHE:
        _MODEL_CACHE["scene"] = mujoco.MjModel.from_xml_path(str(SCENE_XML), _mesh_assets())
    return _MODEL_CACHE["scene"]


def reachable(pos: np.ndarray) -> np.ndarray | bool:
    """Whether the tip can reach a position (or each row of an (N, 3) array)."""
    p = np.asarray(pos, dtype=float)
    in_column = (np.linalg.norm(p[..., :2], axis=-1) < BASE_COLUMN_RADIUS) & (
        p[..., 2] < BASE_COLUMN_TOP
    )
    ok = ~trajectory.out_of_reach(p) & ~in_column
    return bool(ok) if ok.ndim == 0 else ok


def analytic_lead(vel: np.ndarray, acc: np.ndarray, tau: float, max_lead: float) -> np.ndarray:
    """Second-order extrapolation of the target over tau seconds, clipped like the RL lead."""
    return np.clip(vel * tau + 0.5 * acc * tau * tau, -max_lead, max_lead)


@dataclass(frozen=True)
class IKConfig:
    damping: float = 0.05
    """DLS damping lambda (m): keeps steps finite near singularities and out-of-reach targets."""
    iters: int = 1
    """DLS iterations per control step, each from the last (the first from the measured q)."""
    nullspace_gain: float = 0.1
    """Pull towards the home posture in the Jacobian's null space, so the elbow does not drift."""
    max_step: float = 0.5
    """Largest joint change per iteration (rad, infinity norm)."""
    limit_margin: float = 0.02
    """Joint goals stay this far (rad) inside the joint limits."""


class ArmCore:
    """The Panda plus its controller: ``step(lead)`` is one 100 Hz control step.

    A trajectory is played back from arrays precomputed at reset (positions, velocities and
    accelerations at every control step), so a step does no trajectory maths.
    """

    def __init__(self, model: mujoco.MjModel | None = None, ik: IKConfig = IKConfig(),
                 substeps: int = CONTROL_SUBSTEPS):
        self.model = model if model is not None else load_model()
        self.data = mujoco.MjData(self.model)
        self._ik_data = mujoco.MjData(self.model)  # scratch kinematics for IK iterations
        self.ik_config = ik
        self.substeps = int(substeps)
        self.dt = self.model.opt.timestep * self.substeps
        m = self.model
        self._tip = m.site("tip").id
        self._mocap = m.body("target").mocapid[0]
        self._lo = m.jnt_range[:N_JOINTS, 0] + ik.limit_margin
        self._hi = m.jnt_range[:N_JOINTS, 1] - ik.limit_margin
        self._jacp = np.zeros((3, m.nv))
        self._damp3 = np.eye(3) * ik.damping**2
        self._eps3 = np.eye(3) * 1e-10
        self._chol, self._sol = np.zeros((3, 3)), np.zeros(3)
        arm_bodies = {m.body(f"link{i}").id for i in range(8)} | {m.body("hand").id}
        self._is_arm_geom = np.array([m.geom_bodyid[g] in arm_bodies for g in range(m.ngeom)])
        # MuJoCo counts each kind of warning in d.warning; a live numpy view of the counters of
        # the "simulation is unstable" kinds (contiguous in mjtWarning) costs one slice a step.
        w = mujoco.mjtWarning
        bad = sorted(int(x) for x in (w.mjWARN_BADQPOS, w.mjWARN_BADQVEL, w.mjWARN_BADQACC,
                                      w.mjWARN_BADCTRL))
        assert bad == list(range(bad[0], bad[0] + 4)), bad
        self._bad_warnings = self.data.warning.number[bad[0]:bad[0] + 4]
        self._jac_arm = self._jacp[:, :N_JOINTS]  # the arm's columns (all of them here: nv = 7)
        # Live views into MjData, whose buffers never move: bound once, read every step (the
        # tip position in the world, the arm's joint angles and velocities). Copy to keep.
        self.tip_pos = self.data.site_xpos[self._tip]
        self.qpos = self.data.qpos[:N_JOINTS]
        self.qvel = self.data.qvel[:N_JOINTS]
        self.reset()

    # --- state -----------------------------------------------------------------------------
    def reset(self, traj=None, n_steps: int = 0, qpos: np.ndarray | None = None) -> None:
        """Restore every piece of state: arm, actuator goals, IK warm start, target, clock."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        q0 = HOME_QPOS if qpos is None else np.asarray(qpos, dtype=float)
        d.qpos[:N_JOINTS] = q0
        d.ctrl[:N_JOINTS] = q0
        self.q_goal = q0.copy()
        self.step_count = 0
        self.traj = traj
        self.unstable = False
        self.self_collision = False
        self.collision_depth = 0.0
        self.floor_contact = False
        if traj is not None:
            times = np.arange(n_steps + 1) * self.dt
            self.target_path = tuple(np.array(a, dtype=float) for a in traj.at(times))
            d.mocap_pos[self._mocap] = self.target_path[0][0]
        mujoco.mj_forward(m, d)
        self._kinematics_current = True
        self._warnings_seen = self._bad_warning_state()

    @property
    def time(self) -> float:
        return self.step_count * self.dt

    def target(self, k: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(pos, vel, acc) of the target at control step k (default: now)."""
        k = self.step_count if k is None else k
        pos, vel, acc = self.target_path
        if k < len(pos):
            return pos[k], vel[k], acc[k]
        return tuple(np.asarray(a, dtype=float) for a in self.traj.at(k * self.dt))

    # --- control ---------------------------------------------------------------------------
    def ik(self, target: np.ndarray, q0: np.ndarray | None = None, iters: int | None = None
           ) -> np.ndarray:
        """DLS IK for the tip position, warm-started from q0 (default: the measured angles)."""
        m, cfg = self.model, self.ik_config
        q = (self.data.qpos[:N_JOINTS] if q0 is None else q0).copy()
        jacp, jac = self._jacp, self._jac_arm
        for i in range(cfg.iters if iters is None else iters):
            if i == 0 and q0 is None and self._kinematics_current:
                d = self.data  # its kinematics are those of the measured q already
            else:
                d = self._ik_data
                d.qpos[:N_JOINTS] = q
                mujoco.mj_kinematics(m, d)
                mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jacp, None, self._tip)
            err = target - d.site_xpos[self._tip]
            # Damped step J^T (J J^T + l^2 I)^-1 e, and the posture pull projected by the exact
            # null-space projector I - J^T (J J^T)^-1 J (a damped projector would leak the pull
            # into the tip position and bias the solution by centimetres near singularities).
            # 3x3 Cholesky solves through MuJoCo's own routines: a third of an SVD's cost.
            jjt = jac @ jac.T
            chol, sol = self._chol, self._sol
            np.add(jjt, self._damp3, out=chol)
            mujoco.mju_cholFactor(chol, 0.0)
            mujoco.mju_cholSolve(sol, chol, err)
            dq = jac.T @ sol
            if cfg.nullspace_gain:
                pull = cfg.nullspace_gain * (HOME_QPOS - q)
                np.add(jjt, self._eps3, out=chol)
                mujoco.mju_cholFactor(chol, 1e-12)
                mujoco.mju_cholSolve(sol, chol, jac @ pull)
                dq += pull - jac.T @ sol
            peak = np.abs(dq).max()
            if peak > cfg.max_step:
                dq *= cfg.max_step / peak
            q += dq
            np.minimum(np.maximum(q, self._lo, out=q), self._hi, out=q)
        return q

    def step(self, lead: np.ndarray | None = None) -> None:
        """One control step: IK on (target + lead), then the PD runs for `substeps` physics steps."""
        m, d = self.model, self.data
        target = self.target()[0]
        ik_target = target if lead is None else target + lead
        self.q_goal = self.ik(ik_target)
        d.ctrl[:N_JOINTS] = self.q_goal
        self.self_collision = False
        self.collision_depth = 0.0
        self.floor_contact = False
        warnings_before = self._warnings_seen
        self._kinematics_current = False
        for _ in range(self.substeps):
            mujoco.mj_step(m, d)
            if d.ncon:
                self._scan_contacts()
        self.step_count += 1
        if self.step_count < len(self.target_path[0]):
            d.mocap_pos[self._mocap] = self.target_path[0][self.step_count]
        # MuJoCo resets the state itself on a NaN/huge position, velocity, acceleration or
        # control (and only warns); the warning counters and a finiteness check catch it.
        self._warnings_seen = self._bad_warning_state()
        # q.q is NaN or inf exactly when some q is (or is astronomically large): one dot product
        # instead of a ufunc and a reduction.
        if self._warnings_seen != warnings_before or not math.isfinite(d.qpos @ d.qpos):
            self.unstable = True
        else:
            # mj_step leaves positions of the substep's start: refresh them (and the COM
            # quantities the next IK Jacobian needs) for the state the step ends in.
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            self._kinematics_current = True

    def _bad_warning_state(self) -> bytes:
        """The counters as bytes: comparing two of these is cheaper than summing them."""
        return self._bad_warnings.tobytes()

    def _scan_contacts(self) -> None:
        con = self.data.contact
        g1, g2 = con.geom1, con.geom2
        arm1, arm2 = self._is_arm_geom[g1], self._is_arm_geom[g2]
        both = arm1 & arm2
        if both.any():
            self.self_collision = True
            self.collision_depth = max(self.collision_depth, float(-con.dist[both].min()))
        if (arm1 ^ arm2).any():
            self.floor_contact = True

    def contact_pairs(self) -> list[tuple[str, str, float]]:
        """Which arm bodies touch each other now, and how deep (m). For inspection and tests."""
        m, d = self.model, self.data
        mujoco.mj_collision(m, d)
        pairs = []
        for c in d.contact[: d.ncon]:
            if self._is_arm_geom[c.geom1] and self._is_arm_geom[c.geom2]:
                b1, b2 = m.body(m.geom_bodyid[c.geom1]).name, m.body(m.geom_bodyid[c.geom2]).name
                pairs.append((b1, b2, float(-c.dist)))
        return pairs
