"""The scripts end to end, as a user runs them, in subprocesses with tiny budgets."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd=ROOT, timeout=600):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**__import__("os").environ,
                                                           "MUJOCO_GL": "egl"})


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny training run (DummyVecEnv keeps it light), resumed once, then archived."""
    tmp = tmp_path_factory.mktemp("train")
    common = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
              "--eval-freq", "256", "--eval-steps", "50", "--checkpoint-freq", "128",
              "--runs-dir", tmp / "runs", "--no-progress"]
    first = run(ROOT / "train.py", "--timesteps", "256", "--vec-env", "subproc", *common,
                cwd=tmp)
    assert first.returncode == 0, first.stderr
    runs = list((tmp / "runs").iterdir())
    assert len(runs) == 1
    run_dir = runs[0]
    resumed = run(ROOT / "train.py", "--resume", run_dir, "--timesteps", "512",
                  "--archive", "tiny", *common, cwd=tmp)
    assert resumed.returncode == 0, resumed.stderr
    return tmp, run_dir, first, resumed


def test_train_leaves_a_complete_run_folder(trained):
    tmp, run_dir, first, _ = trained
    for name in ("config.json", "command.txt", "final_model.zip", "final_model.json",
                 "best_model.zip", "best_model.json"):
        assert (run_dir / name).is_file(), name
    assert list((run_dir / "checkpoints").glob("model_*_steps.zip"))
    assert list((run_dir / "tb").glob("events.out.tfevents.*"))
    config = json.loads((run_dir / "config.json").read_text())
    assert config["n_steps"] == 64 and config["n_envs"] == 2 and config["env"]["max_lead"] == 0.15


def test_resume_continues_the_step_counter_and_archives(trained):
    tmp, run_dir, _, resumed = trained
    side = json.loads((run_dir / "final_model.json").read_text())
    assert side["timesteps"] >= 512
    assert "resuming" in resumed.stdout
    archived = tmp / "archive" / "tiny.zip"
    assert archived.is_file()
    meta = json.loads((tmp / "archive" / "tiny.json").read_text())
    for key in ("env_config", "train_config", "timesteps", "wall_time_s", "commit", "cpu",
                "test_metrics", "rates", "model_sha256", "policy"):
        assert key in meta, key
    from panda_lead.models import cpu_name

    assert meta["cpu"] == cpu_name() not in ("", "?")  # the machine family its digits hold on
    assert meta["rates"] == {"physics_hz": 500, "control_hz": 100}
    assert 0 < meta["test_metrics"]["mean_error_cm"] < 100


def test_archived_model_loads_and_runs_on_seeds(trained):
    tmp, *_ = trained
    out = run(ROOT / "eval.py", "--seeds", "0-1", "--prefix", "tiny", "--model",
              tmp / "archive" / "tiny.zip", "--duration", "0.5", cwd=tmp)
    assert out.returncode == 0, out.stderr
    files = sorted((tmp / "rollouts" / "tiny").glob("seed_*.npz"))
    assert [f.name for f in files] == ["seed_0000.npz", "seed_0001.npz"]
    from panda_lead.rollout import load

    r = load(files[0])
    assert r.meta["controller"] == "policy" and r.meta["model"].endswith("tiny.zip")
    assert len(r.t) == 50


def test_ikpd_writes_rollouts_and_prints_errors(tmp_path):
    out = run(ROOT / "ikpd.py", "--seeds", "3-4", "--prefix", "ikpd", "--duration", "1",
              cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "seed    3" in out.stdout and "cm" in out.stdout
    from panda_lead.rollout import load

    r = load(tmp_path / "rollouts" / "ikpd" / "seed_0003.npz")
    assert r.meta["controller"] == "classical" and np.all(r.lead == 0)


def test_analytic_controller_uses_a_nonzero_lead(tmp_path):
    out = run(ROOT / "ikpd.py", "--seeds", "5", "--prefix", "an", "--controller", "analytic",
              "--tau", "0.05", "--duration", "0.5", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    from panda_lead.rollout import load

    r = load(tmp_path / "rollouts" / "an" / "seed_0005.npz")
    assert np.abs(r.lead).max() > 0 and r.meta["tau"] == 0.05


@pytest.mark.parametrize("bad,message", [
    (["--seeds", "5-"], "malformed seed range"),
    (["--seeds", "9-3"], "empty"),
    (["--seeds", "-1"], "malformed seed range"),
    (["--seed", "1", "--shape", "circel", "--video", "x.mp4"], "did you mean 'circle'"),
    (["--seed", "1", "--model", "archive/nope.zip", "--controller", "policy", "--video", "x.mp4"],
     "model not found"),
    (["--seeds", "0-1", "--prefix", "../.."], "--prefix must be a plain name"),
    (["--seeds", "0-1", "--prefix", "/tmp/abs"], "--prefix must be a plain name"),
    (["--seeds", "0-99999999"], "more than 100,000 seeds"),
    (["--seeds", "0-1", "--env.obs-noise", "target_vel", "nan"], "must be a finite std"),
    (["--seeds", "0-1", "--env.obs-noise", "targt_vel", "0.1"], "did you mean 'target_vel'"),
    (["--seeds", "0-1", "--env.tracking-scale", "0"], "tracking_scale must be > 0"),
    (["--seeds", "0-1", "--env.ik.iters", "0"], "ik.iters must be in [1, 100]"),
    (["--seeds", "0-1", "--duration", "nan"], "--duration must be a number of seconds in (0, 1000]"),
    (["--seeds", "0-1", "--duration", "1e9"], "--duration must be a number of seconds in (0, 1000]"),
    (["--seed", "9223372036854775808", "--video", "v.mp4"], "--seed must be an integer in 0..2^63-1"),
])
def test_bad_input_is_one_clear_line(tmp_path, bad, message):
    out = run(ROOT / "ikpd.py", *bad, cwd=tmp_path)
    assert out.returncode == 2
    assert message in out.stderr and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1  # one line
    assert not (tmp_path / "rollouts").exists() and not (tmp_path / "x.mp4").exists()


def test_typed_env_flags_apply_over_the_models_sidecar(tmp_path):
    out = run(ROOT / "ikpd.py", "--seeds", "1", "--prefix", "n", "--duration", "0.2",
              "--controller", "analytic", "--env.obs-noise", "target_vel", "0.05",
              "--env.max-lead", "0.1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    from panda_lead.rollout import load

    r = load(tmp_path / "rollouts" / "n" / "seed_0001.npz")
    assert r.meta["env"]["obs_noise"] == {"target_vel": 0.05} and r.meta["env"]["max_lead"] == 0.1
    assert r.meta["env"]["w_distance"] == 1.0  # untouched fields keep their value


def test_video_is_a_playable_mp4(tmp_path):
    out = run(ROOT / "ikpd.py", "--seed", "2", "--duration", "0.3", "--video",
              tmp_path / "v.mp4", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    import imageio.v2 as imageio

    frames = imageio.mimread(tmp_path / "v.mp4")
    assert len(frames) == 15 and frames[0].shape == (480, 640, 3)


def test_the_default_model_is_the_headline_model_whatever_the_file_times(tmp_path):
    """Regression (issue 21): the default was "the newest zip in archive/" by mtime, which git
    does not keep, so a fresh clone played whichever file was checked out last."""
    from panda_lead.models import DEFAULT_MODEL, file_sha256

    headline = ROOT / "archive" / f"{DEFAULT_MODEL}.zip"
    out = run(ROOT / "eval.py", "--seeds", "0", "--prefix", "x", "--duration", "0.05",
              cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    with np.load(tmp_path / "rollouts" / "x" / "seed_0000.npz", allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
    newest = max((ROOT / "archive").glob("*.zip"), key=lambda p: p.stat().st_mtime)
    assert meta["model_sha256"] == file_sha256(headline)
    assert newest == headline or meta["model_sha256"] != file_sha256(newest)
