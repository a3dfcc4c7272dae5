"""The online corrections (panda_lead/online.py): their arithmetic on a stub task whose error
is known, that they are nothing at gain 0 and reset with each episode, that the lap-to-lap one
tracks circles closer on the real arm, and that a rollout set records which one it ran."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from panda_lead.online import OnlineCorrection, wrap

DT, MAX_LEAD = 0.01, 0.1
ROOT = Path(__file__).resolve().parent.parent


class StubTask:
    """What wrap reads: the time, the target and tip (error = target - tip), each slot's lap."""

    def __init__(self, laps, errors):
        self.dt = DT
        self.config = SimpleNamespace(action="lead", episode_steps=len(errors), max_lead=MAX_LEAD,
                                      obs_noise={}, obs_delay=0, action_delay=0, target_delay=0,
                                      random_delay=False, repetitive_gain=0.0)
        self.trajs = [SimpleNamespace(params={"lap_time": lap}) for lap in laps]
        self.errors, self.k = errors, 0  # errors: (steps, n, 3)
        n = len(laps)
        self.core = SimpleNamespace(time=np.zeros(n), tip_pos=np.zeros((n, 3)),
                                    target=lambda: (self.errors[self.k], None, None))

    def error_reading_noise(self):
        return 0.0

    def play(self, act) -> np.ndarray:
        """The lead (m) act adds at each step, (steps, n, 3)."""
        out = []
        for k in range(len(self.errors)):
            self.k = k
            self.core.time = np.full(len(self.trajs), k * DT)
            out.append(act(np.zeros((len(self.trajs), 1)), self) * MAX_LEAD)
        return np.array(out)


def zero_lead(obs, task):
    return np.zeros((len(obs), 3), dtype=np.float32)


def test_the_integral_is_the_gain_times_the_errors_sum_after_its_start():
    steps = 80
    e = np.tile([[[0.01, -0.02, 0.0]]], (steps, 1, 1))  # a constant 1 cm / -2 cm error
    lead = StubTask([1.0], e).play(wrap(zero_lead, OnlineCorrection("integral", 2.0, start=0.5)))
    k = np.arange(steps)
    expected = 2.0 * DT * np.clip(k - 49, 0, None)[:, None] * np.array([0.01, -0.02, 0.0])
    np.testing.assert_allclose(lead[:, 0], expected, atol=1e-7)  # float32 actions


def test_the_repetitive_correction_adds_the_error_one_lap_ago_plus_its_advance():
    """Lap 4 steps; c(k) = c(k-4) + 0.5 e(k-4+1), learning only from errors after 0.1 s."""
    steps, lap_steps, gain, advance = 40, 4, 0.5, 1
    rng = np.random.default_rng(0)
    e = rng.normal(0, 0.01, (steps, 1, 3))
    lead = StubTask([lap_steps * DT], e).play(
        wrap(zero_lead, OnlineCorrection("repetitive", gain, advance, start=0.1)))
    c = np.zeros((steps, 3))
    for k in range(steps):
        src = k - lap_steps + advance
        if k - lap_steps >= 0:
            c[k] = c[k - lap_steps]
        if src >= 0 and src * DT >= 0.1 - 1e-12:
            c[k] += gain * e[src, 0]
    np.testing.assert_allclose(lead[:, 0], np.clip(c, -MAX_LEAD, MAX_LEAD), atol=1e-7)


def test_the_gate_keeps_an_excursion_out_of_what_the_correction_learns():
    """max_error: an error farther than it (a 20 cm excursion) is not learned from, every other
    error is, as the law without the gate learns it; and the gate is recorded only when set."""
    steps, lap_steps, gain = 30, 4, 0.5
    e = np.random.default_rng(2).normal(0, 0.01, (steps, 1, 3))
    e[10, 0] = [0.2, 0.0, 0.0]
    gated = StubTask([lap_steps * DT], e).play(wrap(zero_lead, OnlineCorrection(
        "repetitive", gain, start=0.0, max_error=0.05)))
    c = np.zeros((steps, 3))
    for k in range(lap_steps, steps):
        c[k] = c[k - lap_steps]
        if np.linalg.norm(e[k - lap_steps, 0]) <= 0.05:
            c[k] += gain * e[k - lap_steps, 0]
    np.testing.assert_allclose(gated[:, 0], np.clip(c, -MAX_LEAD, MAX_LEAD), atol=1e-7)
    assert np.abs(gated[14:, 0, 0]).max() < 0.05  # the spike never came back
    assert "max_error" not in OnlineCorrection("repetitive", 0.3).meta()
    assert OnlineCorrection("repetitive", 0.3, max_error=0.05).meta()["max_error"] == 0.05


def test_a_fading_correction_weighs_what_it_learns_by_a_smoothstep_and_records_it():
    """fade: an error made t s after the start is learned from with the weight 3x^2 - 2x^3,
    x = t / fade (then 1), not all at once; without a fade the law is the one above, bit for
    bit, and records no fade."""
    steps, lap_steps, gain, advance, start, fade = 60, 4, 0.5, 1, 0.1, 0.2
    e = np.random.default_rng(3).normal(0, 0.01, (steps, 1, 3))
    faded = StubTask([lap_steps * DT], e).play(
        wrap(zero_lead, OnlineCorrection("repetitive", gain, advance, start=start, fade=fade)))
    c = np.zeros((steps, 3))
    for k in range(steps):
        src = k - lap_steps + advance
        if k - lap_steps >= 0:
            c[k] = c[k - lap_steps]
        x = np.clip((src * DT - start) / fade, 0, 1) if src >= 0 else 0.0
        c[k] += gain * x * x * (3 - 2 * x) * e[max(src, 0), 0]
    np.testing.assert_allclose(faded[:, 0], np.clip(c, -MAX_LEAD, MAX_LEAD), atol=1e-7)
    hard = StubTask([lap_steps * DT], e).play(
        wrap(zero_lead, OnlineCorrection("repetitive", gain, advance, start=start)))
    assert not np.allclose(faded, hard)  # the first lap's errors are learned from less
    assert "fade" not in OnlineCorrection("repetitive", 0.3).meta()
    assert OnlineCorrection("repetitive", 0.3, fade=0.2).meta()["fade"] == 0.2
    w = OnlineCorrection("integral", 1.0, start=0.5, fade=0.2).weight(np.array([0.4, 0.6, 0.8]))
    np.testing.assert_allclose(w, [0.0, 0.5, 1.0])


def test_a_fresh_episode_starts_from_no_correction():
    e = np.full((30, 1, 3), 0.01)
    act = wrap(zero_lead, OnlineCorrection("integral", 5.0, start=0.0))
    task = StubTask([1.0], e)
    first = task.play(act)
    again = task.play(act)  # the same slot, time back at 0: the integral is cleared
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize("kind", ["integral", "repetitive"])
def test_at_gain_zero_a_correction_is_the_lead_alone_bit_for_bit(kind):
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many

    config = EnvConfig(episode_steps=120)
    act = controllers.make_analytic()
    seeds = [800_000, 800_001, 800_002]
    alone = record_many(config, act, seeds)
    wrapped = record_many(config, wrap(act, OnlineCorrection(kind, 0.0, 10)), seeds)
    for a, b in zip(alone, wrapped, strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)


@pytest.mark.parametrize("late", [0, 3])
def test_the_lap_to_lap_correction_tracks_circles_closer_than_the_lead_alone(late):
    """The behaviour it exists for: on circles (several laps in 5 s) the error a lap ago,
    added with a phase lead, brings the settled error down (the tuning seeds' setting); and
    so it does under the deploy table's "latency 3" (the lead's channel 30 ms late both ways),
    computed for when it acts, against the analytic lead alone under the same latency."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many

    config = EnvConfig(episode_steps=500, obs_delay=late, action_delay=late, random_delay=False)
    seeds = list(range(800_000, 800_008))
    act = controllers.make_analytic()
    settled = {}
    for name, a in (("alone", act),
                    ("repetitive", wrap(act, OnlineCorrection("repetitive", 0.3, 10)))):
        rs = record_many(config, a, seeds, shapes=["circle"] * len(seeds))
        settled[name] = np.mean([r.error[r.t >= 0.5].mean() for r in rs])
    assert settled["repetitive"] < 0.9 * settled["alone"]


def test_on_a_zero_lead_latency_changes_nothing_the_correction_is_computed_for_when_it_acts():
    """The latency arithmetic on the real arm: on the classical controller (a zero lead, so the
    late channel carries only the correction) a lap-to-lap correction computed for when it acts
    from the errors known then moves the arm bit for bit as it does without latency (every error
    it needs is a lap old); the feedforward rival's rollouts at 1 and 3 steps showed the same."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many

    seeds, circles = [800_000, 800_001], ["circle", "circle"]
    correction = OnlineCorrection("repetitive", 0.5, 10, 3)
    runs = [record_many(EnvConfig(episode_steps=250, obs_delay=d, action_delay=d,
                                  random_delay=False),
                        wrap(controllers.classical, correction), seeds, shapes=circles)
            for d in (0, 3)]
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)
    alone = record_many(EnvConfig(episode_steps=250), controllers.classical, seeds,
                        shapes=circles)
    assert any(np.abs(a.ee_pos - b.ee_pos).max() > 1e-3 for a, b in
               zip(alone, runs[0], strict=True))


def test_under_noise_the_correction_reads_the_measured_error():
    """Noise on the target's reading reaches nothing of the classical controller (its IK aims
    at the true target) but what the correction reads: the arm moves alike without the
    correction and apart with it; and an env that draws no noise for a noisy reading (neither
    it nor tip_error observed) is refused rather than read exact."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many

    seeds, circles = [800_000, 800_001], ["circle", "circle"]
    quiet, noisy = EnvConfig(episode_steps=250), EnvConfig(episode_steps=250,
                                                            obs_noise={"target_pos": 0.01})
    correction = OnlineCorrection("repetitive", 0.5, 10, 3)
    for a, b in zip(record_many(quiet, controllers.classical, seeds, shapes=circles),
                    record_many(noisy, controllers.classical, seeds, shapes=circles), strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)
    apart = [np.abs(a.ee_pos - b.ee_pos).max() for a, b in zip(
        record_many(quiet, wrap(controllers.classical, correction), seeds, shapes=circles),
        record_many(noisy, wrap(controllers.classical, correction), seeds, shapes=circles),
        strict=True)]
    assert min(apart) > 1e-4
    unread = EnvConfig(episode_steps=20, obs_features=("target_pos", "target_vel"),
                       obs_noise={"ee_pos": 0.01})
    with pytest.raises(ValueError, match="draws no noise for the ee_pos reading"):
        record_many(unread, wrap(controllers.classical, correction), seeds[:1])


def test_a_rollout_set_records_its_correction_and_names_it():
    from panda_lead.metrics.pairing import controller_label
    from panda_lead.rollout import identity

    base = {"controller": "policy", "model_sha256": "ab", "env": {}}
    corrected = {**base, "online": OnlineCorrection("repetitive", 0.3, 15).meta()}
    assert identity(base) != identity(corrected)  # never one set, never mixed in a folder
    rollouts = {0: SimpleNamespace(meta={**corrected, "env": {"action": "lead"}})}
    assert controller_label(rollouts, "x") == "RL+Lead + repetitive"
    looped = {0: SimpleNamespace(meta={**base, "env": {"repetitive_gain": 0.3}})}
    assert controller_label(looped, "x") == "RL+Lead + repetitive in the loop"


def test_the_feedforward_base_is_the_rival_and_its_correction_acts_on_it():
    """online_correction.py --base feedforward: a zero lead on the feedforward env (the rival,
    tests/test_rivals.py), labelled as knowing the path; its lap-to-lap correction at gain 0
    is the rival bit for bit, and at its tuned setting it settles closer on circles."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from online_correction import Args, _base

    from panda_lead.metrics.pairing import controller_label
    from panda_lead.rollout import record_many

    ctrl = _base(Args(command="play", base="feedforward"))
    assert ctrl.config.feedforward and ctrl.config.action == "lead"
    assert ctrl.meta["controller"] == "feedforward" and ctrl.meta["knows_path"]
    rollouts = {0: SimpleNamespace(meta={**ctrl.meta, "online": {"kind": "repetitive"}})}
    assert controller_label(rollouts, "x") == "Feedforward + repetitive"
    config = ctrl.config.replace(episode_steps=300)
    seeds = [800_000, 800_001, 800_002]
    circles = ["circle"] * len(seeds)
    alone = record_many(config, ctrl.act, seeds, shapes=circles)
    off = record_many(config, wrap(ctrl.act, OnlineCorrection("repetitive", 0.0, 12, 5)), seeds,
                      shapes=circles)
    tuned = record_many(config, wrap(ctrl.act, OnlineCorrection("repetitive", 0.3, 12, 5)),
                        seeds, shapes=circles)
    for a, b in zip(alone, off, strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)
    settled = {name: np.mean([r.error[r.t >= 0.5].mean() for r in rs])
               for name, rs in (("alone", alone), ("tuned", tuned))}
    assert settled["tuned"] < 0.9 * settled["alone"]


def test_bad_settings_are_refused():
    for bad in (dict(kind="derivative", gain=1.0), dict(kind="integral", gain=float("nan")),
                dict(kind="repetitive", gain=0.3, advance=-1),
                dict(kind="repetitive", gain=0.3, fade=-0.1),
                dict(kind="repetitive", gain=0.3, fade=float("inf"))):
        with pytest.raises(ValueError):
            OnlineCorrection(**bad)


def test_a_correction_refuses_a_late_camera_or_a_drawn_latency():
    """A late target camera's error is not the tip's; a latency drawn per episode is not one it
    can plan for."""
    for cfg, words in (({"target_delay": 1}, "late target camera"),
                       ({"obs_delay": 1, "action_delay": 1, "random_delay": True},
                        "fixed, known latency")):
        task = StubTask([1.0], np.zeros((3, 1, 3)))
        task.config = SimpleNamespace(**{**vars(task.config), **cfg})
        with pytest.raises(ValueError, match=words):
            task.play(wrap(zero_lead, OnlineCorrection("integral", 1.0)))


def test_under_latency_the_correction_is_computed_for_when_it_acts_from_what_is_known():
    """Latency 2 steps each way, lap 6, advance 1: at step k the lead computer knows the errors
    up to k - 2 and its output acts at k + 2, so it returns C(k + 2) with
    C(i) = C(i - 6) + 0.5 e(i - 5); with an advance that would need errors not yet seen
    (src > k - 2) it learns nothing."""
    steps, lap, gain, late = 40, 6, 0.5, 2
    e = np.random.default_rng(1).normal(0, 0.01, (steps, 1, 3))

    def played(advance):
        task = StubTask([lap * DT], e)
        task.config = SimpleNamespace(**{**vars(task.config), "obs_delay": late,
                                         "action_delay": late})
        correction = OnlineCorrection("repetitive", gain, advance, start=0.0)
        return task.play(wrap(zero_lead, correction))

    big = np.zeros((steps + late, 3))
    for i in range(steps + late):
        if i - lap >= 0:
            big[i] = big[i - lap]
        if i - lap + 1 >= 0:
            big[i] += gain * e[i - lap + 1, 0]
    np.testing.assert_allclose(played(1)[:, 0], np.clip(big[late:], -MAX_LEAD, MAX_LEAD),
                               atol=1e-7)
    assert not played(lap - 2 * late + 1).any()


def test_the_env_runs_the_same_law_as_a_played_correction_bit_for_bit():
    """EnvConfig.repetitive_gain (a policy trained with the correction in the loop) runs
    online.py's law, the one studies/online_correction.py plays on top of a trained lead:
    the same lead in either house gives the same arm, bit for bit."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig, knows_path
    from panda_lead.rollout import record_many

    act, seeds = controllers.make_analytic(), [800_000, 800_001, 800_002]
    shapes = ["circle", "fig8", "fly"]
    in_loop = EnvConfig(episode_steps=500, repetitive_gain=0.3, repetitive_advance=15,
                        repetitive_smooth=2)
    played = record_many(EnvConfig(episode_steps=500), wrap(act, OnlineCorrection(
        "repetitive", 0.3, 15, 2)), seeds, shapes=shapes)
    looped = record_many(in_loop, act, seeds, shapes=shapes)
    alone = record_many(EnvConfig(episode_steps=500), act, seeds, shapes=shapes)
    for a, b in zip(played, looped, strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)
    for a, c in zip(played[:2], alone[:2], strict=True):  # the closed loops: it acted there
        assert not np.array_equal(a.ee_pos, c.ee_pos)
    assert knows_path(in_loop) and knows_path(in_loop.to_dict())  # labelled, never causal
    with pytest.raises(ValueError, match="already runs"):  # never two corrections at once
        record_many(in_loop, wrap(act, OnlineCorrection("repetitive", 0.3, 15)), seeds[:1])


def test_the_in_loop_correction_refuses_a_world_with_noise_or_latency():
    from panda_lead.config import EnvConfig
    from panda_lead.errors import UserError

    for bad in ({"obs_delay": 1}, {"target_delay": 2}, {"action": "joint"},
                {"obs_noise": {"target_pos": 0.01}}, {"random_noise": True}):
        with pytest.raises(UserError, match="repetitive_gain"):
            EnvConfig(repetitive_gain=0.3, **bad)


def test_the_oracle_starts_from_the_in_loop_correction_as_from_the_played_one():
    """The ILC oracle restarted from a lead with the correction in the loop records the
    corrected leads once and replays them without it (else the correction would add twice):
    the same oracle as the one started from the same correction played on top, bit for bit."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.ilc import ILCConfig, learn_leads

    act, seeds, ilc = controllers.make_analytic(), [800_000, 800_001], ILCConfig(iterations=2)
    plain = EnvConfig(episode_steps=300)
    looped = plain.replace(repetitive_gain=0.3, repetitive_advance=15)
    a, history_a = learn_leads(looped, seeds, None, ilc, act)
    b, history_b = learn_leads(plain, seeds, None, ilc,
                               wrap(act, OnlineCorrection("repetitive", 0.3, 15)))
    np.testing.assert_array_equal(a, b)
    assert history_a == history_b and history_a[-1] < history_a[0]


def test_a_baseline_on_an_in_loop_models_env_plays_without_the_correction(monkeypatch):
    """The analytic lead asked to play on such a model's env is the analytic lead (the
    correction on top of it is online_correction.py's own set); the policy keeps it, and the
    oracle started from the policy replays without it (it is in the leads it recorded)."""
    from pathlib import Path

    from panda_lead import harness, models

    env = {"repetitive_gain": 0.3, "repetitive_advance": 15,
           "obs_features": ["tip_error", "repetitive_correction"]}  # (it observes it, too)
    monkeypatch.setattr(models, "load_policy", lambda path: (
        object(), env, {"model_sha256": "0" * 64}))
    monkeypatch.setattr(harness.controllers, "make_policy", lambda *a, **k: None)
    for name, gain in (("classical", 0.0), ("analytic", 0.0), ("policy", 0.3)):
        assert harness.build(name, 10, Path("looped.zip")).config.repetitive_gain == gain
    oracle = harness.build("ilc", 10, Path("looped.zip"))
    assert oracle.config.repetitive_gain == 0.0 and oracle.init_config.repetitive_gain == 0.3


def test_the_observed_correction_is_the_one_the_env_adds():
    """repetitive_correction shows the policy, before it acts, the correction the env then adds
    to its lead: with a zero policy the applied lead is exactly the observed correction."""
    from panda_lead.config import OBS_SCALE, EnvConfig, obs_layout
    from panda_lead.task import LeadTask

    config = EnvConfig(episode_steps=300, repetitive_gain=0.3, repetitive_advance=15,
                       obs_features=("tip_error", "repetitive_correction"))
    cols = next(slice(a, b) for f, a, b in obs_layout(config.obs_features)
                if f == "repetitive_correction")
    task = LeadTask(config, 2, nthread=1)
    obs = task.reset(None, [800_000, 800_001], ["circle", "fig8"])
    seen = []
    for _ in range(config.episode_steps):
        c = obs[:, cols].astype(np.float64) * OBS_SCALE["repetitive_correction"]
        obs, *_, info = task.step(np.zeros((2, 3), np.float32))
        np.testing.assert_allclose(info["lead"], c, atol=1e-7)  # (float32 observation)
        seen.append(np.abs(c).max())
    assert max(seen) > 1e-3  # it acted within the episode
    plain = LeadTask(config.replace(repetitive_gain=0.0), 2, nthread=1)  # none: it reads 0
    obs = plain.reset(None, [800_000, 800_001], ["circle", "fig8"])
    for _ in range(150):
        assert not obs[:, cols].any()
        obs, *_ = plain.step(np.full((2, 3), 0.5, np.float32))


def test_tune_gates_every_setting_and_says_so(monkeypatch, capsys):
    """online_correction.py tune --max-error: every repetitive setting of the grid is gated,
    the header's command and the printed play command carry the gate (a tuning table must
    rerun as printed), and the lead alone is scored beside them. The scoring is stubbed: what
    is tested is the grid, not the arm."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    import online_correction
    import preview_rivals

    from panda_lead import online

    played = []

    def fake_wrap(act, correction):
        played.append(correction)
        return act

    scores = iter([(1.0, 0.9), (0.8, 0.5), (0.8, 0.4)])  # alone, then the grid's two
    monkeypatch.setattr(online, "wrap", fake_wrap)
    monkeypatch.setattr(preview_rivals, "mean_errors", lambda *_: next(scores))
    args = online_correction.Args(command="tune", base="analytic", integral_gains=(),
                                  repetitive_gains=(0.5,), advances=(8, 10), smooths=(3,),
                                  max_error=0.05)
    online_correction.tune(args)
    out = capsys.readouterr().out
    assert [(c.kind, c.gain, c.advance, c.smooth, c.max_error) for c in played] == [
        ("repetitive", 0.5, 8, 3, 0.05), ("repetitive", 0.5, 10, 3, 0.05)]
    assert "tune --base analytic --max-error 0.05 --integral-gains  --repetitive-gains 0.5" in out
    assert "| none (the lead alone) | | | | 1.000 | 0.900 |" in out
    assert ("Tuned repetitive: gain 0.5 --advance 10 --smooth 3 (settled 0.400 cm): `uv run "
            "studies/online_correction.py play --base analytic --max-error 0.05 --kind "
            "repetitive --gain 0.5 --advance 10 --smooth 3") in out


def test_the_feedforward_rival_under_noise_reads_it_only_through_its_correction():
    """online_correction.py --base feedforward --condition noise1: the rival's IK aims at the
    planned path (the plan is known, not measured), so alone it runs as in the ideal world, bit
    for bit; its correction reads the measured error, so with it the noise moves the arm."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from online_correction import Args, _base

    from panda_lead.rollout import record_many

    ideal = _base(Args(command="play", base="feedforward"))
    noisy = _base(Args(command="play", base="feedforward", condition="noise1"))
    assert noisy.config.obs_noise and not noisy.config.noisy_ik_target
    seeds, circles = [800_000, 800_001], ["circle", "circle"]
    runs = {}
    for name, ctrl in (("ideal", ideal), ("noisy", noisy)):
        config = ctrl.config.replace(episode_steps=150)
        corrected = wrap(ctrl.act, OnlineCorrection("repetitive", 0.3, 12, 5))
        runs[name] = (record_many(config, ctrl.act, seeds, shapes=circles),
                      record_many(config, corrected, seeds, shapes=circles))
    for a, b in zip(runs["ideal"][0], runs["noisy"][0], strict=True):
        np.testing.assert_array_equal(a.ee_pos, b.ee_pos)
    moved = [np.abs(a.ee_pos - b.ee_pos).max()
             for a, b in zip(runs["ideal"][1], runs["noisy"][1], strict=True)]
    assert min(moved) > 1e-4


def test_a_noise_condition_on_the_plan_aims_the_ik_at_it_and_says_so():
    """online_correction.condition_overrides: NAME_plan is NAME's noise with the IK aimed at the
    planned path, said as noisy_ik_target False (the hardware model's own env aims it at the
    reading, so leaving the key out would not do); the feedforward rival's noise is always on
    the plan; a condition without noise has no _plan."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from deploy import overrides
    from online_correction import condition_overrides

    from panda_lead.errors import UserError

    reading = condition_overrides("noise1")
    plan = condition_overrides("noise1_plan")
    assert reading["noisy_ik_target"] is True and plan["noisy_ik_target"] is False
    assert plan["obs_noise"] == reading["obs_noise"] == overrides("noise1")["obs_noise"]
    assert condition_overrides("noise1", "feedforward") == plan
    assert condition_overrides("delay3", "feedforward") == overrides("delay3")
    assert condition_overrides("none") is None
    with pytest.raises(UserError, match="only a noise condition"):
        condition_overrides("delay3_plan")


def test_play_duration_sets_the_episode_length():
    """online_correction.py play --duration: the episodes' length (the registered sets keep the
    test seeds' 5 s)."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from online_correction import Args, _base

    assert _base(Args(command="play", base="analytic")).config.episode_steps == 500
    assert _base(Args(command="play", base="analytic", duration=10.0)).config.episode_steps == 1000


def test_the_clearance_reaches_every_base_and_keeps_the_corrected_arm_off_itself():
    """online_correction.py --clearance: the collision-aware IK under the lead and the rival
    alike (every other IK setting as without it, the rival still the rival); on trajectories
    that pass near the arm's body (the collision study's subset) the rival with its correction
    spends less than half the time touching itself with it (its planned joint path is
    collision-aware too: test_clearance.py); bad values and the oracle are refused,
    and so is a bad --fade, before anything is played."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from online_correction import Args, _base, play

    from panda_lead.errors import UserError
    from panda_lead.rollout import record_many

    for base in ("policy", "analytic", "feedforward"):
        plain = _base(Args(command="play", base=base))
        clear = _base(Args(command="play", base=base, clearance=0.02))
        assert plain.config.ik.clearance == 0.0 and clear.config.ik.clearance == 0.02
        assert {**vars(clear.config.ik), "clearance": 0.0} == vars(plain.config.ik)
        assert clear.config.feedforward == plain.config.feedforward == (base == "feedforward")
    seeds = [int(s) for s in (ROOT / "results/studies/collision/collision_seeds.txt")
             .read_text().split()[:8]]
    touching = {}
    for clearance in (0.0, 0.02):
        ctrl = _base(Args(command="play", base="feedforward", clearance=clearance))
        corrected = wrap(ctrl.act, OnlineCorrection("repetitive", 0.3, 12, 5))
        runs = record_many(ctrl.config, corrected, seeds)
        touching[clearance] = sum(np.asarray(r.self_collision).sum() for r in runs)
    assert touching[0.0] > 0 and touching[0.02] < touching[0.0] / 2
    for bad in (-0.01, float("nan")):
        with pytest.raises(UserError, match="--clearance"):
            _base(Args(command="play", clearance=bad))
    with pytest.raises(UserError, match="--clearance must be a distance"):
        play(Args(command="play", oracle=True, clearance=-0.02, prefix="x"))
    from online_correction import tune

    for bad in (-0.1, float("nan")):  # a fade is refused before anything is played
        for command in (play, tune):
            with pytest.raises(UserError, match="--fade must be a time"):
                command(Args(command=command.__name__, fade=bad, prefix="x"))


def test_a_faded_correction_keeps_what_the_real_arm_accepts():
    """Why fade exists: on these test trajectories the hardware model alone is accepted by the
    Panda's limits (docs/deploy.md's check, from 0.5 s on) and its gated correction switched on
    at once is not (the first lap's kink: a joint-2 acceleration spike in the 1 kHz command);
    faded in over 0.1 s (the setting chosen on the selection seeds) it is accepted again."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from deploy import SKIP_S
    from online_correction import Args, _base
    from results_prepare import HARDWARE

    from panda_lead.core import home_qpos
    from panda_lead.limits import check_many
    from panda_lead.rollout import record_many

    ctrl = _base(Args(command="play", model=ROOT / "archive" / f"{HARDWARE}.zip"))
    seeds = [16, 429, 647]

    def checks(act):
        runs = record_many(ctrl.config, act, seeds)
        return check_many(np.stack([r.q_goal for r in runs]), runs[0].dt, home_qpos(),
                          skip=SKIP_S)

    gated = dict(kind="repetitive", gain=0.5, advance=10, smooth=3, max_error=0.05)
    alone = checks(ctrl.act)
    at_once = checks(wrap(ctrl.act, OnlineCorrection(**gated)))
    faded = checks(wrap(ctrl.act, OnlineCorrection(**gated, fade=0.1)))
    assert all(c.accepted for c in alone)
    assert not any(c.accepted for c in at_once)
    assert all(c.worst_limit == "joint 2 acceleration" for c in at_once)
    assert all(c.accepted for c in faded)


def test_summary_levels_are_each_sides_mean_with_a_ci_around_it(tmp_path, monkeypatch, capsys):
    """summary --levels: each side's mean and settled error as a level, its CI around it
    (narrow for near-constant sets, and the difference lines above unchanged by the flag)."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    import online_correction as oc

    rng = np.random.default_rng(0)
    data = {p: {s: {"mean_err": 1.0 + 0.1 * k + 0.01 * rng.standard_normal(),
                    "settled_err": 0.5 + 0.1 * k + 0.01 * rng.standard_normal(),
                    "jerk_rms": 400.0} for s in range(50)}
            for k, p in enumerate(["a1", "b1", "a2", "b2"])}
    monkeypatch.setattr(oc, "_set_metrics", lambda prefix, settle_time=0.5: data[prefix])
    outs = []
    for levels in (False, True):
        oc.summary(oc.Args(command="summary", pairs=["a1:b1", "a2:b2"], bootstrap=500,
                           levels=levels))
        outs.append(capsys.readouterr().out)
    assert outs[1].startswith(outs[0].split("\n", 1)[0].replace("`:", " --levels`:"))
    assert outs[0].split("\n", 1)[1] in outs[1]  # the rest of the plain output, unchanged
    lines = [x for x in outs[1].splitlines() if x.startswith("- level, settled")]
    assert len(lines) == 2
    for line, want in zip(lines, (0.6, 0.7), strict=True):  # (0.5 + 0.7) / 2, (0.6 + 0.8) / 2
        level, lo, hi = (float(x) for x in
                         line.split(": ")[1].replace("[", "").replace("]", "").replace(",", "")
                         .split())
        assert abs(level - want) < 0.01 and lo < level < hi and hi - lo < 0.3
