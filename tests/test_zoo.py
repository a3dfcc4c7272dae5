"""hyperparams/ppo.yml: RL Baselines3 Zoo trains PandaLead-v0 with train.py's defaults."""

import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "hyperparams" / "ppo.yml"


def test_zoo_hyperparams_are_train_py_defaults():
    from panda_lead import training

    zoo = yaml.safe_load(CONF.read_text())["PandaLead-v0"]
    args = training.TrainConfig()
    assert zoo["n_envs"] == args.n_envs and zoo["n_timesteps"] == 5_000_000
    for key in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda",
                "learning_rate", "clip_range", "ent_coef"):
        assert zoo[key] == getattr(args, key), key
    # The policy string is evaluated by RL Zoo with torch.nn in scope.
    import torch.nn as nn

    policy = eval(zoo["policy_kwargs"], {"nn": nn})
    assert policy == dict(net_arch=list(args.net_arch), activation_fn=nn.Tanh,
                          log_std_init=args.log_std_init)
    assert zoo["normalize"] is False and zoo["env_kwargs"] == {}


def test_rl_zoo_trains_and_saves_a_model(tmp_path):
    """RL Zoo's own entry point, as a user runs it from the repo root, on a tiny budget."""
    logs = tmp_path / "logs"
    out = subprocess.run(
        [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "PandaLead-v0",
         "--gym-packages", "env", "-conf", str(CONF), "-n", "2048", "-f", str(logs),
         "--hyperparams", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1",
         "--eval-freq", "-1", "--seed", "0", "--vec-env", "dummy", "--device", "cpu"],
        cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    run = logs / "ppo" / "PandaLead-v0_1"
    assert (run / "PandaLead-v0.zip").is_file(), sorted(p.name for p in run.iterdir())
    assert (run / "PandaLead-v0" / "config.yml").is_file()

    from stable_baselines3 import PPO

    model = PPO.load(run / "PandaLead-v0.zip", device="cpu")  # our own file, just written
    assert model.num_timesteps == 2048
    assert model.n_steps == 64 and model.n_envs == 2  # the overrides reached the model
    assert model.policy.log_std.detach().mean().item() < -0.5  # log_std_init -1 (+ 16 updates)
