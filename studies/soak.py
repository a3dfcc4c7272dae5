"""Soak test: a million env steps of random and extreme actions across all shapes.

    uv run soak.py --steps 1000000 --workers 2

Reports episodes, MuJoCo warnings, NaNs, exceptions, failures and self-collision time, and
exits non-zero if any NaN or exception occurred. Each worker process runs its own env with its
own seed; actions alternate between uniform random, bang-bang (+-1 on every axis, switching
at random) and constant extremes, because those drive the arm hardest into itself and the floor.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Studies import the pipeline, which lives at the repo root (nothing imports a study).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import multiprocessing as mp
import time
import traceback
from dataclasses import dataclass

import numpy as np
import tyro


@dataclass
class Args:
    steps: int = 1_000_000
    """Total env steps over all workers."""
    workers: int = 2
    """Worker processes."""
    episode_steps: int = 500
    """Steps per episode (5 s)."""
    max_lead: float = 0.15
    """Lead at action +-1 (m); try 0.5 to push harder."""
    seed: int = 0
    """Base seed."""


def soak_worker(args: tuple) -> dict:
    import env as env_mod

    n_steps, episode_steps, max_lead, seed = args
    rng = np.random.default_rng(seed)
    e = env_mod.PandaLeadEnv(episode_steps=episode_steps, max_lead=max_lead,
                             obs_features=tuple(env_mod.OBS_FEATURES))
    stats = dict(steps=0, episodes=0, nans=0, exceptions=0, warnings=0, unstable=0,
                 collision_steps=0, floor_steps=0, shapes={}, errors=[])
    e.reset(seed=seed)
    mode, const = 0, np.ones(3, dtype=np.float32)
    while stats["steps"] < n_steps:
        if mode == 0:
            action = rng.uniform(-1, 1, 3).astype(np.float32)
        elif mode == 1:
            action = np.sign(rng.uniform(-1, 1, 3)).astype(np.float32)
        else:
            action = const
        try:
            obs, reward, term, trunc, info = e.step(action)
        except Exception:  # noqa: BLE001  (counting them is the point)
            stats["exceptions"] += 1
            stats["errors"].append(traceback.format_exc(limit=3))
            term, trunc, obs, reward, info = True, False, np.zeros(1), 0.0, {}
        stats["steps"] += 1
        if not (np.isfinite(obs).all() and np.isfinite(reward)):
            stats["nans"] += 1
        stats["collision_steps"] += bool(info.get("self_collision"))
        stats["floor_steps"] += bool(e.core.floor_contact)
        stats["unstable"] += info.get("failure") == "unstable"
        if term or trunc:
            warn = e.core.data.warning
            stats["warnings"] += int(sum(warn[i].number for i in range(len(warn))))
            stats["episodes"] += 1
            shape = e.traj.shape
            stats["shapes"][shape] = stats["shapes"].get(shape, 0) + 1
            e.reset()
            mode = int(rng.integers(3))
            const = np.sign(rng.uniform(-1, 1, 3)).astype(np.float32)
    return stats


def main() -> int:
    args = tyro.cli(Args)
    per = [args.steps // args.workers + (i < args.steps % args.workers)
           for i in range(args.workers)]
    jobs = [(n, args.episode_steps, args.max_lead, args.seed + 1000 * i)
            for i, n in enumerate(per)]
    t = time.perf_counter()
    with mp.get_context("forkserver").Pool(args.workers) as pool:
        results = pool.map(soak_worker, jobs)
    wall = time.perf_counter() - t
    total = {k: sum(r[k] for r in results) for k in
             ("steps", "episodes", "nans", "exceptions", "warnings", "unstable",
              "collision_steps", "floor_steps")}
    shapes: dict[str, int] = {}
    for r in results:
        for s, c in r["shapes"].items():
            shapes[s] = shapes.get(s, 0) + c
    print(f"steps {total['steps']:,} in {wall:.0f} s ({total['steps'] / wall:,.0f}/s), "
          f"episodes {total['episodes']:,} {shapes}")
    print(f"MuJoCo warnings {total['warnings']}, unstable episodes {total['unstable']}, "
          f"NaNs {total['nans']}, exceptions {total['exceptions']}")
    print(f"self-collision time {100 * total['collision_steps'] / total['steps']:.2f}%, "
          f"floor contact time {100 * total['floor_steps'] / total['steps']:.2f}%")
    for r in results:
        for err in r["errors"][:3]:
            print(err, file=sys.stderr)
    ok = total["nans"] == 0 and total["exceptions"] == 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
