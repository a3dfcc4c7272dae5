"""Soak test: a million env steps of random and extreme actions across all shapes.

    uv run studies/soak.py --steps 1000000 --envs 64

Reports episodes, MuJoCo warnings, NaNs, exceptions, failures and self-collision time, and
exits non-zero if any NaN or exception occurred. All envs run in one batched vector env
(`gymnasium.make_vec`, MuJoCo's threads); each env's actions alternate between uniform random,
bang-bang (+-1 on every axis, switching at random) and constant extremes, per episode, because
those drive the arm hardest into itself and the floor.
"""

from __future__ import annotations

import sys
import time
import traceback
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    steps: int = 1_000_000
    """Total env steps over all envs."""
    envs: int = 64
    """Envs stepped together in one batch."""
    workers: int = 0
    """MuJoCo threads (0: one per core)."""
    episode_steps: int = 500
    """Steps per episode (5 s)."""
    max_lead: float = 0.15
    """Lead at action +-1 (m); try 0.5 to push harder."""
    seed: int = 0
    """Seed of the envs' trajectory streams and of the actions."""


def soak(args: Args) -> dict:
    from panda_lead.config import OBS_FEATURES

    n = args.envs
    vec = gym.make_vec("PandaLead-v0", num_envs=n, num_threads=args.workers,
                       episode_steps=args.episode_steps, max_lead=args.max_lead,
                       obs_features=tuple(OBS_FEATURES))
    rng = np.random.default_rng(args.seed)
    stats = dict(steps=0, episodes=0, nans=0, exceptions=0, warnings=0, unstable=0,
                 collision_steps=0, floor_steps=0, shapes={}, errors=[])
    vec.reset(seed=args.seed)
    task = vec.unwrapped.task
    mode = rng.integers(3, size=n)
    const = np.sign(rng.uniform(-1, 1, (n, 3))).astype(np.float32)
    while stats["steps"] < args.steps:
        random = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        action = np.where((mode == 0)[:, None], random,
                          np.where((mode == 1)[:, None], np.sign(random), const))
        try:
            obs, reward, term, trunc, info = vec.step(action)
        except Exception:  # noqa: BLE001  (counting them is the point)
            stats["exceptions"] += 1
            stats["errors"].append(traceback.format_exc(limit=3))
            vec.reset()
            continue
        # Next-step autoreset: an env that ended last step only resets in this one (its row
        # of this step is its new episode's first observation, not a step). Count the envs
        # that stepped: those with step info (Gymnasium's "_key" masks).
        stepped = info.get("_distance", np.zeros(n, dtype=bool))
        stats["steps"] += int(stepped.sum())
        stats["nans"] += int((~np.isfinite(obs).all(axis=1) | ~np.isfinite(reward)).sum())
        if stepped.any():  # (an all-reset step has no step info at all)
            stats["collision_steps"] += int(info["self_collision"].sum())  # False elsewhere
            stats["floor_steps"] += int(task.core.floor_contact[stepped].sum())
        if "failure" in info:
            stats["unstable"] += int((info["failure"][info["_failure"]] == "unstable").sum())
        ended = np.flatnonzero(term | trunc)
        for i in ended:
            stats["episodes"] += 1
            stats["shapes"][task.shapes[i]] = stats["shapes"].get(task.shapes[i], 0) + 1
        mode[ended] = rng.integers(3, size=len(ended))
        const[ended] = np.sign(rng.uniform(-1, 1, (len(ended), 3)))
    stats["warnings"] = int(task.core.warning_counts().sum())
    return stats


def main() -> int:
    args = parse_cli(Args, description=__doc__)
    t = time.perf_counter()
    total = soak(args)
    wall = time.perf_counter() - t
    print(f"steps {total['steps']:,} in {wall:.0f} s ({total['steps'] / wall:,.0f}/s), "
          f"episodes {total['episodes']:,} {total['shapes']}")
    print(f"MuJoCo warnings {total['warnings']}, unstable episodes {total['unstable']}, "
          f"NaNs {total['nans']}, exceptions {total['exceptions']}")
    print(f"self-collision time {100 * total['collision_steps'] / total['steps']:.2f}%, "
          f"floor contact time {100 * total['floor_steps'] / total['steps']:.2f}%")
    for err in total["errors"][:3]:
        print(err, file=sys.stderr)
    ok = total["nans"] == 0 and total["exceptions"] == 0
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    sys.exit(exit_on_user_error(main)())
