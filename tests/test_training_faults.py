"""Training runs given bad input or hit by faults (issue 25): resume that would change what a run
learns, a config.json that is not the run's, Ctrl-C in the final evaluation, absurd sizes,
huge reward weights and a diverged run. Every refusal is one `error:` line, exit status 2, and
nothing is created. Training runs are tiny (a few hundred steps, 2 envs)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import one_line, one_line_in_process

from panda_lead.cli.train import main as train_main
from panda_lead.cli.train import parse_args
from panda_lead.errors import UserError
from panda_lead.training import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--n-envs", "2", "--n-steps", "64", "--batch-size", "64", "--n-epochs", "1",
        "--n-workers", "1", "--no-progress"]
ENV = {**os.environ, "MUJOCO_GL": "egl"}


def run(*args, cwd, timeout=600):
    return subprocess.run([sys.executable, *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=ENV)


def tiny_run(tmp_path: Path) -> Path:
    """A run folder whose config.json is a tiny run's, with no checkpoint yet."""
    run_dir = tmp_path / "runs" / "r"
    run_dir.mkdir(parents=True)
    config = parse_args([*TINY, "--timesteps", "256", "--eval-freq", "0"]).config()
    (run_dir / "config.json").write_text(json.dumps(config.to_dict()))
    return run_dir


# --- item 4: resume keeps what the run learns ---------------------------------------------------

def test_resume_refuses_reference_hparams_and_a_new_torch_thread_count(tmp_path, monkeypatch,
                                                                      capsys):
    run_dir = tiny_run(tmp_path)
    with pytest.raises(UserError, match="--reference-hparams changes what a run learns"):
        parse_args(["--resume", str(run_dir), "--reference-hparams"])
    # The thread count changes torch's float reductions, so the weights: not a run-time flag.
    with pytest.raises(UserError, match="--torch-threads cannot change"):
        parse_args(["--resume", str(run_dir), "--torch-threads", "2"])
    before = sorted(p.name for p in run_dir.iterdir())
    monkeypatch.chdir(tmp_path)
    one_line_in_process(train_main, ["--resume", run_dir, "--reference-hparams"], capsys,
                        "--reference-hparams", "--resume")
    one_line_in_process(train_main, ["--resume", run_dir, "--torch-threads", "2"], capsys,
                        "--torch-threads cannot change")
    assert sorted(p.name for p in run_dir.iterdir()) == before


# --- item 9: config.json is cross-checked against the checkpoint --------------------------------

@pytest.mark.parametrize("content,words", [
    ("{}", ["config.json differs from what", "n_envs"]),
    ('"a string"', ["unreadable run config", "JSON object"]),
    ("[1, 2]", ["unreadable run config", "JSON object"]),
])
def test_resume_refuses_a_config_json_that_is_not_the_runs(untrained_checkpoint_run, content,
                                                           words, monkeypatch, capsys):
    """`{}` parses as train.py's defaults: the checkpoint (bound to its sidecar, which holds
    the config it was trained with) says otherwise. A string or a list is no config at all."""
    run_dir = untrained_checkpoint_run
    (run_dir / "config.json").write_text(content)
    files = lambda: sorted(p.name for p in run_dir.rglob("*") if p.name != ".lock")  # noqa: E731
    before = files()
    monkeypatch.chdir(run_dir.parent)
    one_line_in_process(train_main, ["--resume", run_dir], capsys, *words)
    assert files() == before  # (the run's lock file aside: taking the lock is harmless)


@pytest.fixture
def untrained_checkpoint_run(tmp_path):
    """A run folder with one valid checkpoint (an untrained tiny PPO, saved as the loop saves)."""
    from stable_baselines3 import PPO

    from panda_lead.env import PandaLeadEnv
    from panda_lead.models import save_model

    run_dir = tiny_run(tmp_path)
    config = TrainConfig.from_dict(json.loads((run_dir / "config.json").read_text()))
    model = PPO("MlpPolicy", PandaLeadEnv(config.env), n_steps=64, batch_size=64, device="cpu",
                policy_kwargs={"net_arch": list(config.net_arch)})
    save_model(model, run_dir / "checkpoints" / "model_128_steps.zip",
               {"env_config": config.env.to_dict(), "train_config": config.to_dict(),
                "timesteps": 128, "wall_time_s": 1.0})
    return run_dir


# --- item 12: Ctrl-C during the final evaluation ------------------------------------------------

FINAL_EVAL_CHILD = textwrap.dedent("""
    import signal, sys, time
    from stable_baselines3 import PPO
    from panda_lead.training import callbacks

    learned = []
    plain_learn, plain_eval = PPO.learn, callbacks.TrackingEval.run_eval

    def learn(self, *a, **k):
        out = plain_learn(self, *a, **k)
        learned.append(True)
        return out

    def run_eval(self):
        if learned:  # learn() has returned: this is the final evaluation
            flag = signal.getsignal(signal.SIGINT).__self__  # the loop's SignalFlag
            print("final evaluation started", flush=True)
            while flag.received is None:  # until the test's Ctrl-C has been handled
                time.sleep(0.01)
        return plain_eval(self)

    PPO.learn, callbacks.TrackingEval.run_eval = learn, run_eval
    from panda_lead.cli.train import main
    main(sys.argv[1:])
""")


def test_ctrl_c_during_the_final_evaluation_saves_and_says_how_to_resume(tmp_path):
    """The final evaluation (after learn() returns) prints nothing when it starts, so the
    child marks the moment itself (the one line the patch adds) and waits there for the
    test's SIGINT, as a user's Ctrl-C would arrive. It must save and exit 130, as during
    learn(), not die with a KeyboardInterrupt traceback and lose the run."""
    child = tmp_path / "child.py"
    child.write_text(FINAL_EVAL_CHILD)
    cmd = [sys.executable, str(child), "--timesteps", "128", "--eval-freq", "1000000",
           "--eval-steps", "20", "--runs-dir", str(tmp_path / "runs"), *TINY]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, env=ENV)
    try:
        for line in proc.stdout:  # the event, not a clock
            if "final evaluation started" in line:
                break
        else:
            pytest.fail(f"no final evaluation: {proc.stderr.read()}")
        os.kill(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=600)  # a hang guard: it saves within seconds
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert f"resume with: uv run train.py --resume {run_dir}" in out
    side = json.loads((run_dir / "interrupted_model.json").read_text())
    assert side["timesteps"] == 128
    from panda_lead.models import verify

    verify(run_dir / "interrupted_model.zip")  # a valid pair that --resume will take


# --- item 23: absurd sizes, refused before any folder is made -----------------------------------

@pytest.mark.parametrize("argv,words", [
    (["--n-envs", "1000000"], ["needs at least", "GiB of memory", "n_envs 1000000"]),
    (["--n-steps", "10000000"], ["needs at least", "n_steps 10000000"]),
    (["--net-arch", "200000", "200000"], ["needs at least", "net_arch [200000, 200000]"]),
    (["--env.episode-steps", "1000000000"], ["episode_steps must be 1..100,000"]),
])
def test_absurd_training_sizes_are_refused_before_any_folder_is_made(tmp_path, monkeypatch,
                                                                     argv, words):
    from panda_lead import training
    from panda_lead.training import config as config_module

    # The bound is this machine's memory; a 16 GiB machine makes the test the same anywhere.
    monkeypatch.setattr(config_module, "physical_memory", lambda: 16 * 2**30)
    runs = tmp_path / "runs"
    with pytest.raises(UserError) as exc:
        training.train(parse_args([*argv, "--runs-dir", str(runs), "--no-progress"]))
    assert all(w in str(exc.value) for w in words), str(exc.value)
    assert not runs.exists()


def test_an_absurd_size_is_one_line_through_train_py(tmp_path):
    # 10^9 envs need tens of TB, whatever the machine.
    out = run(ROOT / "train.py", "--n-envs", "1000000000", "--runs-dir", tmp_path / "runs",
              cwd=tmp_path)
    one_line(out, "GiB of memory")
    assert not (tmp_path / "runs").exists()


def test_an_absurd_learning_rate_is_refused():
    # 1e300 passed the finite > 0 check, then torch's Adam raised "value cannot be converted
    # to type float without overflow" (a traceback) after the first rollout.
    with pytest.raises(UserError, match=r"--learning-rate must be a finite number in \(0, 1\]"):
        parse_args(["--learning-rate", "1e300"])


# --- item 26: huge reward weights, and a run whose weights stop being finite --------------------

def test_huge_reward_weights_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    with pytest.raises(UserError, match=r"w_alive must be within \+-1e\+06"):
        parse_args(["--env.w-alive", "-1e308"])
    monkeypatch.chdir(tmp_path)
    one_line_in_process(train_main, ["--env.w-alive", "-1e308", "--runs-dir", tmp_path / "runs"],
                        capsys, "w_alive must be within")
    assert not (tmp_path / "runs").exists()


def diverge_every_update(monkeypatch) -> None:
    """The first update diverges: every weight becomes NaN after Adam's step."""
    import torch

    plain_step = torch.optim.Adam.step

    def step(self, *a, **k):
        out = plain_step(self, *a, **k)
        with torch.no_grad():
            for group in self.param_groups:
                for p in group["params"]:
                    p.fill_(float("nan"))
        return out

    monkeypatch.setattr(torch.optim.Adam, "step", step)


def test_a_diverged_run_stops_with_one_line_and_keeps_its_last_good_checkpoint(
        tmp_path, monkeypatch, capsys):
    """A diverged update (here forced: every weight NaN after the first one) is stopped by
    FiniteWeights before the next rollout: one line, exit 2, and the checkpoint taken before
    the update stays the newest model; nothing is saved from the diverged weights. One
    minibatch per update (batch 128 = 64 steps x 2 envs), so the NaN weights meet no forward
    pass before the check."""
    import numpy as np

    from panda_lead.models import load_policy

    diverge_every_update(monkeypatch)
    monkeypatch.chdir(tmp_path)
    runs = tmp_path / "runs"
    one_line_in_process(train_main, [
        "--timesteps", "512", "--eval-freq", "0", "--checkpoint-freq", "128", "--runs-dir", runs,
        "--n-envs", "2", "--n-steps", "64", "--batch-size", "128", "--n-epochs", "1",
        "--n-workers", "1", "--no-progress"], capsys, "training diverged at 128 steps",
        "no longer finite")
    (run_dir,) = runs.iterdir()
    saved = sorted(p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*.zip"))
    assert saved == ["checkpoints/model_128_steps.zip"]
    policy, _, _ = load_policy(run_dir / saved[0])
    assert all(np.isfinite(p.detach().numpy()).all() for p in policy.parameters())
