"""Training library behind `uv run train.py`: the typed config, presets, vec envs, callbacks,
the loop, archiving.

One folder per run under runs/: config.json (the resolved `TrainConfig`), command.txt, tb/
(TensorBoard, progress.csv), checkpoints/, best_model.zip (lowest evaluation-set tracking
error) and final_model.zip, each model with its sidecar. Ctrl-C or SIGTERM saves the model and
prints how to resume.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import re
import shlex
import shutil
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .config import EnvConfig
from .errors import UserError, did_you_mean
from .models import OBS_12, OBS_15, OBS_29
from .seeds import EVAL_SET


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides what a training run learns. config.json and every sidecar store
    it whole; presets are values of it."""

    env: EnvConfig = EnvConfig()
    """The env's settings (see env.EnvConfig), e.g. --env.max-lead 0.1."""
    timesteps: int = 5_000_000
    """Total environment steps (PPO collects whole rollouts of n_steps x n_envs, so a run ends
    at the next multiple; train.py says so)."""
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
    """Hidden layer sizes of the policy and value MLPs (tanh)."""
    log_std_init: float = -1.0
    """Initial log standard deviation of the Gaussian policy (reference and SB3: 0, std 1)."""
    seed: int = 42
    """Seeds Python, numpy, torch and the environments' streams."""
    device: str = "cpu"
    """Torch device (a 64x64 MLP runs fastest on the CPU)."""
    torch_threads: int = 1
    """Torch threads of the training process. One: while the policy acts, the env workers need
    every other core, and idle torch threads spin on them (2 threads on 2 cores: 3-6x slower)."""
    vec_env: Literal["batched", "subproc", "dummy"] = "batched"
    """batched: all envs in one mujoco.batch.Batch in this process (sb3_vecenv.py); subproc: SB3
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
    stop_below_cm: float | None = None
    """Stop as soon as the evaluation-set mean error drops below this (time-to-quality runs)."""
    curriculum_steps: int = 500_000
    """Speed curriculum: over this many steps the training targets' peak-speed cap rises
    linearly from --curriculum-start-speed to none (0: no curriculum). On by default: it
    reaches the time-to-quality threshold in half the steps (docs/performance.md) and ends as
    well (docs/questions.md 5); the presets, the reference ladder, run without it."""
    curriculum_start_speed: float = 0.8
    """Peak-speed cap (m/s) of the training targets at step 0 of a curriculum."""
    preset: str | None = None
    """Start from a preset (see the list above); every flag given overrides it."""

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        if isinstance(self.env, dict):
            set_("env", EnvConfig.from_dict(self.env))
        if not isinstance(self.env, EnvConfig):
            raise UserError(f"env must be an EnvConfig, got {type(self.env).__name__}")
        set_("net_arch", tuple(self.net_arch))
        for name, low in (("timesteps", 1), ("n_envs", 1), ("n_steps", 1), ("batch_size", 2),
                          ("n_epochs", 1), ("torch_threads", 1), ("n_workers", 0),
                          ("eval_freq", 0), ("eval_steps", 1), ("checkpoint_freq", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise UserError(f"--{_flag(name)} must be an integer >= {low}, got {v!r}")
        if self.n_steps * self.n_envs < 2:
            raise UserError("a PPO rollout needs at least 2 steps: raise --n-steps or --n-envs")
        for name, lo, hi, lo_open in (("gamma", 0, 1, True), ("gae_lambda", 0, 1, False),
                                      ("learning_rate", 0, math.inf, True),
                                      ("clip_range", 0, math.inf, True),
                                      ("ent_coef", 0, math.inf, False),
                                      ("log_std_init", -math.inf, math.inf, False)):
            v = getattr(self, name)
            ok = isinstance(v, int | float) and math.isfinite(v) and v <= hi and (
                v > lo if lo_open else v >= lo)
            if not ok:
                rng = f"in ({lo}, {hi}]" if hi < math.inf else (">" if lo_open else ">=") + f" {lo}"
                raise UserError(f"--{_flag(name)} must be a finite number {rng}, got {v!r}"
                                if math.isfinite(lo) else f"--{_flag(name)} must be finite, got {v!r}")
            set_(name, float(v))
        if not self.net_arch or any(isinstance(n, bool) or not isinstance(n, int) or n < 1
                                    for n in self.net_arch):
            raise UserError(f"--net-arch must be positive layer sizes, got {self.net_arch!r}")
        if self.stop_below_cm is not None and not (math.isfinite(self.stop_below_cm)
                                                   and self.stop_below_cm > 0):
            raise UserError(f"--stop-below-cm must be > 0, got {self.stop_below_cm!r}")
        if isinstance(self.curriculum_steps, bool) or not isinstance(self.curriculum_steps, int) \
                or self.curriculum_steps < 0:
            raise UserError(f"--curriculum-steps must be an integer >= 0, got {self.curriculum_steps!r}")
        if not (math.isfinite(self.curriculum_start_speed) and self.curriculum_start_speed > 0.25):
            raise UserError("--curriculum-start-speed must be above 0.25 m/s, got "
                            f"{self.curriculum_start_speed!r}")
        if self.preset is not None and self.preset not in PRESET_DOCS:
            raise UserError(f"unknown preset {self.preset!r}" + did_you_mean(self.preset, PRESET_DOCS))

    def to_dict(self) -> dict:
        """JSON-friendly, whole: what config.json and sidecars hold."""
        d = asdict(self)
        d["env"] = self.env.to_dict()
        d["net_arch"] = list(self.net_arch)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        """From config.json; also reads the format before TrainConfig (ppo sub-dict, env
        kwargs plus env_resolved)."""
        d = dict(d)
        if "ppo" in d:  # the older layout
            d.update(d.pop("ppo"))
            d["env"] = d.pop("env_resolved", None) or d.get("env", {})
        # Configs written before the curriculum existed trained without one.
        d.setdefault("curriculum_steps", 0)
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


def _flag(name: str) -> str:
    return name.replace("_", "-")


@dataclass(frozen=True)
class TrainArgs(TrainConfig):
    """train.py's command line: the training config plus where the run goes and what happens
    around it."""

    reference_hparams: bool = False
    """Start from the reference work's PPO settings (8 SubprocVecEnv envs, n_steps 1024,
    batch 64, lr 3e-4, log_std_init 0); flags given still override them."""
    runs_dir: Path = Path("runs")
    """Where run folders are created."""
    name: str | None = None
    """Run name prefix (default: the preset, else 'lead')."""
    resume: Path | None = None
    """Continue a run folder from its newest valid checkpoint (or interrupted model); only the
    run-time flags (--timesteps, --eval-freq, --checkpoint-freq, ...) may change."""
    archive: str | None = None
    """At the end, copy the best model to archive/NAME.zip with its sidecar, test metrics and a
    model card (archive/NAME.md)."""
    force: bool = False
    """Replace an existing archive/NAME.zip."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self):
        super().__post_init__()
        for flag, value in (("--name", self.name), ("--archive", self.archive)):
            if value is not None:
                check_plain_name(value, flag)

    def config(self) -> TrainConfig:
        return TrainConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(TrainConfig)})


def check_plain_name(value: str, flag: str) -> str:
    """A file or folder name without separators or dots at the start (no ../, no /abs)."""
    if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*", value or ""):
        raise UserError(f"{flag} must be a plain name (letters, digits, _ . + -, not starting "
                        f"with a dot), got {value!r}")
    return value


# The reference work's configuration (what `--reference-hparams` starts from).
REFERENCE_HPARAMS = dict(n_envs=8, vec_env="subproc", n_steps=1024, batch_size=64, n_epochs=10,
                         learning_rate=3e-4, log_std_init=0.0, curriculum_steps=0)

# Penetration is millimetres deep, so the weight is large: 1 cm deep costs 1 per step, about
# ten times the distance term at a typical 10 cm error.
COLLISION_WEIGHT = 100.0


def _preset(name: str, doc: str, **kw) -> tuple[str, TrainConfig]:
    env = EnvConfig(**kw.pop("env", {}))
    PRESET_DOCS[name] = doc
    kw.setdefault("curriculum_steps", 0)  # the ladder as the reference trained it
    return name, TrainConfig(env=env, preset=name, **kw)


# The reference work's ladder of versions (v1..v9), plus this repo's own `smooth`.
PRESET_DOCS: dict[str, str] = {}
PRESETS: dict[str, TrainConfig] = {}
PRESETS.update([
    _preset("v1", "circles only, 12-D observation (no target_acc)",
            env=dict(obs_features=OBS_12, shapes=("circle",)), timesteps=1_000_000),
    _preset("v2", "all shapes + self-collision penalty",
            env=dict(obs_features=OBS_12, w_collision=COLLISION_WEIGHT)),
    _preset("v3", "v2 without the collision penalty", env=dict(obs_features=OBS_12)),
    _preset("v4", "v3 + entropy bonus ent_coef 0.01", env=dict(obs_features=OBS_12),
            ent_coef=0.01),
    _preset("v5", "v3 + target_acc in the observation (15-D)", env=dict(obs_features=OBS_15)),
    _preset("v6", "v5 + joint angles and velocities (29-D) + early termination on "
            "self-collision", env=dict(obs_features=OBS_29, terminate_on_collision=True)),
    # The termination penalty (50) outweighs what the rest of an episode can still earn (at
    # most ~1 per step from the tracking term, minus the distance), so ending early never pays.
    _preset("v7", "v6 + exponential tracking reward + termination penalty",
            env=dict(obs_features=OBS_29, terminate_on_collision=True, w_tracking=1.0,
                     w_alive=0.0, w_termination=50.0)),
    _preset("v9", "v5 + action-change penalty (weight 0.1) + 5 s episodes",
            env=dict(obs_features=OBS_15, w_action_change=0.1, episode_steps=500)),
    # The policy sees its previous action, so the action-change penalty is a Markov cost it
    # can plan against; the penalty keeps the lead smooth (jerk), the collision term keeps the
    # arm out of itself.
    _preset("smooth", "v5 + prev_action observed + action-change penalty 0.5 + collision "
            "penalty + 5 s episodes (this repo's own)",
            env=dict(obs_features=OBS_15 + ("prev_action",), w_action_change=0.5,
                     w_collision=COLLISION_WEIGHT, episode_steps=500)),
    # The reference author's wish to replace IK: the same task and observation as v5, but the
    # action moves the IK's joint goal (7-D, 0.2 rad per joint at +-1) instead of its target.
    _preset("joint", "v5 with a 7-D joint-goal residual instead of the Cartesian lead",
            env=dict(obs_features=OBS_15, action="joint")),
])


def get_preset(name: str) -> TrainConfig:
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r}" + did_you_mean(name, PRESETS))
    return PRESETS[name]


def preset_table() -> str:
    return "\n".join(f"  {k:7s} {v}" for k, v in PRESET_DOCS.items())


# Run-time settings --resume may change; the rest must stay what the run was trained with.
RESUME_MAY_CHANGE = ("timesteps", "eval_freq", "eval_steps", "checkpoint_freq", "stop_below_cm",
                     "device", "torch_threads", "n_workers")


def parse_args(argv: list[str], prog: str | None = None, description: str | None = None
               ) -> TrainArgs:
    """The command line -> TrainArgs. ``--preset NAME`` (or ``--resume RUN``: the run's
    config) and ``--reference-hparams`` choose the defaults; every flag given overrides them,
    even when it equals the plain default. ``--preset v5 --help`` shows v5's values."""
    import tyro

    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--preset")
    pre.add_argument("--resume")
    pre.add_argument("--reference-hparams", action="store_true")
    known, _ = pre.parse_known_args(argv)
    if known.resume:
        base = read_run_config(Path(known.resume))
    elif known.preset:
        base = get_preset(known.preset)
    else:
        base = TrainConfig()
    if known.reference_hparams:
        base = dataclasses.replace(base, **REFERENCE_HPARAMS)
    default = TrainArgs(**{f.name: getattr(base, f.name) for f in dataclasses.fields(TrainConfig)},
                        reference_hparams=known.reference_hparams)
    args = tyro.cli(TrainArgs, args=argv, default=default, prog=prog, description=description)
    if known.resume:
        changed = [f.name for f in dataclasses.fields(TrainConfig)
                   if f.name not in RESUME_MAY_CHANGE and getattr(args, f.name) != getattr(base, f.name)]
        if changed:
            raise UserError(f"--resume continues the run with its own config; "
                            f"{', '.join('--' + _flag(c) for c in changed)} cannot change "
                            "(start a new run instead)")
    return args


def read_run_config(run_dir: Path) -> TrainConfig:
    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise UserError(f"--resume {run_dir}: not a run folder (no config.json)")
    try:
        return TrainConfig.from_dict(json.loads(path.read_text()))
    except (OSError, json.JSONDecodeError, TypeError) as exc:
        raise UserError(f"{path}: unreadable run config ({exc})") from None


def make_vec_env(env_config: EnvConfig | dict, n_envs: int, seed: int, kind: str = "batched",
                 n_workers: int = 0):
    """The training envs. batched: one `mujoco.batch.Batch` of n_envs arms in this process
    (sb3_vecenv.LeadVecEnv; n_workers = MuJoCo threads, 0 = all cores); subproc: SB3's
    SubprocVecEnv, a process per env (the reference configuration); dummy: a loop of single
    envs in this process."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    config = env_config if isinstance(env_config, EnvConfig) else EnvConfig.from_dict(env_config)
    if kind == "batched":
        from .sb3_vecenv import LeadVecEnv

        vec = LeadVecEnv(config, n_envs, nthread=n_workers)
        vec.seed(seed)
        return VecMonitor(vec)
    settings = config.to_dict()

    def make(rank: int):
        def thunk():
            import panda_lead  # noqa: F401  (registers PandaLead-v0 in the worker)

            if kind == "subproc":  # signals are the main process's to handle (it saves the model)
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                signal.signal(signal.SIGTERM, signal.SIG_IGN)
            e = gym.make("PandaLead-v0", max_episode_steps=-1, **settings)
            # Each env its own stream, spawned from the training seed (as LeadVecEnv does).
            e.reset(seed=int(np.random.SeedSequence(seed).spawn(n_envs)[rank].generate_state(1)[0]))
            return e

        return thunk

    fns = [make(i) for i in range(n_envs)]
    vec = SubprocVecEnv(fns, start_method="forkserver") if kind == "subproc" else DummyVecEnv(fns)
    return VecMonitor(vec)


def evaluate(act_fn, env_kwargs: EnvConfig | dict, steps: int, episodes=EVAL_SET) -> dict:
    """Deterministic episodes on (seed, shape) pairs, played as one batch -> tracking metrics
    in cm and reward."""
    from .rollout import record_many

    base = env_kwargs if isinstance(env_kwargs, EnvConfig) else EnvConfig.from_dict(env_kwargs)
    config = base.replace(episode_steps=steps)
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


_START = time.time()


def sidecar_for(config: TrainConfig, timesteps: int, **extra) -> dict:
    return {"env_config": config.env.to_dict(), "train_config": config.to_dict(),
            "timesteps": int(timesteps), "wall_time_s": round(time.time() - _START, 1), **extra}


def _say(text: str) -> None:
    """Print a line without tearing the progress bar."""
    from tqdm.auto import tqdm

    tqdm.write(text)
    sys.stdout.flush()


def _callbacks(run_dir: Path, config: TrainConfig, on_eval=None, total: int = 0,
               progress: bool = False, signals=None):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

    from .controllers import classical, make_analytic, make_policy
    from .models import save_model, write_json_atomic

    class TrackingEval(BaseCallback):
        """Evaluates on the fixed evaluation set, logs cm figures beside the two baselines,
        prints one line per evaluation, keeps the best model."""

        def __init__(self):
            super().__init__()
            self.best = float("inf")
            self.best_step = None
            self.last_eval = 0
            self.baselines: dict[str, dict] = {}

        def _on_training_start(self) -> None:
            self.last_eval = self.num_timesteps
            if not config.eval_freq:
                return
            self.baselines = {
                "classical": evaluate(classical, config.env, config.eval_steps),
                # The analytic lead is a Cartesian lead: a joint-residual run compares with it
                # on the same task with the lead action (zero action is the same controller).
                "analytic": evaluate(make_analytic(), config.env.replace(action="lead"),
                                     config.eval_steps)}
            best_file = run_dir / "best.json"
            if best_file.is_file():  # resuming: keep the best so far
                best = json.loads(best_file.read_text())
                self.best, self.best_step = best["mean_error_cm"], best.get("timesteps")

        def _on_step(self) -> bool:
            freq = config.eval_freq
            if freq and self.num_timesteps - self.last_eval >= freq:
                res = self.run_eval()
                if on_eval is not None and on_eval(self.num_timesteps, res) is False:
                    return False  # e.g. an Optuna pruner said stop
                stop = config.stop_below_cm
                if stop is not None and res["mean_error_cm"] < stop:
                    _say(f"evaluation error {res['mean_error_cm']:.2f} cm < {stop} cm: stopping "
                         f"at {self.num_timesteps} steps, {time.time() - _START:.0f} s")
                    return False
            return True

        def run_eval(self) -> dict:
            self.last_eval = self.num_timesteps
            res = evaluate(make_policy(self.model), config.env, config.eval_steps)
            for k, v in res.items():
                self.logger.record(f"eval/{k}", v)
            # The baselines at every evaluation step, so they draw as lines across the run.
            for name, base in self.baselines.items():
                for k, v in base.items():
                    self.logger.record(f"eval_{name}/{k}", v)
            self.logger.record("eval/wall_time_s", time.time() - _START)
            self.logger.record("eval/timesteps", self.num_timesteps)
            classical_cm = self.baselines["classical"]["mean_error_cm"]
            self.logger.record("eval/improvement_over_classical_cm",
                               classical_cm - res["mean_error_cm"])
            new_best = res["mean_error_cm"] < self.best
            if new_best:
                self.best, self.best_step = res["mean_error_cm"], self.num_timesteps
                save_model(self.model, run_dir / "best_model.zip",
                           sidecar_for(config, self.num_timesteps, eval_metrics=res))
                write_json_atomic(run_dir / "best.json", {"timesteps": self.num_timesteps, **res})
            self.logger.dump(self.num_timesteps)
            a = self.baselines["analytic"]
            _say(f"step {self.num_timesteps:>10,}  error {res['mean_error_cm']:5.2f} cm  "
                 f"in 5 cm band {res['in_band_pct']:5.1f}%   (classical {classical_cm:.2f} cm / "
                 f"{self.baselines['classical']['in_band_pct']:.1f}%, analytic "
                 f"{a['mean_error_cm']:.2f} cm / {a['in_band_pct']:.1f}%)"
                 + ("  best" if new_best else ""))
            return res

    class AtomicCheckpoint(CheckpointCallback):
        """SB3's checkpoint schedule, but written atomically and with a sidecar, so a process
        killed mid-write never leaves a half zip that --resume would trust."""

        def _on_step(self) -> bool:
            if self.n_calls % self.save_freq == 0:
                path = Path(self._checkpoint_path(extension="zip"))
                save_model(self.model, path, sidecar_for(config, self.num_timesteps))
            return True

    class Progress(BaseCallback):
        """A progress bar whose total is the number of steps the run will really do, and the
        signal check: after SIGINT/SIGTERM, learn() stops at the next step."""

        def _on_training_start(self) -> None:
            self.bar = None
            if progress:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=total, unit="step", unit_scale=True, dynamic_ncols=True)

        def _on_step(self) -> bool:
            if self.bar is not None:
                self.bar.update(min(self.training_env.num_envs, total - self.bar.n))
            return signals is None or signals.received is None

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()

    ckpt = AtomicCheckpoint(save_freq=max(config.checkpoint_freq // config.n_envs, 1),
                            save_path=str(run_dir / "checkpoints"), name_prefix="model")
    return TrackingEval(), ckpt, Progress()


def speed_cap(step: int, start: float, steps: int) -> float | None:
    """The curriculum's peak-speed cap at a training step: linear from start to the fastest
    trajectory (trajectory.MAX_SPEED), then none."""
    from . import trajectory

    if step >= steps:
        return None
    return start + (trajectory.MAX_SPEED - start) * step / steps


def SpeedCurriculum(vec, start: float, steps: int):  # noqa: N802 (a callback factory)
    """An SB3 callback that sets the envs' speed cap before each rollout, through SB3's
    env_method (the batched env, SubprocVecEnv and DummyVecEnv all take it)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Curriculum(BaseCallback):
        def _on_rollout_start(self) -> None:
            cap = speed_cap(self.num_timesteps, start, steps)
            vec.env_method("set_speed_cap", cap)
            self.logger.record("train/speed_cap", cap or 0.0)

        def _on_step(self) -> bool:
            return True

    return _Curriculum()


class _Signals:
    """SIGINT and SIGTERM set a flag that makes learn() stop at the next step (the model is
    then saved); a second signal raises KeyboardInterrupt at once. Only in the main thread."""

    def __init__(self):
        self.received: int | None = None
        self._old: dict = {}

    def _handle(self, signum, frame):
        if self.received is not None:
            raise KeyboardInterrupt
        self.received = signum
        print(f"\n{signal.Signals(signum).name}: stopping at the next step and saving "
              "(again to stop at once)", file=sys.stderr, flush=True)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)


def newest_checkpoint(run_dir: Path) -> tuple[Path, dict] | None:
    """The valid saved model with the most timesteps: its zip must match the SHA-256 in its
    sidecar. A damaged or half-written newest file is reported and skipped, so resuming falls
    back to the one before."""
    from .models import ModelError, verify

    cands = list((run_dir / "checkpoints").glob("model_*_steps.zip"))
    cands += [run_dir / "interrupted_model.zip", run_dir / "final_model.zip"]
    found = []
    for p in cands:
        if not p.is_file():
            continue
        try:
            side = verify(p)
        except ModelError as exc:
            print(f"skipping {p}: {exc}", file=sys.stderr)
            continue
        found.append((int(side.get("timesteps", -1)), p, side))
    if not found:
        return None
    _, p, side = max(found, key=lambda t: t[0])
    return p, side


class _AppendingCSV:
    """SB3's CSV writer, continuing an existing progress.csv instead of truncating it."""

    def __new__(cls, filename: Path):
        from stable_baselines3.common.logger import CSVOutputFormat

        old = Path(filename).read_text() if Path(filename).is_file() else ""
        out = CSVOutputFormat(str(filename))  # opens with "w+": truncates
        if old.strip():
            out.file.write(old if old.endswith("\n") else old + "\n")
            out.file.flush()
            out.keys = old.splitlines()[0].split(",")
        return out


def make_logger(folder: Path):
    from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat

    folder.mkdir(parents=True, exist_ok=True)
    tb = TensorBoardOutputFormat(str(folder))
    # One chart with the policy and both baselines (TensorBoard's "Custom Scalars" tab).
    tb.writer.add_custom_scalars({"tracking": {
        "mean error (cm)": ["Multiline", ["eval/mean_error_cm", "eval_classical/mean_error_cm",
                                          "eval_analytic/mean_error_cm"]],
        "time in 5 cm band (%)": ["Multiline", ["eval/in_band_pct", "eval_classical/in_band_pct",
                                                "eval_analytic/in_band_pct"]]}})
    return Logger(str(folder), [tb, _AppendingCSV(folder / "progress.csv")])


def archive_path(name: str) -> Path:
    from .models import ARCHIVE_DIR

    return ARCHIVE_DIR / f"{check_plain_name(name, '--archive')}.zip"


def _check_archive_free(name: str, force: bool) -> None:
    path = archive_path(name)
    if path.exists() and not force:
        raise UserError(f"{path} exists; choose another --archive name, or add --force to "
                        "replace it")


def archive_model(run_dir: Path, name: str, config=None, force: bool = False) -> Path:
    """Copy the run's best (else final) model to archive/NAME.zip, byte for byte, with a sidecar
    holding test-set metrics and a model card archive/NAME.md. Refuses to replace an existing
    archived model unless ``force``. (``config`` is unused: the source's sidecar says it.)"""
    from .controllers import make_policy
    from .models import file_sha256, load_policy, write_json_atomic
    from .seeds import QUICK_TEST_SEEDS as TEST_SEEDS

    _check_archive_free(name, force)
    src = run_dir / "best_model.zip"
    if not src.is_file():
        src = run_dir / "final_model.zip"
    policy, env_config, side = load_policy(src)
    test = evaluate(make_policy(policy), env_config, 500, episodes=[(s, None) for s in TEST_SEEDS])
    seed0 = card_number(policy, env_config)
    dst = archive_path(name)
    from .atomicio import atomic_write

    with atomic_write(dst, ".tmp.zip") as tmp:
        shutil.copyfile(src, tmp)
    side = {**side, "test_metrics": test, "test_seed0_mean_error_cm": seed0, "source": str(src),
            "name": name, "model_sha256": file_sha256(dst)}
    write_json_atomic(dst.with_suffix(".json"), side)
    write_card(dst, side)
    return dst


def card_number(policy, env_config: dict) -> float:
    """Mean tracking error (cm) on test seed 0, 5 s: the number the model card reproduces."""
    from .controllers import make_policy
    from .rollout import record_many

    r = record_many(EnvConfig.from_dict(env_config).replace(episode_steps=500),
                    make_policy(policy), [0])[0]
    return float(100 * r.error.mean())


CARD_SNIPPET = '''\
import gymnasium as gym
import numpy as np

import panda_lead  # noqa: F401  (registers PandaLead-v0)
from panda_lead.models import load_policy

policy, env_config, sidecar = load_policy("{zip}")  # weights only: never unpickles
e = gym.make("PandaLead-v0", **{{**env_config, "episode_steps": 500}}, max_episode_steps=500)
obs, _ = e.reset(seed=0, options={{"traj_seed": 0}})
errors, done = [], False
while not done:
    action, _ = policy.predict(obs, deterministic=True)
    obs, reward, terminated, truncated, info = e.step(action)
    errors.append(info["distance"])
    done = terminated or truncated
print(f"test seed 0: mean error {{100 * np.mean(errors):.6f}} cm")  # card: {seed0:.6f} cm
'''


def write_card(zip_path: Path, side: dict) -> Path:
    """archive/NAME.md: what the model is, its config, its test results, how to load it."""
    from .seeds import QUICK_TEST_SEEDS as TEST_SEEDS

    name = zip_path.stem
    train = side.get("train_config", {})
    test = side.get("test_metrics", {})
    env_rows = "\n".join(f"| {k} | {v} |" for k, v in sorted(side["env_config"].items()))
    train_rows = "\n".join(f"| {k} | {v} |" for k, v in sorted(train.items()) if k != "env")
    shape_rows = "\n".join(
        f"| {s} | {test[f'{s}/mean_error_cm']:.2f} | {test[f'{s}/in_band_pct']:.1f} |"
        for s in ("circle", "fig8", "fly") if f"{s}/mean_error_cm" in test)
    preset = train.get("preset")
    from_preset = f" from preset `{preset}`" if preset else ""
    text = f"""# Model card: {name}

A PPO policy (stable-baselines3, MLP {train.get('net_arch', '?')}) that outputs a Cartesian
lead added to the IK target of a classical IK+PD Franka Panda controller (`PandaLead-v0`).
Trained {side.get('timesteps', '?'):,} steps{from_preset}, seed {train.get('seed', '?')}, \
{side.get('wall_time_s', '?')} s, code commit `{side.get('commit', '?')}`.
Files: `{name}.zip` (SB3 format), `{name}.json` (sidecar: the full env and training config and
`model_sha256`, the zip's SHA-256), this card.

## Test results (seeds {TEST_SEEDS[0]}-{TEST_SEEDS[-1]}, 5 s episodes, shape drawn from the seed)

| set | mean error (cm) | time in 5 cm band (%) |
|---|---|---|
| all | {test.get('mean_error_cm', float('nan')):.2f} | {test.get('in_band_pct', float('nan')):.1f} |
{shape_rows}

Test seed 0 alone: {side['test_seed0_mean_error_cm']:.6f} cm (the snippet below reproduces it).

## Load it

Run from the repository root. `PPO.load` would unpickle objects stored in the zip (running any
code a tampered file carries); `models.load_policy` rebuilds the policy from the sidecar and
reads only tensors (`torch.load(weights_only=True)`), after checking the zip's SHA-256.

```python
{CARD_SNIPPET.format(zip=zip_path.as_posix(), seed0=side['test_seed0_mean_error_cm'])}```

## Env config

| setting | value |
|---|---|
{env_rows}

## Training config

| setting | value |
|---|---|
{train_rows}
"""
    from .atomicio import atomic_write

    out = zip_path.with_suffix(".md")
    with atomic_write(out, ".tmp.md") as tmp:
        Path(tmp).write_text(text)
    return out


def _check_device(device: str, torch) -> None:
    """A CUDA device that is not there is a clear error (SB3 would quietly use the CPU)."""
    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError):
        raise UserError(f"--device {device!r} is not a torch device (e.g. cpu, cuda, cuda:1)") from None
    if kind == "cuda" and not torch.cuda.is_available():
        raise UserError(f"--device {device}: no CUDA GPU is available to torch here; use --device cpu")


def train(args: TrainArgs, on_eval=None, extra: dict | None = None) -> Path:
    """Run (or resume) one training run; returns its folder. ``args`` as `parse_args` makes
    them (the preset already applied). ``on_eval(timesteps, metrics)`` is called after each
    evaluation and may return False to stop the run (sweep.py's pruner); ``extra`` is recorded
    in config.json (e.g. sweep.py's trial)."""
    global _START
    _START = time.time()
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.utils import set_random_seed

    from .models import load_training_state, save_model, write_json_atomic

    if args.archive:
        _check_archive_free(args.archive, args.force)  # before hours of training, not after
    _check_device(args.device, torch)
    if args.resume:
        run_dir = Path(args.resume)
        config = args.config()
        found = newest_checkpoint(run_dir)
        if found is None:
            raise UserError(f"--resume {run_dir}: no valid checkpoint or saved model to resume from")
        ckpt, ckpt_side = found
    else:
        config = args.config()
        stem = args.name or args.preset or "lead"
        run_dir = args.runs_dir / f"{stem}__{args.seed}__{int(time.time())}"
        run_dir.mkdir(parents=True, exist_ok=False)
        write_json_atomic(run_dir / "config.json",
                          {**config.to_dict(), **({"extra": extra} if extra else {})})
        (run_dir / "command.txt").write_text(shlex.join([sys.executable, *sys.argv]) + "\n")
        ckpt = ckpt_side = None
    print(f"run folder: {run_dir}", flush=True)

    set_random_seed(config.seed)
    torch.set_num_threads(config.torch_threads)
    vec = make_vec_env(config.env, config.n_envs, config.seed, config.vec_env, config.n_workers)
    logger = make_logger(run_dir / "tb")
    ppo = {k: getattr(config, k) for k in ("n_steps", "batch_size", "n_epochs", "gamma",
                                           "gae_lambda", "learning_rate", "clip_range", "ent_coef")}
    model = PPO("MlpPolicy", vec, seed=config.seed, device=config.device, verbose=0,
                policy_kwargs=dict(net_arch=list(config.net_arch), activation_fn=torch.nn.Tanh,
                                   log_std_init=config.log_std_init), **ppo)
    if ckpt is not None:
        load_training_state(model, ckpt)  # tensors only, never PPO.load (see models.py)
        model.num_timesteps = int(ckpt_side["timesteps"])
        # Fresh training streams for the rest of the run (not a replay of its first episodes).
        vec.seed(int(np.random.SeedSequence([config.seed, model.num_timesteps]).generate_state(1)[0]))
        print(f"resuming {run_dir} from {ckpt.name} at {model.num_timesteps} steps")
    else:
        table = "|param|value|\n|-|-|\n" + "\n".join(
            f"|{k}|{v}|" for k, v in config.to_dict().items())
        # A str value goes to TensorBoard's text tab as a table.
        logger.record("hyperparameters", table, exclude=("stdout", "csv"))
    model.set_logger(logger)
    remaining = config.timesteps - model.num_timesteps
    per_rollout = config.n_steps * config.n_envs
    real = math.ceil(max(remaining, 0) / per_rollout) * per_rollout
    if remaining > 0 and real != remaining:
        print(f"note: PPO collects whole rollouts of {config.n_steps} x {config.n_envs} = "
              f"{per_rollout:,} steps, so this run ends at {model.num_timesteps + real:,} steps "
              f"(asked: {config.timesteps:,})")
    if config.curriculum_steps > model.num_timesteps:
        print(f"note: speed curriculum: the training targets' peak speed is capped at "
              f"{config.curriculum_start_speed:g} m/s, the cap rising to none at "
              f"{config.curriculum_steps:,} steps (--curriculum-steps 0 turns it off)")
    signals = _Signals()
    tracker, checkpoint, progress = _callbacks(run_dir, config, on_eval, real,
                                               args.progress, signals)
    callbacks = [tracker, checkpoint, progress]
    if config.curriculum_steps:
        callbacks.append(SpeedCurriculum(vec, config.curriculum_start_speed,
                                         config.curriculum_steps))
    print("training started", flush=True)
    interrupted = None
    with signals:
        try:
            if remaining > 0:
                model.learn(remaining, callback=callbacks,
                            reset_num_timesteps=ckpt is None)
        except KeyboardInterrupt:
            interrupted = signals.received or signal.SIGINT
        interrupted = interrupted or signals.received
    if interrupted:
        path = save_model(model, run_dir / "interrupted_model.zip",
                          sidecar_for(config, model.num_timesteps))
        print(f"\ninterrupted at {model.num_timesteps} steps; saved {path}\n"
              f"resume with: uv run train.py --resume {run_dir}", flush=True)
        vec.close()
        raise SystemExit(128 + int(interrupted))
    if config.eval_freq and tracker.last_eval != model.num_timesteps and remaining > 0:
        tracker.run_eval()
    final = save_model(model, run_dir / "final_model.zip", sidecar_for(config, model.num_timesteps))
    vec.close()
    _summary(run_dir, tracker, model.num_timesteps, final)
    if args.archive:
        path = archive_model(run_dir, args.archive, force=args.force)
        print(f"archived: {path} (+ {path.with_suffix('.json').name}, "
              f"{path.with_suffix('.md').name})")
    return run_dir


def _summary(run_dir: Path, tracker, steps: int, final: Path) -> None:
    best = run_dir / "best_model.zip"
    model = best if best.is_file() else final
    lines = [f"done: {steps:,} steps in {time.time() - _START:.0f} s; run folder {run_dir}"]
    if tracker.best_step is not None:
        base = tracker.baselines
        lines.append(f"best evaluation error {tracker.best:.2f} cm at {tracker.best_step:,} steps "
                     f"(classical {base['classical']['mean_error_cm']:.2f} cm, analytic "
                     f"{base['analytic']['mean_error_cm']:.2f} cm): {best}")
    else:
        lines.append(f"no evaluation ran (--eval-freq 0); final model: {final}")
    prefix = run_dir.name.split("__")[0]
    lines += ["next: test it on the test seeds and compare with the classical controller:",
              f"  uv run eval.py --seeds 0-99 --prefix {prefix} --model {model}",
              "  uv run ikpd.py --seeds 0-99 --prefix ikpd",
              f"  uv run metrics.py --prefix-a ikpd --prefix-b {prefix}"]
    print("\n".join(lines), flush=True)
