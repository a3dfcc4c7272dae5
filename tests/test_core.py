"""The IK+PD core: Jacobian, IK convergence, holding a pose, self-collision, reachability; the
one-arm tests run on both implementations of one arm, the reference ArmBatch(1) and the
single env's fast path core_one.ArmOne, which must be a row of a batch bit for bit."""

import mujoco
import numpy as np
import pytest

from panda_lead.core import N_JOINTS, ArmBatch, IKConfig, home_qpos, load_model
from panda_lead.trajectory import leaves_reach, reachable, sample

try:
    from panda_lead.core_one import ArmOne
except ImportError:  # the fast path deleted (core_one.py says how): the reference alone
    ArmOne = None

HOME_QPOS = home_qpos()
# The implementations of one arm: the reference (ArmBatch of one) and the fast path.
ONE_ARM = [ArmBatch] + ([ArmOne] if ArmOne is not None else [])


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


@pytest.fixture(scope="module", params=ONE_ARM, ids=lambda cls: cls.__name__)
def core(request):
    return request.param(1, nthread=1)


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
        q = core.ik(target[None], q0=HOME_QPOS, iters=200)[0]
        assert np.linalg.norm(tip_at(core, q) - target) < 1e-3
        lo, hi = core.model.jnt_range[:N_JOINTS].T
        assert np.all(q >= lo) and np.all(q <= hi)


def test_ik_respects_joint_limits_for_unreachable_target(core):
    q = core.ik(np.array([[3.0, 0.0, 0.5]]), q0=HOME_QPOS, iters=100)[0]
    lo, hi = core.model.jnt_range[:N_JOINTS].T
    assert np.all(q >= lo) and np.all(q <= hi) and np.isfinite(q).all()


def test_closed_loop_reaches_static_target(core):
    target = tip_at(core, HOME_QPOS + np.array([0.3, 0.2, -0.2, 0.3, 0.1, -0.2, 0.0]))
    core.reset(trajs=[StaticTarget(target)], n_steps=300)
    for _ in range(300):
        core.step()
    assert np.linalg.norm(core.tip_pos[0] - target) < 1e-3


def test_pd_holds_home_pose_under_gravity(core):
    core.reset(trajs=[StaticTarget(tip_at(core, HOME_QPOS))], n_steps=200)
    start_tip = core.tip_pos[0].copy()
    for _ in range(200):  # 2 s
        core.step()
    assert np.abs(core.qpos - HOME_QPOS).max() < 1e-3
    assert np.linalg.norm(core.tip_pos[0] - start_tip) < 1e-3
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
    core.reset(trajs=[StaticTarget(tip_at(core, folded))], n_steps=5, qpos=folded)
    core.step()
    assert core.self_collision[0] and core.collision_depth[0] > 0


def test_reachability():
    assert reachable(np.array([0.5, 0.0, 0.4]))
    assert not reachable(np.array([1.5, 0.0, 0.4]))  # far outside the sphere
    assert not reachable(np.array([0.5, 0.0, -0.1]))  # below the floor
    assert not reachable(np.array([0.0, 0.0, 0.1]))  # inside the base column
    pts = np.array([[0.5, 0.0, 0.4], [1.5, 0.0, 0.4]])
    assert reachable(pts).tolist() == [True, False]


def test_one_definition_of_reachable():
    """Regression: leaves_reach used the sphere and floor only, the env's flag also the base
    column, so the two disagreed on test seeds whose target passes through the column."""
    disagree = 0
    for s in range(300):
        traj = sample(s)
        pos = traj.at(np.arange(501) / 100)[0]
        assert leaves_reach(traj) == bool((~reachable(pos)).any())
        in_column = (np.linalg.norm(pos[:, :2], axis=1) < 0.12) & (pos[:, 2] < 0.30)
        disagree += bool(in_column.any())
    assert disagree > 0  # seeds where only the column makes the target unreachable exist


def test_contact_flags_match_a_scan_of_every_substeps_contacts():
    """The contact sensors recorded after each substep say what a loop of mj_step with a scan
    of d.contact after every substep says (self-collision, its depth, floor contact)."""
    m = load_model()
    rng = np.random.default_rng(5)
    n = 24
    arms = ArmBatch(n, nthread=1)
    starts = HOME_QPOS + rng.uniform(-1.5, 1.5, (n, N_JOINTS))
    starts = np.clip(starts, m.jnt_range[:N_JOINTS, 0], m.jnt_range[:N_JOINTS, 1])
    targets = [StaticTarget(rng.uniform([-0.3, -0.6, -0.1], [0.9, 0.6, 0.9])) for _ in range(n)]
    arms.reset(trajs=targets, n_steps=40, qpos=starts)
    datas = [arms.get_data(i) for i in range(n)]
    seen_self = seen_floor = 0
    for _ in range(40):
        goals = arms.ik(arms.target()[0])
        arms.step()
        for i, d in enumerate(datas):
            d.ctrl[:N_JOINTS] = goals[i]
            hit, depth, floor = False, 0.0, False
            for _ in range(arms.substeps):
                mujoco.mj_step(m, d)
                for c in d.contact[: d.ncon]:
                    b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
                    if b1 and b2:
                        hit, depth = True, max(depth, -c.dist)
                    else:
                        floor = True
            np.testing.assert_array_equal(d.qpos[:N_JOINTS], arms.qpos[i])
            assert arms.self_collision[i] == hit and arms.floor_contact[i] == floor
            assert arms.collision_depth[i] == depth
            seen_self += hit
            seen_floor += floor
    assert seen_self > 0 and seen_floor > 0, "the test never exercised a contact"


def test_home_pose_and_rates_come_from_the_mjcf():
    m = load_model()
    np.testing.assert_array_equal(HOME_QPOS, m.key("home").qpos[:N_JOINTS])
    assert ArmBatch(1, nthread=1).dt == pytest.approx(m.opt.timestep * 5) == pytest.approx(0.01)


def test_stepping_before_a_target_path_is_a_clear_error():
    for cls in ONE_ARM:
        with pytest.raises(RuntimeError, match="reset\\(trajs="):
            cls(1, nthread=1).step()


@pytest.mark.skipif(ArmOne is None, reason="the fast path is deleted")
def test_the_single_env_takes_the_fast_path():
    """The single env runs task_one.LeadTaskOne on core_one.ArmOne, and a lead step goes
    through their step_one (the Python-float route the tests here and in test_batched.py and
    test_vector.py hold to the batch); settings it does not cover take the reference."""
    from panda_lead.env import PandaLeadEnv
    from panda_lead.task_one import LeadTaskOne

    assert ArmOne(1).lean and not ArmOne(1, IKConfig(substep_ik=True)).lean
    with pytest.raises(ValueError, match="clearance"):
        ArmOne(1, IKConfig(clearance=0.02))
    with pytest.raises(ValueError, match="ArmBatch"):
        ArmOne(2)
    env = PandaLeadEnv()
    assert type(env.task) is LeadTaskOne and type(env.core) is ArmOne and env.task._lean_lead
    assert not PandaLeadEnv(action_delay=1).task._lean_lead
    assert not PandaLeadEnv(action="joint").task._lean_lead
    assert type(PandaLeadEnv(ik={"clearance": 0.02}).core) is ArmBatch  # it needs the batch
    env.reset(seed=0)
    calls = []
    env.core.step_one = lambda lead: calls.append(lead) or (False, 0.0, False)
    env.step(np.zeros(3, np.float32))
    assert calls == [[0.0, 0.0, 0.0]]


# Every route of one arm's step: IK iterations from the measured angles and beyond, no posture
# pull, the step cap, the IK before every substep, and (below) joint offsets and joint goals.
ONE_ARM_IKS = [IKConfig(), IKConfig(iters=2), IKConfig(nullspace_gain=0.0),
               IKConfig(max_step=0.01), IKConfig(substep_ik=True), IKConfig(clearance=0.02)]


@pytest.mark.parametrize("ik", ONE_ARM_IKS, ids=lambda ik: repr(ik)[9:-1])
@pytest.mark.parametrize("cls", ONE_ARM, ids=lambda cls: cls.__name__)
def test_one_arm_is_a_row_of_a_batch_bit_for_bit(cls, ik):
    """One arm (ArmBatch(1), the reference, and ArmOne, which steps one plain MjData and does
    the IK's elementwise maths on Python floats) is the same arm as a row of a batch of
    several, bit for bit: state, Jacobian-driven goals, flags, warnings, with a lead, joint
    offsets and joint goals, including an arm MuJoCo finds unstable (its warning counters stop
    the remaining substeps, as Batch.rollout does)."""
    from panda_lead import trajectory

    if cls is ArmOne and ik.clearance:
        with pytest.raises(ValueError, match="clearance"):
            cls(1, ik)
        return
    rng = np.random.default_rng(7)
    trajs = [trajectory.sample(s) for s in (4, 5, 6)]
    one, many = cls(1, ik, nthread=1), ArmBatch(3, ik, nthread=1)
    one.reset(trajs=trajs[1:2], n_steps=40)
    many.reset(trajs=trajs, n_steps=40)
    for t in range(40):
        lead = rng.uniform(-0.15, 0.15, (3, 3))
        offset = rng.uniform(-0.1, 0.1, (3, N_JOINTS)) if t % 3 == 0 else None
        goal = HOME_QPOS + rng.uniform(-0.2, 0.2, (3, N_JOINTS)) if t % 7 == 5 else None
        if t == 25:  # blow arm 1 up
            one.qvel[0, 2] = many.qvel[1, 2] = 1e12
        if goal is not None:
            one.step(joint_goal=goal[1:2])
            many.step(joint_goal=goal)
        else:
            one.step(lead[1:2], None if offset is None else offset[1:2])
            many.step(lead, offset)
        for a, b in ((one.qpos, many.qpos), (one.qvel, many.qvel), (one.tip_pos, many.tip_pos),
                     (one.q_goal, many.q_goal), (one.self_collision, many.self_collision),
                     (one.collision_depth, many.collision_depth),
                     (one.floor_contact, many.floor_contact), (one.unstable, many.unstable),
                     (one.warning_counts(), many.warning_counts())):
            assert a.shape[1:] == b.shape[1:] and a.dtype == b.dtype
            assert np.array_equal(a[0], b[1]), t
        assert many.unstable[1] == (t == 25)
        for a, b in zip(one.target(), many.target(), strict=True):
            assert np.array_equal(a[0], b[1])
    target = many.target()[0]
    q0 = HOME_QPOS + rng.uniform(-0.5, 0.5, N_JOINTS)
    assert np.array_equal(one.ik(target[1:2], q0=q0, iters=20)[0],
                          many.ik(target, q0=q0, iters=20)[1])
    data = one.get_data(0)
    assert np.array_equal(data.qpos[:N_JOINTS], one.qpos[0])
    data.qpos[0] += 1.0  # a copy: the arm is untouched
    assert not np.array_equal(data.qpos[:N_JOINTS], one.qpos[0])


@pytest.mark.parametrize("cls", ONE_ARM, ids=lambda cls: cls.__name__)
def test_one_arm_contacts_come_from_the_sensor_history_as_from_a_read_after_each_substep(cls):
    """The single env's step (ArmOne) runs its substeps in one mj_step call and reads each
    substep's contact sensors from MuJoCo's sensor history (core_one._substeps_one): its flags
    are those of a loop of mj_step reading the sensors after every substep, also after an arm
    MuJoCo reset mid-step (the history's ring then starts elsewhere) and while it touches
    itself and the floor; as the reference's (ArmBatch(1), Batch.rollout's records) are."""
    m = load_model()
    rng = np.random.default_rng(3)
    start = np.clip(HOME_QPOS + rng.uniform(-1.5, 1.5, N_JOINTS), m.jnt_range[:N_JOINTS, 0],
                    m.jnt_range[:N_JOINTS, 1])
    target = StaticTarget(rng.uniform([-0.3, -0.6, -0.1], [0.9, 0.6, 0.9]))
    one = cls(1, nthread=1)
    assert cls is ArmBatch or (one.lean and one._history_rows)
    one.reset(trajs=[target], n_steps=80, qpos=start[None])
    d = one.get_data(0)
    seen = {"self": 0, "floor": 0}
    for t in range(80):
        if t == 12:  # a blow-up: MuJoCo resets the arm in the first substep
            one.qvel[0, 1] = d.qvel[1] = 1e12
        one.step()
        d.ctrl[:N_JOINTS] = one.q_goal[0]
        start_warnings = d.warning.number.copy()
        rows = []
        for _ in range(one.substeps):
            mujoco.mj_step(m, d)
            rows.append(d.sensordata.copy())
            if not np.array_equal(d.warning.number, start_warnings):
                break
        rows = np.array(rows)
        np.testing.assert_array_equal(d.qpos[:N_JOINTS], one.qpos[0])
        found = rows[:, 0] > 0
        assert one.self_collision[0] == found.any()
        assert one.floor_contact[0] == (rows[:, 2] > 0).any()
        assert one.collision_depth[0] == np.where(found, -rows[:, 1], 0.0).max()
        assert one.unstable[0] == (t == 12)
        shifted = int(d.history[m.sensor_historyadr[0] + 1]) != 4
        seen["self"] += shifted and found.any()
        seen["floor"] += shifted and (rows[:, 2] > 0).any()
    assert seen["self"] and seen["floor"]
