"""trajectory.py: analytic derivatives, determinism, speed/acc bounds, reach fraction, CLI."""

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from panda_lead import trajectory as T

REPO = Path(__file__).parents[1]
H = 1e-5  # finite-difference step (s)


def central(tr, ts):
    """Central differences of position and velocity at times ts >= H."""
    (pp, vp, _), (pm, vm, _) = tr.at(ts + H), tr.at(ts - H)
    return (pp - pm) / (2 * H), (vp - vm) / (2 * H)


def one_sided(tr, t0, sign):
    """Second-order one-sided differences (forward for sign=+1, backward for -1) at t0."""
    (p0, v0, _), (p1, v1, _), (p2, v2, _) = (tr.at(t0 + sign * k * H) for k in range(3))
    return sign * (-3 * p0 + 4 * p1 - p2) / (2 * H), sign * (-3 * v0 + 4 * v1 - v2) / (2 * H)


@pytest.mark.parametrize("shape", T.SHAPES)
def test_analytic_derivatives_match_finite_differences(shape):
    for seed in range(30):
        tr = T.sample(seed, shape)
        ts = np.random.default_rng(seed).uniform(H, 10.0, 200)
        if shape == "fly":  # keep clear of the knots, where acc jumps (the spline is only C1)
            seg = tr.params["segment_time"]
            ts = ts[np.abs(ts / seg - np.round(ts / seg)) * seg > 1e-3]
        _, vel, acc = tr.at(ts)
        fd_vel, fd_acc = central(tr, ts)
        np.testing.assert_allclose(fd_vel, vel, rtol=0, atol=1e-6, err_msg=f"seed {seed}")
        np.testing.assert_allclose(fd_acc, acc, rtol=0, atol=1e-4, err_msg=f"seed {seed}")
        _, v0, a0 = tr.at(0.0)
        fd_v0, fd_a0 = one_sided(tr, 0.0, +1)
        np.testing.assert_allclose(fd_v0, v0, rtol=0, atol=1e-6, err_msg=f"seed {seed} t=0")
        np.testing.assert_allclose(fd_a0, a0, rtol=0, atol=1e-3, err_msg=f"seed {seed} t=0")


def test_fly_spline_passes_its_waypoints_and_is_c1_at_the_knots():
    for seed in range(30):
        tr = T.sample(seed, "fly")
        pts, seg = np.array(tr.params["waypoints"]), tr.params["segment_time"]
        k = np.arange(1, 3 * len(pts))  # three laps of knots, so the loop's wrap is covered
        knots = k * seg
        np.testing.assert_allclose(tr.at(knots)[0], pts[k % len(pts)], atol=1e-9)
        (pl, vl, al), (pr, vr, ar) = tr.at(knots - 1e-9), tr.at(knots + 1e-9)
        np.testing.assert_allclose(pl, pr, atol=1e-8)
        np.testing.assert_allclose(vl, vr, atol=1e-6)  # C1: velocity is continuous ...
        assert np.abs(al - ar).max() > 1e-3  # ... acceleration is not, as Catmull-Rom's isn't
        for t in knots[:4]:  # the velocity at a knot is both one-sided derivatives
            v = tr.at(t)[1]
            for sign in (+1, -1):
                np.testing.assert_allclose(one_sided(tr, t, sign)[0], v, atol=1e-5)


def test_same_seed_same_trajectory_and_forcing_the_drawn_shape_changes_nothing():
    ts = np.linspace(0, 7, 300)
    for seed in range(20):
        a, b = T.sample(seed), T.sample(seed)
        assert a.shape == b.shape and a.params == b.params
        for x, y in zip(a.at(ts), b.at(ts), strict=True):
            assert np.array_equal(x, y)
        forced = T.sample(seed, a.shape)
        assert forced.params == a.params
        assert np.array_equal(forced.at(ts)[0], a.at(ts)[0])
        for other in T.SHAPES:  # the shape draw comes first, so the later draws never shift
            f = T.sample(seed, other)
            assert f.shape == other and f.params["speed_level"] == a.params["speed_level"]
        json.dumps(a.params)  # JSON-friendly
        lap = a.params["lap_time"]  # every shape is a closed loop of this period
        for x, y in zip(a.at(ts), a.at(ts + lap), strict=True):
            np.testing.assert_allclose(x, y, atol=1e-8 * max(1.0, np.abs(x).max()))


def test_drawn_shapes_are_a_mix():
    counts = Counter(T.sample(s).shape for s in range(100))
    assert set(counts) == set(T.SHAPES) and min(counts.values()) >= 20, counts


def test_same_trajectory_in_a_fresh_process():
    """Seeds are the contract: a fresh interpreter (another hash seed, no shared state) must
    draw the very same trajectories, bit for bit."""
    code = ("import json, numpy as np, trajectory as T; ts = np.linspace(0, 5, 51); "
            "print(json.dumps([[T.sample(s).shape, np.concatenate(T.sample(s).at(ts)).tolist()]"
            " for s in range(6)]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO, env={**os.environ, "PYTHONHASHSEED": "123"})
    ts = np.linspace(0, 5, 51)
    here = [[T.sample(s).shape, np.concatenate(T.sample(s).at(ts)).tolist()] for s in range(6)]
    assert json.loads(out.stdout) == here


def test_speed_and_acceleration_bounds_hold_and_are_attained():
    ts = np.arange(0, 10.0, 1e-3)
    speeds = []
    for seed in range(200):
        tr = T.sample(seed)
        _, vel, acc = tr.at(ts)
        assert np.linalg.norm(vel, axis=1).max() <= T.MAX_SPEED + 1e-9, seed
        assert np.linalg.norm(acc, axis=1).max() <= T.MAX_ACC + 1e-9, seed
        # The stated peaks are the real ones over a loop, not loose bounds. A fly spline's acc
        # peaks at a segment's start or end: just after or just before a knot.
        grid = np.linspace(0, tr.params["lap_time"], 20001)
        if tr.shape == "fly":
            knots = np.arange(1, len(tr.params["waypoints"]) + 1) * tr.params["segment_time"]
            grid = np.concatenate([grid, knots - 1e-9, knots + 1e-9])
        _, vel, acc = tr.at(grid)
        assert np.linalg.norm(vel, axis=1).max() == pytest.approx(tr.peak_speed, rel=1e-4)
        assert np.linalg.norm(acc, axis=1).max() == pytest.approx(tr.peak_acc, rel=1e-4)
        speeds.append(tr.peak_speed)
    speeds = np.array(speeds)
    assert 0.05 < np.mean(speeds < 0.6) < 0.3  # some slow ones ...
    assert np.mean(speeds >= 0.8) > 0.7  # ... but mostly fast enough to make a PD lag


def test_vectorised_equals_scalar_calls():
    ts = np.array([0.0, 0.013, 0.5, 1.0, 2.71, 9.99])
    for seed in range(9):
        tr = T.sample(seed, T.SHAPES[seed % 3])
        vec = tr.at(ts)
        for x in vec:
            assert x.shape == (len(ts), 3) and x.dtype == np.float64
        for i, t in enumerate(ts):
            for x, y in zip(tr.at(float(t)), vec, strict=True):
                assert x.shape == (3,) and x.dtype == np.float64
                np.testing.assert_allclose(x, y[i], rtol=1e-13, atol=1e-13)
        assert tr.at(1)[0].shape == (3,) and tr.at([0.5])[0].shape == (1, 3)


def test_about_one_in_ten_leaves_the_reach_sphere():
    frac = np.mean([T.leaves_reach(T.sample(s)) for s in range(300)])
    assert 0.03 <= frac <= 0.25, frac
    near_base = np.mean([(np.linalg.norm(T.sample(s).at(np.arange(501) / 100)[0][:, :2], axis=1)
                          < 0.15).any() for s in range(300)])
    assert near_base > 0.03, near_base  # some pass close to the arm's own column


def test_bad_input_raises():
    with pytest.raises(ValueError, match="did you mean 'circle'"):
        T.sample(0, "cirle")
    with pytest.raises(ValueError, match=r"valid: circle, fig8, fly"):
        T.sample(0, "square")
    for seed in (-1, 1.5, "3", True):
        with pytest.raises(ValueError, match="seed"):
            T.sample(seed)
    tr = T.sample(0)
    for t in (-0.01, [0.0, -1.0], float("nan"), np.zeros((2, 2))):
        with pytest.raises(ValueError):
            tr.at(t)
    assert T.sample(np.int64(5)).params == T.sample(5).params


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "trajectory.py", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=60)


def test_cli_writes_a_png(tmp_path):
    out = tmp_path / "sub" / "traj.png"
    r = run_cli("--seed", "3", "--out", str(out))
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    assert data.startswith(b"\x89PNG") and len(data) > 10_000
    assert list(out.parent.iterdir()) == [out]  # no temp file left behind


def test_cli_text_and_errors():
    r = run_cli("--seed", "3", "--shape", "fly")
    assert r.returncode == 0 and "fly" in r.stdout and "peak_speed" in r.stdout
    for args in (("--shape", "cirle"), ("--seed", "-1")):
        r = run_cli(*args)
        assert r.returncode == 2 and r.stderr.startswith("error:"), r.stderr
        assert "Traceback" not in r.stderr
    assert "did you mean 'circle'" in run_cli("--shape", "cirle").stderr
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = run_cli("--show", env=env)
    assert r.returncode == 2 and "no display: use --out FILE.png" in r.stderr


def test_plot_png_has_ordinary_permissions(tmp_path):
    import os
    import stat

    from conftest import run_script

    out = tmp_path / "t.png"
    res = run_script("trajectory.py", "--seed", "3", "--out", out, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask  # not mkstemp's private 0600
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("script", ["train.py", "eval.py", "ikpd.py", "metrics.py", "trajectory.py",
                                    "studies/bench.py", "studies/ttq.py", "studies/soak.py",
                                    "studies/sweep.py", "studies/tau.py", "studies/robustness.py",
                                    "studies/spread.py", "studies/collision.py"])
def test_every_script_describes_itself_in_help(script):
    from conftest import run_script

    res = run_script(script, "--help")
    assert res.returncode == 0, res.stderr
    usage_end = res.stdout.index("\n\n")
    description = res.stdout[usage_end:].strip().split("\n")[0]
    assert len(description) > 20 and not description.startswith("╭"), res.stdout[:300]
