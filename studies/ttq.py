"""Time-to-quality study: wall-clock until a policy beats the classical controller by a margin.

    uv run studies/ttq.py --seeds 1 2 --margin-cm 1.5
    uv run studies/ttq.py --candidates default default_sb3_update --seeds 1 2 3 4 5 --extra

Each candidate configuration trains with `train.py --stop-below-cm T` where T is the classical
controller's evaluation-set mean error minus the margin; the figure is the wall time (and env
steps) of the first evaluation below T. Runs go one at a time so that each has the machine to
itself, interleaved (each seed's candidates one after the other, so that a change in the
machine's load reaches every candidate alike), and the table gives each candidate's paired
wall-time ratio to the first candidate. Only the evaluation set is used (never the test seeds).

`default` against `default_sb3_update` is issue 39's before/after: train.py's defaults with
FastPPO's update and with SB3's own (`--no-fast-update`). The two are bit-identical per sample
(tests/test_fast_ppo.py), so every seed must reach the threshold at the same env step in both,
and the wall-time ratio is the update's speed-up in a whole run.
"""

from __future__ import annotations

import csv
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from panda_lead.errors import UserError, did_you_mean, exit_on_user_error, parse_cli

TRAIN_PY = Path(__file__).resolve().parents[1] / "train.py"

# Every candidate names its curriculum explicitly (train.py's default has one since this study).
_NO_CURRICULUM = ["--curriculum-steps", "0"]
CANDIDATES: dict[str, list[str]] = {
    # train.py's defaults as they are (FastPPO's update), and with SB3's own update.
    "default": [],
    "default_sb3_update": ["--no-fast-update"],
    # The reference work's PPO settings exactly (lr 3e-4, log_std_init 0 included).
    "reference": ["--reference-hparams"],
    "b16x256_bs1024": ["--n-envs", "16", "--vec-env", "batched", "--n-steps", "256",
                       "--batch-size", "1024", "--n-epochs", "10", *_NO_CURRICULUM],
    "b16x512_bs2048_e5": ["--n-envs", "16", "--vec-env", "batched", "--n-steps", "512",
                          "--batch-size", "2048", "--n-epochs", "5", *_NO_CURRICULUM],
    "b64x64_bs1024_lr1e-3": ["--n-envs", "64", "--vec-env", "batched", "--n-steps", "64",
                             "--batch-size", "1024", "--n-epochs", "10", "--learning-rate", "1e-3",
                             *_NO_CURRICULUM],
    "b32x128_bs1024_lr1e-3": ["--n-envs", "32", "--vec-env", "batched", "--n-steps", "128",
                              "--batch-size", "1024", "--n-epochs", "10",
                              "--learning-rate", "1e-3", *_NO_CURRICULUM],
    # The same with the speed curriculum of docs/questions.md 5 (slow targets first): the
    # default since this study.
    "b32x128_bs1024_lr1e-3_curr": ["--n-envs", "32", "--vec-env", "batched", "--n-steps", "128",
                                   "--batch-size", "1024", "--n-epochs", "10",
                                   "--learning-rate", "1e-3", "--curriculum-steps", "500000"],
}


@dataclass
class Args:
    seeds: list[int] = field(default_factory=lambda: [1, 2])
    """Training seeds per candidate."""
    candidates: list[str] = field(default_factory=lambda: list(CANDIDATES))
    """Which candidates to run (names in ttq.CANDIDATES)."""
    margin_cm: float = 1.5
    """How far below the classical evaluation error a policy must get."""
    max_timesteps: int = 1_500_000
    """Budget per run; a run that never gets there is reported as not reached."""
    eval_freq: int = 25_000
    """Evaluation interval in env steps (the same for every candidate)."""
    extra: list[str] = field(default_factory=lambda: ["--log-std-init", "-1"])
    """Flags given to every run."""
    runs_dir: Path = Path("runs/ttq")
    """Where the runs go."""


def classical_eval_error() -> float:
    from panda_lead.controllers import classical
    from panda_lead.training import evaluate

    return evaluate(classical, {}, 500)["mean_error_cm"]


def first_below(progress: Path, threshold: float) -> tuple[int, float] | None:
    with open(progress) as f:
        for row in csv.DictReader(f):
            err = row.get("eval/mean_error_cm")
            if err and float(err) < threshold:
                return int(float(row["eval/timesteps"])), float(row["eval/wall_time_s"])
    return None


@exit_on_user_error
def main(args: Args) -> None:
    for name in args.candidates:
        if name not in CANDIDATES:
            raise UserError(f"unknown candidate {name!r}" + did_you_mean(name, CANDIDATES))
    if not args.seeds or not args.candidates:
        raise UserError("give at least one --seeds and one --candidates")
    base = classical_eval_error()
    threshold = base - args.margin_cm
    print(f"classical evaluation error {base:.2f} cm -> threshold {threshold:.2f} cm", flush=True)
    results: dict[str, list] = {}
    for seed in args.seeds:
        for name in args.candidates:
            out_dir = args.runs_dir / f"{name}__s{seed}__{int(time.time())}"
            cmd = [sys.executable, str(TRAIN_PY), *CANDIDATES[name], *args.extra, "--seed",
                   str(seed), "--timesteps", str(args.max_timesteps), "--eval-freq",
                   str(args.eval_freq), "--stop-below-cm", f"{threshold:.4f}", "--runs-dir",
                   str(out_dir), "--name", name, "--no-progress", "--checkpoint-freq",
                   str(10**9)]
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            run = next(out_dir.iterdir())
            hit = first_below(run / "tb" / "progress.csv", threshold)
            results.setdefault(name, []).append(hit)
            shown = f"{hit[0]:,} steps, {hit[1]:.0f} s" if hit else "not reached"
            print(f"{name} seed {seed}: {shown}", flush=True)
    first = args.candidates[0]
    print(f"\n| candidate | flags | seeds reached | env steps (median) | wall s (median) | "
          f"wall / {first}'s, paired by seed (median) |")
    print("|---|---|---|---|---|---|")
    for name, hits in results.items():
        ok = [h for h in hits if h]
        steps = f"{statistics.median(h[0] for h in ok):,.0f}" if ok else "-"
        wall = f"{statistics.median(h[1] for h in ok):.0f}" if ok else "-"
        ratios = [h[1] / g[1] for h, g in zip(hits, results[first], strict=True) if h and g]
        ratio = (f"{statistics.median(ratios):.3f} ({', '.join(f'{r:.2f}' for r in ratios)})"
                 if ratios else "-")
        print(f"| {name} | `{' '.join(CANDIDATES[name])}` | {len(ok)}/{len(hits)} | {steps} "
              f"| {wall} | {ratio} |")

if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
