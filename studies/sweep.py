"""Grids of presets x training seeds, and hyperparameter searches, on Optuna.

    uv run studies/sweep.py --name ladder --presets v1 v5 v9 --seeds 1 2 3 --timesteps 500000
    uv run studies/sweep.py --name hp --search --n-trials 30 --timesteps 400000 --workers 2
    uv run studies/sweep.py --report ladder
    uv run studies/sweep.py --archive ladder --archive-as ladder_best
    uv run studies/sweep.py --archive ladder --archive-preset v5 --archive-as v5  # best v5 seed

Every trial is a train.py run (the same `train.train` code path) with its own run folder
under sweeps/<name>/runs/; its objective is the best evaluation-set mean tracking error in cm
(never a test seed). The study lives in an Optuna storage: by default a SQLite file
sweeps/<name>.db; with `--storage postgresql://user@host:port/db` any number of machines share
one study. The password comes from PGPASSWORD or ~/.pgpass (libpq reads both), never from a
file this writes: a password given in the URL is moved into the workers' environment and masked
wherever the URL is printed or recorded. docs/sweeps.md is the guide.
A grid maps Optuna's trial numbers one-to-one onto grid points, so no point runs twice; a
worker that dies mid-trial stops sending heartbeats, its trial is marked failed after the
grace period and retried once per failure (RetryFailedTrialCallback). Rerunning the same
command continues the study where it stopped.
"""

from __future__ import annotations

import math
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import tyro

from panda_lead.errors import UserError, exit_on_user_error

SWEEPS_DIR = Path("sweeps")


@dataclass
class Args:
    name: str = "sweep"
    """Study name; also the folder sweeps/<name>/ for its runs."""
    presets: list[str] = field(default_factory=lambda: ["v5"])
    """Grid mode: presets to train ('default' = train.py's defaults, no preset)."""
    seeds: list[int] = field(default_factory=lambda: [1, 2, 3])
    """Grid mode: training seeds per preset."""
    search: bool = False
    """Hyperparameter search (TPE sampler, median pruner) instead of a grid."""
    n_trials: int = 20
    """Search mode: trials in total (over all workers and machines)."""
    timesteps: int = 300_000
    """Training budget per trial."""
    eval_freq: int = 50_000
    """Evaluation interval per trial (the pruner sees each evaluation)."""
    workers: int = 1
    """Trials run in parallel on this machine (each gets cores/workers cores)."""
    storage: str | None = None
    """Optuna storage URL (default: sqlite:///sweeps/<name>.db); postgresql://user@host:port/db for
    many machines, the password in PGPASSWORD or ~/.pgpass."""
    heartbeat: int = 30
    """Seconds between a running trial's heartbeats; a trial silent for 3x this is failed."""
    max_retry: int = 2
    """How often a failed (e.g. killed) trial is retried."""
    train_args: str = ""
    """Extra train.py flags for every trial, one string: --train-args="--n-envs 4 --vec-env dummy"."""
    report: str | None = None
    """Print the trials of this study and per-configuration statistics, then exit."""
    archive: str | None = None
    """Send the best trial of this study to the archive (as train.py --archive does), then exit."""
    archive_as: str | None = None
    """Archive name for --archive (default: the study name)."""
    archive_preset: str | None = None
    """With --archive on a grid: the best trial of this preset only (e.g. the best of 3 seeds)."""
    worker_id: int = -1
    """(internal) set for the worker processes this command starts."""


def _parse_url(url: str):
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        return make_url(url)
    except ArgumentError:
        # SQLAlchemy's message does not repeat the URL; ours must not either (a password).
        raise UserError("--storage is not a database URL (e.g. postgresql://user@host:5432/db "
                        "or sqlite:///sweeps/name.db)") from None


def shown(url: str) -> str:
    """The URL as it may be printed or written anywhere: any password replaced by ***."""
    u = _parse_url(url)
    if "password" in u.query:
        u = u.update_query_dict({"password": "***"})
    return u.render_as_string(hide_password=True)


def take_password(args: Args) -> Args:
    """Move a password out of --storage into PGPASSWORD, where libpq (and so every worker this
    starts, through its environment) finds it, and out of sys.argv, which the training loop writes to
    each trial's command.txt and which the workers' command lines are built from. The shell
    that started this process still shows it in `ps`: PGPASSWORD or ~/.pgpass avoid that."""
    from sqlalchemy.engine import URL

    if not args.storage:
        return args
    u = _parse_url(args.storage)
    query = dict(u.query)
    password = u.password if u.password is not None else query.pop("password", None)
    if password is None:
        return args
    clean = URL.create(u.drivername, u.username, None, u.host, u.port, u.database,
                       query).render_as_string(hide_password=False)
    os.environ["PGPASSWORD"] = str(password)
    sys.argv = [a.replace(args.storage, clean) for a in sys.argv]
    print("warning: a password in --storage is visible to `ps` for this command; put it in "
          "PGPASSWORD or ~/.pgpass instead (see docs/sweeps.md)", file=sys.stderr)
    return replace(args, storage=clean)


def engine_url(url: str) -> str:
    """postgresql:// (and postgres://) -> postgresql+psycopg://: the psycopg 3 driver this project
    installs, whatever SQLAlchemy's default driver for the plain scheme is (psycopg2 before 2.1)."""
    u = _parse_url(url)
    if u.drivername in ("postgresql", "postgres"):
        u = u.set(drivername="postgresql+psycopg")
    return u.render_as_string(hide_password=False)


def storage_for(args: Args, name: str):
    import warnings

    import optuna
    import sqlalchemy.exc
    from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback

    # Heartbeats and the stale-trial retry are marked experimental; they are what we rely on.
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)

    url = args.storage or f"sqlite:///{SWEEPS_DIR / name}.db"
    if url.startswith("sqlite:///"):
        Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    for attempt in range(5):
        try:
            return RDBStorage(engine_url(url), heartbeat_interval=args.heartbeat,
                              grace_period=3 * args.heartbeat,
                              heartbeat_stale_trial_callback=RetryHeartbeatStaleTrialCallback(
                                  max_retry=args.max_retry))
        except sqlalchemy.exc.IntegrityError:
            # Machines started at once on a fresh database race to create Optuna's tables;
            # the loser retries and finds them made.
            time.sleep(0.5 + attempt)
        except sqlalchemy.exc.OperationalError as exc:
            # Unreachable server, wrong password, no such database: libpq's reason, one line
            # (libpq never repeats the password; the URL is shown masked).
            reason = " ".join(str(exc.orig or exc).split())
            raise UserError(f"cannot open the study storage {shown(url)}: {reason}") from None
        except ImportError:
            raise UserError(f"the database driver of {shown(url)} is not installed; "
                            "postgresql://... uses psycopg 3, which is") from None
    raise RuntimeError(f"could not open the Optuna storage {shown(url)}")


def grid_space(args: Args) -> dict:
    return {"preset": list(args.presets), "seed": list(args.seeds)}


def make_study(args: Args, storage):
    import optuna

    if args.search:
        sampler = optuna.samplers.TPESampler(seed=0)
        pruner = optuna.pruners.MedianPruner(n_startup_trials=4, n_warmup_steps=1)
    else:
        # A fixed seed: every worker must shuffle the grid the same way.
        sampler, pruner = optuna.samplers.GridSampler(grid_space(args), seed=0), None
    study = optuna.create_study(study_name=args.name, storage=storage, direction="minimize",
                                sampler=sampler, pruner=pruner, load_if_exists=True)
    study.set_user_attr("mode", "search" if args.search else "grid")
    return study


def suggest(trial, args: Args) -> tuple[list[str], dict]:
    """-> (train.py flags, params shown in reports) for one trial."""
    if not args.search:
        preset, seed = trial.suggest_categorical("preset", args.presets), trial.suggest_categorical(
            "seed", args.seeds)
        flags = ["--seed", str(seed)] + ([] if preset == "default" else ["--preset", preset])
        return flags, {"preset": preset, "seed": seed}
    p = {
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 3e-3, log=True),
        "n_epochs": trial.suggest_categorical("n_epochs", [3, 5, 10]),
        "batch_size": trial.suggest_categorical("batch_size", [256, 512, 1024, 2048]),
        "n_steps": trial.suggest_categorical("n_steps", [128, 256, 512]),
        "gamma": trial.suggest_categorical("gamma", [0.95, 0.98, 0.99]),
        "log_std_init": trial.suggest_float("log_std_init", -2.0, 0.0),
    }
    flags = [x for k, v in p.items() for x in (f"--{k.replace('_', '-')}", str(v))]
    return flags + ["--seed", "0"], p


def objective(trial, args: Args) -> float:
    import optuna

    from panda_lead import training
    from panda_lead.cli.train import parse_args

    flags, params = suggest(trial, args)
    run_root = SWEEPS_DIR / args.name / "runs"
    argv = [*flags, "--timesteps", str(args.timesteps), "--eval-freq", str(args.eval_freq),
            "--runs-dir", str(run_root), "--name", f"t{trial.number:04d}", "--no-progress",
            *shlex.split(args.train_args)]
    targs = parse_args(argv)
    pruned = []

    def on_eval(step: int, res: dict) -> bool:
        trial.report(res["mean_error_cm"], step)
        if args.search and trial.should_prune():
            pruned.append(step)
            return False
        return True

    t0 = time.time()
    try:
        run_dir = training.train(targs, on_eval=on_eval)
    except training.TrainingInterrupted as exc:  # saved; the worker stops as train.py would
        raise SystemExit(128 + exc.signum) from None
    trial.set_user_attr("run_dir", str(run_dir))
    trial.set_user_attr("wall_time_s", round(time.time() - t0, 1))
    if pruned:
        raise optuna.TrialPruned(f"pruned at {pruned[0]} steps")
    import json

    return float(json.loads((run_dir / "best.json").read_text())["mean_error_cm"])


def _duplicate(study, trial) -> bool:
    """Whether another live trial already holds this trial's grid point. Workers asking at the
    same moment can be handed the same point; the lowest trial number keeps it."""
    from optuna.trial import TrialState

    gid = trial.storage.get_trial_system_attrs(trial._trial_id).get("grid_id")
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING)):
        if t.number != trial.number and t.system_attrs.get("grid_id") == gid:
            if t.state == TrialState.COMPLETE or t.number < trial.number:
                return True
    return False


def work(args: Args) -> None:
    """One worker: run trials until every grid point is done (or the search has n_trials)."""
    import optuna
    from optuna.trial import TrialState

    storage = storage_for(args, args.name)
    study = make_study(args, storage)
    n_grid = math.prod(len(v) for v in grid_space(args).values())

    while True:
        optuna.storages.fail_stale_trials(study)  # a dead worker's trial -> FAIL -> retried
        trials = study.get_trials(deepcopy=False)
        by_state = {s: [t for t in trials if t.state == s] for s in TrialState}
        waiting, running = by_state[TrialState.WAITING], by_state[TrialState.RUNNING]
        if args.search:
            finished = len(by_state[TrialState.COMPLETE]) + len(by_state[TrialState.PRUNED])
            if finished + len(running) >= args.n_trials and not waiting:
                if not running:
                    return
                time.sleep(min(5, args.heartbeat))
                continue
        else:
            done = {t.system_attrs.get("grid_id") for t in by_state[TrialState.COMPLETE]}
            tried = {t.system_attrs.get("grid_id") for t in trials if t.state.is_finished()}
            if len(done) >= n_grid or (len(tried) >= n_grid and not waiting and not running):
                return  # all points done (or failed more often than retries allow)
            if not waiting and len(tried | {t.system_attrs.get("grid_id") for t in running}) \
                    >= n_grid:
                time.sleep(min(5, args.heartbeat))  # the rest are running; a retry may appear
                continue

        def guarded(trial):
            if not args.search and _duplicate(study, trial):
                raise optuna.TrialPruned("grid point already taken by another worker")
            return objective(trial, args)

        study.optimize(guarded, n_trials=1, catch=(ValueError,))


def launch(args: Args) -> None:
    if args.workers <= 1:
        work(args)
        return
    storage_for(args, args.name)  # create the schema once, before the workers race for it
    # sys.argv holds no password (take_password); PGPASSWORD reaches the workers through the
    # environment they inherit, which, unlike a command line, other users cannot read.
    procs = [subprocess.Popen([sys.executable, __file__, *sys.argv[1:], "--worker-id", str(i)])
             for i in range(args.workers)]
    codes = [p.wait() for p in procs]
    if any(codes):
        raise SystemExit(f"a worker exited with {codes}; rerun the command to continue")


def report(args: Args, name: str) -> None:
    import numpy as np
    import optuna
    from rich.console import Console
    from rich.table import Table
    from scipy import stats

    try:
        study = optuna.load_study(study_name=name, storage=storage_for(args, name))
    except KeyError:
        where = shown(args.storage) if args.storage else f"{SWEEPS_DIR}/"
        raise UserError(f"no study named {name!r} in {where}") from None
    trials = study.get_trials(deepcopy=False)
    table = Table(title=f"study {name}: {len(trials)} trials")
    for col in ("#", "state", "configuration", "seed", "eval error (cm)", "wall (s)"):
        table.add_column(col)
    groups: dict[str, list[float]] = {}
    for t in trials:
        params = dict(t.params)
        seed = params.pop("seed", "-")
        config = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in sorted(params.items()))
        value = f"{t.value:.2f}" if t.value is not None else "-"
        table.add_row(str(t.number), t.state.name, config, str(seed), value,
                      str(t.user_attrs.get("wall_time_s", "-")))
        if t.state.name == "COMPLETE":
            groups.setdefault(config, []).append(t.value)
    console = Console(width=160)
    console.print(table)
    summary = Table(title="per configuration, across training seeds")
    for col in ("configuration", "n", "mean (cm)", "std", "95% interval of the mean"):
        summary.add_column(col)
    for config, vals in sorted(groups.items(), key=lambda kv: np.mean(kv[1])):
        v = np.array(vals)
        if len(v) > 1:
            half = stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / math.sqrt(len(v))
            ci, sd = f"[{v.mean() - half:.2f}, {v.mean() + half:.2f}]", f"{v.std(ddof=1):.2f}"
        else:
            ci, sd = "n/a (1 seed)", "-"
        summary.add_row(config, str(len(v)), f"{v.mean():.2f}", sd, ci)
    console.print(summary)


def archive(args: Args, name: str) -> None:

    import optuna

    from panda_lead import training

    try:
        study = optuna.load_study(study_name=name, storage=storage_for(args, name))
    except KeyError:
        where = shown(args.storage) if args.storage else f"{SWEEPS_DIR}/"
        raise UserError(f"no study named {name!r} in {where}") from None
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    if args.archive_preset is not None:
        done = [t for t in done if t.params.get("preset") == args.archive_preset]
    if not done:
        which = f" with preset {args.archive_preset!r}" if args.archive_preset else ""
        raise UserError(f"study {name!r} has no completed trial{which}")
    # Chosen on the evaluation-set error (the objective), never on test seeds.
    best = min(done, key=lambda t: t.value)
    run_dir = Path(best.user_attrs["run_dir"])
    if not (run_dir / "config.json").is_file():
        raise UserError(f"trial #{best.number}'s run folder {run_dir} is not here: run --archive "
                        "on the machine that ran it, or copy the folder to that path first")
    path = training.archive_model(run_dir, args.archive_as or name)
    print(f"best trial #{best.number} ({best.value:.2f} cm, {best.params}) -> {path}")


@exit_on_user_error
def main() -> None:
    args = take_password(tyro.cli(Args, description=__doc__))
    if args.report:
        report(args, args.report)
    elif args.archive:
        archive(args, args.archive)
    elif args.worker_id >= 0:
        work(args)
    else:
        from panda_lead.training import get_preset

        try:
            for p in args.presets:
                if p != "default":
                    get_preset(p)  # "did you mean" before any work starts
        except ValueError as exc:
            raise UserError(str(exc)) from None
        launch(args)
        report(args, args.name)


if __name__ == "__main__":
    main()
