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

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import metrics  # noqa: E402
import rollout  # noqa: E402
from rollout import Rollout  # noqa: E402

DT = 0.01


def make_rollout(ee, target=None, seed=0, shape="circle", reachable=None, dt=DT, duration=None):
    """A Rollout with the given tip and target paths (T, 3); everything else zero/False."""
    ee = np.asarray(ee, dtype=float)
    T = len(ee)
    target = np.zeros((T, 3)) if target is None else np.asarray(target, dtype=float)
    zeros3, zeros7 = np.zeros((T, 3)), np.zeros((T, 7))
    return Rollout(
        t=dt * np.arange(1, T + 1), ee_pos=ee, target_pos=target, target_vel=zeros3,
        target_acc=zeros3, lead=zeros3, qpos=zeros7, qvel=zeros7,
        self_collision=np.zeros(T, bool), collision_depth=np.zeros(T),
        reachable=np.ones(T, bool) if reachable is None else np.asarray(reachable, bool),
        meta=dict(seed=seed, shape=shape, controller="test", model="none",
                  duration=T * dt if duration is None else duration, dt=dt),
    )


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
    with pytest.raises(ValueError, match="duration"):
        metrics.compare(a, {0: offset_rollout(0.01, T=50)})
    with pytest.raises(ValueError, match="shape"):
        metrics.compare(a, {0: offset_rollout(0.01, shape="fly")})


# ---- CLI end to end -------------------------------------------------------------------------


def write_prefix(root, prefix, offset_m, seeds, T=100):
    for s in seeds:
        shape = "circle" if s % 2 == 0 else "fig8"
        rollout.save(offset_rollout(offset_m, T=T, seed=s, shape=shape),
                     rollout.rollout_path(prefix, s, root))


def run_cli(*args):
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    return subprocess.run([sys.executable, "metrics.py", *args, "--bootstrap", "200"],
                          cwd=REPO, capture_output=True, text=True, timeout=60, env=env)


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
    assert "n=4 pairs duration=1.00s" in p.stdout
    assert "Alpha" in p.stdout and "Beta" in p.stdout
    assert "shape circle" in p.stdout and "shape fig8" in p.stdout and "per seed" in p.stdout
    assert "warning: seeds only in learned, not compared: [9]" in p.stdout
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
    rows = [ln for ln in lines if ln.startswith("|")]
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
