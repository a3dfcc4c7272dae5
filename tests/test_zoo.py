"""hyperparams/ppo.yml: RL Baselines3 Zoo trains PandaLead-v0 with train.py's defaults."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import run_in_process

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "hyperparams" / "ppo.yml"


def test_zoo_hyperparams_are_train_py_defaults():
    from panda_lead import training

    zoo = yaml.safe_load(CONF.read_text())["PandaLead-v0"]
    args = training.TrainConfig()
    # Fewer envs than train.py's one batch of 32 (RL Zoo makes a process or a Python env per
    # env: 32 cost minutes and gigabytes on 2 cores), the same steps per rollout.
    assert zoo["n_envs"] * zoo["n_steps"] == args.n_envs * args.n_steps
    assert zoo["n_envs"] <= 8 and zoo["n_timesteps"] == 5_000_000
    for key in ("batch_size", "n_epochs", "gamma", "gae_lambda",
                "learning_rate", "clip_range", "ent_coef"):
        assert zoo[key] == getattr(args, key), key
    # The policy string is evaluated by RL Zoo with torch.nn in scope.
    import torch.nn as nn

    policy = eval(zoo["policy_kwargs"], {"nn": nn})
    assert policy == dict(net_arch=list(args.net_arch), activation_fn=nn.Tanh,
                          log_std_init=args.log_std_init)
    assert zoo["normalize"] is False and zoo["env_kwargs"] == {}


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory):
    """RL Zoo's own entry point, as a user runs it from the repo root (the command of
    hyperparams/ppo.yml's header), on a tiny budget: once per module, shared by the tests
    below. `--num-threads 1`: without it this takes 56 s instead of 15 on 2 cores."""
    logs = tmp_path_factory.mktemp("zoo") / "logs"
    out = subprocess.run(
        [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "PandaLead-v0",
         "--gym-packages", "panda_lead", "-conf", str(CONF), "-n", "2048", "-f", str(logs),
         "--hyperparams", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1",
         "--eval-freq", "-1", "--seed", "0", "--vec-env", "dummy", "--num-threads", "1",
         "--device", "cpu"],
        cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    return logs / "ppo" / "PandaLead-v0_1"


def test_rl_zoo_trains_and_saves_a_model(zoo_run):
    run = zoo_run
    assert (run / "PandaLead-v0.zip").is_file(), sorted(p.name for p in run.iterdir())
    assert (run / "PandaLead-v0" / "config.yml").is_file()

    from stable_baselines3 import PPO

    model = PPO.load(run / "PandaLead-v0.zip", device="cpu")  # our own file, just written
    assert model.num_timesteps == 2048
    assert model.n_steps == 64 and model.n_envs == 2  # the overrides reached the model
    assert model.policy.log_std.detach().mean().item() < -0.5  # log_std_init -1 (+ 16 updates)


def test_an_rl_zoo_model_is_adopted_and_evaluated_by_eval_py(zoo_run, tmp_path):
    """The third-party path end to end: RL Zoo trains, `eval.py --adopt` makes it a bound,
    carded archive entry, and eval.py plays it like any archived model."""
    def run(*args):  # eval.py in-process (conftest.run_in_process)
        return run_in_process("eval.py", *args, cwd=tmp_path)

    out = run("--adopt", zoo_run / "PandaLead-v0.zip", "--name", "zoo")
    assert out.returncode == 0, out.stderr[-3000:]
    for ext in ("zip", "json", "md"):
        assert (tmp_path / "archive" / f"zoo.{ext}").is_file()

    # The adopted policy is the Zoo's: the same deterministic actions, read without unpickling.
    from stable_baselines3 import PPO

    from panda_lead.models import load_policy

    adopted, env_config, _ = load_policy(tmp_path / "archive" / "zoo.zip")
    zoo = PPO.load(zoo_run / "PandaLead-v0.zip", device="cpu")  # our own file, just written
    obs = np.random.default_rng(0).normal(size=(8, 15)).astype(np.float32)
    np.testing.assert_allclose(adopted.predict(obs, deterministic=True)[0],
                               zoo.predict(obs, deterministic=True)[0], atol=1e-6)
    out = run("--seeds", "0-1", "--prefix", "zoo", "--model", "archive/zoo.zip",
              "--duration", "0.5")
    assert out.returncode == 0, out.stderr[-3000:]
    files = sorted((tmp_path / "rollouts" / "zoo").glob("*.npz"))
    assert len(files) == 2
    meta = json.loads(str(np.load(files[0])["meta"]))
    side = json.loads((tmp_path / "archive" / "zoo.json").read_text())
    assert meta["controller"] == "policy" and meta["model_sha256"] == side["model_sha256"]


@pytest.mark.slow
def test_rl_zoo_enjoy_plays_its_model(zoo_run):
    """RL Zoo's enjoy, as hyperparams/ppo.yml's header runs it: it reads the run's config.yml
    (env_kwargs) and plays the model headless."""
    out = subprocess.run(
        [sys.executable, "-m", "rl_zoo3.enjoy", "--algo", "ppo", "--env", "PandaLead-v0",
         "--gym-packages", "panda_lead", "-f", str(zoo_run.parents[1]), "--exp-id", "1",
         "--no-render", "-n", "400", "--num-threads", "1", "--device", "cpu"],
        cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Episode Length 200" in out.stdout and "2 Episodes" in out.stdout, out.stdout[-2000:]
