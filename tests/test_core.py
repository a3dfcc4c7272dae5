"""The IK+PD core: Jacobian, IK convergence, holding a pose, self-collision, reachability."""

import mujoco
import numpy as np
import pytest

from core import HOME_QPOS, N_JOINTS, ArmCore, reachable


class StaticTarget:
    """A target that never moves (the trajectory interface with zero derivatives)."""

    def __init__(self, pos):
        self.pos = np.asarray(pos, dtype=float)
        self.shape, self.seed = "static", -1

    def at(self, t):
        t = np.asarray(t, dtype=float)
        if t.ndim == 0:
            return self.pos.copy(), np.zeros(3), np.zeros(3)
        n = len(t)
        return np.tile(self.pos, (n, 1)), np.zeros((n, 3)), np.zeros((n, 3))


@pytest.fixture(scope="module")
def core():
    return ArmCore()


def tip_at(core, q):
    d = mujoco.MjData(core.model)
    d.qpos[:N_JOINTS] = q
    mujoco.mj_kinematics(core.model, d)
    return d.site("tip").xpos.copy()


def test_tip_jacobian_matches_finite_differences(core):
    rng = np.random.default_rng(0)
    m = core.model
    for _ in range(10):
        q = HOME_QPOS + rng.uniform(-0.8, 0.8, N_JOINTS)
        d = mujoco.MjData(m)
        d.qpos[:N_JOINTS] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        jac = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jac, None, m.site("tip").id)
        h = 1e-6
        fd = np.stack([(tip_at(core, q + h * e) - tip_at(core, q - h * e)) / (2 * h)
                       for e in np.eye(N_JOINTS)], axis=1)
        np.testing.assert_allclose(jac[:, :N_JOINTS], fd, atol=1e-6)


def test_ik_converges_to_reachable_static_targets(core):
    rng = np.random.default_rng(1)
    for _ in range(30):
        # Targets the arm can reach: the tip of a random posture around the home pose.
        target = tip_at(core, HOME_QPOS + rng.uniform(-0.7, 0.7, N_JOINTS))
        q = core.ik(target, q0=HOME_QPOS, iters=200)
        assert np.linalg.norm(tip_at(core, q) - target) < 1e-3
        lo, hi = core.model.jnt_range[:N_JOINTS].T
        assert np.all(q >= lo) and np.all(q <= hi)


def test_ik_respects_joint_limits_for_unreachable_target(core):
    q = core.ik(np.array([3.0, 0.0, 0.5]), q0=HOME_QPOS, iters=100)
    lo, hi = core.model.jnt_range[:N_JOINTS].T
    assert np.all(q >= lo) and np.all(q <= hi) and np.isfinite(q).all()


def test_closed_loop_reaches_static_target(core):
    target = tip_at(core, HOME_QPOS + np.array([0.3, 0.2, -0.2, 0.3, 0.1, -0.2, 0.0]))
    core.reset(StaticTarget(target), 300)
    for _ in range(300):
        core.step()
    assert np.linalg.norm(core.tip_pos - target) < 1e-3


def test_pd_holds_home_pose_under_gravity(core):
    core.reset(StaticTarget(tip_at(core, HOME_QPOS)), 200)
    start_tip = core.tip_pos.copy()
    for _ in range(200):  # 2 s
        core.step()
    assert np.abs(core.qpos - HOME_QPOS).max() < 1e-3
    assert np.linalg.norm(core.tip_pos - start_tip) < 1e-3
    assert np.abs(core.qvel).max() < 1e-3


def test_gravity_compensation_is_what_holds_the_arm(core):
    """Without the actuators' PD the arm still does not fall: gravcomp carries its weight."""
    m = core.model
    d = mujoco.MjData(m)
    d.qpos[:N_JOINTS] = HOME_QPOS
    mujoco.mj_forward(m, d)
    # bias forces (gravity) are cancelled by gravcomp when at rest
    np.testing.assert_allclose(d.qfrc_gravcomp[:N_JOINTS], d.qfrc_bias[:N_JOINTS], atol=1e-6)


def test_self_collision_detected_on_folded_pose_and_not_at_home(core):
    core.reset(qpos=HOME_QPOS)
    assert core.contact_pairs() == []
    folded = np.array([0.0, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0])  # wrist folded onto the forearm
    core.reset(qpos=folded)
    pairs = core.contact_pairs()
    bodies = {frozenset((a, b)) for a, b, _ in pairs}
    assert frozenset(("link5", "hand")) in bodies
    assert all(depth > 0 for _, _, depth in pairs)


def test_self_collision_flag_during_a_step(core):
    folded = np.array([0.0, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0])
    core.reset(StaticTarget(tip_at(core, folded)), 5, qpos=folded)
    core.step()
    assert core.self_collision and core.collision_depth > 0


def test_reachability():
    assert reachable(np.array([0.5, 0.0, 0.4]))
    assert not reachable(np.array([1.5, 0.0, 0.4]))  # far outside the sphere
    assert not reachable(np.array([0.5, 0.0, -0.1]))  # below the floor
    assert not reachable(np.array([0.0, 0.0, 0.1]))  # inside the base column
    pts = np.array([[0.5, 0.0, 0.4], [1.5, 0.0, 0.4]])
    assert reachable(pts).tolist() == [True, False]
