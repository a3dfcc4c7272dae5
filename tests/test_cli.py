"""The scripts end to end, as a user runs them, with tiny budgets: the training run is the
session's shared tiny run (conftest.tiny_run: train.py in a subprocess, then resumed and
archived); eval.py and ikpd.py are called in-process through their main functions (the exit
status from SystemExit, output from capsys), and as processes where the process is the point
(a real exit status 2 and its one stderr line)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import main_exit

from panda_lead.cli.main import eval_command, ikpd_command

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd=ROOT, timeout=600):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**__import__("os").environ,
                                                           "MUJOCO_GL": "egl"})


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    """The scripts write rollouts/ under the working folder: make it this test's."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_train_leaves_a_complete_run_folder(tiny_run):
    tmp, run_dir, first, _ = tiny_run
    for name in ("config.json", "command.txt", "final_model.zip", "final_model.json",
                 "best_model.zip", "best_model.json"):
        assert (run_dir / name).is_file(), name
    assert list((run_dir / "checkpoints").glob("model_*_steps.zip"))
    assert list((run_dir / "tb").glob("events.out.tfevents.*"))
    config = json.loads((run_dir / "config.json").read_text())
    assert config["n_steps"] == 64 and config["n_envs"] == 2 and config["env"]["max_lead"] == 0.15


def test_resume_continues_the_step_counter_and_archives(tiny_run):
    tmp, run_dir, _, resumed = tiny_run
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


def test_archived_model_loads_and_runs_on_seeds(tiny_run, in_tmp, capsys):
    tmp, *_ = tiny_run
    code, _, err = main_exit(eval_command, ["--seeds", "0-1", "--prefix", "tiny", "--model",
                                            tmp / "archive" / "tiny.zip", "--duration", "0.5"],
                             capsys)
    assert code == 0, err
    files = sorted((in_tmp / "rollouts" / "tiny").glob("seed_*.npz"))
    assert [f.name for f in files] == ["seed_0000.npz", "seed_0001.npz"]
    from panda_lead.rollout import load

    r = load(files[0])
    assert r.meta["controller"] == "policy" and r.meta["model"].endswith("tiny.zip")
    assert len(r.t) == 50


def test_ikpd_writes_rollouts_and_prints_errors(in_tmp, capsys):
    tmp_path = in_tmp
    code, stdout, err = main_exit(ikpd_command, ["--seeds", "3-4", "--prefix", "ikpd",
                                                 "--duration", "1"], capsys)
    assert code == 0, err
    assert "seed    3" in stdout and "cm" in stdout
    from panda_lead.rollout import load

    r = load(tmp_path / "rollouts" / "ikpd" / "seed_0003.npz")
    assert r.meta["controller"] == "classical" and np.all(r.lead == 0)


def test_analytic_controller_uses_a_nonzero_lead(in_tmp, capsys):
    tmp_path = in_tmp
    code, _, err = main_exit(ikpd_command, ["--seeds", "5", "--prefix", "an", "--controller",
                                            "analytic", "--tau", "0.05", "--duration", "0.5"],
                             capsys)
    assert code == 0, err
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
    (["--seed", "9223372036854775808", "--video", "v.mp4"],
     "--seed must be an integer in 0..9223372036854775807 (2^63-1)"),
])
def test_bad_input_is_one_clear_line(in_tmp, capsys, bad, message):
    tmp_path = in_tmp
    code, _, err = main_exit(ikpd_command, bad, capsys)
    assert code == 2
    assert message in err and "Traceback" not in err
    assert err.count("\n") == 1  # one line
    assert not (tmp_path / "rollouts").exists() and not (tmp_path / "x.mp4").exists()


def test_bad_input_is_exit_status_2_and_one_line_from_the_process(tmp_path):
    """The same refusal as the process gives it (the cases above run in-process)."""
    out = run(ROOT / "ikpd.py", "--seeds", "5-", cwd=tmp_path)
    assert out.returncode == 2
    assert "malformed seed range" in out.stderr and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1 and not (tmp_path / "rollouts").exists()


def test_typed_env_flags_apply_over_the_models_sidecar(in_tmp, capsys):
    tmp_path = in_tmp
    code, _, err = main_exit(ikpd_command, ["--seeds", "1", "--prefix", "n", "--duration", "0.2",
                                            "--controller", "analytic", "--env.obs-noise",
                                            "target_vel", "0.05", "--env.max-lead", "0.1"],
                             capsys)
    assert code == 0, err
    from panda_lead.rollout import load

    r = load(tmp_path / "rollouts" / "n" / "seed_0001.npz")
    assert r.meta["env"]["obs_noise"] == {"target_vel": 0.05} and r.meta["env"]["max_lead"] == 0.1
    assert r.meta["env"]["w_distance"] == 1.0  # untouched fields keep their value


def test_video_is_a_playable_mp4(in_tmp, capsys):
    tmp_path = in_tmp
    code, _, err = main_exit(ikpd_command, ["--seed", "2", "--duration", "0.3", "--video",
                                            tmp_path / "v.mp4"], capsys)
    assert code == 0, err
    import imageio.v2 as imageio

    frames = imageio.mimread(tmp_path / "v.mp4")
    assert len(frames) == 15 and frames[0].shape == (480, 640, 3)


def test_the_default_model_is_the_headline_model_whatever_the_file_times(in_tmp, capsys):
    """Regression (issue 21): the default was "the newest zip in archive/" by mtime, which git
    does not keep, so a fresh clone played whichever file was checked out last."""
    from panda_lead.models import DEFAULT_MODEL, file_sha256

    headline = ROOT / "archive" / f"{DEFAULT_MODEL}.zip"
    tmp_path = in_tmp
    code, _, err = main_exit(eval_command, ["--seeds", "0", "--prefix", "x", "--duration",
                                            "0.05"], capsys)
    assert code == 0, err
    with np.load(tmp_path / "rollouts" / "x" / "seed_0000.npz", allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
    newest = max((ROOT / "archive").glob("*.zip"), key=lambda p: p.stat().st_mtime)
    assert meta["model_sha256"] == file_sha256(headline)
    assert newest == headline or meta["model_sha256"] != file_sha256(newest)
