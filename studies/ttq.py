"""Time-to-quality study: wall-clock until a policy beats the classical controller by a margin.

    uv run studies/ttq.py --seeds 1 2 --margin-cm 1.5

Each candidate configuration trains with `train.py --stop-below-cm T` where T is the classical
controller's evaluation-set mean error minus the margin; the figure is the wall time (and env
steps) of the first evaluation below T. Runs go one at a time so that each has the machine to
itself. Only the evaluation set is used (never the test seeds).
"""

from __future__ import annotations

import csv
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import tyro

TRAIN_PY = Path(__file__).resolve().parents[1] / "train.py"

# Every candidate names its curriculum explicitly (train.py's default has one since this study).
_NO_CURRICULUM = ["--curriculum-steps", "0"]
CANDIDATES: dict[str, list[str]] = {
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


def main() -> None:
    args = tyro.cli(Args, description=__doc__)
    base = classical_eval_error()
    threshold = base - args.margin_cm
    print(f"classical evaluation error {base:.2f} cm -> threshold {threshold:.2f} cm", flush=True)
    results: dict[str, list] = {}
    for name in args.candidates:
        for seed in args.seeds:
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
    print("\n| candidate | flags | seeds reached | env steps (median) | wall s (median) |")
    print("|---|---|---|---|---|")
    for name, hits in results.items():
        ok = [h for h in hits if h]
        steps = f"{statistics.median(h[0] for h in ok):,.0f}" if ok else "-"
        wall = f"{statistics.median(h[1] for h in ok):.0f}" if ok else "-"
        print(f"| {name} | `{' '.join(CANDIDATES[name])}` | {len(ok)}/{len(hits)} | {steps} "
              f"| {wall} |")


if __name__ == "__main__":
    main()
