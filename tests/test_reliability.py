"""Reliability: determinism, instability, bad and hostile model files, sidecars bound to their
models, full disks, damaged rollouts, rollout folders that never mix. (Signals and resume:
test_training.py; issue 25's hostile files, bad input, locks and training faults:
test_hostile_files.py, test_bad_input.py, test_locks.py, test_training_faults.py.) Each promise
is listed in docs/reliability.md with its test."""

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from panda_lead.env import PandaLeadEnv
from panda_lead.rollout import load_prefix, record, rollout_path, save

ROOT = Path(__file__).resolve().parents[1]


def run(*args, cwd, timeout=300):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, "MUJOCO_GL": "egl"})


def test_rerun_gives_the_same_rollout_bit_for_bit():
    act = lambda obs, task: np.tanh(obs[:, :3]).astype(np.float32)  # noqa: E731
    a = record(PandaLeadEnv(episode_steps=120), act, traj_seed=17)
    b = record(PandaLeadEnv(episode_steps=120), act, traj_seed=17)
    for key in ("ee_pos", "qpos", "qvel", "lead", "target_pos"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key


def test_unstable_simulation_ends_the_episode_as_a_flagged_failure(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to MUJOCO_LOG.TXT in the cwd
    e = PandaLeadEnv(w_termination=2.0)
    e.reset(seed=0, options={"traj_seed": 42})
    e.core.qvel[:] = 1e12  # a blow-up: MuJoCo flags the acceleration as bad
    obs, reward, term, trunc, info = e.step(np.zeros(3, dtype=np.float32))
    assert term and not trunc and info["failure"] == "unstable"
    assert "seed 42" in info["message"]
    assert np.isfinite(obs).all() and np.isfinite(reward) and reward == -2.0


def test_half_written_files_are_never_trusted(tmp_path):
    r = record(PandaLeadEnv(episode_steps=10), lambda o, t: np.zeros((len(o), 3), np.float32), 1)
    save(r, rollout_path("set", 1, tmp_path))
    # What an interrupted save leaves behind: a temporary name, never the final one.
    (tmp_path / "set" / ".seed_0002.abc.tmp.npz").write_bytes(b"PK\x03\x04 half")
    assert list(load_prefix("set", tmp_path)) == [1]


@pytest.fixture(scope="module")
def untrained_model(tmp_path_factory):
    """A real (untrained) PPO model with its sidecar, saved the way train.py saves models."""
    from stable_baselines3 import PPO

    from panda_lead.models import save_model

    tmp = tmp_path_factory.mktemp("model")
    e = PandaLeadEnv()
    model = PPO("MlpPolicy", e, n_steps=64, batch_size=64, device="cpu")
    path = save_model(model, tmp / "m.zip", {"env_config": e.config, "train_config": {},
                                             "timesteps": 0})
    assert json.loads(path.with_suffix(".json").read_text())["model_sha256"]
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
    ("changed_zip", "SHA-256 differs from its sidecar's"),
    ("no_sidecar", "no sidecar"),
    ("mismatched_sidecar", "the sidecar does not belong to this model"),
])
def test_bad_model_files_get_one_clear_message(untrained_model, tmp_path, case, message):
    bad = tmp_path / "bad.zip"
    if case == "truncated":
        _copy(untrained_model, bad)
        bad.write_bytes(untrained_model.read_bytes()[:500])
    elif case in ("corrupt_member", "changed_zip"):
        _copy(untrained_model, bad)
        with zipfile.ZipFile(untrained_model) as zin, zipfile.ZipFile(bad, "w") as zout:
            for item in zin.infolist():
                data = b"garbage" if item.filename == "policy.pth" else zin.read(item)
                zout.writestr(item, data)
        if case == "corrupt_member":  # a sidecar bound to the damaged file: the load must say
            from panda_lead.models import bind_sidecar

            bind_sidecar(bad)
    elif case == "no_sidecar":
        _copy(untrained_model, bad, side=None)
    else:
        side = json.loads(untrained_model.with_suffix(".json").read_text())
        side["env_config"]["obs_features"] = ["ee_pos", "ee_vel", "target_pos", "target_vel"]
        _copy(untrained_model, bad, side=side)
        from panda_lead.models import bind_sidecar

        bind_sidecar(bad)  # even a bound sidecar must describe the weights it sits beside
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


def test_soak_script_runs_clean():
    out = run(ROOT / "studies" / "soak.py", "--steps", "4000", "--envs", "16", "--workers", "2",
              "--episode-steps", "100",
              "--max-lead", "0.5", cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "NaNs 0, exceptions 0" in out.stdout and "PASS" in out.stdout


def test_atomic_write_renames_on_success_and_leaves_nothing_on_error(tmp_path):
    import os

    from panda_lead.atomicio import atomic_write

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


def _hostile_zip(src: Path, dst: Path, marker: Path) -> None:
    """A copy of a real model whose pickled fields and policy.pth would create ``marker`` if
    anything unpickled them."""
    import base64
    import pickle

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    blob = pickle.dumps(Payload())
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "data":
                d = json.loads(data)
                for key in ("policy_class", "policy_kwargs", "lr_schedule", "observation_space"):
                    d[key] = {":type:": "<class 'x'>",
                              ":serialized:": base64.b64encode(blob).decode()}
                data = json.dumps(d).encode()
            elif item.filename in ("policy.pth", "policy.optimizer.pth", "pytorch_variables.pth"):
                data = blob
            zout.writestr(item, data)


@pytest.mark.parametrize("via", ["eval", "load_policy", "resume"])
def test_a_hostile_model_file_runs_nothing(untrained_model, tmp_path, via):
    """SB3's zip holds pickles: PPO.load on this file would run `touch marker`. Every way in
    (eval.py, the loader, train.py --resume) must refuse it without executing anything, even
    with a sidecar that vouches for the file (its hash bound to it)."""
    from panda_lead.models import ModelError, bind_sidecar, load_policy

    marker = tmp_path / "PWNED"
    evil = tmp_path / "evil.zip"
    _hostile_zip(untrained_model, evil, marker)
    _copy(untrained_model, tmp_path / "x.zip")
    evil.with_suffix(".json").write_text(untrained_model.with_suffix(".json").read_text())
    bind_sidecar(evil)
    if via == "eval":
        out = run(ROOT / "eval.py", "--seed", "0", "--model", evil, "--video", tmp_path / "v.mp4",
                  cwd=tmp_path)
        assert out.returncode == 2 and "cannot load model" in out.stderr, out.stderr
    elif via == "load_policy":
        with pytest.raises(ModelError, match="cannot load model"):
            load_policy(evil)
    else:
        from panda_lead import training

        run_dir = tmp_path / "run"
        (run_dir / "checkpoints").mkdir(parents=True)
        config = training.TrainConfig(n_envs=2, n_steps=64, batch_size=64, timesteps=256,
                                      eval_freq=0).to_dict()
        (run_dir / "config.json").write_text(json.dumps(config))
        ckpt = run_dir / "checkpoints" / "model_128_steps.zip"
        ckpt.write_bytes(evil.read_bytes())
        side = json.loads(evil.with_suffix(".json").read_text())
        ckpt.with_suffix(".json").write_text(json.dumps({**side, "timesteps": 128,
                                                         "train_config": config}))
        bind_sidecar(ckpt)  # the attacker vouches for the file: the load itself must refuse it
        out = run(ROOT / "train.py", "--resume", run_dir, "--no-progress", cwd=tmp_path)
        assert out.returncode == 2 and "cannot load model" in out.stderr, out.stderr
    assert not marker.exists()


def test_a_sidecar_of_another_model_with_the_same_observation_size_is_refused(untrained_model,
                                                                             tmp_path):
    """The old check compared sizes only: another 15-D feature list ran silently."""
    side = json.loads(untrained_model.with_suffix(".json").read_text())
    side["env_config"]["obs_features"] = ["ee_pos", "ee_vel", "target_pos", "target_vel",
                                          "prev_action"]  # also 15-D
    other = _copy(untrained_model, tmp_path / "m.zip", side=side)
    from panda_lead.models import ModelError, load_policy

    with pytest.raises(ModelError, match="obs_features: sidecar .*prev_action"):
        load_policy(other)
    side.pop("model_sha256")
    other.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(ModelError, match="no model_sha256"):
        load_policy(other)


def test_archived_models_load_safely_and_are_bound():
    from panda_lead.models import ARCHIVE_DIR, load_policy

    for p in sorted((ROOT / ARCHIVE_DIR).glob("*.zip")):
        policy, env_config, side = load_policy(p)
        assert side["model_sha256"] and policy.observation_space.shape[0] >= 12


def test_loading_a_policy_to_act_builds_no_optimizer():
    # Any torch optimizer imports torch._dynamo when built (seconds per eval.py process); a
    # policy loaded to act needs none. In a fresh process, so nothing imported it before.
    code = ("import sys\n"
            "from panda_lead.models import archived, load_policy\n"
            "policy, _, _ = load_policy(archived('v5_5m'))\n"
            "import torch\n"
            "print('torch._dynamo' in sys.modules, isinstance(policy.optimizer, "
            "torch.optim.Optimizer))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


def test_a_full_disk_is_one_line_and_keeps_the_previous_files(untrained_model, tmp_path,
                                                             monkeypatch):
    import errno

    from panda_lead.errors import UserError
    from panda_lead.models import save_model

    target = _copy(untrained_model, tmp_path / "m.zip")
    before = target.read_bytes(), target.with_suffix(".json").read_text()

    class FullDisk:
        policy_kwargs: dict = {}

        def save(self, path):
            Path(path).write_bytes(b"half")
            raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(UserError, match="cannot write .*m.zip: No space left on device"):
        save_model(FullDisk(), target, {"env_config": {}})
    assert (target.read_bytes(), target.with_suffix(".json").read_text()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "m.zip"]

    r = record(PandaLeadEnv(episode_steps=5), lambda o, t: np.zeros((len(o), 3), np.float32), 1)
    path = save(r, rollout_path("set", 1, tmp_path))
    old = path.read_bytes()

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full)
    with pytest.raises(UserError, match="No space left"):
        save(r, path)
    assert path.read_bytes() == old


def test_a_truncated_rollout_file_is_one_clear_error(tmp_path):
    from panda_lead.errors import UserError
    from panda_lead.rollout import load

    r = record(PandaLeadEnv(episode_steps=5), lambda o, t: np.zeros((len(o), 3), np.float32), 1)
    path = save(r, rollout_path("set", 1, tmp_path))
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(UserError, match="cannot read rollout .*damaged or truncated"):
        load(path)
    with pytest.raises(UserError, match="no rollouts under"):
        load_prefix("nothing", tmp_path)


def test_a_rollout_folder_never_mixes_two_controllers(tmp_path):
    ok = run(ROOT / "ikpd.py", "--seeds", "0-1", "--prefix", "p", "--duration", "0.1", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    again = run(ROOT / "ikpd.py", "--seeds", "2", "--prefix", "p", "--duration", "0.1", cwd=tmp_path)
    assert again.returncode == 0, again.stderr  # the same controller may add seeds
    other = run(ROOT / "ikpd.py", "--seeds", "0", "--prefix", "p", "--duration", "0.1",
                "--controller", "analytic", cwd=tmp_path)
    assert other.returncode == 2 and "holds 3 rollouts of another controller" in other.stderr
    assert "--force" in other.stderr
    forced = run(ROOT / "ikpd.py", "--seeds", "0", "--prefix", "p", "--duration", "0.1",
                 "--controller", "analytic", "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert sorted(load_prefix("p", tmp_path / "rollouts")) == [0]
    assert load_prefix("p", tmp_path / "rollouts")[0].meta["controller"] == "analytic"


def test_two_runs_on_one_prefix_cannot_run_at_once(tmp_path):
    import fcntl

    folder = tmp_path / "rollouts" / "p"
    folder.mkdir(parents=True)
    with open(folder / ".lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what a running eval.py holds
        out = run(ROOT / "ikpd.py", "--seeds", "0", "--prefix", "p", "--duration", "0.1",
                  cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.count("\n") == 1, out.stderr
    # (worded by the rollout writer's lock: atomicio.folder_lock's, or the older own one)
    assert ("the rollout set is in use by another process" in out.stderr
            or "another run is writing rollouts there now" in out.stderr), out.stderr
    assert not list(folder.glob("seed_*.npz"))
