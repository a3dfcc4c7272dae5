"""Collision-aware IK (clearance.py): its geometry is MuJoCo's, and it keeps the arm apart."""

from __future__ import annotations

import mujoco
import mujoco.batch
import numpy as np
import pytest

from panda_lead import clearance, controllers
from panda_lead.config import EnvConfig
from panda_lead.core import N_JOINTS, ArmBatch, IKConfig, load_model
from panda_lead.errors import UserError
from panda_lead.rollout import record_many


def _random_arms(n, seed=0):
    m = load_model()
    b = mujoco.batch.Batch(m, nsim=n, nthread=1, persistent=True)
    b.reset(None, keyframe=m.key("home").id)
    lo, hi = m.jnt_range[:N_JOINTS].T
    b.bind("qpos")[:, :N_JOINTS] = np.random.default_rng(seed).uniform(lo, hi, (n, N_JOINTS))
    b.forward()
    return m, b


def test_the_pairs_are_every_arm_pair_mujoco_reports_in_contact():
    m = load_model()
    pairs = set(map(tuple, clearance.capsule_pairs(m).tolist()))
    d, rng, seen = mujoco.MjData(m), np.random.default_rng(1), set()
    lo, hi = m.jnt_range[:N_JOINTS].T
    for _ in range(1500):
        d.qpos[:N_JOINTS] = rng.uniform(lo, hi)
        mujoco.mj_forward(m, d)
        seen |= {tuple(sorted((int(c.geom1), int(c.geom2)))) for c in d.contact[:d.ncon]
                 if m.geom_bodyid[c.geom1] and m.geom_bodyid[c.geom2]}
    assert len(seen) >= 10  # random poses fold the arm into itself in many ways
    assert seen <= pairs
    # Parent-child links and the explicitly excluded base pair are never checked.
    names = {(m.geom(a).name, m.geom(b).name) for a, b in pairs}
    assert ("link0_c", "link1_c") not in names and ("link4_c", "link5_c") not in names


def test_distances_and_point_jacobians_are_mujocos():
    m, b = _random_arms(6)
    clr = clearance.Clearance(m, b, N_JOINTS, 0.02)
    dist, normal, p1, p2 = clr.distances()
    np.testing.assert_allclose(np.linalg.norm(normal, axis=-1), 1.0, atol=1e-12)
    for s in range(6):
        d = b.get_data(s)
        for k, (g1, g2) in enumerate(clr.pairs):
            assert dist[s, k] == pytest.approx(
                mujoco.mj_geomDistance(m, d, g1, g2, 10.0, np.zeros(6)), abs=1e-12)
        for body in range(1, m.nbody):
            point = d.xpos[body] + np.array([0.03, -0.02, 0.05])
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, None, point, body)
            z, anchor = clr._axis[s], clr._anchor[s]
            mine = np.cross(z, point - anchor) * clr._moves[body][:, None]
            np.testing.assert_allclose(mine.T, jacp[:, :N_JOINTS], atol=1e-12)


def test_the_projected_step_meets_every_near_pairs_constraint():
    m, b = _random_arms(64, seed=2)
    clr = clearance.Clearance(m, b, N_JOINTS, 0.02)
    dq = np.random.default_rng(3).normal(0, 0.2, (64, N_JOINTS))
    out = clr.project(dq)
    dist, normal, p1, p2 = clr.distances()
    # The first-order change of each near pair's distance, by finite differences of the pose.
    q = b.bind("qpos")[:, :N_JOINTS].copy()
    near = dist < clr.clearance + clearance.INFLUENCE
    assert near.any(axis=1).sum() >= 10  # random poses: many arms have a pair near
    eps = 1e-6
    b.bind("qpos")[:, :N_JOINTS] = q + eps * out
    b.forward()
    rate = (clr.distances()[0] - dist) / eps
    nearest = np.argsort(dist, axis=1)[:, :clearance.SLOTS]
    for i in range(64):
        for k in nearest[i]:
            if near[i, k]:
                assert rate[i, k] >= -clr.gain * (dist[i, k] - clr.clearance) - 1e-4
    untouched = ~near.any(axis=1)
    np.testing.assert_array_equal(out[untouched], dq[untouched])


def test_collision_aware_ik_keeps_a_colliding_trajectory_apart():
    # Test seeds whose classical rollout touches itself within its first 0.5 s (an input,
    # found by scanning the test set's classical rollouts, not a result of the code here).
    seeds = [264, 205, 952]
    base = EnvConfig(episode_steps=120, terminate_on_collision=False)
    plain = record_many(base, controllers.classical, seeds)
    aware = record_many(base.merged({"ik": {"clearance": 0.02}}), controllers.classical, seeds)
    before = np.mean([r.self_collision.mean() for r in plain])
    after = np.mean([r.self_collision.mean() for r in aware])
    assert before > 0.05
    assert after < before / 4
    err = lambda rs: np.mean([np.linalg.norm(r.ee_pos - r.target_pos, axis=1).mean() for r in rs])  # noqa: E731
    assert err(aware) < err(plain) + 0.01  # it does not give the target up to get there


def test_clearance_off_is_the_plain_ik_and_bad_values_are_clear_errors():
    assert ArmBatch(2, IKConfig())._clearance is None
    with pytest.raises(UserError, match="ik.clearance"):
        EnvConfig(ik={"clearance": -0.01})
    with pytest.raises(UserError, match="ik.clearance needs ik.iters 1"):
        EnvConfig(ik={"clearance": 0.02, "iters": 2})
    # Sidecars from before the IK settings were nested read the same.
    assert EnvConfig.from_dict({"ik_clearance": 0.02}).ik.clearance == 0.02


def test_a_planned_joint_path_is_collision_aware_where_the_plan_puts_the_arm():
    """The IK away from the measured angles (preview.desired_joint_path: the feedforward rival's
    plan, computed at reset while the arm is at home) projects each step with the capsules
    where that step's angles put them: on paths that pass near the body the plain plan goes
    into the arm, the collision-aware one stays clear of it; the clearance never shortens the
    first, unconstrained solve (the arm at home is far from itself)."""
    from panda_lead import preview, trajectory

    seeds = [264, 205, 952]  # test_collision_aware_ik_keeps_a_colliding_trajectory_apart's
    times = np.arange(120) * ArmBatch(1).dt
    pos = np.stack([trajectory.sample(s).at(times)[0] for s in seeds])
    plain, aware = ArmBatch(3), ArmBatch(3, IKConfig(clearance=0.02))
    paths = {name: preview.desired_joint_path(core, pos)
             for name, core in (("plain", plain), ("aware", aware))}
    closest = {}
    for name, q in paths.items():  # the nearest capsule pair at every planned step
        closest[name] = []
        for k in range(q.shape[1]):
            aware._kinematics_at(q[:, k])
            closest[name].append(aware._scratch_clearance.distances()[0].min(axis=1))
        closest[name] = np.array(closest[name])  # (T, N)
    assert closest["plain"].min() < 0  # the plain plan puts the arm into itself
    assert closest["aware"].min() > 0.0
    assert (closest["aware"].min(axis=0) > closest["plain"].min(axis=0)).all()


def test_a_goal_set_around_the_ik_is_projected_as_the_iks_own_steps():
    """Under ik.clearance the damper sees the whole command: a joint goal that skips the IK
    (the feedforward rival's) and a joint offset on the IK's solution go through the same
    projection as the IK's steps, here one that forbids any motion (so the goal stays at the
    measured angles); without a clearance both go to the PD as they are."""
    from panda_lead import trajectory

    trajs = [trajectory.sample(s) for s in (264, 205)]
    goal = np.tile(ArmBatch(1).home, (2, 1)) + 0.05
    for margin in (0.0, 0.02):
        core = ArmBatch(2, IKConfig(clearance=margin))
        core.reset(trajs=trajs, n_steps=50)
        if margin:
            core._clearance.project = lambda dq: np.zeros_like(dq)  # a wall every way
        still = core.qpos.copy()
        core.step(joint_goal=goal)
        np.testing.assert_allclose(core.q_goal, still if margin else goal)
        still = core.qpos.copy()
        core.step(lead=np.zeros((2, 3)), joint_offset=np.full((2, N_JOINTS), 0.05))
        if margin:
            np.testing.assert_allclose(core.q_goal, still)
        else:
            assert np.abs(core.q_goal - still).max() > 0.04
