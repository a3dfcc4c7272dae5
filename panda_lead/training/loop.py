"""The training loop: `train(args)` runs (or resumes) one PPO run in its own folder.

One folder per run under runs/: config.json (the resolved `TrainConfig`), command.txt, tb/
(TensorBoard, progress.csv), checkpoints/, best_model.zip (lowest evaluation-set tracking
error) and final_model.zip, each model with its sidecar. The folder is locked while a run
trains in it. SIGINT or SIGTERM saves the model and raises `TrainingInterrupted`, which says
how to resume.
"""

from __future__ import annotations

import math
import shlex
import signal
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from ..atomicio import folder_lock
from ..errors import UserError
from ..models import (
    ModelError,
    cpu_name,
    git_commit,
    load_training_state,
    read_sidecar,
    save_model,
    verify,
    write_json_atomic,
)
from .archive import archive_model, check_archive_free
from .callbacks import (
    AtomicCheckpoint,
    FiniteWeights,
    Progress,
    RunClock,
    SignalFlag,
    SpeedCurriculum,
    TrackingEval,
    TrainingDiverged,
    best_record,
    make_logger,
    resume_best,
)
from .config import RESUME_MAY_CHANGE, TrainArgs, TrainConfig, check_fits, read_run_config
from .envs import make_vec_env
from .warm_start import check_init_from, warm_start

# The code this process trains with: read when the training code is imported, not when a
# model is saved (a sweep's later trial, or a save after someone edits the tree, would name
# a commit or a clean tree it does not run). "+dirty": tracked files differed from it.
CODE_COMMIT = git_commit()
CPU = cpu_name()  # the machine family a run's digits re-derive on (results/studies/rederive/rederive.md)


class TrainingInterrupted(Exception):
    """A run stopped by SIGINT or SIGTERM after saving its model; ``signum`` says which."""

    def __init__(self, run_dir: Path, steps: int, signum: int):
        super().__init__(f"interrupted at {steps} steps; saved {run_dir}/interrupted_model.zip")
        self.run_dir, self.steps, self.signum = run_dir, steps, int(signum)


def check_device(device: str, torch) -> None:
    """A CUDA device that is not there is a clear error (SB3 would quietly use the CPU)."""
    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError):
        raise UserError(f"--device {device!r} is not a torch device (e.g. cpu, cuda, cuda:1)") from None
    if kind == "cuda" and not torch.cuda.is_available():
        raise UserError(f"--device {device}: no CUDA GPU is available to torch here; use --device cpu")


def newest_checkpoint(run_dir: Path) -> tuple[Path, dict] | None:
    """The valid saved model with the most timesteps (its sidecar bound to it). A damaged or
    half-written newest file is reported and skipped, so resuming falls back to the one before."""
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


def _resume_point(run_dir: Path, config: TrainConfig) -> tuple[Path, dict]:
    """The checkpoint to resume from, after checking that config.json says what the checkpoint
    was trained with (config.json is a file anyone can edit; the checkpoint is bound)."""
    found = newest_checkpoint(run_dir)
    if found is None:
        raise UserError(f"--resume {run_dir}: no valid checkpoint or saved model to resume from")
    ckpt, side = found
    try:
        trained = TrainConfig.from_dict(side.get("train_config") or {})
    except (UserError, TypeError) as exc:
        raise UserError(f"--resume {run_dir}: {ckpt.name}'s training config is unreadable "
                        f"({exc})") from None
    differ = [k for k, v in config.to_dict().items()
              if k not in RESUME_MAY_CHANGE and trained.to_dict().get(k) != v]
    if differ:
        raise UserError(f"--resume {run_dir}: config.json differs from what {ckpt.name} was "
                        f"trained with ({', '.join(differ)}); it was edited or belongs to "
                        "another run")
    return ckpt, side


def _new_run_dir(runs_dir: Path, stem: str, seed: int) -> Path:
    """runs/<stem>__<seed>__<unix time>, with a counter when that name is taken (two runs started
    in the same second)."""
    runs_dir.mkdir(parents=True, exist_ok=True)
    base = f"{stem}__{seed}__{int(time.time())}"
    for k in range(1000):
        path = runs_dir / (base if k == 0 else f"{base}_{k}")
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue
    raise UserError(f"{runs_dir}: cannot find a free run folder name for {base}")


def train(args: TrainArgs, on_eval=None, extra: dict | None = None) -> Path:
    """Run (or resume) one training run; returns its folder. ``args`` as cli.train.parse_args
    makes them (the preset already applied). ``on_eval(timesteps, metrics)`` is called after
    each evaluation and may return False to stop the run (sweep.py's pruner); ``extra`` is
    recorded in config.json (e.g. sweep.py's trial). Raises `TrainingInterrupted` after saving
    on SIGINT/SIGTERM."""
    import torch

    check_device(args.device, torch)
    config = args.config()
    check_fits(config)  # refuse what cannot fit in memory before creating anything
    if args.archive:
        check_archive_free(args.archive, args.force)  # before hours of training, not after
    if config.init_from and not args.resume:
        check_init_from(config.init_from, config.seed, config)  # before a run folder is made
    if args.resume:
        run_dir = Path(args.resume)
        if not run_dir.is_dir():
            raise UserError(f"--resume {run_dir}: not a run folder")
        read_run_config(run_dir)
    else:
        run_dir = _new_run_dir(args.runs_dir, args.name or args.preset or "lead", args.seed)
    with folder_lock(run_dir, "the run folder"), ExitStack() as cleanup:
        return _train_locked(args, config, run_dir, on_eval, extra, cleanup)


def _train_locked(args: TrainArgs, config: TrainConfig, run_dir: Path, on_eval, extra,
                  cleanup: ExitStack) -> Path:
    import torch
    from stable_baselines3.common.utils import set_random_seed

    from .fast_ppo import build_ppo

    best = (math.inf, None)
    started_from = None  # the model a warm-started run began with (its sidecars keep it)
    if args.resume:
        ckpt, ckpt_side = _resume_point(run_dir, config)
        clock = RunClock(before_s=float(ckpt_side.get("wall_time_s") or 0.0))
        best = resume_best(run_dir)  # before any work: a damaged best is one line
        started_from = ckpt_side.get("init_from")
    else:
        write_json_atomic(run_dir / "config.json",
                          {**config.to_dict(), **({"extra": extra} if extra else {})})
        (run_dir / "command.txt").write_text(shlex.join([sys.executable, *sys.argv]) + "\n")
        ckpt = ckpt_side = None
        clock = RunClock()
    print(f"run folder: {run_dir}", flush=True)

    def sidecar(steps: int, **more) -> dict:
        return {"env_config": config.env.to_dict(), "train_config": config.to_dict(),
                "timesteps": int(steps), "wall_time_s": round(clock.elapsed(), 1),
                "commit": CODE_COMMIT, "cpu": CPU,
                **({"init_from": started_from} if started_from else {}), **more}

    def save(model, path: Path, steps: int, **more) -> Path:
        return save_model(model, path, sidecar(steps, **more))

    def save_best(model, steps: int, metrics: dict) -> None:
        path = save(model, run_dir / "best_model.zip", steps, eval_metrics=metrics)
        write_json_atomic(run_dir / "best.json", best_record(read_sidecar(path)))  # bound

    set_random_seed(config.seed)
    torch.set_num_threads(config.torch_threads)
    logger = make_logger(run_dir / "tb")  # a progress.csv that cannot be continued: one line
    vec = make_vec_env(config.env, config.n_envs, config.seed, config.vec_env, config.n_workers)
    cleanup.callback(vec.close)  # closed on any error from here on (and below on success)
    model = build_ppo(config, vec)  # FastPPO, or SB3's PPO with --no-fast-update
    if ckpt is not None:
        load_training_state(model, ckpt)  # tensors only, never PPO.load (see models.py)
        model.num_timesteps = int(ckpt_side["timesteps"])
        # Fresh training streams for the rest of the run (not a replay of its first episodes).
        vec.seed(int(np.random.SeedSequence([config.seed, model.num_timesteps]).generate_state(1)[0]))
        print(f"resuming {run_dir} from {ckpt.name} at {model.num_timesteps} steps")
    else:
        if config.init_from:
            started_from = warm_start(model, config.init_from, config)
            print(f"started from {started_from['path']} (sha256 {started_from['sha256'][:12]})")
        table = "|param|value|\n|-|-|\n" + "\n".join(
            f"|{k}|{v}|" for k, v in config.to_dict().items())
        # A str value goes to TensorBoard's text tab as a table.
        logger.record("hyperparameters", table, exclude=("stdout", "csv"))
    model.set_logger(logger)
    remaining = config.timesteps - model.num_timesteps
    per_rollout = config.n_steps * config.n_envs
    real = -(-max(remaining, 0) // per_rollout) * per_rollout  # integers: no float rounding
    if remaining > 0 and real != remaining:
        print(f"note: PPO collects whole rollouts of {config.n_steps} x {config.n_envs} = "
              f"{per_rollout:,} steps, so this run ends at {model.num_timesteps + real:,} steps "
              f"(asked: {config.timesteps:,})")
    if config.curriculum_steps > model.num_timesteps:
        print(f"note: speed curriculum: the training targets' peak speed is capped at "
              f"{config.curriculum_start_speed:g} m/s, the cap rising to none at "
              f"{config.curriculum_steps:,} steps (--curriculum-steps 0 turns it off)")
    signals = SignalFlag()
    tracker = TrackingEval(config, run_dir, clock, save_best, on_eval, best)
    callbacks = [tracker, FiniteWeights(),
                 AtomicCheckpoint(max(config.checkpoint_freq // config.n_envs, 1),
                                  str(run_dir / "checkpoints"), save),
                 Progress(real, args.progress, signals)]
    if config.curriculum_steps:
        callbacks.append(SpeedCurriculum(vec, config.curriculum_start_speed,
                                         config.curriculum_steps))
    print("training started", flush=True)
    interrupted = diverged = None
    with signals:  # the final evaluation too: Ctrl-C there also saves and says how to resume
        try:
            if remaining > 0:
                model.learn(remaining, callback=callbacks, reset_num_timesteps=ckpt is None)
            if not signals.received and config.eval_freq \
                    and tracker.last_eval != model.num_timesteps and remaining > 0:
                tracker.run_eval()
        except KeyboardInterrupt:
            interrupted = signals.received or signal.SIGINT
        except TrainingDiverged as exc:
            diverged = exc
        interrupted = interrupted or signals.received
    cleanup.close()  # vec.close()
    if diverged is not None:
        raise UserError(f"training diverged at {diverged.steps:,} steps (the policy's weights "
                        "are no longer finite: reward weights or the learning rate are too "
                        f"large); nothing was saved after the last good checkpoint in {run_dir}")
    if interrupted:
        save(model, run_dir / "interrupted_model.zip", model.num_timesteps)
        print(f"\ninterrupted at {model.num_timesteps} steps; saved "
              f"{run_dir / 'interrupted_model.zip'}\n"
              f"resume with: uv run train.py --resume {run_dir}", flush=True)
        raise TrainingInterrupted(run_dir, model.num_timesteps, interrupted)
    final = save(model, run_dir / "final_model.zip", model.num_timesteps)
    _summary(run_dir, tracker, model.num_timesteps, final, clock)
    if args.archive:
        path = archive_model(run_dir, args.archive, force=args.force)
        print(f"archived: {path} (+ {path.with_suffix('.json').name}, "
              f"{path.with_suffix('.md').name})")
    return run_dir


def _summary(run_dir: Path, tracker: TrackingEval, steps: int, final: Path, clock: RunClock
             ) -> None:
    best = run_dir / "best_model.zip"
    model = best if best.is_file() else final
    lines = [f"done: {steps:,} steps in {clock.elapsed():.0f} s; run folder {run_dir}"]
    if tracker.best_step is not None:
        base = tracker.baselines
        lines.append(f"best evaluation error {tracker.best:.2f} cm at {tracker.best_step:,} steps "
                     f"(classical {base['classical']['mean_error_cm']:.2f} cm, analytic "
                     f"{base['analytic']['mean_error_cm']:.2f} cm"
                     + (f", feedforward {base['feedforward']['mean_error_cm']:.2f} cm"
                        if "feedforward" in base else "") + f"): {best}")
    else:
        lines.append(f"no evaluation ran (--eval-freq 0); final model: {final}")
    prefix = run_dir.name  # unique to the run: a second run's eval set is not refused
    lines += ["next: test it on the test seeds and compare with the classical controller:",
              f"  uv run eval.py --seeds 0-99 --prefix {prefix} --model {model}",
              "  uv run ikpd.py --seeds 0-99 --prefix ikpd",
              f"  uv run metrics.py --prefix-a ikpd --prefix-b {prefix}"]
    print("\n".join(lines), flush=True)
