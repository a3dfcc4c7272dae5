"""Reliability: determinism across vectorisation, instability, bad model files, Ctrl-C."""

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import env as env_mod
from rollout import load_prefix, record, rollout_path, save

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd, timeout=300):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, "MUJOCO_GL": "egl"})


def test_rerun_gives_the_same_rollout_bit_for_bit():
    act = lambda obs, task: np.tanh(obs[:, :3]).astype(np.float32)  # noqa: E731
    a = record(env_mod.PandaLeadEnv(episode_steps=120), act, traj_seed=17)
    b = record(env_mod.PandaLeadEnv(episode_steps=120), act, traj_seed=17)
    for key in ("ee_pos", "qpos", "qvel", "lead", "target_pos"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key


def test_unstable_simulation_ends_the_episode_as_a_flagged_failure(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to MUJOCO_LOG.TXT in the cwd
    e = env_mod.PandaLeadEnv(w_termination=2.0)
    e.reset(seed=0, options={"traj_seed": 42})
    e.core.qvel[:] = 1e12  # a blow-up: MuJoCo flags the acceleration as bad
    obs, reward, term, trunc, info = e.step(np.zeros(3, dtype=np.float32))
    assert term and not trunc and info["failure"] == "unstable"
    assert "seed 42" in info["message"]
    assert np.isfinite(obs).all() and np.isfinite(reward) and reward == -2.0


def test_half_written_files_are_never_trusted(tmp_path):
    r = record(env_mod.PandaLeadEnv(episode_steps=10), lambda o, t: np.zeros((len(o), 3), np.float32), 1)
    save(r, rollout_path("set", 1, tmp_path))
    # What an interrupted save leaves behind: a temporary name, never the final one.
    (tmp_path / "set" / ".seed_0002.abc.tmp.npz").write_bytes(b"PK\x03\x04 half")
    assert list(load_prefix("set", tmp_path)) == [1]


@pytest.fixture(scope="module")
def untrained_model(tmp_path_factory):
    """A real (untrained) PPO model with its sidecar, saved the way train.py saves models."""
    from stable_baselines3 import PPO

    from models import save_model

    tmp = tmp_path_factory.mktemp("model")
    e = env_mod.PandaLeadEnv()
    model = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu")
    path = save_model(model, tmp / "m.zip", {"env_config": e.config, "train_config": {},
                                             "timesteps": 0})
    return path


def _copy(src: Path, dst: Path, side: dict | None = "same") -> Path:
    dst.write_bytes(src.read_bytes())
    if side == "same":
        dst.with_suffix(".json").write_text(src.with_suffix(".json").read_text())
    elif side is not None:
        dst.with_suffix(".json").write_text(json.dumps(side))
    return dst


@pytest.mark.parametrize("case,message", [
    ("truncated", "not a model zip"),
    ("corrupt_member", "cannot load model"),
    ("no_sidecar", "no sidecar"),
    ("mismatched_sidecar", "takes a 15-D observation but its sidecar's features"),
])
def test_bad_model_files_get_one_clear_message(untrained_model, tmp_path, case, message):
    bad = tmp_path / "bad.zip"
    if case == "truncated":
        _copy(untrained_model, bad)
        bad.write_bytes(untrained_model.read_bytes()[:500])
    elif case == "corrupt_member":
        _copy(untrained_model, bad)
        with zipfile.ZipFile(untrained_model) as zin, zipfile.ZipFile(bad, "w") as zout:
            for item in zin.infolist():
                data = b"garbage" if item.filename == "policy.pth" else zin.read(item)
                zout.writestr(item, data)
    elif case == "no_sidecar":
        _copy(untrained_model, bad, side=None)
    else:
        side = json.loads(untrained_model.with_suffix(".json").read_text())
        side["env_config"]["obs_features"] = ["ee_pos", "ee_vel", "target_pos", "target_vel"]
        _copy(untrained_model, bad, side=side)
    before = sorted(p.name for p in tmp_path.iterdir())
    out = run(ROOT / "eval.py", "--seeds", "0-1", "--prefix", "x", "--model", bad, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr and "Traceback" not in out.stderr
    if case == "no_sidecar":
        assert "15-D" in out.stderr  # says what can be inferred
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_unknown_preset_suggests_the_closest(tmp_path):
    out = run(ROOT / "train.py", "--preset", "v55", "--runs-dir", tmp_path, cwd=tmp_path)
    assert out.returncode == 2 and "did you mean 'v5'" in out.stderr
    assert "Traceback" not in out.stderr and not any(tmp_path.iterdir())


def test_ctrl_c_saves_a_resumable_model(tmp_path):
    cmd = [sys.executable, str(ROOT / "train.py"), "--timesteps", "100000", "--n-envs", "2",
           "--vec-env", "batched", "--n-workers", "2", "--n-steps", "64", "--batch-size", "64",
           "--n-epochs", "1", "--eval-freq", "0", "--checkpoint-freq", "256", "--runs-dir",
           str(tmp_path / "runs"), "--no-progress"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ})
    deadline = time.time() + 120
    while time.time() < deadline and not list(tmp_path.glob("runs/*/checkpoints/*.json")):
        time.sleep(0.2)
    assert list(tmp_path.glob("runs/*/checkpoints/*.json")), "no checkpoint appeared"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    run_dir = next((tmp_path / "runs").iterdir())
    assert (run_dir / "interrupted_model.zip").is_file()
    assert "--resume" in out
    steps = json.loads((run_dir / "interrupted_model.json").read_text())["timesteps"]
    resumed = run(ROOT / "train.py", "--resume", run_dir, "--timesteps", str(steps + 256),
                  "--no-progress", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    final = json.loads((run_dir / "final_model.json").read_text())
    assert final["timesteps"] >= steps + 256


def test_soak_script_runs_clean():
    out = run(ROOT / "studies" / "soak.py", "--steps", "4000", "--envs", "16", "--workers", "2",
              "--episode-steps", "100",
              "--max-lead", "0.5", cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "NaNs 0, exceptions 0" in out.stdout and "PASS" in out.stdout


def test_atomic_write_renames_on_success_and_leaves_nothing_on_error(tmp_path):
    import os

    from atomicio import atomic_write

    target = tmp_path / "sub" / "model.json"
    with atomic_write(target, ".tmp.json") as tmp, open(tmp, "w") as f:
        f.write("{}")
    assert target.read_text() == "{}"
    # The final file gets ordinary permissions (0666 less the umask), not mkstemp's 0600.
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(RuntimeError), atomic_write(target, ".tmp.json") as tmp:
        Path(tmp).write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "{}"  # the old file is untouched
    assert sorted(p.name for p in target.parent.iterdir()) == ["model.json"]
