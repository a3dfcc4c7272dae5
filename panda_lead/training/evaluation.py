"""The evaluation a training run reports and selects its best model on: deterministic episodes
on the fixed evaluation set (seeds.EVAL_SET, never a test seed), played as one batch."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..config import EnvConfig, as_config
from ..rollout import record_many
from ..seeds import EVAL_SET


def evaluate(act_fn, env_config: EnvConfig | dict, steps: int, episodes=EVAL_SET) -> dict:
    """Episodes on (seed, shape) pairs -> tracking metrics in cm, time in the 5 cm band, mean
    return. Every episode runs its full length: an evaluation never ends one early on a
    self-collision (a failure is data to be scored, not a reason to drop the episode)."""
    config = as_config(env_config, {}).replace(episode_steps=steps, terminate_on_collision=False)
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


def eval_curve(run_dir: Path) -> list[list[float]]:
    """A run's evaluations as logged (tb/progress.csv): [timesteps, evaluation-set mean error in
    cm to 4 decimals] each, what a committed run summary holds (studies/runs.py)."""
    with open(Path(run_dir) / "tb" / "progress.csv") as f:
        rows = [r for r in csv.DictReader(f) if r.get("eval/mean_error_cm")]
    return [[int(float(r["eval/timesteps"])), round(float(r["eval/mean_error_cm"]), 4)]
            for r in rows]
