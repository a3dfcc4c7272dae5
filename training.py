"""Training library behind `uv run train.py`: config resolution, vec envs, callbacks, the loop.

One folder per run under runs/: config.json (resolved), command.txt, tb/ (TensorBoard),
checkpoints/, best_model.zip (lowest evaluation-set tracking error) and final_model.zip, each
model with its sidecar. Ctrl-C saves the model and prints how to resume.
"""

from __future__ import annotations

import json
import random
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from seeds import EVAL_SET


@dataclass
class Args:
    preset: str | None = None
    """A version of the reference ladder (v1..v9, see presets.py); flags override it."""
    timesteps: int | None = None
    """Total environment steps (default: the preset's, else 5M)."""
    n_envs: int = 32
    """Parallel environments (reference: 8)."""
    n_steps: int = 128
    """Steps per environment per PPO rollout (reference: 1024)."""
    batch_size: int = 1024
    """PPO minibatch size (reference: 64)."""
    n_epochs: int = 10
    """PPO epochs per rollout."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    learning_rate: float = 1e-3
    """Adam learning rate (reference: 3e-4)."""
    clip_range: float = 0.2
    """PPO clipping parameter."""
    ent_coef: float = 0.0
    """Entropy bonus coefficient."""
    net_arch: tuple[int, ...] = (64, 64)
    """Hidden layer sizes of the policy and value MLPs."""
    log_std_init: float = -1.0
    """Initial log standard deviation of the Gaussian policy (reference and SB3: 0, std 1)."""
    seed: int = 42
    """Seeds Python, numpy, torch and the environments."""
    device: str = "cpu"
    """Torch device (a 64x64 MLP runs fastest on the CPU)."""
    torch_threads: int = 1
    """Torch threads of the training process. One: while the policy acts, the env workers need
    every other core, and idle torch threads spin on them (2 threads on 2 cores: 3-6x slower)."""
    env_kwargs: str = "{}"
    """JSON of env constructor arguments, applied over the preset's, e.g. '{"max_lead": 0.1}'."""
    vec_env: Literal["subproc", "batched", "dummy"] = "batched"
    """batched: all envs in one mujoco.batch.Batch in this process (vecenv.py); subproc: SB3
    SubprocVecEnv, a process per env (the reference configuration); dummy: a loop of single
    envs in this process."""
    n_workers: int = 0
    """MuJoCo threads stepping the batched envs (0: one per CPU core)."""
    eval_freq: int = 50_000
    """Evaluate on the fixed evaluation set every this many total steps (0: never)."""
    eval_steps: int = 500
    """Steps per evaluation episode (500 = 5 s, as the test rollouts)."""
    checkpoint_freq: int = 500_000
    """Save a checkpoint every this many total steps."""
    runs_dir: Path = Path("runs")
    """Where run folders are created."""
    name: str | None = None
    """Run name prefix (default: the preset, else 'lead')."""
    resume: Path | None = None
    """Continue a run folder from its newest checkpoint (or interrupted model)."""
    archive: str | None = None
    """At the end, copy the best model to archive/NAME.zip with its sidecar and test metrics."""
    stop_below_cm: float | None = None
    """Stop as soon as the evaluation-set mean error drops below this (time-to-quality runs)."""
    progress: bool = True
    """Show a progress bar."""
    reference_hparams: bool = False
    """Use the reference work's PPO settings (8 SubprocVecEnv envs, n_steps 1024, batch 64,
    lr 3e-4, log_std_init 0), overriding the flags above."""
    extra: dict = field(default_factory=dict)
    """(internal) extra fields recorded in config.json, e.g. by sweep.py."""


# The reference work's configuration (what `--reference-hparams` restores).
REFERENCE_HPARAMS = dict(n_envs=8, vec_env="subproc", n_steps=1024, batch_size=64, n_epochs=10,
                         learning_rate=3e-4, log_std_init=0.0)

PPO_KEYS = ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "learning_rate",
            "clip_range", "ent_coef")


def resolve_config(args: Args) -> dict:
    """Preset + flags -> one config dict: {env: {...}, ppo: {...}, timesteps, ...}."""
    from dataclasses import replace

    from presets import get_preset

    if args.reference_hparams:
        args = replace(args, **REFERENCE_HPARAMS)
    preset = get_preset(args.preset) if args.preset else {"env": {}, "ppo": {}}
    try:
        env_over = json.loads(args.env_kwargs)
    except json.JSONDecodeError as exc:
        raise ValueError(f"--env-kwargs is not valid JSON: {exc}") from None
    env_kwargs = {**preset["env"], **env_over}
    ppo = {k: getattr(args, k) for k in PPO_KEYS}
    defaults = Args()
    # A preset's PPO setting wins unless the flag was changed from its default.
    for k, v in preset.get("ppo", {}).items():
        if getattr(args, k) == getattr(defaults, k):
            ppo[k] = v
    timesteps = args.timesteps or preset.get("timesteps", 5_000_000)
    return dict(preset=args.preset, env=env_kwargs, ppo=ppo, net_arch=list(args.net_arch),
                log_std_init=args.log_std_init,
                timesteps=int(timesteps), n_envs=args.n_envs, seed=args.seed, device=args.device,
                vec_env=args.vec_env, n_workers=args.n_workers, eval_freq=args.eval_freq,
                eval_steps=args.eval_steps, stop_below_cm=args.stop_below_cm,
                checkpoint_freq=args.checkpoint_freq, torch_threads=args.torch_threads,
                **args.extra)


def seed_everything(seed: int) -> None:
    import torch

    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def make_vec_env(env_config: dict, n_envs: int, seed: int, kind: str = "batched",
                 n_workers: int = 0):
    """The training envs. batched: one `mujoco.batch.Batch` of n_envs arms in this process
    (vecenv.LeadVecEnv; n_workers = MuJoCo threads, 0 = all cores); subproc: SB3's
    SubprocVecEnv, a process per env (the reference configuration); dummy: a loop of single
    envs in this process."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    from env import EnvConfig

    if kind == "batched":
        from vecenv import LeadVecEnv

        vec = LeadVecEnv(EnvConfig.from_dict(env_config), n_envs, nthread=n_workers)
        vec.seed(seed)
        return VecMonitor(vec)

    def make(rank: int):
        def thunk():
            import signal

            import env  # noqa: F401  (registers PandaLead-v0 in the worker)

            if kind == "subproc":  # Ctrl-C is the main process's to handle (it saves the model)
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            e = gym.make("PandaLead-v0", max_episode_steps=-1, **env_config)
            # Each env its own stream, spawned from the training seed (as LeadVecEnv does).
            e.reset(seed=int(np.random.SeedSequence(seed).spawn(n_envs)[rank].generate_state(1)[0]))
            return e

        return thunk

    fns = [make(i) for i in range(n_envs)]
    vec = SubprocVecEnv(fns, start_method="forkserver") if kind == "subproc" else DummyVecEnv(fns)
    return VecMonitor(vec)


def evaluate(act_fn, env_kwargs: dict, steps: int, episodes=EVAL_SET) -> dict:
    """Deterministic episodes on (seed, shape) pairs, played as one batch -> tracking metrics
    in cm and reward."""
    from env import EnvConfig
    from rollout import record_many

    config = EnvConfig.from_dict(env_kwargs).replace(episode_steps=steps)
    seeds, shapes = zip(*episodes, strict=True)
    per_shape: dict[str, list] = {}
    returns = []
    for r in record_many(config, act_fn, seeds, shapes):
        err = r.error
        returns.append(r.meta["return"])
        # Grouped by the shape actually played (a None in `episodes` means drawn from the seed).
        per_shape.setdefault(r.meta["shape"], []).append((100 * err.mean(), 100 * (err < 0.05).mean()))
    out = {"mean_error_cm": float(np.mean([m for v in per_shape.values() for m, _ in v])),
           "in_band_pct": float(np.mean([b for v in per_shape.values() for _, b in v])),
           "mean_return": float(np.mean(returns))}
    for shape, vals in per_shape.items():
        out[f"{shape}/mean_error_cm"] = float(np.mean([m for m, _ in vals]))
        out[f"{shape}/in_band_pct"] = float(np.mean([b for _, b in vals]))
    return out


def _callbacks(run_dir: Path, config: dict, n_envs: int, on_eval=None):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

    from controllers import classical, make_analytic, make_policy
    from models import save_model

    class TrackingEval(BaseCallback):
        """Evaluates on the fixed evaluation set, logs cm figures, keeps the best model."""

        def __init__(self):
            super().__init__()
            self.best = float("inf")
            self.last_eval = 0

        def _on_training_start(self) -> None:
            self.last_eval = self.num_timesteps
            base = evaluate(classical, config["env"], config["eval_steps"])
            for k, v in base.items():
                self.logger.record(f"eval_classical/{k}", v)
            for k, v in evaluate(make_analytic(), config["env"], config["eval_steps"]).items():
                self.logger.record(f"eval_analytic/{k}", v)
            self.baseline = base
            best_file = run_dir / "best.json"
            if best_file.is_file():  # resuming: keep the best so far
                self.best = json.loads(best_file.read_text())["mean_error_cm"]

        def _on_step(self) -> bool:
            freq = config["eval_freq"]
            if freq and self.num_timesteps - self.last_eval >= freq:
                self.last_eval = self.num_timesteps
                res = self.run_eval()
                if on_eval is not None and on_eval(self.num_timesteps, res) is False:
                    return False  # e.g. an Optuna pruner said stop
                stop = config.get("stop_below_cm")
                if stop is not None and res["mean_error_cm"] < stop:
                    print(f"evaluation error {res['mean_error_cm']:.2f} cm < {stop} cm: stopping "
                          f"at {self.num_timesteps} steps, {time.time() - _START:.0f} s")
                    return False
            return True

        def run_eval(self) -> dict:
            res = evaluate(make_policy(self.model), config["env"], config["eval_steps"])
            for k, v in res.items():
                self.logger.record(f"eval/{k}", v)
            self.logger.record("eval/wall_time_s", time.time() - _START)
            self.logger.record("eval/timesteps", self.num_timesteps)
            self.logger.record("eval/improvement_over_classical_cm",
                               self.baseline["mean_error_cm"] - res["mean_error_cm"])
            if res["mean_error_cm"] < self.best:
                self.best = res["mean_error_cm"]
                save_model(self.model, run_dir / "best_model.zip",
                           sidecar_for(config, self.num_timesteps, eval_metrics=res))
                from models import write_json_atomic

                write_json_atomic(run_dir / "best.json",
                                  {"timesteps": self.num_timesteps, **res})
            self.logger.dump(self.num_timesteps)
            return res

    class AtomicCheckpoint(CheckpointCallback):
        """SB3's checkpoint schedule, but written atomically and with a sidecar, so a process
        killed mid-write never leaves a half zip that --resume would trust."""

        def _on_step(self) -> bool:
            if self.n_calls % self.save_freq == 0:
                path = Path(self._checkpoint_path(extension="zip"))
                save_model(self.model, path, sidecar_for(config, self.num_timesteps))
            return True

    ckpt = AtomicCheckpoint(save_freq=max(config["checkpoint_freq"] // n_envs, 1),
                            save_path=str(run_dir / "checkpoints"), name_prefix="model")
    return TrackingEval(), ckpt


_START = time.time()


def sidecar_for(config: dict, timesteps: int, **extra) -> dict:
    return {"env_config": config["env_resolved"], "train_config": config,
            "timesteps": int(timesteps), "wall_time_s": round(time.time() - _START, 1), **extra}


def newest_checkpoint(run_dir: Path) -> Path | None:
    """The saved model with the most timesteps, by its sidecar; files without one are skipped
    (every save writes the zip first and its sidecar last)."""
    import zipfile

    cands = list((run_dir / "checkpoints").glob("model_*_steps.zip"))
    cands += [run_dir / "interrupted_model.zip", run_dir / "final_model.zip"]
    best, best_steps = None, -1
    for p in cands:
        side = p.with_suffix(".json")
        if p.is_file() and side.is_file() and zipfile.is_zipfile(p):
            steps = json.loads(side.read_text()).get("timesteps", -1)
            if steps > best_steps:
                best, best_steps = p, steps
    return best


def archive_model(run_dir: Path, name: str, config: dict) -> Path:
    """Copy the run's best (else final) model to archive/NAME.zip, adding test-set metrics."""
    from stable_baselines3 import PPO

    from controllers import make_policy
    from models import ARCHIVE_DIR, read_sidecar, save_model
    from seeds import TEST_SEEDS

    src = run_dir / "best_model.zip"
    if not src.is_file():
        src = run_dir / "final_model.zip"
    side = read_sidecar(src)
    model = PPO.load(src, device="cpu")
    test = evaluate(make_policy(model), side["env_config"], 500,
                    episodes=[(s, None) for s in TEST_SEEDS])
    side = {**side, "test_metrics": test, "source": str(src), "name": name}
    return save_model(model, ARCHIVE_DIR / f"{name}.zip", side)


def train(args: Args, on_eval=None) -> Path:
    """Run (or resume) one training run; returns its folder. ``on_eval(timesteps, metrics)`` is
    called after each evaluation and may return False to stop the run (sweep.py's pruner)."""
    global _START
    _START = time.time()
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    import env as env_mod
    from models import save_model, write_json_atomic

    if args.resume:
        run_dir = Path(args.resume)
        if not (run_dir / "config.json").is_file():
            raise ValueError(f"--resume {run_dir}: not a run folder (no config.json)")
        config = json.loads((run_dir / "config.json").read_text())
        if args.timesteps:
            config["timesteps"] = int(args.timesteps)
    else:
        config = resolve_config(args)
        # Validates the settings before any work; the sidecar stores every field.
        config["env_resolved"] = env_mod.EnvConfig.from_dict(config["env"]).to_dict()
        stem = args.name or args.preset or "lead"
        run_dir = args.runs_dir / f"{stem}__{args.seed}__{int(time.time())}"
        run_dir.mkdir(parents=True, exist_ok=False)
        write_json_atomic(run_dir / "config.json", config)
        (run_dir / "command.txt").write_text(shlex.join([sys.executable, *sys.argv]) + "\n")

    seed_everything(config["seed"])
    import torch

    torch.set_num_threads(config.get("torch_threads", 1))  # runs from before the flag: 1
    vec = make_vec_env(config["env"], config["n_envs"], config["seed"], config["vec_env"],
                       config.get("n_workers", 0))
    logger = configure(str(run_dir / "tb"), ["tensorboard", "csv"])
    ckpt = newest_checkpoint(run_dir) if args.resume else None
    if args.resume and ckpt is None:
        raise ValueError(f"--resume {run_dir}: no checkpoint or saved model to resume from")
    if ckpt:
        model = PPO.load(ckpt, env=vec, device=config["device"])
        print(f"resuming {run_dir} from {ckpt.name} at {model.num_timesteps} steps")
    else:
        import torch

        model = PPO("MlpPolicy", vec, seed=config["seed"], device=config["device"], verbose=0,
                    policy_kwargs=dict(net_arch=config["net_arch"], activation_fn=torch.nn.Tanh,
                                       log_std_init=config.get("log_std_init", 0.0)),
                    **config["ppo"])
        table = "|param|value|\n|-|-|\n" + "\n".join(
            f"|{k}|{v}|" for k, v in config["ppo"].items())
        # A str value goes to TensorBoard's text tab as a table.
        logger.record("hyperparameters", table, exclude=("stdout", "csv"))
    model.set_logger(logger)
    tracker, checkpoint = _callbacks(run_dir, config, config["n_envs"], on_eval)
    remaining = config["timesteps"] - model.num_timesteps
    try:
        if remaining > 0:
            model.learn(remaining, callback=[tracker, checkpoint], progress_bar=args.progress,
                        reset_num_timesteps=not ckpt, tb_log_name="tb")
            if config["eval_freq"]:
                tracker.run_eval()
    except KeyboardInterrupt:
        path = save_model(model, run_dir / "interrupted_model.zip",
                          sidecar_for(config, model.num_timesteps))
        print(f"\ninterrupted at {model.num_timesteps} steps; saved {path}\n"
              f"resume with: uv run train.py --resume {run_dir}")
        vec.close()
        raise SystemExit(130) from None
    save_model(model, run_dir / "final_model.zip", sidecar_for(config, model.num_timesteps))
    vec.close()
    print(f"run folder: {run_dir}")
    if args.archive:
        path = archive_model(run_dir, args.archive, config)
        print(f"archived: {path} (+ {path.with_suffix('.json').name})")
    return run_dir
