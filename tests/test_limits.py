"""The real-arm limits check (panda_lead.limits) on paths whose derivatives are known in closed
form, its forward kinematics against MuJoCo's, and the commanded joint goals in rollout files."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from panda_lead import limits

DT = 0.01  # the controller's period: 100 Hz goals
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def sine_goals(joint: int, amplitude: float, omega: float, seconds: float = 2.0) -> np.ndarray:
    """100 Hz goals: the home pose with amplitude * sin(omega t) on one joint (0-based)."""
    t = np.arange(int(round(seconds / DT))) * DT
    q = np.tile(HOME, (len(t), 1))
    q[:, joint] += amplitude * np.sin(omega * t)
    return q


def test_cubic_stream_has_the_sines_derivatives():
    """A sine's velocity, acceleration and jerk peaks are A w, A w^2, A w^3: the cubic spline
    through its 100 Hz samples, differenced at 1 kHz, must give them within a few percent."""
    a, w = 0.3, 2 * np.pi * 2.0
    stream = limits.upsample(sine_goals(6, a, w)[:, 6], DT, "cubic")
    vel, acc, jerk = limits.derivatives(stream, limits.ROBOT_DT)
    inner = slice(300, -300)  # away from the natural spline's free ends
    for got, want in ((vel, a * w), (acc, a * w ** 2), (jerk, a * w ** 3)):
        assert np.abs(got[inner]).max() == pytest.approx(want, rel=0.03)


def test_upsample_passes_through_every_goal():
    q = sine_goals(2, 0.5, 7.0)
    for method in limits.METHODS:
        stream = limits.upsample(q, DT, method)
        assert stream.shape == ((len(q) - 1) * 10 + 1, 7)
        np.testing.assert_allclose(stream[::10], q, atol=1e-12)


def test_lowpass_is_a_first_order_filter_at_100_hz():
    """A step reaches 1 - 1/e of its height after one time constant, 1 / (2 pi 100 Hz) = 1.6 ms,
    and a constant passes unchanged."""
    step = np.r_[np.zeros(5), np.ones(50)]
    y = limits.lowpass(step)
    crossed = np.argmax(y >= 1 - np.exp(-1)) - 4  # samples after the step
    assert 1 <= crossed <= 3
    assert y[-1] == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_array_equal(limits.lowpass(np.full((9, 7), 0.3)), np.full((9, 7), 0.3))


@pytest.mark.parametrize("share", [0.8, 1.2])
def test_check_names_the_limit_and_its_margin(share):
    """Joint 7 turns the hand about its own axis (the tool centre point stays put), so only
    joint 7's limits see it; at 3 Hz its acceleration A w^2 binds (20 rad/s^2, against
    velocity A w / 2.61 and jerk A w^3 / 10,000): margin = share, accepted below 1."""
    w = 2 * np.pi * 3.0
    amplitude = share * limits.JOINT_ACC[6] / w ** 2
    q = sine_goals(6, amplitude, w)
    got = limits.check(q, DT, skip=0.3)
    assert got.worst_limit == "joint 7 acceleration"
    assert got.worst_margin == pytest.approx(share, rel=0.03)
    assert got.accepted == (share < 1)
    assert got.margins["tip velocity"] < 1e-6


def test_linear_interpolation_breaks_the_jerk_limit_that_the_spline_keeps():
    """Why the check interpolates with a spline: straight segments step the velocity every
    10 ms, which the low-pass turns into jerk far above the limit for the same smooth path."""
    w = 2 * np.pi * 1.0
    q = sine_goals(6, 0.5 * limits.JOINT_ACC[6] / w ** 2, w)
    assert limits.check(q, DT, skip=0.3, method="cubic").accepted
    linear = limits.check(q, DT, skip=0.3, method="linear")
    assert not linear.accepted and linear.worst_limit == "joint 7 jerk"


def _mujoco_tip(q: np.ndarray) -> np.ndarray:
    from panda_lead.core import load_model

    model = load_model()
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tip")
    out = []
    for row in q:
        data.qpos[:7] = row
        mujoco.mj_kinematics(model, data)
        out.append(data.site_xpos[site].copy())
    return np.array(out)


def test_forward_kinematics_matches_mujocos_tip_site():
    rng = np.random.default_rng(3)
    lo = np.array([-2.8, -1.7, -2.8, -3.0, -2.8, 0.0, -2.8])
    hi = np.array([2.8, 1.7, 2.8, -0.1, 2.8, 3.7, 2.8])
    q = np.vstack([HOME, rng.uniform(lo, hi, size=(20, 7))])
    np.testing.assert_allclose(limits.tip_positions(q), _mujoco_tip(q), atol=1e-9)


def test_tip_speed_of_a_base_rotation():
    """Joint 1 turning at w carries the tip round the base's vertical axis at r w (r: the tip's
    distance from that axis, from MuJoCo): the tip-velocity margin is r w / 1.7 m/s."""
    w = 1.2
    t = np.arange(150) * DT
    q = np.tile(HOME, (len(t), 1))
    q[:, 0] = w * t
    r = np.hypot(*_mujoco_tip(HOME[None])[0, :2])
    got = limits.check(q, DT, skip=0.5)
    assert got.margins["tip velocity"] == pytest.approx(r * w / limits.TIP_VEL, rel=0.01)
    assert got.margins["joint 1 velocity"] == pytest.approx(w / limits.JOINT_VEL[0], rel=0.01)


def test_a_jump_from_rest_is_refused():
    """The arm at rest at home, then goals 0.2 rad away on joint 4: no real arm may jump."""
    q = np.tile(HOME, (50, 1))
    q[:, 3] += 0.2
    got = limits.check(q, DT, q_start=HOME)
    assert not got.accepted and got.worst_margin > 10


def test_rollouts_record_the_commanded_goals(tmp_path):
    """q_goal is what the PD aimed at, not where the arm is: its tip (forward kinematics) is
    nearer the target than the measured tip while the arm lags; it survives a save and load,
    and a file written before the column existed still loads (q_goal None)."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import ARRAY_KEYS, load, record_many, save

    r = record_many(EnvConfig(episode_steps=60), controllers.classical, [3])[0]
    assert r.q_goal.shape == (60, 7)
    after_swing = slice(20, None)
    goal_err = np.linalg.norm(limits.tip_positions(r.q_goal) - r.target_pos, axis=1)
    tip_err = np.linalg.norm(r.ee_pos - r.target_pos, axis=1)
    assert goal_err[after_swing].mean() < 0.5 * tip_err[after_swing].mean()
    np.testing.assert_array_equal(load(save(r, tmp_path / "seed_0003.npz")).q_goal, r.q_goal)
    import json

    old = tmp_path / "old.npz"
    np.savez_compressed(old, **{k: np.asarray(getattr(r, k)) for k in ARRAY_KEYS},
                        meta=np.array(json.dumps(r.meta, sort_keys=True)))
    assert load(old).q_goal is None


def test_the_check_says_when_the_worst_limit_peaks():
    """A kink in joint 2's goals (its velocity jumps at 1.0 s, as a correction switched on at
    once makes it do): the worst limit is joint 2's acceleration, peaking within a control
    period or two of the kink, whether the kink is early or late in the episode."""
    for kink in (1.0, 1.73):
        t = np.arange(300) * DT
        q = np.tile(HOME, (len(t), 1))
        q[:, 1] += 0.3 * np.clip(t - kink, 0, None)  # at rest, then 0.3 rad/s from the kink on
        got = limits.check(q, DT, q_start=HOME, skip=0.5)
        assert got.worst_limit == "joint 2 acceleration"
        assert abs(got.worst_time - kink) < 2 * DT


def test_many_episodes_at_once_check_as_each_alone():
    q = np.stack([sine_goals(6, a, 2 * np.pi * 3.0) for a in (0.02, 0.05, 0.08)])
    together = limits.check_many(q, DT, skip=0.3)
    for episode, got in zip(q, together, strict=True):
        alone = limits.check(episode, DT, skip=0.3)
        assert got.worst_limit == alone.worst_limit
        assert got.margins == pytest.approx(alone.margins, rel=1e-12)
        assert got.worst_time == pytest.approx(alone.worst_time)
