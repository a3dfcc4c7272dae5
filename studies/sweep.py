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

from panda_lead.errors import UserError, check_plain_name, exit_on_user_error, parse_cli

SWEEPS_DIR = Path("sweeps")
# How long a SQLite write waits for another worker's transaction before failing ("database is
# locked"); SQLite's own default, 5 s, is shorter than a busy study's commits can take.
SQLITE_TIMEOUT_S = 60.0
# The storage backends this project installs a driver for.
BACKENDS = ("sqlite", "postgresql", "postgres")
# train.py flags every trial gets from the sweep itself: --train-args may not set them.
SWEEP_FLAGS = ("--seed", "--timesteps", "--eval-freq", "--runs-dir", "--name", "--resume",
               "--archive", "--force", "--help", "-h")
GRID_FLAGS = ("--preset",)
SEARCH_FLAGS = ("--learning-rate", "--n-epochs", "--batch-size", "--n-steps", "--gamma",
                "--log-std-init")


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
    """Trials run in parallel on this machine, each a train.py run as it would run alone. One
    run keeps about 1.2 cores busy (its MuJoCo threads wait on the policy, the update has one
    torch thread), so on 2 cores two at a time train 1.7-1.9x the samples per hour
    (docs/performance.md, "More runs per hour: two at a time on 2 cores")."""
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


def check_storage_url(url: str) -> None:
    """A URL of a backend this project can open (no driver is imported to find out)."""
    backend = _parse_url(url).get_backend_name()
    if backend not in BACKENDS:
        raise UserError(f"--storage {shown(url)}: no driver for {backend!r} databases here; use "
                        "sqlite:///PATH.db or postgresql://user@host:port/db")


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

    url = storage_url(args, name)
    check_storage_url(url)
    sqlite = _parse_url(url).get_backend_name() == "sqlite"
    if sqlite and url.startswith("sqlite:///"):
        db = Path(url.removeprefix("sqlite:///"))
        if db.parent.exists() and not db.parent.is_dir():
            raise UserError(f"cannot open the study storage {shown(url)}: {db.parent} is a file, "
                            "not a folder")
        db.parent.mkdir(parents=True, exist_ok=True)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    engine_kwargs = {"connect_args": {"timeout": SQLITE_TIMEOUT_S}} if sqlite else {}

    for attempt in range(5):
        try:
            return RDBStorage(engine_url(url), engine_kwargs=engine_kwargs,
                              heartbeat_interval=args.heartbeat,
                              grace_period=3 * args.heartbeat,
                              heartbeat_stale_trial_callback=RetryHeartbeatStaleTrialCallback(
                                  max_retry=args.max_retry))
        except sqlalchemy.exc.IntegrityError:
            # Machines started at once on a fresh database race to create Optuna's tables;
            # the loser retries and finds them made.
            time.sleep(0.5 + attempt)
        except sqlalchemy.exc.DatabaseError as exc:
            # Unreachable server, wrong password, no such database, a file that is not a
            # SQLite database: the driver's reason, one line (libpq never repeats the
            # password; the URL is shown masked).
            reason = " ".join(str(exc.orig or exc).split())
            raise UserError(f"cannot open the study storage {shown(url)}: {reason}") from None
        except ImportError:
            raise UserError(f"the database driver of {shown(url)} is not installed; "
                            "postgresql://... uses psycopg 3, which is") from None
    raise RuntimeError(f"could not open the Optuna storage {shown(url)}")


def storage_url(args: Args, name: str) -> str:
    return args.storage or f"sqlite:///{SWEEPS_DIR / name}.db"


def storage_errors() -> tuple[type[BaseException], ...]:
    """What a storage that fails mid-study raises (through Optuna or directly)."""
    import optuna
    import sqlalchemy.exc

    return (sqlalchemy.exc.SQLAlchemyError, optuna.exceptions.StorageInternalError)


def storage_failure(exc: BaseException) -> BaseException | None:
    """The storage error behind ``exc``, else None: the deepest in its chain (the driver's,
    which says why: "database is locked"), as Optuna wraps it, or fails again while
    recording the failed trial."""
    errors, seen, found = storage_errors(), set(), None
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, errors):
            found = exc
        exc = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    return found


def trial_argv(args: Args, flags: list[str], number: int) -> list[str]:
    """A trial's train.py command line: its own flags, the sweep's, then --train-args."""
    return [*flags, "--timesteps", str(args.timesteps), "--eval-freq", str(args.eval_freq),
            "--runs-dir", str(SWEEPS_DIR / args.name / "runs"), "--name", f"t{number:04d}",
            "--no-progress", *shlex.split(args.train_args)]


def parse_train_args(argv: list[str]):
    """train.py's own parser on a trial's command line; a bad one is one UserError line."""
    from panda_lead.cli.train import parse_args
    from panda_lead.errors import call_cli

    return call_cli(lambda: parse_args(argv, prog="train.py"), "train.py")


def check_args(args: Args) -> None:
    """Everything a study needs, checked before it starts (nothing is created on a refusal):
    names, counts, and every trial's train.py command line, parsed as the trial will parse it
    and checked to fit in memory."""
    import torch

    from panda_lead.training.config import check_fits
    from panda_lead.training.loop import check_device

    check_plain_name(args.name, "--name")
    for flag, value in (("--report", args.report), ("--archive", args.archive),
                        ("--archive-as", args.archive_as)):
        if value is not None:
            check_plain_name(value, flag)
    if args.storage:
        check_storage_url(args.storage)
    for flag, value, low in (("--heartbeat", args.heartbeat, 1), ("--max-retry", args.max_retry, 0),
                             ("--workers", args.workers, 1), ("--n-trials", args.n_trials, 1),
                             ("--timesteps", args.timesteps, 1), ("--eval-freq", args.eval_freq, 1)):
        if value < low:
            raise UserError(f"{flag} must be at least {low}, got {value}")
    if args.report or args.archive:
        return
    if not args.search:
        from panda_lead.training import get_preset

        if not args.presets or not args.seeds:
            raise UserError("a grid needs at least one --presets and one --seeds")
        for p in args.presets:
            if p != "default":
                get_preset(p)  # "did you mean" before any work starts
    try:
        extra = shlex.split(args.train_args)
    except ValueError as exc:  # an unclosed quote
        raise UserError(f"--train-args {args.train_args!r}: {exc}") from None
    owned = SWEEP_FLAGS + (SEARCH_FLAGS if args.search else GRID_FLAGS)
    taken = sorted({a.split("=")[0] for a in extra if a.split("=")[0] in owned})
    if taken:
        raise UserError(f"--train-args may not set {', '.join(taken)}: the sweep sets "
                        f"{'it' if len(taken) == 1 else 'them'} for every trial")
    if args.search:
        grid = [["--seed", "0"]]
    else:
        grid = [["--seed", str(seed)] + ([] if p == "default" else ["--preset", p])
                for p in args.presets for seed in args.seeds]
    for flags in grid:
        try:
            targs = parse_train_args(trial_argv(args, flags, 0))
            check_fits(targs.config())
            check_device(targs.device, torch)
        except UserError as exc:
            raise UserError(f"a trial's train.py flags ({shlex.join(flags + extra)}): "
                            f"{exc}") from None


def grid_space(args: Args) -> dict:
    return {"preset": list(args.presets), "seed": list(args.seeds)}


def check_grid_unchanged(study, args: Args) -> None:
    """A grid study's points are fixed by its first trial (Optuna refuses a categorical whose
    choices change, and a trial would fail on it): adding a seed is one clear line, not a
    failed trial and a sweep that reports success."""
    space = grid_space(args)
    for t in study.get_trials(deepcopy=False):
        for name, dist in t.distributions.items():
            if name in space and list(dist.choices) != space[name]:
                raise UserError(
                    f"study {study.study_name!r} is a grid over {name} {list(dist.choices)}, "
                    f"not {space[name]}: a grid's points cannot change; run the new points under "
                    "another --name and summarize both runs folders into one study "
                    "(studies/runs.py summarize --study NAME --runs A/runs/*/ B/runs/*/)")


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

    flags, params = suggest(trial, args)
    targs = parse_train_args(trial_argv(args, flags, trial.number))
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
    if not args.search:
        check_grid_unchanged(study, args)
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
    storage = storage_for(args, args.name)  # the schema once, before the workers race for it
    if not args.search:
        check_grid_unchanged(make_study(args, storage), args)
    # sys.argv holds no password (take_password); PGPASSWORD reaches the workers through the
    # environment they inherit, which, unlike a command line, other users cannot read.
    procs = [subprocess.Popen([sys.executable, __file__, *sys.argv[1:], "--worker-id", str(i)])
             for i in range(args.workers)]
    codes = [p.wait() for p in procs]
    if any(codes):
        raise SystemExit(f"a worker exited with {codes}; rerun the command to continue")


def load_study(args: Args, name: str):
    """An existing study (never creates one, nor its SQLite file)."""
    import optuna

    where = shown(args.storage) if args.storage else f"{SWEEPS_DIR}/"
    if not args.storage and not (SWEEPS_DIR / f"{name}.db").is_file():
        raise UserError(f"no study named {name!r} in {where} (no {SWEEPS_DIR / name}.db)")
    try:
        return optuna.load_study(study_name=name, storage=storage_for(args, name))
    except KeyError:
        raise UserError(f"no study named {name!r} in {where}") from None


def report(args: Args, name: str) -> None:
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from panda_lead.metrics.stats import t_ci

    study = load_study(args, name)
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
            lo, hi = t_ci(v)
            ci, sd = f"[{lo:.2f}, {hi:.2f}]", f"{v.std(ddof=1):.2f}"
        else:
            ci, sd = "n/a (1 seed)", "-"
        summary.add_row(config, str(len(v)), f"{v.mean():.2f}", sd, ci)
    console.print(summary)


def archive(args: Args, name: str) -> None:

    import optuna

    from panda_lead import training

    study = load_study(args, name)
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


class _NoStorageTraceback:
    """A logging filter for Optuna's handler: its 'Trial N failed ... because of' record (with
    a traceback) and the 'Trial N failed with value' that follows it are dropped when the
    failure is the storage's; main says it in one line instead."""

    def __init__(self):
        self.dropped: str | None = None  # "Trial N " of the last record dropped

    def filter(self, record) -> bool:
        text = record.getMessage()
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None and storage_failure(exc) is not None:
            self.dropped = " ".join(text.split()[:2]) + " "
            return False
        if self.dropped and text.startswith(self.dropped + "failed with value"):
            self.dropped = None
            return False
        return True


def _quiet_storage_tracebacks() -> None:
    import logging

    import optuna

    optuna.logging.get_logger("optuna")  # makes Optuna's own handler
    for handler in logging.getLogger("optuna").handlers:
        handler.addFilter(_NoStorageTraceback())


@exit_on_user_error
def main() -> None:
    try:
        args = take_password(parse_cli(Args, None, description=__doc__))
    except UserError as exc:
        if "'--train-args'" not in str(exc):
            raise
        raise UserError(f"{exc}; give the flags after an equals sign, as one string: "
                        "--train-args=\"--n-envs 4 --vec-env dummy\"") from None
    check_args(args)
    _quiet_storage_tracebacks()
    try:
        run(args)
    except UserError:
        raise
    except Exception as exc:
        lost = storage_failure(exc)
        if lost is None:
            raise
        name = args.report or args.archive or args.name
        reason = " ".join(str(getattr(lost, "orig", None) or lost).split())[:300]
        if len(reason) == 300:
            reason += "..."
        raise UserError(f"the study storage {shown(storage_url(args, name))} failed: {reason}; "
                        "finished trials are kept, rerun the same command to continue") from None


def run(args: Args) -> None:
    if args.report:
        report(args, args.report)
    elif args.archive:
        archive(args, args.archive)
    elif args.worker_id >= 0:
        work(args)
    else:
        launch(args)
        report(args, args.name)


if __name__ == "__main__":
    main()
