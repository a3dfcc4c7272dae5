"""Does a committed training run re-derive from git? Retrain a summary's run (results/runs/) from
its recorded config and seed, for its first few evaluations, and compare the evaluation curve
with the one the summary holds.

    uv run studies/rederive.py --study v5_err_decay --seed 4            # first 2 evaluations
    uv run studies/rederive.py --study v5 --seed 1 --evals 4 --keep-run

The rerun keeps the run's --timesteps (a linear learning-rate schedule depends on it) and stops
after --evals evaluations. Exit 0: every compared point equal to the summary's 4 decimals;
exit 1: a point differs (the table says which, and by how much).

What a mismatch means: the summary names the commit it trained at; code changed since, or the
run trained on another CPU family. Measured 2026-11-25 (results/studies/rederive/rederive.md): on
the machine family that trained them, runs re-derive to every printed digit; runs trained on earlier
sessions' machines (AMD EPYC where recorded), rerun on an Intel Xeon, differ from the first
evaluation on (0.003 to 0.12 cm at 50k steps), at their own commit as at HEAD, and pinning
torch's MKL to SSE4.2 does not bring them back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import tempfile
from dataclasses import dataclass
from pathlib import Path

from panda_lead.errors import UserError, check_plain_name, exit_on_user_error, parse_cli, printable
from panda_lead.summaries import check_curve_points, read_json

RUNS_DIR = Path("results/runs")


@dataclass
class Args:
    study: str
    """The study: its summaries live in results/runs/<study>/seed_<N>.json."""
    seed: int
    """The training seed of the run to re-derive."""
    evals: int = 2
    """How many of the run's evaluations to retrain and compare (each is eval_freq steps)."""
    keep_run: bool = False
    """Keep the rerun's folder (under runs/rederive/) instead of a temporary one."""


def load_summary(study: str, seed: int) -> dict:
    """The summary's config and curve, checked: a summary is a file anyone can edit."""
    path = RUNS_DIR / check_plain_name(study, "--study") / f"seed_{seed}.json"
    if not path.is_file():
        raise UserError(f"no summary {path} (see `ls {RUNS_DIR / study}`)")
    summary = read_json(path, "a run summary")  # bounded; no NaN, no deep nesting
    config = summary.get("train_config") if isinstance(summary, dict) else None
    if not isinstance(config, dict):
        raise UserError(f"{path}: not a run summary (train_config is not an object)")
    if config.get("seed") != seed:
        raise UserError(f"{path}: its train_config has seed {printable(config.get('seed'), 40)}, "
                        f"not {seed}")
    points = check_curve_points(summary.get("eval_curve"), path)
    _train_config(config, path)  # every value checked before the rerun starts
    cpu = summary.get("cpu")  # summaries before 2026-11-25 do not name it
    cpu = printable(cpu) if isinstance(cpu, str) and cpu else None
    commit = summary.get("commit")
    return {"path": path, "config": config, "curve": points,
            "commit": printable(commit, 80) if commit is not None else None, "cpu": cpu}


def _train_config(config: dict, path: Path):
    """The summary's training config as TrainConfig, any bad value as one line naming the file
    (a wrong type, e.g. net_arch 5 or curriculum_start_speed "fast", is a TypeError there)."""
    from panda_lead.training.config import TrainConfig

    try:
        return TrainConfig.from_dict(config)
    except UserError as exc:
        raise UserError(f"{path}: train_config: {exc}") from None
    except (TypeError, ValueError, KeyError, AttributeError) as exc:
        raise UserError(f"{path}: train_config is not a training config "
                        f"({printable(exc, 120)})") from None


def rerun_curve(config: dict, evals: int, runs_dir: Path) -> list[tuple[int, float]]:
    """Train with the summary's config in a run folder under ``runs_dir``, stopping after
    ``evals`` evaluations; the (timesteps, evaluation error) points it logged."""
    from panda_lead import training
    from panda_lead.training.config import TrainArgs, TrainConfig
    from panda_lead.training.evaluation import eval_curve

    trained = TrainConfig.from_dict(config)  # load_summary checked it
    if not trained.eval_freq:
        raise UserError("the run never evaluated (eval_freq 0): there is no curve to compare")
    fields = {f.name: getattr(trained, f.name) for f in dataclasses.fields(TrainConfig)}
    # A very large checkpoint interval: the rerun saves no checkpoint it does not need.
    args = TrainArgs(**{**fields, "checkpoint_freq": 10**12}, runs_dir=runs_dir,
                     name="rederive", progress=False)
    seen: list[int] = []

    def on_eval(step: int, res: dict) -> bool:
        seen.append(step)
        return len(seen) < evals

    return [tuple(point) for point in eval_curve(training.train(args, on_eval=on_eval))]


def compare(recorded: list[tuple[int, float]], rerun: list[tuple[int, float]]) -> tuple[str, bool]:
    """A markdown table of the points both hold, and whether every one agrees."""
    lines = ["| steps | summary (cm) | rerun (cm) | rerun - summary |", "|---|---|---|---|"]
    same = len(rerun) == len(recorded)  # a rerun that stopped early did not re-derive
    for (s0, e0), (s1, e1) in zip(recorded, rerun, strict=False):
        ok = s0 == s1 and math.isclose(e0, e1, abs_tol=5e-5)
        same &= ok
        step = str(s0) if s0 == s1 else f"{s0} / {s1}"
        lines.append(f"| {step} | {e0:.4f} | {e1:.4f} | {e1 - e0:+.4f}{'' if ok else ' **differs**'} |")
    lines += [f"| {s0} | {e0:.4f} | (none) | **missing** |" for s0, e0 in recorded[len(rerun):]]
    return "\n".join(lines), same


class _Terminated(BaseException):  # not swallowed by an `except Exception`
    """SIGTERM, raised where the process is, so the temporary run folder is removed on the way
    out (the default action would kill the process and leave rederive_* behind)."""


@contextlib.contextmanager
def _sigterm_unwinds():
    def handle(signum, frame):
        raise _Terminated

    old = signal.signal(signal.SIGTERM, handle)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def main(args: Args) -> int:
    if args.evals < 1:
        raise UserError(f"--evals must be at least 1, got {args.evals}")
    summary = load_summary(args.study, args.seed)
    if args.evals > len(summary["curve"]):
        raise UserError(f"{summary['path']} holds {len(summary['curve'])} evaluations, "
                        f"fewer than --evals {args.evals}")
    from panda_lead.models import cpu_name
    from panda_lead.training import TrainingInterrupted

    here = cpu_name()
    print(f"re-deriving {summary['path']} (trained at commit {summary['commit']}, on "
          f"{summary['cpu'] or 'a CPU it does not name'}; this CPU: {here}): "
          f"{args.evals} evaluation(s)", flush=True)
    try:
        with _sigterm_unwinds():
            if args.keep_run:
                rerun = rerun_curve(summary["config"], args.evals, Path("runs/rederive"))
            else:
                with tempfile.TemporaryDirectory(prefix="rederive_") as tmp:
                    rerun = rerun_curve(summary["config"], args.evals, Path(tmp))
    except (TrainingInterrupted, _Terminated, KeyboardInterrupt) as exc:
        signum = getattr(exc, "signum", signal.SIGTERM if isinstance(exc, _Terminated)
                         else signal.SIGINT)
        where = ("its run folder is under runs/rederive/" if args.keep_run else
                 "its run folder was temporary and is deleted, so there is nothing to resume")
        print(f"interrupted: nothing re-derived ({where}); run rederive.py again", flush=True)
        return 128 + int(signum)
    if not args.keep_run:
        print("(the rerun's folder above was temporary and is gone: --keep-run keeps it)")
    table, same = compare(summary["curve"][:args.evals], rerun[:args.evals])
    print(table)
    other_cpu = summary["cpu"] not in (None, here)
    print("re-derived: every point equal to 4 decimals" if same else
          "not re-derived: a point differs "
          + ("(it trained on another CPU: results/studies/rederive/rederive.md)" if other_cpu
             else "(see the module's docstring for why it can)"))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))())
