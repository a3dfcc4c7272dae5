"""The classical rivals that know the planned path (issue 37): the IK aimed at the exact future
target, and the model-based feedforward that inverts the simulated joint servos."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from panda_lead import controllers, preview
from panda_lead.config import EnvConfig
from panda_lead.core import N_JOINTS, home_qpos, load_model
from panda_lead.harness import build
from panda_lead.rollout import record_many
from panda_lead.task import LeadTask

ROOT = Path(__file__).resolve().parents[1]
SEEDS = [3, 11]


def test_the_future_target_lead_is_the_path_ahead_minus_the_present():
    tau = 0.05  # 5 control steps: p(t + tau) is a row of the path, no interpolation
    config = EnvConfig(episode_steps=40, max_lead=1.0)  # a bound that clips nothing here
    task = LeadTask(config, len(SEEDS))
    obs = task.reset(None, SEEDS)
    act = preview.make_future_target(tau)
    for _ in range(7):
        obs, *_ = task.step(act(obs, task))
    lead = act(obs, task) * config.max_lead
    for i in range(len(SEEDS)):
        t = task.core.time[i]
        want = task.trajs[i].at(t + tau)[0] - task.trajs[i].at(t)[0]
        assert np.allclose(lead[i], want, atol=1e-6)  # float32 actions


def test_the_future_target_lead_reads_the_path_past_the_episodes_end():
    config = EnvConfig(episode_steps=5, max_lead=1.0)
    task = LeadTask(config, 1)
    obs = task.reset(None, [7])
    act = preview.make_future_target(0.2)  # 20 steps ahead of a 5-step episode
    for _ in range(5):
        obs, *_ = task.step(act(obs, task))
    t = task.core.time[0]
    want = task.trajs[0].at(t + 0.2)[0] - task.trajs[0].at(t)[0]
    assert np.allclose(act(obs, task)[0], want, atol=1e-6)


def test_the_servo_correction_is_mass_times_acceleration_plus_bias_without_gravity():
    """The brief's formula, computed independently: (M qdd + qfrc_bias - gravity compensation
    + joint damping qd + actuator kv qd) / kp, from mj_fullM and mj_forward."""
    config = EnvConfig(episode_steps=30)
    task = LeadTask(config, 1)
    task.reset(None, [5])
    cache = preview._PathCache(0.0, joint_path=True)
    cache.update(task)
    q, corr = cache.goal[0, :, :, 0], cache.goal[0, :, :, 1]
    dt = task.dt
    qd, qdd = np.gradient(q, dt, axis=0), np.gradient(np.gradient(q, dt, axis=0), dt, axis=0)
    m = load_model()
    d = mujoco.MjData(m)
    kp = np.array([2000, 2000, 1500, 1500, 500, 500, 300.0])  # assets/panda.xml
    for k in (3, 15, 28):
        d.qpos[:N_JOINTS], d.qvel[:N_JOINTS] = q[k], qd[k]
        mujoco.mj_forward(m, d)
        mass = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, mass)
        kv = -m.actuator_biasprm[:N_JOINTS, 2]
        force = (mass @ qdd[k] + d.qfrc_bias - d.qfrc_gravcomp)[:N_JOINTS]
        want = (force + (m.dof_damping[:N_JOINTS] + kv) * qd[k]) / kp
        assert np.allclose(corr[k], want, rtol=1e-6, atol=1e-9)
    # The desired path is the IK of the target: the tip sits on the target along it.
    tip = m.site("tip").id
    for k in (0, 15, 30):
        d.qpos[:N_JOINTS] = q[k]
        mujoco.mj_kinematics(m, d)
        assert np.linalg.norm(d.site_xpos[tip] - cache.pos[0, k]) < 1e-3


def test_a_joint_goal_survives_the_joint_target_action_map():
    task = LeadTask(EnvConfig(episode_steps=3, action="joint_target"), 1)
    task.reset(None, [1])
    goal = home_qpos() + np.array([0.3, -0.2, 0.1, 0.4, -0.5, 0.2, -0.1])
    task.step(preview.joint_target_action(task.core, goal[None]))
    assert np.allclose(task.core.q_goal[0], goal, atol=1e-6)


def test_inverting_the_servos_tracks_better_than_the_plain_ik():
    config = EnvConfig(episode_steps=150)
    base = record_many(config, controllers.classical, SEEDS)
    ff = record_many(config.replace(action="joint_target"), controllers.make_feedforward(),
                     SEEDS)
    for a, b in zip(base, ff, strict=True):
        assert b.error[50:].mean() < 0.5 * a.error[50:].mean()


def test_ikpd_writes_both_rivals_rollouts_labelled_as_knowing_the_path(tmp_path):
    for name in controllers.PREVIEW_RIVALS:
        out = subprocess.run([sys.executable, str(ROOT / "ikpd.py"), "--controller", name,
                              "--seeds", "0-1", "--prefix", name, "--duration", "0.3"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr
        files = sorted((tmp_path / "rollouts" / name).glob("seed_*.npz"))
        assert len(files) == 2
        meta = json.loads(str(np.load(files[0])["meta"]))
        assert meta["controller"] == name and meta["knows_path"] is True
        settings = json.loads(json.dumps(build(name, 30).meta))  # as the file stores them
        assert {k: meta[k] for k in settings} == settings


@pytest.mark.parametrize("name", controllers.PREVIEW_RIVALS)
def test_a_rival_refuses_the_wrong_action_kind(name):
    wrong = "joint_target" if name == "future_target" else "lead"
    task = LeadTask(EnvConfig(episode_steps=3, action=wrong), 1)
    obs = task.reset(None, [1])
    act = {"future_target": controllers.make_future_target,
           "feedforward": controllers.make_feedforward,
           "feedforward_plan": controllers.make_planned_feedforward}[name]()
    with pytest.raises(ValueError, match="needs action"):
        act(obs, task)


def test_the_clipped_correction_asks_no_motor_for_more_than_its_force_range():
    """On the planned path the goal's force kp (u - q_d) - kv qd_d stays within each motor's
    forcerange once clipped; unclipped, a fast path asks for more (else the test shows
    nothing)."""
    task = LeadTask(EnvConfig(episode_steps=60), 1)
    task.reset(None, [38])  # a fast circle near the workspace's edge (test seed 38)
    m = load_model()
    kp, kv = m.actuator_gainprm[:N_JOINTS, 0], -m.actuator_biasprm[:N_JOINTS, 2]
    limit = m.actuator_forcerange[:N_JOINTS, 1]
    forces = {}
    for clip in (False, True):
        cache = preview._PathCache(0.0, joint_path=True, clip=clip)
        cache.update(task)
        q, corr = cache.goal[0, :, :, 0], cache.goal[0, :, :, 1]
        qd = np.gradient(q, task.dt, axis=0)
        forces[clip] = kp * corr - kv * qd
    assert (np.abs(forces[True]) <= limit + 1e-9).all()
    assert (np.abs(forces[False]) > limit).any()


def test_a_reset_slot_gets_the_same_servo_goals_without_the_others_inverse_dynamics():
    """The path cache recomputes only the slot that reset; its goals are those a whole-batch
    computation gives it, and the other slot's rows are left as they were."""
    config = EnvConfig(episode_steps=20)
    task = LeadTask(config, 2)
    task.reset(None, SEEDS)
    cache = preview._PathCache(0.05, joint_path=True)
    cache.update(task)
    kept = cache.goal[0].copy()
    task.reset([1], [29])
    cache.update(task)
    whole = preview.servo_goals(task.core, cache.pos, task.dt)
    np.testing.assert_array_equal(cache.goal[1], whole[1])
    np.testing.assert_array_equal(cache.goal[0], kept)
    assert not np.allclose(cache.goal[1], whole[0])


# --- the feedforward rival under a learned lead (EnvConfig.feedforward) ----------------------

def test_a_zero_lead_on_the_feedforward_env_is_the_feedforward_rival():
    """The env's feedforward with no lead tracks as the rival does (the rival's goal passes
    through the float32 joint_target action: ~1e-7 rad), and a lead moves the arm."""
    config = EnvConfig(episode_steps=120)
    rival = record_many(config.replace(action="joint_target"), controllers.make_feedforward(),
                        SEEDS)
    in_env = record_many(config.replace(feedforward=True), controllers.classical, SEEDS)
    leading = record_many(config.replace(feedforward=True), controllers.make_analytic(), SEEDS)
    for a, b, c in zip(rival, in_env, leading, strict=True):
        np.testing.assert_allclose(b.error, a.error, atol=1e-5)
        assert np.abs(c.error - b.error).max() > 1e-3


def test_the_feedforward_env_knows_the_path_and_its_baselines_play_without_it(monkeypatch):
    from panda_lead import harness, models
    from panda_lead.config import knows_path

    assert knows_path(EnvConfig(feedforward=True))
    assert knows_path({"obs_features": ["ee_pos"], "feedforward": True})  # a sidecar's env
    assert not knows_path(EnvConfig()) and not knows_path(("ee_pos", "tip_error"))
    with pytest.raises(Exception, match="feedforward puts the feedforward rival"):
        EnvConfig(feedforward=True, action="joint")
    # a baseline asked to play on a residual model's env plays without the feedforward (it
    # would be the feedforward rival under another name); the policy keeps it
    monkeypatch.setattr(models, "load_policy", lambda path: (
        object(), {"feedforward": True}, {"model_sha256": "0" * 64}))
    for name, kept in (("classical", False), ("analytic", False), ("policy", True)):
        monkeypatch.setattr(harness.controllers, "make_policy", lambda *a, **k: None)
        ctrl = harness.build(name, 10, Path("residual.zip"))
        assert ctrl.config.feedforward is kept


def test_preview_rivals_tunes_the_clipped_feedforward_when_asked(monkeypatch, capsys):
    """studies/preview_rivals.py --clip --no-future: each feedforward setting of the grid is
    built clipped to the motors (the rival in use), the future-target lead is skipped, and the
    header's command carries both flags (a tuning table must rerun as printed). The scoring is
    stubbed: what is tested is the grid, not the arm."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "studies"))
    import preview_rivals

    from panda_lead import preview

    built = []
    monkeypatch.setattr(preview, "make_feedforward",
                        lambda tau, gain, tau_ik, clip=False: built.append(
                            (tau, gain, tau_ik, clip)) or (lambda obs, task: None))
    scores = iter([(4.0, 3.0), (2.5, 1.5), (2.0, 1.0)])  # analytic, then the two settings
    monkeypatch.setattr(preview_rivals, "mean_errors", lambda *_: next(scores))
    preview_rivals.main(preview_rivals.Args(clip=True, future=False,
                                            ff_settings=("0.02:0.8:0.01", "0.03:0.9:none")))
    out = capsys.readouterr().out
    assert built == [(0.02, 0.8, 0.01, True), (0.03, 0.9, None, True)]
    assert ("`uv run studies/preview_rivals.py --clip --no-future --ff-settings 0.02:0.8:0.01 "
            "0.03:0.9:none` at commit") in out
    assert "future target |" not in out
    assert "best: feedforward 0.03:0.9:none (2.00 cm)" in out


# --- the feedforward that follows its plan (feedforward_plan, EnvConfig.follow_plan) ---------

FOLLOWABLE, BEYOND = 5, 38  # 1.5 s episodes: the arm can follow seed 5's plan, not seed 38's


def test_within_marks_the_steps_a_motor_or_a_joint_limit_refuses():
    """_PathCache.within, computed independently from the unclipped goals: a step is within when
    every motor's force kp (u - q_d) - kv qd_d is inside its forcerange and every goal inside
    the core's joint limits; the fast circle has steps outside, the followable path none."""
    task = LeadTask(EnvConfig(episode_steps=150), 2)
    task.reset(None, [FOLLOWABLE, BEYOND])
    cache = preview._PathCache(0.0, joint_path=True)  # unclipped
    cache.update(task)
    m = load_model()
    kp, kv = m.actuator_gainprm[:N_JOINTS, 0], -m.actuator_biasprm[:N_JOINTS, 2]
    q, corr = cache.goal[..., 0], cache.goal[..., 1]
    force = kp * corr - kv * np.gradient(q, task.dt, axis=1)
    lo, hi = task.core.joint_limits
    want = ((np.abs(force) <= m.actuator_forcerange[:N_JOINTS, 1] + 1e-9)
            & (q + corr >= lo) & (q + corr <= hi)).all(axis=-1)
    np.testing.assert_array_equal(cache.within, want)
    steps = slice(0, 151)
    assert cache.within[0, steps].all() and not cache.within[1, steps].all()
    np.testing.assert_array_equal(cache.followable, cache.within[:, steps].all(axis=1))


def _goals(config, act, seeds, steps):
    """The core's joint goal after each of ``steps`` control steps, (steps, N, 7)."""
    task = LeadTask(config, len(seeds))
    obs = task.reset(None, seeds)
    out = []
    for _ in range(steps):
        obs, *_ = task.step(act(obs, task))
        out.append(task.core.q_goal.copy())
    return np.array(out), task


def test_the_plan_is_followed_after_the_handover_and_only_where_the_arm_can():
    """Before the handover starts the goal is the feedforward's (the fallback); once it is
    over, a followable episode's goal is the plan's own half a control period ahead, and an
    episode the arm cannot follow keeps the feedforward's throughout."""
    config = EnvConfig(episode_steps=150, action="joint_target")
    seeds = [FOLLOWABLE, BEYOND]
    start, ramp = 0.05, 0.1  # steps 0-4 fallback, steps from 15 on the plan
    planned, task = _goals(config, preview.make_planned_feedforward(
        (start, ramp), dict(tau=0.02, gain=0.8, tau_ik=0.01, clip=True)), seeds, 40)
    fallback, _ = _goals(config, preview.make_feedforward(0.02, 0.8, 0.01, True), seeds, 40)
    cache = preview._PathCache(0.0, joint_path=True, clip=True)
    cache.update(task)
    plan = cache.goal[..., 0] + cache.goal[..., 1]
    atol = 1e-6  # the float32 joint_target action
    np.testing.assert_allclose(planned[:5], fallback[:5], atol=atol)
    for k in range(15, 40):  # the goal of step k: the plan at k + 1/2
        np.testing.assert_allclose(planned[k, 0], 0.5 * (plan[0, k] + plan[0, k + 1]), atol=atol)
    assert np.abs(planned[15:, 0] - fallback[15:, 0]).max() > 1e-3  # else the test shows nothing
    np.testing.assert_allclose(planned[:, 1], fallback[:, 1], atol=atol)


def test_following_the_plan_tracks_a_followable_path_closer_than_the_feedforward():
    config = EnvConfig(episode_steps=250, action="joint_target")
    plan = record_many(config, controllers.make_planned_feedforward(), [FOLLOWABLE, 3])
    ff = record_many(config, controllers.make_feedforward(), [FOLLOWABLE, 3])
    for a, b in zip(ff, plan, strict=True):  # well after the handover (over at 0.6 s)
        assert b.error[150:].mean() < 0.5 * a.error[150:].mean()


def test_the_planners_hand_on_the_feedforward_env_is_the_plan_following_rival():
    """EnvConfig.follow_plan with a zero lead on the feedforward env plays what the
    feedforward_plan rival plays (its goal through the float32 action: ~1e-7 rad)."""
    config = EnvConfig(episode_steps=120)
    rival = record_many(config.replace(action="joint_target"),
                        controllers.make_planned_feedforward(), [FOLLOWABLE, BEYOND])
    in_env = record_many(config.replace(feedforward=True, follow_plan=True),
                         controllers.classical, [FOLLOWABLE, BEYOND])
    for a, b in zip(rival, in_env, strict=True):
        np.testing.assert_allclose(b.error, a.error, atol=1e-5)


def test_the_planners_hand_leaves_an_episode_the_arm_cannot_follow_as_it_was():
    """Where the plan is not followable the lead keeps the arm: bit-identical to the env without
    follow_plan; where it is, the plan takes over (the analytic lead's error changes)."""
    config = EnvConfig(episode_steps=100)
    act = controllers.make_analytic()
    plain = record_many(config, act, [BEYOND, FOLLOWABLE])
    planned = record_many(config.replace(follow_plan=True), act, [BEYOND, FOLLOWABLE])
    np.testing.assert_array_equal(planned[0].error, plain[0].error)
    np.testing.assert_array_equal(planned[0].q_goal, plain[0].q_goal)
    assert np.abs(planned[1].error - plain[1].error).max() > 1e-3
    assert planned[1].error[60:].mean() < plain[1].error[60:].mean()


@pytest.mark.parametrize("bad", [dict(action="joint"), dict(ik={"substep_ik": True})])
def test_the_planners_hand_refuses_what_it_cannot_hand_over(bad):
    from panda_lead.config import knows_path
    from panda_lead.errors import UserError

    assert knows_path(EnvConfig(follow_plan=True))
    assert knows_path({"obs_features": ["ee_pos"], "follow_plan": True})
    with pytest.raises(UserError, match="follow_plan hands"):
        EnvConfig.from_dict({"follow_plan": True, **bad})


@pytest.mark.parametrize("base", ["lead", "feedforward"])
def test_on_the_collision_aware_ik_the_hand_still_leaves_what_it_cannot_follow(base):
    """Under ik.clearance an episode the arm cannot follow keeps its goal bit for bit (the
    IK's goal not projected twice, the feedforward's projected as before), and a followable one
    is handed over."""
    config = EnvConfig(episode_steps=100, feedforward=base == "feedforward").replace(
        ik={"clearance": 0.03})
    act = controllers.make_analytic() if base == "lead" else controllers.classical
    plain = record_many(config, act, [BEYOND, FOLLOWABLE])
    planned = record_many(config.replace(follow_plan=True), act, [BEYOND, FOLLOWABLE])
    np.testing.assert_array_equal(planned[0].q_goal, plain[0].q_goal)
    assert planned[1].error[60:].mean() < plain[1].error[60:].mean()


def test_the_damper_projects_a_joint_goal_only_where_asked(monkeypatch):
    """core.step(joint_goal, off_itself=mask) under ik.clearance: the masked slots' goals as
    the damper gives them (stubbed here: a visible shift), the others as given; no mask, all
    projected. The damper itself is clearance.py's (tests/test_clearance.py)."""
    from panda_lead.core import ArmBatch
    from panda_lead.ikconfig import IKConfig
    from panda_lead.trajectory import sample

    core = ArmBatch(2, IKConfig(clearance=0.05))
    core.reset(trajs=[sample(3), sample(4)], n_steps=5)
    monkeypatch.setattr(core, "_off_itself", lambda goal: goal - 0.01)
    goal = np.broadcast_to(core.home, (2, N_JOINTS)).copy()
    core.step(joint_goal=goal, off_itself=np.array([True, False]))
    np.testing.assert_allclose(core.q_goal[0], np.clip(goal[0] - 0.01, *core.joint_limits))
    np.testing.assert_array_equal(core.q_goal[1], goal[1])
    core.step(joint_goal=goal)
    np.testing.assert_allclose(core.q_goal, np.clip(goal - 0.01, *core.joint_limits))


def test_the_handover_weight_is_a_smoothstep_and_zero_where_the_plan_is_not_followable():
    t = np.array([0.0, 0.2, 0.3, 0.4, 0.6, 0.9, 0.3])
    followable = np.array([True] * 6 + [False])
    w = preview.handover_weight(t, (0.2, 0.4), followable)
    np.testing.assert_allclose(w, [0.0, 0.0, 0.15625, 0.5, 1.0, 1.0, 0.0])
    np.testing.assert_array_equal(preview.handover_weight(t, (0.3, 0.0), followable),
                                  [0, 0, 1, 1, 1, 1, 0])


def test_feedforward_plan_refuses_a_tau():
    from panda_lead.errors import UserError

    with pytest.raises(UserError, match="--tau does not apply to feedforward_plan"):
        build("feedforward_plan", 10, tau=0.03)


def test_preview_rivals_tunes_the_plan_following_feedforward_when_asked(monkeypatch, capsys):
    """studies/preview_rivals.py --plan-settings: each start:ramp:ahead is built on the
    feedforward in use as its fallback, 'half' leaves the plan's reading at its default, and
    the header carries the flag. Scoring stubbed: what is tested is the grid."""
    sys.path.insert(0, str(ROOT / "studies"))
    import preview_rivals

    built = []
    monkeypatch.setattr(preview, "make_planned_feedforward",
                        lambda handover, fallback, ahead=None: built.append(
                            (handover, fallback, ahead)) or (lambda obs, task: None))
    # analytic (mean, settled), then the feedforward and the two settings with their medians
    scores = iter([(4.0, 3.0), (2.1, 1.0, 0.3), (2.0, 0.9, 0.13), (1.9, 0.95, 0.2)])
    monkeypatch.setattr(preview_rivals, "mean_errors", lambda *a, **k: next(scores))
    preview_rivals.main(preview_rivals.Args(future=False,
                                            plan_settings=("0.2:0.4:half", "0:0:0.01")))
    out = capsys.readouterr().out
    fallback = dict(tau=controllers.FEEDFORWARD_TAU, gain=controllers.FEEDFORWARD_GAIN,
                    tau_ik=controllers.FEEDFORWARD_TAU_IK, clip=controllers.FEEDFORWARD_CLIP)
    assert built == [((0.2, 0.4), fallback, None), ((0.0, 0.0), fallback, 0.01)]
    assert ("`uv run studies/preview_rivals.py --no-future --plan-settings 0.2:0.4:half 0:0:0.01` "
            "at commit") in out
    assert "best: 0:0:0.01 (1.90 cm)" in out
    assert "| 2.00 | 0.90 | 0.13 |" in out  # the median settled error beside mean and settled


def test_preview_rivals_counts_the_followable_episodes_per_shape(capsys):
    """--followable: the episodes whose whole plan is within the motors and the joint limits,
    per shape and in all (seed 5's plan is followable for 1.5 s, the fast circle 38's not)."""
    sys.path.insert(0, str(ROOT / "studies"))
    import preview_rivals

    preview_rivals.main(preview_rivals.Args(followable="5,38", duration=1.5))
    out = capsys.readouterr().out
    assert "`uv run studies/preview_rivals.py --followable 5,38 --duration 1.5`" in out
    assert "| all | 2 | 1 | 50.0% |" in out
    assert "| circle | 1 | 0 | 0.0% |" in out



def test_plan_weight_is_the_hands_share_known_and_never_late():
    """The plan_weight feature is the weight the hand gives the next goal (0 where the plan is
    not followable, the smoothstep where it is), read without the observation's delay and never
    noisy; 0 throughout without the hand."""
    from panda_lead.config import obs_layout
    from panda_lead.task import LeadTask

    features = ("ee_pos", "tip_error", "plan_weight")
    config = EnvConfig(episode_steps=150, follow_plan=True, obs_features=features, obs_delay=3,
                       obs_noise={"ee_pos": 0.01, "tip_error": 0.01})
    col = obs_layout(features)[-1][1]
    task = LeadTask(config, 2)
    obs = task.reset(traj_seeds=[FOLLOWABLE, BEYOND])
    assert task._plan.followable.tolist() == [True, False]
    seen = [obs[:, col]]
    for _ in range(80):
        obs = task.step(np.zeros((2, 3)))[0]
        seen.append(obs[:, col])
    seen = np.array(seen)
    times = np.arange(81) * task.dt
    want = preview.handover_weight(times, controllers.PLAN_HANDOVER, np.ones(81, bool))
    np.testing.assert_allclose(seen[:, 0], want, atol=1e-6)  # this step's, not 3 steps old
    assert seen[-1, 0] == 1.0 and seen[20, 0] == 0.0 and 0 < seen[40, 0] < 1
    assert np.all(seen[:, 1] == 0.0)
    task = LeadTask(config.replace(follow_plan=False), 2)
    task.reset(traj_seeds=[FOLLOWABLE, BEYOND])
    for _ in range(70):
        obs = task.step(np.zeros((2, 3)))[0]
    assert np.all(obs[:, col] == 0.0)
