"""The deployability study (studies/deploy.py) and the rivals it fields: the analytic lead with
a Kalman filter under noise, and the analytic lead that predicts through a known latency."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from panda_lead import controllers
from panda_lead.config import OBS_SCALE, EnvConfig
from panda_lead.core import analytic_lead
from panda_lead.errors import UserError
from panda_lead.task import LeadTask

ROOT = Path(__file__).resolve().parents[1]
NOISE_1CM = {"ee_pos": 0.01, "target_pos": 0.01, "ee_vel": 0.1, "target_vel": 0.1,
             "target_acc": 1.0}


def _leads(config: EnvConfig, acts: dict, steps: int = 150, seeds=(3, 4, 5, 6)):
    """Play the classical controller and, at every step, ask each act function for its lead
    (m) and record the true analytic lead (from the true target) at that step."""
    task = LeadTask(config, len(seeds))
    task.rngs = [np.random.default_rng(s) for s in seeds]
    obs = task.reset(None, list(seeds))
    got = {name: [] for name in acts}
    truth = []
    for _ in range(steps):
        for name, act in acts.items():
            got[name].append(act(obs, task) * config.max_lead)
        _, vel, acc = task.core.target()
        truth.append(analytic_lead(vel, acc, controllers.DEFAULT_TAU, config.max_lead))
        obs = task.step(controllers.classical(obs, task))[0]
    return {k: np.array(v) for k, v in got.items()}, np.array(truth)


def test_filter_recovers_the_lead_that_noise_hides():
    """Under 1 cm of noise the filtered lead is nearer the lead of the true target than the
    analytic lead computed from the noisy readings, by more than half."""
    config = EnvConfig(obs_noise=NOISE_1CM)
    got, truth = _leads(config, {"raw": controllers.make_analytic(),
                                 "filtered": controllers.make_filtered_analytic()})
    settled = slice(30, None)
    raw = np.abs(got["raw"] - truth)[settled].mean()
    filtered = np.abs(got["filtered"] - truth)[settled].mean()
    assert filtered < 0.5 * raw


def test_filter_without_noise_is_the_analytic_lead():
    got, truth = _leads(EnvConfig(), {"raw": controllers.make_analytic(),
                                      "filtered": controllers.make_filtered_analytic()}, 60)
    np.testing.assert_allclose(got["filtered"], got["raw"], atol=1e-5)


def test_steady_state_gain_trusts_the_better_sensor():
    """A precise position reading and poor velocity: the gain follows the position."""
    k = controllers.steady_state_gain(0.01, np.array([1e-4, 1.0, 10.0]), 1e3)
    assert k[0, 0] > 0.9 and k[1, 1] < 0.1  # position followed, velocity smoothed
    assert np.allclose(controllers.steady_state_gain(0.01, np.zeros(3), 1e3), np.eye(3),
                       atol=1e-6)


def test_prediction_through_the_delay_lands_nearer_the_lead_it_should_be():
    """With 2 steps of observation and 2 of action latency, the lead computed now lands 2 steps
    later from readings 2 steps old: the predicting lead is nearer the true lead at the step it
    is applied than the plain analytic lead."""
    config = EnvConfig(obs_delay=2, action_delay=2)
    got, truth = _leads(config, {"plain": controllers.make_analytic(),
                                 "predict": controllers.make_predicting_analytic()})
    applied = slice(30, -2)  # the lead asked for at step k acts at step k + 2
    later = truth[32:]
    plain = np.abs(got["plain"][applied] - later).mean()
    predict = np.abs(got["predict"][applied] - later).mean()
    assert predict < 0.8 * plain


def _deploy_module():
    spec = importlib.util.spec_from_file_location("deploy_study", ROOT / "studies" / "deploy.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["deploy_study"] = module
    spec.loader.exec_module(module)
    return module


def test_deploy_writes_the_table_and_the_figure(tmp_path, capsys):
    deploy = _deploy_module()
    args = deploy.Args(seeds="0-1", conditions=["noise1", "delay1"], out=tmp_path,
                       bootstrap=100, duration=0.8)
    deploy.main(args)
    text = (tmp_path / "deploy.md").read_text()
    assert text.startswith("`uv run studies/deploy.py --seeds 0-1 --conditions noise1 delay1` "
                           "(2 test seeds, ")
    rows = [line for line in text.splitlines() if line.startswith("| ")][1:]
    names = [(r.split(" | ")[0][2:], r.split(" | ")[1]) for r in rows]
    assert names == [("noise 1 cm", "Classical"), ("noise 1 cm", "Analytic"),
                     ("noise 1 cm", "Analytic+filter"),
                     ("latency 1 step (10 ms)", "Classical"),
                     ("latency 1 step (10 ms)", "Analytic"),
                     ("latency 1 step (10 ms)", "Analytic+predict")]
    assert (tmp_path / "deploy.png").stat().st_size > 10_000
    with pytest.raises(SystemExit) as exc:  # no overwrite without --force
        deploy.main(args)
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().startswith("error: ")


def test_deploy_refuses_an_unknown_condition(tmp_path, capsys):
    deploy = _deploy_module()
    with pytest.raises(SystemExit) as exc:
        deploy.main(deploy.Args(conditions=["delay2"], out=tmp_path))
    assert exc.value.code == 2
    assert "unknown condition 'delay2'" in capsys.readouterr().err
    assert not (tmp_path / "deploy.md").exists()


def test_lead_filter_tuning_refuses_a_missing_model_and_an_impossible_seed_count(
        tiny_run, tmp_path, capsys):
    deploy = _deploy_module()
    tmp, _, _, _ = tiny_run
    for args, words in ((deploy.Args(tune_lead_filter=tmp_path / "absent.zip"), "no model file"),
                        (deploy.Args(tune_lead_filter=tmp / "archive" / "tiny.zip",
                                     tune_on=10 ** 7), "--tune-on must be 0..2378")):
        with pytest.raises(SystemExit) as exc:
            deploy.main(args)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and words in err and err.count("\n") == 1, err


def test_the_probes_refuse_a_missing_model_and_an_unknown_condition(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("deploy_probes",
                                                  ROOT / "studies" / "deploy_probes.py")
    probes = importlib.util.module_from_spec(spec)
    sys.modules["deploy_probes"] = probes  # (its dataclass looks its module up)
    spec.loader.exec_module(probes)
    for args, words in ((probes.Args("margins", models=[tmp_path / "absent.zip"]),
                         "no model file"),
                        (probes.Args("margins", models=[], conditions=["delay2"]),
                         "unknown condition 'delay2'"),
                        (probes.Args("lost-paths", models=[], on_selection=10 ** 7),
                         "--on-selection must be 0..2378")):
        with pytest.raises(SystemExit) as exc:
            probes.main(args)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and words in err and err.count("\n") == 1, err


def test_stack_weights_reads_one_norm_per_stacked_observation_and_refuses_mixed_stacks(capsys):
    spec = importlib.util.spec_from_file_location("deploy_probes",
                                                  ROOT / "studies" / "deploy_probes.py")
    probes = importlib.util.module_from_spec(spec)
    sys.modules["deploy_probes"] = probes
    spec.loader.exec_module(probes)
    seeds = ROOT / "archive" / "seeds"
    four = seeds / "deploy_large_batch_curv10_actions_stack4_continued_5m_s1.zip"
    eight = seeds / "deploy_large_batch_curv10_actions_stack8_continued_5m_s1.zip"
    probes.main(probes.Args("stack-weights", models=[four]))
    line = capsys.readouterr().out.strip()
    norms = [float(x) for x in line.split(": ")[-1].split(" / ")]
    # four norms, the newest observation (the start's weights) above each older, new one
    assert "4 stacked observations" in line and len(norms) == 4
    assert norms[0] > max(norms[1:]) > 0
    with pytest.raises(SystemExit) as exc:
        probes.main(probes.Args("stack-weights", models=[four, eight]))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "stacks 8 observations, the models before it 4" in err and err.count("\n") == 1, err


def test_noise_condition_reaches_the_tip_error():
    """Under the study's 1 cm condition the tip error a learned lead observes is the tip
    reading minus the target reading: the difference of the ee_pos and target_pos features it
    observes beside it, noise and all (sqrt(2) cm about the true error, not an independent
    draw)."""
    from panda_lead.config import OBS_15, OBS_SCALE

    deploy = _deploy_module()
    config = EnvConfig(obs_features=OBS_15 + ("tip_error",)).merged(deploy.overrides("noise1"))
    task = LeadTask(config, 64)
    task.rngs = [np.random.default_rng(s) for s in range(64)]
    obs = task.reset(None, list(range(64))).astype(np.float64)
    cols = {f: slice(a, b) for f, a, b in task.layout}
    seen = {f: obs[:, cols[f]] * OBS_SCALE[f] for f in ("tip_error", "ee_pos", "target_pos")}
    pos, _, _ = task.core.target()
    assert np.std(seen["tip_error"] - (task.core.tip_pos - pos)) == pytest.approx(
        0.01 * np.sqrt(2), rel=0.15)
    np.testing.assert_allclose(seen["tip_error"], seen["ee_pos"] - seen["target_pos"],
                               atol=1e-6)  # float32 observations


def test_target_noise_leaves_the_arm_readings_exact():
    """targetnoise1: the target's readings carry the 1 cm condition's noise, the tip reading
    (the encoders' kinematics) none, so the tip error's noise is the target's alone."""
    from panda_lead.config import OBS_15, OBS_SCALE

    deploy = _deploy_module()
    config = EnvConfig(obs_features=OBS_15 + ("tip_error",)).merged(
        deploy.overrides("targetnoise1"))
    assert config.noisy_ik_target
    task = LeadTask(config, 64)
    task.rngs = [np.random.default_rng(s) for s in range(64)]
    obs = task.reset(None, list(range(64))).astype(np.float64)
    cols = {f: slice(a, b) for f, a, b in task.layout}
    seen = {f: obs[:, cols[f]] * OBS_SCALE[f] for f in ("tip_error", "ee_pos", "target_pos")}
    pos, _, _ = task.core.target()
    np.testing.assert_allclose(seen["ee_pos"], task.core.tip_pos, atol=1e-6)
    assert np.std(seen["target_pos"] - pos) == pytest.approx(0.01, rel=0.15)
    assert np.std(seen["tip_error"] - (task.core.tip_pos - pos)) == pytest.approx(0.01, rel=0.15)
    ctrls = deploy.controllers_for("targetnoise1", [], 10)
    assert "Analytic+filter" in ctrls  # the rival a camera's noise calls for


def test_unobserved_readings_still_carry_their_noise_into_the_tip_error():
    """A lead that observes the tip error but neither position still sees the readings' noise
    in it (hidden channels: std sqrt(s_tip^2 + s_target^2)), and the running average it
    observes is the average of that measured error, not of the true one."""
    from panda_lead.config import OBS_SCALE

    config = EnvConfig(obs_features=("tip_error", "tip_error_avg"), episode_steps=50,
                       obs_noise={"ee_pos": 0.03, "target_pos": 0.04}, error_avg_clip=1.0)
    noisy, true = LeadTask(config, 200), LeadTask(replace(config, obs_noise={}), 200)
    for task in (noisy, true):
        task.rngs = [np.random.default_rng(s) for s in range(200)]
        task.reset(None, list(range(200)))
    a, b = next((a, b) for f, a, b in noisy.layout if f == "tip_error")
    pos, _, _ = noisy.core.target()
    seen = noisy.observe().astype(np.float64)[:, a:b] * OBS_SCALE["tip_error"]
    assert np.std(seen - (noisy.core.tip_pos - pos)) == pytest.approx(0.05, rel=0.1)
    for _ in range(5):  # zero actions: both arms move alike, only the averages' inputs differ
        noisy.step(np.zeros((200, 3)))
        true.step(np.zeros((200, 3)))
    np.testing.assert_array_equal(noisy.core.tip_pos, true.core.tip_pos)
    rate = noisy.dt / config.error_avg_time  # 5 draws of 5 cm, weighted by the rate (no clip)
    expected = 0.05 * rate * np.sqrt(sum((1 - rate) ** (2 * k) for k in range(5)))
    assert np.std(noisy.err_avg - true.err_avg) == pytest.approx(expected, rel=0.15)


def test_the_lead_filter_is_a_first_order_low_pass_in_the_loop():
    """With lead_filter_hz the applied lead moves 1 - exp(-2 pi f dt) of the way to the
    action's lead each step, from 0 at reset: a unit step reaches 1 - (1 - alpha)^k after k
    steps, and the arm is driven by that lead, not the action's."""
    hz, steps = 5.0, 6
    filtered = LeadTask(EnvConfig(episode_steps=20, lead_filter_hz=hz), 1, nthread=1)
    plain = LeadTask(EnvConfig(episode_steps=20), 1, nthread=1)
    filtered.reset(None, [3])
    plain.reset(None, [3])
    alpha = 1 - np.exp(-2 * np.pi * hz * filtered.dt)
    action = np.array([[1.0, -0.5, 0.25]])
    for k in range(1, steps + 1):
        info = filtered.step(action)[4]
        want = action[0] * filtered.config.max_lead * (1 - (1 - alpha) ** k)
        assert np.allclose(info["lead"][0], want, rtol=1e-12)
        plain.step(np.array([want / plain.config.max_lead]))
        # the arm under the filter moves as the arm given the filtered lead directly
        assert np.allclose(filtered.core.qpos, plain.core.qpos, atol=1e-12)
    filtered.reset(None, [4])
    assert np.allclose(filtered.step(action)[4]["lead"][0],
                       action[0] * filtered.config.max_lead * alpha)


def test_the_noisy_lead_filter_smooths_the_noisy_episodes_and_no_other():
    """noisy_lead_filter_hz: in an episode whose sensors are noisy the lead is lead_filter_hz's
    low-pass of the action; in one drawn noise-free (random_noise's nominal share), or where
    obs_noise is empty, the lead is the action's, bit for bit, and so is the arm."""
    hz, noise = 10.0, {"target_pos": 0.01}
    common = dict(episode_steps=20, obs_features=("tip_error", "target_pos"))
    smoothed = LeadTask(EnvConfig(**common, obs_noise=noise, lead_filter_hz=hz), 1, nthread=1)
    noisy = LeadTask(EnvConfig(**common, obs_noise=noise, noisy_lead_filter_hz=hz), 1,
                     nthread=1)
    exact = LeadTask(EnvConfig(**common, noisy_lead_filter_hz=hz), 1, nthread=1)
    plain = LeadTask(EnvConfig(**common), 1, nthread=1)
    for task in (smoothed, noisy, exact, plain):
        task.reset(None, [5])
    rng = np.random.default_rng(0)
    for _ in range(8):
        action = rng.uniform(-1, 1, (1, 3))
        leads = [task.step(action)[4]["lead"][0].copy() for task in (smoothed, noisy, exact,
                                                                     plain)]
        np.testing.assert_array_equal(leads[1], leads[0])  # noisy: filtered as always
        np.testing.assert_array_equal(leads[2], leads[3])  # exact: unfiltered
        assert not np.allclose(leads[1], leads[3])
    np.testing.assert_array_equal(exact.core.qpos, plain.core.qpos)
    # random_noise with every episode drawn nominal (noise-free): no slot is filtered
    free = LeadTask(EnvConfig(**common, obs_noise=noise, noisy_lead_filter_hz=hz,
                              random_noise=True, nominal_share=1.0), 2, nthread=1)
    free.reset(None, [5, 6])
    action = np.array([[1.0, -0.5, 0.25]] * 2)
    np.testing.assert_array_equal(free.step(action)[4]["lead"], action * free.config.max_lead)
    with pytest.raises(UserError, match="set one of them"):
        EnvConfig(lead_filter_hz=5.0, noisy_lead_filter_hz=5.0)


def test_the_target_camera_delays_the_target_for_the_ik_and_the_lead_alike():
    """target_delay k: every target feature observed is the true target of k steps ago (the
    first while there is none older), the IK of a zero lead aims there (so the classical arm
    lags more than without it), and tracking is still measured against the true target."""
    k, steps = 3, 60
    features = ("target_pos", "target_vel", "tip_error")
    late = LeadTask(EnvConfig(episode_steps=steps, obs_features=features, target_delay=k), 1,
                    nthread=1)
    now = LeadTask(EnvConfig(episode_steps=steps, obs_features=features), 1, nthread=1)
    obs_late, obs_now = late.reset(None, [11]), now.reset(None, [11])
    true_pos = [now.core.target()[0][0].copy()]
    dist_late, dist_now = [], []
    for t in range(steps):
        seen = obs_late[0, :3]  # target_pos at scale 1
        assert np.allclose(seen, true_pos[max(t - k, 0)], atol=1e-6), t
        tip = late.core.tip_pos[0]
        assert np.allclose(obs_late[0, 6:9] * 0.05, tip - true_pos[max(t - k, 0)], atol=1e-6)
        obs_late, _, _, _, info_late = late.step(np.zeros((1, 3)))
        obs_now, _, _, _, info_now = now.step(np.zeros((1, 3)))
        true_pos.append(now.core.target()[0][0].copy())
        assert np.isclose(info_late["distance"][0],
                          np.linalg.norm(late.core.tip_pos[0] - true_pos[-1]))
        dist_late.append(info_late["distance"][0])
        dist_now.append(info_now["distance"][0])
    assert np.mean(dist_late[20:]) > np.mean(dist_now[20:]) + 0.005  # 30 ms more lag: > 5 mm


def test_prediction_through_the_target_camera_reaches_over_the_delay():
    """Under target_delay k the predicting rival leads by tau + k dt from the old target: the
    IK's aim lands nearer where the analytic lead means to aim (the true target tau ahead of
    now) than the plain analytic lead's, which reaches only tau past the old target."""
    k = 3
    config = EnvConfig(episode_steps=40, target_delay=k)
    predict, plain = controllers.make_predicting_analytic(), controllers.make_analytic()
    errors = {}
    for name, act in (("predict", predict), ("plain", plain)):
        task = LeadTask(config, 1, nthread=1)
        obs = task.reset(None, [2])
        miss = []
        for _ in range(40):
            action = act(obs, task)
            aim = task.known_target()[0] + action * config.max_lead
            meant = task.trajs[0].at(float(task.core.time[0]) + controllers.DEFAULT_TAU)[0]
            miss.append(np.linalg.norm(aim - meant))
            obs = task.step(action)[0]
        errors[name] = np.mean(miss[5:])
    assert errors["predict"] < 0.5 * errors["plain"], errors


def test_a_noisy_ik_target_reaches_the_classical_controller_and_the_filter_cleans_it():
    """noisy_ik_target: the IK aims at the observation's target_pos reading. Without noise that
    is the true target, bit for bit; with 1 cm of noise the classical arm's commanded goals
    shake (their jerk rises), and the Kalman-filtered analytic lead, which moves the aim to its
    estimate, commands smoother goals than the plain analytic lead."""
    steps = 80

    def goal_jerk(config, act, seed=6):
        task = LeadTask(config, 1, nthread=1)
        obs = task.reset(None, [seed])
        task.rngs[0] = np.random.default_rng(0)
        goals = []
        for _ in range(steps):
            obs = task.step(act(obs, task))[0]
            goals.append(task.core.q_goal[0].copy())
        return np.sqrt(np.mean(np.diff(np.array(goals)[20:], 3, axis=0) ** 2)), np.array(goals)

    plain = EnvConfig(episode_steps=steps)
    _, a = goal_jerk(plain, controllers.classical)
    _, b = goal_jerk(plain.replace(noisy_ik_target=True), controllers.classical)
    assert np.array_equal(a, b)
    noise = _deploy_module().robustness_condition("noise", 1.0)["obs_noise"]
    quiet, _ = goal_jerk(plain.replace(obs_noise=noise), controllers.classical)
    shaken, _ = goal_jerk(plain.replace(obs_noise=noise, noisy_ik_target=True),
                          controllers.classical)
    assert shaken > 3 * quiet
    noisy = plain.replace(obs_noise=noise, noisy_ik_target=True)
    filtered, _ = goal_jerk(noisy, controllers.make_filtered_analytic())
    unfiltered, _ = goal_jerk(noisy, controllers.make_analytic())
    assert filtered < 0.5 * unfiltered



def test_resetting_one_slot_keeps_the_other_slots_noisy_target_readings():
    """A vector env resets a finished slot alone (observe(ids) draws noise for it only): the
    other slots' IK keeps aiming at their own last noisy reading, not the true target."""
    config = EnvConfig(episode_steps=30, noisy_ik_target=True,
                       obs_noise={"target_pos": 0.01})
    task = LeadTask(config, 3, nthread=1)
    task.reset(None, [1, 2, 3])
    task.step(np.zeros((3, 3)))
    before = task._target_reading.copy()
    assert np.all(np.abs(before - task.core.target()[0]) > 0)  # noisy readings
    task.reset([1], [9])
    assert np.array_equal(task._target_reading[[0, 2]], before[[0, 2]])
    assert not np.array_equal(task._target_reading[1], before[1])


def test_the_cameras_delay_and_the_noise_level_are_drawn_per_episode():
    """random_delay with target_delay k: each episode knows the target of its own 0..k steps
    ago (drawn from the slot's generator, so a replay of the seed draws it again); random_noise:
    each episode's noise is obs_noise times its own factor in [0, 1]."""
    from panda_lead.config import OBS_SCALE

    config = EnvConfig(episode_steps=20, target_delay=3, random_delay=True, random_noise=True,
                       obs_features=("target_pos",), obs_noise={"target_pos": 0.01})
    task = LeadTask(config, 64)
    task.rngs = [np.random.default_rng(s) for s in range(64)]
    task.reset(None, list(range(64)))
    assert set(task.target_delay.tolist()) == {0, 1, 2, 3}
    assert 0 < task.noise_scale.min() and task.noise_scale.max() < 1
    assert len(set(task.noise_scale.tolist())) == 64
    for _ in range(6):
        obs = task.step(np.zeros((64, 3)))[0]
    pos, _, _ = task.known_target()
    steps = task.core.step_count
    for i in (0, 1, 2):  # each slot's known target is its own camera's
        assert np.array_equal(pos[i], task.core.target_pos[i, steps[i] - task.target_delay[i]])
    # noise about each slot's known target, in proportion to its factor: 500 readings per slot
    readings = []
    for _ in range(500):
        task.observe()
        readings.append(task._raw[:, :3] - task.known_target()[0])
    spread = np.std(np.array(readings), axis=(0, 2))
    np.testing.assert_allclose(spread, 0.01 * task.noise_scale, rtol=0.1, atol=2e-4)
    again = LeadTask(config, 64)
    again.rngs = [np.random.default_rng(s) for s in range(64)]
    again.reset(None, list(range(64)))
    assert np.array_equal(again.target_delay, task.target_delay) and np.array_equal(
        again.noise_scale, task.noise_scale)
    assert obs.dtype == np.float32 and OBS_SCALE["target_pos"] == 1.0


def test_split_conditions_draw_latency_alone_noise_alone_or_both():
    """split_conditions: an episode not drawn nominal is delayed only (no noise), noisy only (no
    delay of any kind) or both, about a third each, and its installation feature says which;
    without it every randomised episode is both."""
    common = dict(episode_steps=20, obs_delay=3, action_delay=3, target_delay=3,
                  random_delay=True, random_noise=True, nominal_share=0.25,
                  obs_features=("target_pos", "installation"), obs_noise={"target_pos": 0.01})
    kinds = {}
    for split in (False, True):
        task = LeadTask(EnvConfig(**common, split_conditions=split), 600)
        task.rngs = [np.random.default_rng(s) for s in range(600)]
        task.reset(None, list(range(600)))
        delays = np.stack([task.obs_delay, task.action_delay, task.target_delay], axis=1)
        delayed, noisy = delays.any(axis=1), task.noise_scale > 0
        kinds[split] = (np.mean(delayed & ~noisy), np.mean(~delayed & noisy),
                        np.mean(delayed & noisy), np.mean(~delayed & ~noisy))
        np.testing.assert_array_equal(task._installation[:, :3], delays)
        np.testing.assert_allclose(task._installation[:, 3], task.noise_scale)  # 1 cm at 1
    latency_alone, noise_alone, both, nominal = kinds[True]
    # a third of 75% each; a delayed-only draw is all zero in 1 of 64 (then it reads nominal)
    assert 0.20 < latency_alone < 0.30 and 0.20 < noise_alone < 0.30 and 0.20 < both < 0.30
    assert 0.20 < nominal < 0.32
    assert kinds[False][0] == 0 and kinds[False][1] < 0.02  # joint: (all-zero delays: 1 in 64)
    with pytest.raises(UserError, match="split_conditions"):
        EnvConfig(random_delay=True, split_conditions=True)


# --- the env's own Kalman filter (EnvConfig.target_filter) -----------------------------------

def _distances(config: EnvConfig, act, steps: int = 120, seeds=(3, 4, 5, 6)) -> np.ndarray:
    task = LeadTask(config, len(seeds))
    task.rngs = [np.random.default_rng(s) for s in seeds]
    obs = task.reset(None, list(seeds))
    out = []
    for _ in range(steps):
        obs, _, _, _, info = task.step(act(obs, task))
        out.append(info["distance"])
    return np.array(out)


def test_env_filter_is_the_filtered_rivals_filter():
    """The analytic lead on an env with target_filter (the IK at the noisy reading) tracks
    as the filtered analytic lead does on the env without it: one filter, not two."""
    noisy = EnvConfig(obs_noise=NOISE_1CM, noisy_ik_target=True)
    rival = _distances(noisy, controllers.make_filtered_analytic())
    in_env = _distances(replace(noisy, target_filter=True), controllers.make_analytic())
    raw = _distances(noisy, controllers.make_analytic())
    # (the rival filters the float32 observation, the env the float64 reading: ~1e-8 m)
    np.testing.assert_allclose(in_env, rival, atol=1e-6)
    assert not np.allclose(raw, rival, atol=1e-4)  # the filter changes what the arm does


def _observed_readings(config: EnvConfig, steps: int = 80, seeds=(3, 4, 5, 6)):
    """Per step of a zero lead: the observation unscaled by feature, the true tip and the
    true target position."""
    task = LeadTask(config, len(seeds))
    task.rngs = [np.random.default_rng(s) for s in seeds]
    task.reset(None, list(seeds))
    cols = {f: slice(a, b) for f, a, b in task.layout}
    rows = []
    for _ in range(steps):
        obs = task.step(np.zeros((len(seeds), 3)))[0]
        rows.append(({f: obs[:, c] * OBS_SCALE[f] for f, c in cols.items()},
                     task.core.tip_pos.copy(), task.core.target()[0].copy()))
    return rows


def _assert_filter_estimates(config: EnvConfig, switch: str, feature: str, truth: int):
    """Under 1 cm of noise the filtered ``feature`` is nearer the truth (index ``truth`` of
    _observed_readings' rows) than the reading with ``switch`` off, and the observed tip error
    stays the observed tip minus the observed target."""
    seen = {name: _observed_readings(cfg) for name, cfg in
            (("filtered", config), ("raw", replace(config, **{switch: False})))}
    error = {name: np.mean([np.abs(row[0][feature] - row[truth]).mean() for row in rows[20:]])
             for name, rows in seen.items()}
    assert error["filtered"] < 0.6 * error["raw"]
    for o, _, _ in seen["filtered"]:
        np.testing.assert_allclose(o["tip_error"], o["ee_pos"] - o["target_pos"], atol=2e-6)


def test_env_filter_estimates_the_target_and_the_tip_error_follows():
    config = EnvConfig(obs_noise=NOISE_1CM, target_filter=True,
                       obs_features=("ee_pos", "target_pos", "target_vel", "target_acc",
                                     "tip_error"))
    _assert_filter_estimates(config, "target_filter", "target_pos", truth=2)


def test_env_filter_passes_readings_through_without_noise():
    config = EnvConfig(target_filter=True)
    a = _distances(config, controllers.make_analytic(), 40)
    b = _distances(replace(config, target_filter=False), controllers.make_analytic(), 40)
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_env_filter_needs_the_target_readings():
    from panda_lead.errors import UserError

    with pytest.raises(UserError, match="target_filter .* observe target_pos, target_vel"):
        EnvConfig(target_filter=True, obs_features=("ee_pos", "target_pos"))


ARM_FEATURES = ("ee_pos", "ee_vel", "target_pos", "target_vel", "target_acc", "tip_error")


def test_arm_filter_estimates_the_tip_and_the_tip_error_follows():
    """(with the target's own filter on, the tip error is the difference of both estimates)"""
    config = EnvConfig(obs_noise=NOISE_1CM, arm_filter=True, target_filter=True,
                       obs_features=ARM_FEATURES)
    _assert_filter_estimates(config, "arm_filter", "ee_pos", truth=1)


def test_arm_filter_passes_readings_through_without_noise():
    config = EnvConfig(arm_filter=True, obs_features=ARM_FEATURES)
    for (a, _, _), (b, _, _) in zip(_observed_readings(config, 40),
                                    _observed_readings(replace(config, arm_filter=False), 40),
                              strict=True):
        for f in ARM_FEATURES:
            np.testing.assert_allclose(a[f], b[f], atol=1e-5)


def test_a_state_not_measured_gets_no_gain():
    from panda_lead import kalman

    quiet = kalman.steady_state_gain(0.01, [0.0, 0.0], kalman.DEFAULT_JERK_PSD, measured=2)
    np.testing.assert_array_equal(quiet[:, 2], 0.0)
    np.testing.assert_allclose(quiet[:2, :2], np.eye(2), atol=1e-6)
    noisy = kalman.steady_state_gain(0.01, [0.01, 0.1], kalman.DEFAULT_JERK_PSD, measured=2)
    assert 0 < noisy[0, 0] < 1 and noisy[2, 1] != 0  # the acceleration from the velocity


def test_arm_filter_needs_the_tip_readings():
    from panda_lead.errors import UserError

    with pytest.raises(UserError, match="arm_filter .* observe ee_pos and ee_vel"):
        EnvConfig(arm_filter=True, obs_features=("ee_pos", "target_pos"))


# --- what the installation's engineer knows, observed (the installation feature) -------------

def test_the_installation_feature_shows_each_episodes_drawn_latency_and_noise():
    """From an episode's first observation on, each slot observes the delays and the target
    noise level drawn for it (what the predicting rival and the filter are given)."""
    config = EnvConfig(obs_features=("tip_error", "installation"), obs_delay=3, action_delay=2,
                       target_delay=3, random_delay=True, random_noise=True,
                       obs_noise={"target_pos": 0.01})
    task = LeadTask(config, 8)
    task.rngs = [np.random.default_rng(s) for s in range(8)]
    cols = {f: slice(a, b) for f, a, b in task.layout}["installation"]
    for episode in range(3):
        obs = task.reset() if episode == 0 else task.reset(list(range(8)))
        for _ in range(4):
            want = np.stack([task.obs_delay, task.action_delay, task.target_delay,
                             100 * 0.01 * task.noise_scale], axis=1)
            np.testing.assert_allclose(obs[:, cols] * OBS_SCALE["installation"], want,
                                       atol=1e-6)
            obs = task.step(np.zeros((8, 3)))[0]
    assert len(set(task.obs_delay.tolist())) > 1  # drawn per slot, not one for all


def test_the_installation_takes_no_noise():
    from panda_lead.errors import UserError

    with pytest.raises(UserError, match="installation feature is known, not measured"):
        EnvConfig(obs_features=("installation",), obs_noise={"installation": 0.1})


def test_nominal_episodes_have_no_delay_no_noise_and_a_pass_through_filter():
    """nominal_share: about that share of episodes has every delay and the noise at zero (and
    the installation feature says so); the filter's gain follows each episode's noise level:
    the identity for a nominal one, the config's full-noise gain at a share of 1."""
    from panda_lead import kalman

    noise = {"target_pos": 0.01, "target_vel": 0.1, "target_acc": 1.0}
    config = EnvConfig(obs_features=("target_pos", "target_vel", "target_acc", "installation"),
                       obs_delay=3, action_delay=3, target_delay=3, random_delay=True,
                       random_noise=True, nominal_share=0.5, target_filter=True, obs_noise=noise)
    task = LeadTask(config, 64)
    task.rngs = [np.random.default_rng(s) for s in range(64)]
    task.reset()
    quiet = ((task.obs_delay == 0) & (task.action_delay == 0) & (task.target_delay == 0)
             & (task.noise_scale == 0))
    assert 20 <= quiet.sum() <= 44  # ~half of 64, where 1 in 64 would be chance
    (target_filter,) = task._filters
    gains = target_filter.gain
    np.testing.assert_allclose(gains[quiet], np.eye(3)[None].repeat(quiet.sum(), 0), atol=1e-6)
    full = kalman.steady_state_gain(task.dt, [0.01, 0.1, 1.0], kalman.DEFAULT_JERK_PSD)
    table = kalman.gains_by_share(task.dt, [0.01, 0.1, 1.0], kalman.DEFAULT_JERK_PSD)
    np.testing.assert_array_equal(table[-1], full)
    loud = np.flatnonzero(task.noise_scale > 0.975)
    for i in loud:
        np.testing.assert_array_equal(gains[i], full)
    cols = {f: slice(a, b) for f, a, b in task.layout}["installation"]
    inst = task.observe()[:, cols] * OBS_SCALE["installation"]
    assert np.allclose(inst[quiet], 0.0)
    with pytest.raises(Exception, match="nominal_share .* needs random_delay or random_noise"):
        EnvConfig(nominal_share=0.5)


def test_the_lead_filter_rule_takes_the_least_jerk_at_no_more_error(tiny_run):
    """deploy.py's tuning rule for noisy_lead_filter_hz, and the flag that runs every model
    with a cutoff: the model gets it (labelled), the rivals do not."""
    deploy = _deploy_module()
    found = {0.0: (2.10, 690.0), 20.0: (1.95, 620.0), 10.0: (2.07, 570.0), 5.0: (2.60, 530.0)}
    assert deploy.choose_cutoff(found) == 10.0  # 5 Hz is smoother but less precise
    assert deploy.choose_cutoff({0.0: (2.0, 690.0), 10.0: (2.01, 500.0)}) == 0.0
    tmp, _, _, _ = tiny_run
    ctrls = deploy.controllers_for("noise1", [tmp / "archive" / "tiny.zip"], 10, lead_hz=12.0)
    (label,) = [k for k in ctrls if "tiny" in k]
    assert label.endswith("lead low-pass 12 Hz under noise")
    assert ctrls[label].config.noisy_lead_filter_hz == 12.0
    assert ctrls["Analytic+filter"].config.noisy_lead_filter_hz == 0.0


def test_the_limit_term_charges_the_joint_goals_clipped_acceleration_excess():
    """w_limit: per step, -w * sum over joints of clip(|second difference of the 100 Hz joint
    goals| / the Panda's acceleration limit - 1, 0, 1), from 0.5 s on; the single env (which
    leaves its lean route for it) agrees with the batched one."""
    from panda_lead.env import PandaLeadEnv
    from panda_lead.limits import JOINT_ACC

    w, steps = 0.02, 90
    task = LeadTask(EnvConfig(episode_steps=steps, w_limit=w), 1, nthread=1)
    single = PandaLeadEnv(episode_steps=steps, w_limit=w)
    task.reset(None, [11])
    single.reset(options={"traj_seed": 11})
    rng = np.random.default_rng(1)
    goals, charged = [task.core.q_goal[0].copy()], 0
    for k in range(1, steps + 1):
        action = rng.uniform(-1, 1, (1, 3)).astype(np.float32)
        terms = task.step(action)[4]["reward_terms"]
        one = single.step(action[0])[4]["reward_terms"]
        goals.append(task.core.q_goal[0].copy())
        if k * task.dt < 0.5 - 1e-9:
            want = 0.0
        else:
            acc = (goals[-1] - 2 * goals[-2] + goals[-3]) / task.dt ** 2
            want = -w * np.clip(np.abs(acc) / JOINT_ACC - 1, 0, 1).sum()
        assert terms["limit"][0] == pytest.approx(want, abs=1e-12)
        assert one["limit"] == pytest.approx(want, abs=1e-9)
        charged += want < 0
    assert charged > 10  # random leads break the limits: the term is exercised


def test_the_limit_term_can_charge_only_what_the_lead_changes_on_paths_a_panda_could_run():
    """limit_lead_only: zero for a zero lead even where the IK chasing a noisy target breaks the
    limits (the plain term charges it there), zero on a path faster than LIMIT_FEASIBLE_ACC,
    and for a lead on a slow path the goals' excess minus the zero lead's (the zero lead's
    goals from the IK at the same angles and aim, solved here by hand); the single env agrees
    with the batched one (without noise: the two draw it from other streams); refused without
    w_limit."""
    from panda_lead import trajectory
    from panda_lead.config import LIMIT_FEASIBLE_ACC, LIMIT_FROM_S
    from panda_lead.core import control_dt
    from panda_lead.env import PandaLeadEnv
    from panda_lead.limits import JOINT_ACC

    seeds = range(800_000, 800_050)
    slow = next(s for s in seeds if trajectory.sample(s).peak_acc < 0.5 * LIMIT_FEASIBLE_ACC)
    fast = next(s for s in seeds if trajectory.sample(s).peak_acc > 2 * LIMIT_FEASIBLE_ACC)
    steps, w = 80, 0.05
    rng = np.random.default_rng(2)
    leads = rng.uniform(-1, 1, (steps, 2, 3)).astype(np.float32)

    def run(actions, **settings) -> tuple[np.ndarray, float, list]:
        task = LeadTask(EnvConfig(episode_steps=steps, w_limit=w, **settings), 2, nthread=1)
        single = PandaLeadEnv(episode_steps=steps, w_limit=w, **settings)
        task.reset(None, [slow, fast])
        single.reset(options={"traj_seed": slow})
        total, one, per_step = np.zeros(2), 0.0, [(None, task.core.q_goal[0].copy(), 0.0, 0.0)]
        for a in actions:
            zero_lead = task.core.ik(task.core.target()[0])  # (exact sensors: the aim point)
            terms = task.step(a)[4]["reward_terms"]
            per_step.append((zero_lead[0], task.core.q_goal[0].copy(), terms["limit"][0],
                             task.core.time[0]))
            total += terms["limit"]
            one += single.step(a[0])[4]["reward_terms"]["limit"]
        if "obs_noise" not in settings:
            assert one == pytest.approx(total[0], abs=1e-9)
        return total, per_step

    noise = {"obs_noise": {"target_pos": 0.01}, "noisy_ik_target": True}
    zeros = np.zeros((steps, 2, 3), np.float32)
    assert (run(zeros, **noise)[0] < 0).all()  # the plain term: the noisy aim's jitter
    assert run(zeros, limit_lead_only=True, **noise)[0].tolist() == [0.0, 0.0]
    plain = run(leads)[0]
    gated, per_step = run(leads, limit_lead_only=True)
    assert plain[1] < 0 and gated[1] == 0.0  # the fast path: left out
    assert gated[0] != 0.0
    start = per_step[0][1]  # the reset's goal: both histories start there
    refs, goals = [start, start], [start, start]
    for zero_lead, goal, charged, t in per_step[1:]:
        refs.append(zero_lead)
        goals.append(goal)
        excess = [np.clip(np.abs(h[-1] - 2 * h[-2] + h[-3]) / control_dt() ** 2 / JOINT_ACC
                          - 1, 0, 1).sum() for h in (goals, refs)]
        want = -w * (excess[0] - excess[1]) if t >= LIMIT_FROM_S - 1e-9 else 0.0
        assert charged == pytest.approx(want, abs=1e-9)
    with pytest.raises(UserError, match="limit_lead_only"):
        EnvConfig(limit_lead_only=True)


def test_deploy_checks_the_limits_from_later_starts_too(tiny_run, tmp_path, capsys):
    """--check-from: a third table, each controller's share accepted from 0.5 s (the main
    table's) and from each later start; a later start checks a part of the same command, so
    no share falls; a start outside the episode is one line and exit 2, nothing written."""
    deploy = _deploy_module()
    tmp, _, _, _ = tiny_run
    args = deploy.Args(models=[tmp / "archive" / "tiny.zip"], seeds="0-3", conditions=["none"],
                       out=tmp_path, bootstrap=100, duration=1.0, check_from=[0.7, 0.9])
    deploy.main(args)
    text = (tmp_path / "deploy.md").read_text()
    assert "--check-from 0.7 0.9`" in text.splitlines()[0]
    main, window = text.split("Accepted by when the check starts")
    main_share = {line.split(" | ")[1]: line.split(" | ")[9] for line in main.splitlines()
                  if line.startswith("| no delay")}
    shares: dict[str, list[float]] = {}
    for line in window.splitlines():
        if line.startswith("| no delay"):
            cells = line.split(" | ")
            shares.setdefault(cells[1], []).append(float(cells[3].rstrip("%")))
            if cells[2] == "0.5":
                assert main_share[cells[1]].startswith(cells[3])
    assert set(shares) == {"Classical", "Analytic", "tiny"}
    assert all(len(v) == 3 and v == sorted(v) for v in shares.values())
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        deploy.main(deploy.Args(check_from=[1.5], duration=1.0, out=tmp_path / "bad"))
    assert exc.value.code == 2
    assert "--check-from 1.5" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_deploy_compares_each_model_with_the_rival_its_condition_calls_for(tiny_run, tmp_path):
    """The second table: a model minus the filtered analytic lead under noise and minus the
    predicting one under latency (none without delay or noise), with the command's flags."""
    deploy = _deploy_module()
    tmp, _, _, _ = tiny_run
    args = deploy.Args(models=[tmp / "archive" / "tiny.zip"], seeds="0-1",
                       conditions=["none", "noise1", "delay1"], out=tmp_path, bootstrap=100,
                       duration=0.8, noisy_lead_filter_hz=10.0)
    deploy.main(args)
    text = (tmp_path / "deploy.md").read_text()
    assert "--noisy-lead-filter-hz 10`" in text.splitlines()[0]
    rival = text.split("Against the rival")[1]
    rows = [line.split(" | ")[:3] for line in rival.splitlines() if line.startswith("| ")][1:]
    label = "tiny + lead low-pass 10 Hz under noise"
    assert rows == [["| noise 1 cm", label, "Analytic+filter"],
                    ["| latency 1 step (10 ms)", label, "Analytic+predict"]]


def test_deploy_compares_two_studies_over_their_seeds(tiny_run, tmp_path, monkeypatch,
                                                     capsys):
    """--studies A B: each study's archived seeds join the rows, and a table gives B minus A
    per condition, each study the mean over its seeds: the shares and the error difference
    agree with the per-seed rows of the main table. A study with fewer than two archived
    seeds, or the same study twice, is one line and exit 2, nothing written."""
    import shutil

    deploy = _deploy_module()
    tmp, _, _, _ = tiny_run
    seeds = tmp_path / "archive" / "seeds"
    seeds.mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    # study a: the archived model twice; study b: it once and once adopted with half its lead
    # bound, so that the two studies differ (the adoption's quick test on two seeds)
    from panda_lead import adopt
    from panda_lead import seeds as seed_sets

    monkeypatch.setattr(seed_sets, "QUICK_TEST_SEEDS", (0, 1))
    tiny = tmp / "archive" / "tiny"
    half = adopt.adopt(tiny.with_suffix(".zip"), "half",
                       {"max_lead": json.loads(tiny.with_suffix(".json").read_text())[
                           "env_config"]["max_lead"] / 2}, log=lambda *_: None).with_suffix("")
    for name, src in (("a_s1", tiny), ("a_s2", tiny), ("b_s1", half), ("b_s2", tiny)):
        for ext in (".zip", ".json"):
            shutil.copy(src.with_suffix(ext), (seeds / name).with_suffix(ext))
    args = deploy.Args(studies=["a", "b"], seeds="0-3", conditions=["none", "delay1"],
                       out=tmp_path / "out", bootstrap=200, duration=0.8)
    deploy.main(args)
    text = (tmp_path / "out" / "deploy.md").read_text()
    assert "--studies a b`" in text.splitlines()[0]
    main, between = text.split("Against the rival")[0], text.split("Between studies")[1]
    for cond in ("no delay, no noise", "latency 1 step (10 ms)"):
        cells = {line.split(" | ")[1]: line.split(" | ") for line in main.splitlines()
                 if line.startswith(f"| {cond} |")}
        assert set(cells) >= {"a_s1", "a_s2", "b_s1", "b_s2"}
        share = {k: float(c[9].split("%")[0]) for k, c in cells.items()}
        error = {k: float(c[2]) for k, c in cells.items()}
        (row,) = [line.split(" | ") for line in between.splitlines()
                  if line.startswith(f"| {cond} |")]
        assert float(row[1].rstrip("%")) == pytest.approx((share["a_s1"] + share["a_s2"]) / 2,
                                                          abs=0.06)
        assert float(row[2].rstrip("%")) == pytest.approx((share["b_s1"] + share["b_s2"]) / 2,
                                                          abs=0.06)
        want = (error["b_s1"] + error["b_s2"] - error["a_s1"] - error["a_s2"]) / 2
        assert want and float(row[4].split()[0]) == pytest.approx(want, abs=0.006)
        assert "[" in row[3] and ("shown" in row[4] or "not shown" in row[4])
    for studies, words in ((["a"], "two different study names"),
                           (["a", "a"], "two different study names"),
                           (["a", "c"], "--studies c: 0 archived seed model(s)")):
        capsys.readouterr()
        with pytest.raises(SystemExit) as exc:
            deploy.main(deploy.Args(studies=studies, out=tmp_path / "bad"))
        assert exc.value.code == 2
        assert words in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_recent_actions_are_the_last_actions_sent_and_skip_the_observation_delay():
    """recent_actions (issue 36: a delayed system is Markov again with its recent actions): the
    last RECENT_ACTIONS actions the policy sent, newest first, zeros before the episode, as
    fresh under an observation delay as without one, while prev_action arrives late with the
    rest of the observation; the single env observes what the batched one does."""
    from panda_lead.config import RECENT_ACTIONS
    from panda_lead.env import PandaLeadEnv

    features = ("tip_error", "prev_action", "recent_actions")
    config = EnvConfig(obs_features=features, obs_delay=2, action_delay=1, episode_steps=12)
    task = LeadTask(config, 3)
    cols = {f: slice(a, b) for f, a, b in task.layout}
    rng = np.random.default_rng(0)
    obs, sent = task.reset(traj_seeds=[1, 2, 3]), []
    assert not obs[:, cols["recent_actions"]].any()
    single = PandaLeadEnv(config)
    first, _ = single.reset(seed=0, options={"traj_seed": 1})
    np.testing.assert_array_equal(first, obs[0])
    for t in range(10):
        action = rng.uniform(-1, 1, (3, 3)).astype(np.float32)
        sent.insert(0, action)
        obs = task.step(action)[0]
        got = obs[:, cols["recent_actions"]].reshape(3, RECENT_ACTIONS, 3)
        for k in range(RECENT_ACTIONS):
            want = sent[k] if k < len(sent) else np.zeros((3, 3))
            np.testing.assert_allclose(got[:, k], want, atol=1e-6)
        late = sent[2] if t >= 2 else np.zeros((3, 3))  # the observation is 2 steps old
        np.testing.assert_allclose(obs[:, cols["prev_action"]], late, atol=1e-6)
        np.testing.assert_array_equal(single.step(action[0])[0], obs[0])


def test_recent_actions_take_no_noise_and_need_a_lead():
    with pytest.raises(UserError, match="recent_actions feature is known, not measured"):
        EnvConfig(obs_features=("recent_actions",), obs_noise={"recent_actions": 0.1})
    with pytest.raises(UserError, match="recent_actions holds 3-D leads"):
        EnvConfig(obs_features=("recent_actions",), action="joint")
