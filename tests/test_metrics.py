"""metrics.py: per-rollout metrics, paired statistics and the CLI, on hand-built rollouts whose
answers are known in closed form."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_in_process

from panda_lead import metrics, rollout, trajectory
from panda_lead.cli import metrics as metrics_cli
from panda_lead.errors import UserError
from panda_lead.metrics import figures
from panda_lead.metrics import pairing as compare_module
from panda_lead.rollout import Rollout

REPO = Path(__file__).resolve().parents[1]

DT = 0.01


def make_rollout(ee, target=None, seed=0, shape="circle", reachable=None, dt=DT, duration=None,
                 controller="test", target_vel=None):
    """A Rollout with the given tip and target paths (T, 3); everything else zero/False."""
    ee = np.asarray(ee, dtype=float)
    T = len(ee)
    target = np.zeros((T, 3)) if target is None else np.asarray(target, dtype=float)
    zeros3, zeros7 = np.zeros((T, 3)), np.zeros((T, 7))
    return Rollout(
        t=dt * np.arange(1, T + 1), ee_pos=ee, target_pos=target,
        target_vel=zeros3 if target_vel is None else np.asarray(target_vel, dtype=float),
        target_acc=zeros3, lead=zeros3, qpos=zeros7, qvel=zeros7,
        self_collision=np.zeros(T, bool), collision_depth=np.zeros(T),
        reachable=np.ones(T, bool) if reachable is None else np.asarray(reachable, bool),
        meta=dict(seed=seed, shape=shape, controller=controller, model="none",
                  duration=T * dt if duration is None else duration, dt=dt),
    )


def on_its_trajectory(r):
    """The rollout with the target its seed and shape give (trajectory.sample), the tip keeping
    its offset from the target: what a rollout file must hold to load (a file's target is
    checked against its seed's trajectory, rollout.check_against_meta)."""
    pos, vel, acc = trajectory.sample(r.seed, r.shape).at(r.t)
    r.ee_pos = pos + (np.asarray(r.ee_pos) - np.asarray(r.target_pos))
    r.target_pos, r.target_vel, r.target_acc = pos, vel, acc
    return r


def offset_rollout(offset_m, T=100, **kw):
    """Target moving at constant velocity, tip a constant x offset away."""
    t = DT * np.arange(1, T + 1)
    target = np.stack([0.3 * t, 0.5 + 0.0 * t, 0.2 * t], axis=1)
    return make_rollout(target + [offset_m, 0.0, 0.0], target, **kw)


def test_constant_offset_gives_that_error_everywhere_and_zero_jerk():
    m = metrics.rollout_metrics(offset_rollout(0.03), settle_time=0.5, band_cm=5.0)
    for key in ("mean_err", "rmse", "max_err", "p95_err", "settled_err", "in_reach_err"):
        assert m[key] == pytest.approx(3.0, abs=1e-9), key
    assert m["jerk_rms"] == pytest.approx(0.0, abs=1e-6)  # constant velocity
    assert m["in_band"] == 100.0 and m["in_band_reachable"] == 100.0
    assert math.isnan(m["out_reach_err"])  # never out of reach
    assert m["self_collision"] == 0.0


def test_cubic_path_jerk_is_six_c():
    c = -2.5
    t = DT * np.arange(1, 201)
    ee = np.stack([c * t**3, np.zeros_like(t), np.zeros_like(t)], axis=1)
    m = metrics.rollout_metrics(make_rollout(ee))
    assert m["jerk_rms"] == pytest.approx(6 * abs(c), rel=1e-6)


def test_settled_error_excludes_the_start_up_transient():
    r = offset_rollout(0.02, T=100)
    r.ee_pos[:49, 0] += 0.5  # huge error while t < 0.5 s (t = 0.01 .. 0.49)
    assert metrics.rollout_metrics(r, settle_time=0.5)["settled_err"] == pytest.approx(2.0)


def test_time_in_band_half_and_half():
    err = np.r_[np.full(50, 0.01), np.full(50, 0.10)]  # 1 cm then 10 cm
    ee = np.stack([err, np.zeros(100), np.zeros(100)], axis=1)
    m = metrics.rollout_metrics(make_rollout(ee), band_cm=5.0)
    assert m["in_band"] == pytest.approx(50.0)
    assert m["mean_err"] == pytest.approx(5.5)


def test_reachable_split_and_out_of_reach_count_in_label():
    err = np.r_[np.full(50, 0.02), np.full(50, 0.08)]  # 2 cm reachable, 8 cm unreachable
    ee = np.stack([err, np.zeros(100), np.zeros(100)], axis=1)
    reach = np.r_[np.ones(50, bool), np.zeros(50, bool)]
    r = make_rollout(ee, reachable=reach, seed=1)
    m = metrics.rollout_metrics(r, band_cm=5.0)
    assert m["in_reach_err"] == pytest.approx(2.0)
    assert m["out_reach_err"] == pytest.approx(8.0)
    assert m["in_band_reachable"] == pytest.approx(100.0)
    assert m["in_band"] == pytest.approx(50.0)

    a = {0: offset_rollout(0.01, seed=0), 1: r}
    b = {0: offset_rollout(0.01, seed=0), 1: make_rollout(ee * 0.5, reachable=reach, seed=1)}
    cmp = metrics.compare(a, b, n_boot=200)
    row = cmp.row("out_reach_err")
    assert "(1/2)" in row.label
    assert (row.n_a, row.n_b, row.n_pairs) == (1, 1, 1)
    assert row.mean_a == pytest.approx(8.0) and row.mean_b == pytest.approx(4.0)
    assert row.delta == pytest.approx(-4.0)  # only seed 1 has out-of-reach steps in both


def test_paired_ci_constant_deltas_collapse():
    lo, hi = metrics.paired_ci(np.full(12, 0.7), n_boot=500, seed=3)
    assert lo == pytest.approx(0.7) and hi == pytest.approx(0.7)


def test_paired_ci_contains_mean_and_is_reproducible():
    d = np.random.default_rng(1).normal(1.0, 2.0, size=30)
    lo, hi = metrics.paired_ci(d, n_boot=2000, seed=0)
    assert lo < d.mean() < hi
    assert metrics.paired_ci(d, n_boot=2000, seed=0) == (lo, hi)
    for degenerate in ([], [0.4], [np.nan, 0.4]):  # a single seed has no spread to resample
        assert all(math.isnan(x) for x in metrics.paired_ci(degenerate, n_boot=10))


def test_wilcoxon():
    d = np.linspace(0.5, 2.0, 20)
    assert metrics.wilcoxon_p(d) < 0.01
    # Exact two-sided test: all 20 ranks positive has probability 2 / 2**20.
    assert metrics.wilcoxon_p(d) == pytest.approx(2 / 2**20, rel=1e-6)
    assert math.isnan(metrics.wilcoxon_p(np.zeros(10)))
    assert math.isnan(metrics.wilcoxon_p([1.0]))


def test_compare_reports_unpaired_seeds_and_known_deltas():
    a = {s: offset_rollout(0.03, seed=s, shape="circle" if s < 2 else "fig8") for s in range(4)}
    b = {s: offset_rollout(0.01, seed=s, shape="circle" if s < 2 else "fig8")
         for s in (0, 1, 2, 5)}
    cmp = metrics.compare(a, b, n_boot=300)
    assert cmp.seeds == [0, 1, 2]
    assert cmp.only_a == [3] and cmp.only_b == [5]
    row = cmp.row("mean_err")
    assert row.mean_a == pytest.approx(3.0) and row.mean_b == pytest.approx(1.0)
    assert row.delta == pytest.approx(-2.0)
    assert row.ci == pytest.approx((-2.0, -2.0))
    assert set(cmp.by_shape) == {"circle", "fig8"}
    fig8 = cmp.row("mean_err", "fig8")
    assert fig8.n_pairs == 1 and fig8.delta == pytest.approx(-2.0)
    assert math.isnan(fig8.ci[0]) and math.isnan(fig8.p)  # one seed: no CI, no test


def test_compare_rejects_mismatched_duration_and_shape():
    a = {0: offset_rollout(0.01, T=100)}
    with pytest.raises(UserError, match="duration"):
        metrics.compare(a, {0: offset_rollout(0.01, T=50)})
    with pytest.raises(UserError, match="shape"):
        metrics.compare(a, {0: offset_rollout(0.01, shape="fly")})


# ---- CLI end to end -------------------------------------------------------------------------


def write_prefix(root, prefix, offset_m, seeds, T=100):
    for s in seeds:
        shape = "circle" if s % 2 == 0 else "fig8"
        rollout.save(on_its_trajectory(offset_rollout(offset_m, T=T, seed=s, shape=shape)),
                     rollout.rollout_path(prefix, s, root))


def run_cli(*args):
    """metrics.py in-process (conftest.run_in_process), as `python metrics.py ...` from the
    root; `--help` below runs as a process."""
    return run_in_process("metrics.py", *args, "--bootstrap", "200", cwd=REPO)


@pytest.fixture
def root(tmp_path):
    write_prefix(tmp_path, "base", 0.03, range(4))
    write_prefix(tmp_path, "learned", 0.01, [0, 1, 2, 3, 9])
    write_prefix(tmp_path, "short", 0.01, range(4), T=50)
    return tmp_path


def test_cli_table_breakdown_and_plot(root):
    png = root / "plots" / "cmp.png"
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                "--label-a", "Alpha", "--label-b", "Beta", "--breakdown", "--plot", str(png))
    assert p.returncode == 0, p.stderr
    assert "n=4 seeds; failures charged: Alpha 0, Beta 0; duration=1.00s" in p.stdout
    assert "Alpha" in p.stdout and "Beta" in p.stdout
    assert "shape circle" in p.stdout and "shape fig8" in p.stdout and "per seed" in p.stdout
    assert "warning: 1 seed only in learned, not compared: 9" in p.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(png.parent.glob("*.tmp.png"))


def test_cli_markdown_tables_are_github_markdown(root):
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                "--label-a", "Alpha", "--label-b", "Beta", "--breakdown", "--markdown")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    heads = [i for i, ln in enumerate(lines) if ln.startswith("| Metric")]
    assert len(heads) == 3  # all seeds, then one per shape (circle, fig8)
    for i in heads:
        assert set(lines[i + 1]) <= set("|-: ")  # the markdown separator row
        assert lines[i + 2].startswith("| mean error (cm)")
        assert lines[i - 1].strip()  # a title line above each table
        assert not lines[i - 1].startswith("|")  # a one-row header: no wrapped cells
    rows = [ln for ln in lines if ln.startswith("|")]
    assert any(ln.startswith("| out-of-reach error (cm) (") for ln in rows)  # label not wrapped
    assert all(ln.endswith("|") and ln == ln.rstrip() for ln in rows)
    assert not any(ln.strip() == "" and ln != "" for ln in lines)  # no lines of bare spaces


def test_cli_unknown_prefix_lists_existing(root):
    p = run_cli("--root", str(root), "--prefix-a", "nope", "--prefix-b", "learned")
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    assert "error:" in p.stderr and "base, learned, short" in p.stderr


def test_cli_mismatched_duration_exits_2(root):
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "short")
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    assert "base" in p.stderr and "short" in p.stderr and "duration" in p.stderr


# ---- medians, share improved, the "shown" rule ----------------------------------------------


def offsets_sets(offsets_a, offsets_b, T=100):
    """Two sets of constant-offset rollouts, seed i with offsets_a[i] and offsets_b[i] (m)."""
    a = {s: offset_rollout(o, T=T, seed=s) for s, o in enumerate(offsets_a)}
    b = {s: offset_rollout(o, T=T, seed=s) for s, o in enumerate(offsets_b)}
    return a, b


def test_tight_band_counts_steps_below_2_cm():
    err = np.r_[np.full(50, 0.01), np.full(50, 0.03)]  # 1 cm then 3 cm
    ee = np.stack([err, np.zeros(100), np.zeros(100)], axis=1)
    m = metrics.rollout_metrics(make_rollout(ee), band_cm=5.0, tight_band_cm=2.0)
    assert m["in_band"] == pytest.approx(100.0)
    assert m["in_band_tight"] == pytest.approx(50.0)


def test_medians_and_share_improved_follow_each_metrics_direction():
    # A: 6 cm everywhere; B: 4 cm on four seeds, 15 cm on one. Differences in cm: -2 x4, +9.
    a, b = offsets_sets([0.06] * 5, [0.04] * 4 + [0.15])
    cmp = metrics.compare(a, b, n_boot=500)
    row = cmp.row("mean_err")
    assert row.better == "lower"
    assert row.median_a == pytest.approx(6.0) and row.median_b == pytest.approx(4.0)
    assert row.delta == pytest.approx((4 * -2 + 9) / 5)  # the outlier pulls the mean up
    assert row.median_delta == pytest.approx(-2.0)
    assert row.improved == 4 and row.share_improved == pytest.approx(0.8)
    # Time within 5 cm: higher is better. A is never within (6 cm); B is on the four 4 cm seeds.
    band = cmp.row("in_band")
    assert band.better == "higher"
    assert band.improved == 4
    assert band.median_delta == pytest.approx(100.0)
    # A tie is not an improvement: no self-collision anywhere.
    assert cmp.row("self_collision").improved == 0


def test_shown_means_the_ci_excludes_zero():
    assert metrics.shown((-2.0, -1.0)) and metrics.shown((0.5, 3.0))
    assert not metrics.shown((-1.0, 1.0))
    assert not metrics.shown((0.0, 1.0))  # touching zero does not exclude it
    assert not metrics.shown((math.nan, math.nan))


def test_median_ci_is_robust_where_the_mean_ci_is_not():
    # 25 seeds 1 cm better, 5 seeds 10 cm worse: the mean (+0.83) is not distinguishable from
    # 0 (sd 4.1, so a CI half-width near 1.5), but a resampled median is -1 unless half the
    # draws are outliers, which has probability ~1e-4 per resample.
    d = np.r_[np.full(25, -1.0), np.full(5, 10.0)]
    assert metrics.median_ci(d, n_boot=2000) == (-1.0, -1.0)
    lo, hi = metrics.paired_ci(d, n_boot=2000)
    assert lo < 0 < hi

    a, b = offsets_sets([0.05] * 30, [0.04] * 25 + [0.15] * 5)
    line = metrics.claim(metrics.compare(a, b, n_boot=2000).row("mean_err"), "Beta")
    assert "mean diff +0.83 [" in line and "] not shown;" in line
    assert "median diff -1.00 [-1.00, -1.00] shown;" in line
    assert "Beta better on 25/30 seeds (83%)" in line


def test_no_claim_from_a_handful_of_pairs():
    a, b = offsets_sets([0.03] * 4, [0.01] * 4)
    row = metrics.compare(a, b, n_boot=300).row("mean_err")
    assert metrics.shown(row.ci)  # the CI itself has zero width at -2 ...
    assert "not shown (only 4 pairs" in metrics.claim(row)  # ... but 4 pairs back no claim


# ---- silently wrong numbers: regressions ----------------------------------------------------


def _frozen_error_cm(r, from_row: int, tip) -> np.ndarray:
    """The charge, computed independently: the real trajectory's target after ``from_row``,
    against a tip frozen at ``tip``."""
    from panda_lead import trajectory

    times = DT * np.arange(from_row + 1, int(round(r.duration / DT)) + 1)
    target = trajectory.sample(r.seed, r.shape).at(times)[0]
    return 100 * np.linalg.norm(target - tip, axis=1)


def test_a_non_finite_episode_is_charged_not_left_out():
    """Regression (issue 22): a seed with NaN or inf in either set was dropped from both, so
    a controller's own failures left its score. Now it stays in and pays: from the first
    non-finite step on, the arm counts as frozen where it was while the target moves on."""
    a, b = offsets_sets([0.03] * 5, [0.01] * 5)
    b[2].ee_pos[10, 1] = np.nan
    a[4].qvel[3, 0] = np.inf
    cmp = metrics.compare(a, b, n_boot=300)
    assert cmp.seeds == [0, 1, 2, 3, 4]
    assert cmp.row("mean_err").n_pairs == 5
    charged = cmp.pairing.charged
    assert set(charged["A"]) == {4} and set(charged["B"]) == {2}
    assert "non-finite ee_pos from 0.10 s" in charged["B"][2]
    assert "qvel" in charged["A"][4]
    want = np.concatenate([100 * b[2].error[:10], _frozen_error_cm(b[2], 10, b[2].ee_pos[9])])
    assert cmp.metrics_b[2]["mean_err"] == pytest.approx(want.mean())
    assert cmp.metrics_b[2]["mean_err"] > 1.0  # worse than the 1 cm it held before failing
    lines = cmp.pairing.warnings()
    assert len(lines) == 2 and all("charged" in line for line in lines)


def test_failed_and_short_episodes_are_charged():
    a, b = offsets_sets([0.03] * 5, [0.01] * 5)
    b[1].meta["failure"] = "unstable"
    a[3] = offset_rollout(0.03, T=15, seed=3, duration=1.0)  # stopped after 15 of 100 steps
    cmp = metrics.compare(a, b, n_boot=300)
    assert cmp.seeds == [0, 1, 2, 3, 4]
    assert "unstable" in cmp.pairing.charged["B"][1]
    assert "ended after 15 of 100 steps" in cmp.pairing.charged["A"][3]
    want = np.concatenate([100 * a[3].error, _frozen_error_cm(a[3], 15, a[3].ee_pos[14])])
    assert cmp.metrics_a[3]["mean_err"] == pytest.approx(want.mean())
    assert "failures charged: A 1, B 1" in cmp.pairing.counts()


def test_a_set_holding_two_controllers_is_refused():
    a = {s: offset_rollout(0.03, seed=s) for s in range(4)}
    for s in range(3):
        a[s].meta["controller"] = "classical"
    a[3].meta["controller"] = "analytic"
    b = {s: offset_rollout(0.01, seed=s) for s in range(4)}
    with pytest.raises(UserError, match=r"mixes 2 controllers.*classical.*0-2.*analytic.*3"):
        metrics.compare(a, b, n_boot=200)


@pytest.mark.parametrize("kw", [dict(band_cm=math.nan), dict(band_cm=0.0), dict(band_cm=-5.0),
                                dict(band_cm=math.inf), dict(tight_band_cm=math.nan),
                                dict(settle_time=math.nan), dict(settle_time=-1.0)])
def test_non_finite_or_non_positive_options_are_refused(kw):
    a, b = offsets_sets([0.03] * 3, [0.01] * 3)
    with pytest.raises(UserError, match="must be finite"):
        metrics.compare(a, b, n_boot=200, **kw)


# ---- figures --------------------------------------------------------------------------------


def test_seed_set_titles_and_colours():
    assert metrics.seed_ranges([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"
    assert metrics.seed_set_title(list(range(1000))) == "test seeds 0-999, n=1000 pairs"
    c = figures.colours_for(["RL+Lead", "Classical", "Mine", "Yours"])
    assert c["Classical"] == figures.colours_for(["Classical"])["Classical"]
    assert len(set(c.values())) == 4  # every label its own colour
    # a figure of many controllers (the deploy figure has 10+) gets a colour for each: the
    # first 15 distinct, then repeats, never StopIteration
    from matplotlib.colors import to_hex

    many = figures.colours_for([f"model {i}" for i in range(30)])
    assert len(many) == 30
    assert len({to_hex(many[f"model {i}"]) for i in range(15)}) == 15
    # the deploy figure's five models beside the baselines and both rivals: every model a hue
    # of its own, none a pale shade of the classical controller's blue
    from colorsys import rgb_to_hsv

    from matplotlib.colors import to_rgb

    models = [f"model {i}" for i in range(5)]
    deploy = figures.colours_for(["Classical", "Analytic", *models, "Analytic+predict",
                                  "Analytic+filter"])
    assert len(set(deploy.values())) == 9
    hue = {lab: rgb_to_hsv(*to_rgb(c))[0] for lab, c in deploy.items()}
    assert all(abs(hue[m] - hue["Classical"]) > 0.05 for m in models)
    assert deploy["Classical"] == figures.COLOURS["Classical"]  # the baselines' never lent


def test_family_colours_give_a_study_one_hue_and_its_seeds_shades():
    from colorsys import rgb_to_hsv

    from matplotlib.colors import to_rgb

    labels = ["Classical", "Analytic", *(f"stack4_s{i}" for i in range(1, 6)),
              *(f"stack8_s{i}" for i in range(1, 6)), "Analytic+predict"]
    c = figures.family_colours(labels)
    assert len({tuple(round(v, 4) for v in c[lab]) for lab in labels}) == len(labels)
    assert c["Classical"] == to_rgb(figures.COLOURS["Classical"])
    hue = {lab: rgb_to_hsv(*c[lab])[0] for lab in labels}
    for study in ("stack4", "stack8"):
        seeds = [hue[f"{study}_s{i}"] for i in range(1, 6)]
        assert max(seeds) - min(seeds) < 0.01  # one hue ...
        light = [sum(c[f"{study}_s{i}"]) for i in range(1, 6)]
        assert light == sorted(light)  # ... from dark to light in the order given
    # two studies and the baselines: hues apart, not shades of each other
    assert abs(hue["stack4_s1"] - hue["stack8_s1"]) > 0.05
    for base in ("Classical", "Analytic", "Analytic+predict"):
        assert all(abs(hue[base] - hue[f"{s}_s1"]) > 0.05 for s in ("stack4", "stack8"))
    # a rival keeps its colour whatever comes before it in the figure
    alone = figures.family_colours(["Analytic+predict", "Analytic+filter"])
    assert c["Analytic+predict"] == alone["Analytic+predict"]
    assert alone["Analytic+filter"] != alone["Analytic+predict"]


def test_paired_difference_plot_is_a_distribution_at_n_1000():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    offsets = rng.uniform(0.0, 0.05, size=1000)
    a, b = offsets_sets(0.05 + 0 * offsets, offsets, T=20)
    cmp = metrics.compare(a, b, n_boot=100)
    fig, ax = plt.subplots()
    figures.plot_paired_differences(ax, cmp, "C2")
    assert len(ax.patches) <= 60  # histogram bins, not 1000 bars
    assert any(list(ln.get_xdata()) == [0, 0] for ln in ax.get_lines())  # zero marked
    legend = " ".join(t.get_text() for t in ax.get_legend().get_texts())
    assert "median" in legend and "mean" in legend and "/1000 seeds" in legend
    assert "n=1000 pairs" in ax.get_title()
    plt.close(fig)


def test_error_over_time_axis_is_not_set_by_the_start_up_transient():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def transient(seed, settled_m):
        err = np.where(DT * np.arange(1, 101) < 0.2, 0.5, settled_m)  # 50 cm, then settled
        return make_rollout(np.stack([err, 0 * err, 0 * err], axis=1), seed=seed)

    sets = {"Classical": {s: transient(s, 0.03) for s in range(30)},
            "Analytic": {s: transient(s, 0.02) for s in range(30)}}
    fig, ax = plt.subplots()
    figures.plot_error_over_time(ax, sets, list(range(30)), figures.colours_for(sets), 0.5,
                                 (5.0, 2.0))
    lo, hi = ax.get_ylim()
    assert lo == 0 and 3.0 < hi < 10.0  # the 3 cm settled error is visible, 50 cm is clipped
    assert "clipped" in ax.get_title() and "n=30" in ax.get_title()
    assert any(list(ln.get_xdata()) == [0.5, 0.5] for ln in ax.get_lines())  # t = 0.5 s marked
    plt.close(fig)


# ---- headline: error against peak speed -----------------------------------------------------


def speed_rollout(seed, speed, gain, shape):
    """Target moving at a constant `speed` along x; the tip `gain * speed` metres behind."""
    T = 100
    vel = np.tile([speed, 0.0, 0.0], (T, 1))
    target = np.cumsum(vel * DT, axis=0)
    r = make_rollout(target - [gain * speed, 0, 0], target, seed=seed, shape=shape,
                     target_vel=vel)
    return r


def headline_sets():
    shapes = ("circle", "fig8", "fly")
    return {label: {s: speed_rollout(s, 0.5 + 0.1 * s, gain, shapes[s % 3]) for s in range(15)}
            for label, gain in (("Classical", 0.01), ("Analytic", 0.02), ("RL+Lead", 0.03))}


def test_peak_speed_is_the_largest_target_speed():
    r = make_rollout(np.zeros((3, 3)), target_vel=[[1, 0, 0], [3, 4, 0], [0, 2, 0]])
    assert metrics.peak_speed(r) == pytest.approx(5.0)


def test_headline_bins_error_by_peak_speed():
    sets = headline_sets()
    data = figures.headline_data(sets, list(range(15)), n_bins=3, n_boot=500)
    assert list(data) == ["all", "circle", "fig8", "fly"]
    # all: speeds 0.5 .. 1.9 in three equal-count bins of five: seeds 0-4, 5-9, 10-14.
    for label, gain in (("Classical", 0.01), ("Analytic", 0.02), ("RL+Lead", 0.03)):
        bins = data["all"][label]
        assert [b["n"] for b in bins] == [5, 5, 5]
        assert [b["x"] for b in bins] == pytest.approx([0.7, 1.2, 1.7])
        for b in bins:  # error (cm) = 100 * gain * speed; mean = median for evenly spaced speeds
            assert b["mean"] == pytest.approx(100 * gain * b["x"])
            assert b["median"] == pytest.approx(100 * gain * b["x"])
            assert b["mean_ci"][0] <= b["mean"] <= b["mean_ci"][1]
        # circle: seeds 0, 3, 6, 9, 12 -> one bin (five rollouts), median speed 1.1 m/s
        (circle,) = data["circle"][label]
        assert circle["n"] == 5 and circle["x"] == pytest.approx(1.1)
        assert circle["mean"] == pytest.approx(100 * gain * 1.1)


def test_cli_headline_three_sets(tmp_path):
    for label, prefix in (("Classical", "ikpd"), ("Analytic", "analytic"), ("RL+Lead", "eval")):
        for r in headline_sets()[label].values():
            rollout.save(on_its_trajectory(r), rollout.rollout_path(prefix, r.seed, tmp_path))
    png = tmp_path / "head.png"
    p = run_cli("--root", str(tmp_path), "--headline", "ikpd", "analytic", "eval",
                "--plot", str(png))
    assert p.returncode == 0, p.stderr
    assert "n=15 seeds; failures charged: Classical 0, Analytic 0, RL+Lead 0" in p.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    p = run_cli("--root", str(tmp_path), "--headline", "ikpd", "--plot", str(png))
    assert p.returncode == 2 and "2 or more" in p.stderr
    p = run_cli("--root", str(tmp_path), "--headline", "ikpd", "eval")
    assert p.returncode == 2 and "--plot" in p.stderr


# ---- CLI: errors and warnings ---------------------------------------------------------------


def test_cli_help_has_a_description():
    p = subprocess.run([sys.executable, "metrics.py", "--help"], cwd=REPO, capture_output=True,
                       text=True, timeout=60, env={**os.environ, "COLUMNS": "120"})
    assert p.returncode == 0
    assert "Compare rollout sets" in p.stdout and "--headline" in p.stdout


def test_cli_prints_claims_with_not_shown(tmp_path):
    for s in range(30):
        rollout.save(on_its_trajectory(offset_rollout(0.05, seed=s)),
                     rollout.rollout_path("base", s, tmp_path))
        rollout.save(on_its_trajectory(offset_rollout(0.04 if s < 25 else 0.15, seed=s)),
                     rollout.rollout_path("new", s, tmp_path))
    p = run_cli("--root", str(tmp_path), "--prefix-a", "base", "--prefix-b", "new")
    assert p.returncode == 0, p.stderr
    line = next(ln for ln in p.stdout.splitlines() if ln.strip().startswith("mean error (cm),"))
    assert "not shown" in line.split(";")[0] and "median diff -1.00" in line


@pytest.mark.parametrize("opt", [("--band-cm", "nan"), ("--band-cm", "-1"), ("--band-cm", "inf"),
                                 ("--tight-band-cm", "0"), ("--settle-time", "nan")])
def test_cli_bad_number_is_one_error_line(root, opt):
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned", *opt)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [p.stderr.strip()]  # one line
    assert p.stderr.startswith(f"error: {opt[0]} must be finite")


def test_cli_non_finite_and_failed_seeds_are_charged_and_named(root):
    r = rollout.load(rollout.rollout_path("learned", 2, root))
    r.ee_pos[5, 0] = np.nan
    rollout.save(r, rollout.rollout_path("learned", 2, root))
    r = rollout.load(rollout.rollout_path("base", 1, root))
    r.meta["failure"] = "unstable"
    rollout.save(r, rollout.rollout_path("base", 1, root))
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned")
    assert p.returncode == 0, p.stderr
    assert "n=4 seeds; failures charged: base 1, learned 1" in p.stdout  # no seed left out
    charged = [ln for ln in p.stdout.splitlines() if "charged as if the arm froze" in ln]
    # Both sets record the same controller ("test"), so their prefixes name them.
    assert len(charged) == 2
    assert "warning: base: 1 failed" in charged[0] and "1 (unstable at 1.00 s)" in charged[0]
    assert "warning: learned: 1" in charged[1] and "2 (non-finite ee_pos from 0.05 s)" in charged[1]


def test_cli_names_each_set_by_its_controller_by_default(tmp_path):
    for prefix, controller in (("ikpd", "classical"), ("lead", "analytic"), ("mine", "policy")):
        for s in range(3):
            rollout.save(on_its_trajectory(offset_rollout(0.01, seed=s, shape="circle",
                                                          controller=controller)),
                         rollout.rollout_path(prefix, s, tmp_path))
    p = run_cli("--root", str(tmp_path), "--prefix-a", "lead", "--prefix-b", "mine")
    assert p.returncode == 0, p.stderr
    assert "A = Analytic (" in p.stdout and "B = RL+Lead (" in p.stdout
    p = run_cli("--root", str(tmp_path), "--prefix-a", "ikpd", "--prefix-b", "lead",
                "--label-b", "Mine")
    assert "A = Classical (" in p.stdout and "B = Mine (" in p.stdout


def test_cli_mixed_controllers_is_one_error_line(root):
    r = rollout.load(rollout.rollout_path("base", 3, root))
    r.meta["controller"] = "analytic"
    rollout.save(r, rollout.rollout_path("base", 3, root))
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned")
    assert p.returncode == 2
    assert len(p.stderr.strip().splitlines()) == 1
    assert "mixes 2 controllers" in p.stderr and "analytic" in p.stderr and "base" in p.stderr


def test_a_bug_keeps_its_traceback(root, monkeypatch):
    def broken(*a, **k):
        raise ValueError("a bug, not a user error")

    monkeypatch.setattr(compare_module, "rollout_metrics", broken)
    args = metrics_cli.Args(root=root, prefix_a="base", prefix_b="learned", bootstrap=200)
    with pytest.raises(ValueError, match="a bug"):
        metrics_cli.run(args)
    with pytest.raises(SystemExit) as exc:  # a user error becomes exit status 2
        metrics_cli.run(metrics_cli.Args(root=root, prefix_a="nope", prefix_b="learned"))
    assert exc.value.code == 2


def test_diff_text_is_the_claims_format():
    assert metrics.diff_text(1.234, (0.5, 2.0), n_pairs=30, p_holm=0.001) == \
        "+1.23 [+0.50, +2.00] shown"
    assert metrics.diff_text(-0.05, (-0.22, 0.11), n_pairs=30, p_holm=0.4) == \
        "-0.05 [-0.22, +0.11] not shown"
    assert metrics.diff_text(0.12, (0.08, 0.17), verdict=False) == "+0.12 [+0.08, +0.17]"
    with pytest.raises(TypeError):  # no verdict without the rule's inputs
        metrics.diff_text(1.0, (0.5, 2.0))


def test_the_study_tables_judge_by_the_one_rule():
    """The studies' cells (row_diff, deltas_diffs) say 'shown' only as finding_verdict does:
    a CI that excludes 0 over too few pairs, or with a large Holm p, is not a finding."""
    d = np.r_[np.full(25, -1.0), np.full(5, 10.0)]
    mean, median = metrics.deltas_diffs([(d, "mean"), (d, "median")], n_boot=2000)
    assert median.endswith(" shown") and "[-1.00, -1.00]" in median
    assert "not shown" in mean
    few, = metrics.deltas_diffs([(np.full(4, -2.0), "mean")], n_boot=300)
    assert "[-2.00, -2.00] not shown (only 4 pairs" in few
    a, b = offsets_sets([0.05] * 30, [0.04] * 25 + [0.15] * 5)
    row = metrics.compare(a, b, n_boot=2000).row("mean_err")
    assert metrics.row_diff(row, median=True) == "-1.00 [-1.00, -1.00] shown"
    assert metrics.row_diff(row).endswith("not shown")


def test_sets_that_would_share_a_name_are_named_by_their_prefixes():
    def one(controller):
        return {0: offset_rollout(0.01, seed=0, shape="circle", controller=controller)}

    labels = metrics.set_labels([one("classical"), one("policy"), one("policy")],
                                ["ikpd", "v5", "v9"])
    assert labels == ["Classical", "v5", "v9"]
    assert metrics.set_labels([one("test"), one("test")], ["analytic", "mine"]) == ["Analytic", "mine"]


def test_a_policy_that_outputs_no_lead_is_not_called_a_lead():
    def policy(action):
        r = offset_rollout(0.01, seed=0, shape="circle", controller="policy")
        r.meta["env"] = {"action": action}
        return {0: r}

    labels = metrics.set_labels([policy("joint_target"), policy("lead")], ["ikfree", "v5"])
    assert labels == ["RL joint goals (no IK)", "RL+Lead"]


def test_holm_adjusts_a_family_of_p_values():
    from panda_lead.metrics.stats import holm

    # Sorted 0.01, 0.03, 0.04, 0.5 of m=4: 4*0.01, 3*0.03, max(2*0.04, 0.09), max(0.5, 0.09).
    assert holm([0.01, 0.04, 0.03, float("nan"), 0.5]) == pytest.approx(
        [0.04, 0.09, 0.09, float("nan"), 0.5], nan_ok=True)


def test_a_shown_but_tiny_difference_is_called_negligible():
    a, b = offsets_sets([0.030] * 12, [0.0298] * 12)  # 0.02 cm better everywhere
    row = metrics.compare(a, b, n_boot=300).row("mean_err")
    assert metrics.shown(row.ci)
    assert "mean diff -0.02 [-0.02, -0.02] shown, negligible (|diff| < 0.05)" in metrics.claim(row)


def test_share_of_the_achievable_gain_captured():
    from panda_lead.metrics.stats import share_captured

    base = np.full(50, 4.0) + np.linspace(0, 1, 50)
    share, (lo, hi) = share_captured(base, base - 1.5, base - 3.0, n_boot=500)
    assert share == pytest.approx(0.5) and lo == pytest.approx(0.5) and hi == pytest.approx(0.5)
    rng = np.random.default_rng(1)
    share, (lo, hi) = share_captured(base, base - 1.5 + rng.normal(0, 0.3, 50), base - 3.0,
                                     n_boot=2000)
    assert lo < share < hi and lo < 0.5 < hi


def test_differences_by_target_speed_bins_hold_every_seed_once():
    a = {s: offset_rollout(0.03, seed=s) for s in range(20)}
    b = {s: offset_rollout(0.01 if s < 10 else 0.05, seed=s) for s in range(20)}
    for s in range(20):  # faster targets for higher seeds
        for r in (a[s], b[s]):
            r.target_vel[:] = [0.1 * (s + 1), 0.0, 0.0]
    cmp = metrics.compare(a, b, n_boot=300, speed_bins=2)
    assert [n for _, _, rows in cmp.by_speed for n in [rows[0].n_pairs]] == [10, 10]
    (lo1, hi1, slow), (lo2, hi2, fast) = cmp.by_speed
    assert lo1 == pytest.approx(0.1) and hi2 == pytest.approx(2.0)
    assert slow[0].delta == pytest.approx(-2.0) and fast[0].delta == pytest.approx(2.0)


def test_cli_oracle_prints_the_share_of_the_achievable_gain_captured(root):
    """(A - B) / (A - oracle): base 3 cm, learned 1 cm, oracle 0.5 cm -> 80%, on every seed."""
    write_prefix(root, "oracle", 0.005, range(4))
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                "--oracle", "oracle")
    assert p.returncode == 0, p.stderr
    assert "the oracle (oracle, n=4 seeds" in p.stdout
    assert "mean error: base 3.00, learned 1.00, oracle 0.50 cm; captured 80% [80, 80]" in p.stdout
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                "--oracle", "nope")
    assert p.returncode == 2 and "nope" in p.stderr


def test_cli_oracle_breakdown_gives_the_share_captured_per_shape(root):
    """Circles (even seeds): oracle 0.5 cm -> (3 - 1) / (3 - 0.5) = 80%; figure-eights: oracle
    0 cm -> 67%; all four: oracle 0.25 -> 73%."""
    for s in range(4):
        write_prefix(root, "oracle", 0.005 if s % 2 == 0 else 0.0, [s])
    p = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                "--oracle", "oracle", "--breakdown")
    assert p.returncode == 0, p.stderr
    assert "mean error: base 3.00, learned 1.00, oracle 0.25 cm; captured 73%" in p.stdout
    assert ("shape circle (n=2), mean error: base 3.00, learned 1.00, oracle 0.50 cm; "
            "captured 80%") in p.stdout
    assert ("shape fig8 (n=2), settled mean error: base 3.00, learned 1.00, oracle 0.00 cm; "
            "captured 67%") in p.stdout
    plain = run_cli("--root", str(root), "--prefix-a", "base", "--prefix-b", "learned",
                    "--oracle", "oracle")
    assert "captured" in plain.stdout and "shape circle (n=2), mean" not in plain.stdout


def test_a_narrow_terminal_gets_the_table_in_two_halves_nothing_truncated():
    from rich.console import Console

    a = {s: offset_rollout(0.03, seed=s) for s in range(12)}
    b = {s: offset_rollout(0.01, seed=s) for s in range(12)}
    cmp = metrics.compare(a, b, n_boot=100)
    assert [len(t.columns) for t in metrics_cli.metrics_tables(cmp.rows, "A", "B", "t", 240)] == [11]
    halves = metrics_cli.metrics_tables(cmp.rows, "Classical", "RL+Lead", "t", 100)
    assert [len(t.columns) for t in halves] == [6, 6]
    import io

    out = io.StringIO()
    console = Console(width=100, file=out)
    for t in halves:
        console.print(t)
    text = out.getvalue()
    assert "…" not in text and "0.000488" in text and "p (Wilcoxon)" in text  # wrapped, not cut
    assert max(len(line) for line in text.splitlines()) <= 100


def test_t_ci_is_students_interval_of_the_mean():
    from scipy import stats as sps

    from panda_lead.metrics.stats import t_ci

    values = np.array([2.53, 2.57, 2.48, 2.80, 2.70])
    expected = sps.t.interval(0.95, len(values) - 1, loc=values.mean(), scale=sps.sem(values))
    assert np.allclose(t_ci(values), expected)
    assert all(np.isnan(t_ci([2.5])))  # one seed has no interval


def test_the_two_level_bootstrap_carries_the_seeds_spread_and_pairs_seeds_when_told():
    """Five training seeds whose levels differ by 1 cm, each improved by exactly 0.1 cm: drawn
    independently the seeds' spread hides the gain; drawn once for both sides (the same
    models with and without something added) only the gain is left."""
    from panda_lead.metrics.stats import shown, two_level_bootstrap

    rng = np.random.default_rng(0)
    level = np.arange(5.0)[:, None]
    a = level + rng.normal(0.0, 0.05, (5, 400))
    b = a - 0.1
    independent, _ = two_level_bootstrap(a, b, 2000, np.random.default_rng(1))
    paired, _ = two_level_bootstrap(a, b, 2000, np.random.default_rng(1), paired=True)
    assert not shown(independent) and independent[1] - independent[0] > 1.0
    assert paired == pytest.approx((-0.1, -0.1), abs=1e-9)
    with pytest.raises(ValueError, match="as many seeds"):
        two_level_bootstrap(a, b[:4], 10, rng, paired=True)


def test_excursions_count_the_episodes_far_off_after_the_first_second(tmp_path, monkeypatch,
                                                                      capsys):
    """online_correction.py excursions: a set whose tip stays 35 cm off counts every episode,
    one 1 cm off none, and a group sums its sets."""
    sys.path.insert(0, str(REPO / "studies"))
    from online_correction import Args, excursions

    monkeypatch.chdir(tmp_path)
    write_prefix(tmp_path / "rollouts", "near", 0.01, [0, 1], T=200)
    write_prefix(tmp_path / "rollouts", "far", 0.35, [0, 1, 2], T=200)
    excursions(Args(command="excursions", groups=["both=near,far", "near=near"]))
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| both")
            or line.startswith("| near")]
    assert rows == ["| both | 5 | 3 | 0 |", "| near | 2 | 0 | 0 |"]
    excursions(Args(command="excursions", groups=["both=near,far", "near=near"],
                    list_seeds=True))
    out = capsys.readouterr().out
    assert "--list-seeds`" in out  # (the command as it reruns)
    assert "- both: 0 (1/2; 35.0; 0), 1 (1/2; 35.0; 0), 2 (1/2; 35.0; 0)" in out
    assert "- near: none" in out


def test_the_figure_puts_each_group_at_its_sets_mean_and_refuses_bad_output(tmp_path,
                                                                            monkeypatch):
    """online_correction.py figure: a group's point is the mean over its sets of the settled
    error (here each set's constant offset), its CI brackets it, and a group of one exact
    set has a zero-width CI; the PNG is written, an existing one kept without --force."""
    sys.path.insert(0, str(REPO / "studies"))
    from online_correction import Args, figure, figure_points

    from panda_lead.errors import UserError

    monkeypatch.chdir(tmp_path)
    for name, offset in (("near", 0.01), ("mid", 0.03), ("far", 0.05)):
        write_prefix(tmp_path / "rollouts", name, offset, [0, 1, 2, 3], T=120)
    points, shared = figure_points([("A @ calm", ["near"]), ("B @ calm", ["mid", "far"]),
                                    ("A @ rough", ["far"])], 200)
    assert shared == [0, 1, 2, 3]
    by = {(p["controller"], p["world"]): p for p in points}
    assert by["A", "calm"]["err"] == pytest.approx(1.0, abs=1e-6)
    assert by["B", "calm"]["err"] == pytest.approx(4.0, abs=1e-6)
    assert by["B", "calm"]["sets"] == 2
    lo, hi = by["B", "calm"]["ci"]
    assert 3.0 - 1e-6 <= lo <= 4.0 <= hi <= 5.0 + 1e-6 and hi - lo > 0.5
    assert by["A", "calm"]["ci"] == pytest.approx((1.0, 1.0), abs=1e-6)
    out = tmp_path / "fig.png"
    args = Args(command="figure", groups=["A @ calm=near", "B @ calm=mid,far"], out=out,
                bootstrap=500)
    figure(args)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(UserError, match="exists"):
        figure(args)
    with pytest.raises(UserError, match="PATH.png"):
        figure(Args(command="figure", groups=["A=near"], out=tmp_path / "fig.jpg"))


def _write_x_offsets(root, steps: int, offsets: dict) -> None:
    """Rollout sets on seeds 0-2 (circle, fig8, circle) whose tip sits offsets[prefix](t) metres
    along x from a straight-line target, at every step of ``steps``."""
    t = DT * np.arange(1, steps + 1)
    target = np.stack([0.3 * t, 0.5 + 0.0 * t, 0.2 * t], axis=1)
    for seed in (0, 1, 2):
        shape = "circle" if seed % 2 == 0 else "fig8"
        for prefix, off in offsets.items():
            tip = target + np.broadcast_to(off(t), t.shape)[:, None] * [1.0, 0.0, 0.0]
            r = on_its_trajectory(make_rollout(tip, target, seed=seed, shape=shape))
            rollout.save(r, rollout.rollout_path(prefix, seed, root / "rollouts"))


def test_summary_settles_from_the_time_it_is_given(tmp_path, monkeypatch, capsys):
    """online_correction.py summary --settle-time: the settled error is the mean from that
    time on (here a tip 2 cm off that closes to 1 cm at 5 s), said in the header and in the
    command it prints (a table must rerun as printed); a negative time is refused."""
    sys.path.insert(0, str(REPO / "studies"))
    from online_correction import Args, summary

    from panda_lead.errors import UserError

    monkeypatch.chdir(tmp_path)
    _write_x_offsets(tmp_path, 600, {"a": lambda t: 0.02,
                                     "b": lambda t: np.where(t < 5.0, 0.02, 0.01)})
    summary(Args(command="summary", pairs=["a:b", "a:b"], settle_time=5.0, bootstrap=200))
    out = capsys.readouterr().out
    assert "summary --pairs a:b a:b --settle-time 5`" in out and "settled from 5 s" in out
    assert "| a:b | 2.000 | 1.832 | 2.000 | 1.000 | -1.000 |" in out
    summary(Args(command="summary", pairs=["a:b", "a:b"], bootstrap=200))
    assert "| a:b | 2.000 | 1.832 | 2.000 | 1.817 | -0.183 |" in capsys.readouterr().out
    with pytest.raises(UserError, match="--settle-time"):
        summary(Args(command="summary", pairs=["a:b"], settle_time=-1.0))


def test_windows_average_each_groups_error_per_shape_and_window(tmp_path, monkeypatch, capsys):
    """online_correction.py windows: per shape, a group's mean error in each window from 0.5 s
    (here a tip 2 cm off that closes to 1 cm at 1.5 s, beside one 3 cm off), a group of two sets
    their mean, and the shape's lap times; a window that is not positive is refused."""
    sys.path.insert(0, str(REPO / "studies"))
    from online_correction import Args, windows

    from panda_lead import trajectory
    from panda_lead.errors import UserError

    monkeypatch.chdir(tmp_path)
    _write_x_offsets(tmp_path, 200, {"closing": lambda t: np.where(t < 1.5, 0.02, 0.01),
                                     "far": lambda t: 0.03})
    windows(Args(command="windows", groups=["closing=closing", "both=closing,far"]))
    out = capsys.readouterr().out
    laps = [trajectory.sample(k, "circle").params["lap_time"] for k in (0, 2)]
    assert f"**circle** (2 trajectories; lap time median {np.median(laps):.2f} s" in out
    assert "| group | 0.5-1 s | 1-1.5 s | 1.5-2 s |" in out
    assert out.count("| closing | 2.00 | 2.00 | 1.00 |") == 2  # circle and fig8
    assert out.count("| both | 2.50 | 2.50 | 2.00 |") == 2
    with pytest.raises(UserError, match="--window"):
        windows(Args(command="windows", groups=["closing=closing"], window=0.0))


def test_limits_count_the_episodes_a_panda_would_accept(tmp_path, monkeypatch, capsys):
    """online_correction.py limits: per group, its episodes and those the deploy check accepts
    (here a stubbed check that accepts even seeds only), a group summing its sets."""
    from types import SimpleNamespace

    sys.path.insert(0, str(REPO / "studies"))
    import deploy
    from online_correction import Args, limits

    monkeypatch.chdir(tmp_path)
    write_prefix(tmp_path / "rollouts", "a", 0.01, [0, 1, 2, 3], T=120)
    write_prefix(tmp_path / "rollouts", "b", 0.01, [0, 1], T=120)
    monkeypatch.setattr(deploy, "accepted_by_arm", lambda rollouts: {
        s: SimpleNamespace(accepted=s % 2 == 0) for s in rollouts})
    limits(Args(command="limits", groups=["both=a,b", "b=b"]))
    out = capsys.readouterr().out
    assert "limits --groups both=a,b b=b`" in out
    assert "| both | 6 | 3 | 50.0% |" in out and "| b | 2 | 1 | 50.0% |" in out
    # --against: the paired difference per trajectory, here every trajectory's share equal
    write_prefix(tmp_path / "rollouts", "c", 0.01, [0, 1, 2, 3], T=120)
    monkeypatch.setattr(deploy, "accepted_by_arm", lambda rollouts: {
        s: SimpleNamespace(accepted=s % 2 == 0 or len(rollouts) == 4 and s == 1)
        for s in rollouts})
    limits(Args(command="limits", groups=["a=a", "c=c", "b=b"], against="b", bootstrap=200))
    out = capsys.readouterr().out
    assert "limits --groups a=a c=c b=b --against b`" in out
    # a and c accept 0, 1 and 2 of 0-3 (seed 1 only where a set has 4 seeds); b accepts 0:
    # on the shared trajectories 0 and 1, a minus b is +0 and +100 points: +50 on average
    assert "| a | 4 | 3 | 75.0% | +50.0 [" in out
    assert "| b | 2 | 1 | 50.0% | |" in out
    # --by-shape: each group's accepted episodes per shape (even seeds are circles here, and
    # accepted; seed 1, a figure-eight, too where a set has four seeds)
    limits(Args(command="limits", groups=["both=a,b", "c=c"], by_shape=True))
    out = capsys.readouterr().out
    assert "limits --groups both=a,b c=c --by-shape`" in out
    assert "| group | circle | fig8 |" in out
    assert "| both | 3 of 3 | 1 of 3 |" in out and "| c | 2 of 2 | 1 of 2 |" in out
    with pytest.raises(UserError, match="--against 'z'"):
        limits(Args(command="limits", groups=["a=a"], against="z"))


def test_limits_list_the_episodes_a_group_loses_and_where(tmp_path, monkeypatch, capsys):
    """limits --lost-against: the episodes the reference accepts and a group refuses, with the
    worst limit, when it peaks, when the two sets' leads part (here from 0.41 s on) and the
    peak's distance to a spline waypoint (a fly trajectory, peaking 0.03 s before its second)."""
    from types import SimpleNamespace

    sys.path.insert(0, str(REPO / "studies"))
    import deploy
    from online_correction import Args, limits

    monkeypatch.chdir(tmp_path)
    seg = trajectory.sample(5, "fly").params["segment_time"]
    for prefix in ("ref", "mine"):
        for seed, shape in ((0, "circle"), (1, "fig8"), (5, "fly")):
            r = on_its_trajectory(offset_rollout(0.01, T=120, seed=seed, shape=shape))
            if prefix == "mine":
                r.lead = np.asarray(r.lead, dtype=float).copy()
                r.lead[40:] += 0.01
            rollout.save(r, rollout.rollout_path(prefix, seed, tmp_path / "rollouts"))

    def check(rollouts):  # the reference accepts all; "mine" refuses seeds 0 and 5
        return {s: SimpleNamespace(accepted=not r.lead.any() or s == 1,
                                   worst_limit="joint 2 acceleration", worst_margin=1.5,
                                   worst_time=0.45 if s == 0 else 2 * seg - 0.03)
                for s, r in rollouts.items()}

    monkeypatch.setattr(deploy, "accepted_by_arm", check)
    limits(Args(command="limits", groups=["ref=ref", "mine=mine"], lost_against="ref"))
    out = capsys.readouterr().out
    assert "limits --groups ref=ref mine=mine --lost-against ref`" in out
    assert "| mine | 0 | circle | joint 2 acceleration | 1.50 | 0.45 | 0.41 | - |" in out
    peak = f"{2 * seg - 0.03:.2f}"
    assert f"| mine | 5 | fly | joint 2 acceleration | 1.50 | {peak} | 0.41 | 0.03 |" in out
    assert ("mine: 2 episodes lost (joint 2 acceleration 2); the worst peak within 0.1 s of the "
            "leads parting in 1 of 2, within 0.05 s of a spline waypoint in 1 of 1.") in out
    with pytest.raises(UserError, match="--lost-against 'z'"):
        limits(Args(command="limits", groups=["a=ref"], lost_against="z"))
