"""The cheap probe of issue 37: does the ILC oracle's lead become predictable when the student
also sees the planned path?

    uv run studies/preview_probe.py > results/studies/preview/probe.md

studies/distill.py's probe found that no causal observation determines the oracle's lead
(the student's held-out error stays near the lead's own spread). Here the same teacher data
(the oracle, ILCConfig defaults, started from the headline model, on the last distillation
slice's first ``--probe-n`` trajectories, 5 s) is regressed twice per observation: without
and with the target's future positions, p(t + h) - p(t) for h in ``--preview-times``, scaled
by 1/0.1 m. The preview columns are computed from each trajectory (defined for every t >= 0),
exactly what an env feature "target_preview" would observe; the student is a 64x64 tanh MLP
(the policies' shape) fitted by MSE (Adam, one torch thread), the last 10% of the
trajectories held out.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli

ROOT = Path(__file__).resolve().parents[1]
PREVIEW_SCALE_M = 0.1


@dataclass
class Args:
    probe_n: int = 100
    """Teacher trajectories."""
    preview_times: tuple[float, ...] = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3)
    """How far ahead (s) the student sees the target."""
    init_model: Path = Path("archive/v5_err_decay_s4.zip")
    """The oracle starts from this model's lead (the headline)."""
    epochs: int = 30
    batch_size: int = 512
    learning_rate: float = 1e-3
    fit_seeds: tuple[int, ...] = (1,)
    """The student's initialisations and minibatch orders: each row is the mean over them, with
    the held-out R^2's range when there is more than one."""
    val_frac: float = 0.1


def preview_columns(seeds, steps: int, dt: float, times) -> np.ndarray:
    """(N, T, 3 x len(times)) scaled offsets of the future target from the present one, as
    observed before step k (time k dt)."""
    from panda_lead import trajectory

    t = np.arange(steps) * dt
    out = np.zeros((len(seeds), steps, 3 * len(times)), np.float32)
    for i, s in enumerate(seeds):
        traj = trajectory.sample(int(s))
        now = traj.at(t)[0]
        for j, h in enumerate(times):
            out[i, :, 3 * j:3 * j + 3] = (traj.at(t + h)[0] - now) / PREVIEW_SCALE_M
    return out


def fit_mlp(x, y, vx, args: Args, seed: int):
    import torch

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], 64), torch.nn.Tanh(),
                              torch.nn.Linear(64, 64), torch.nn.Tanh(), torch.nn.Linear(64, 3))
    opt = torch.optim.Adam(net.parameters(), lr=args.learning_rate)
    x, y, vx = (torch.as_tensor(a) for a in (x, y, vx))
    gen = np.random.default_rng(seed)
    for _ in range(args.epochs):
        perm = torch.as_tensor(gen.permutation(len(x)))
        for i in range(0, len(x), args.batch_size):
            idx = perm[i:i + args.batch_size]
            loss = torch.nn.functional.mse_loss(net(x[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        train = float(torch.nn.functional.mse_loss(net(x), y))
        pred = net(vx).numpy()
    return train, pred


def _scores(o, act, held, settle: int, max_lead_cm: float, total_var: float, args: Args,
            seed: int) -> tuple[float, ...]:
    """One student fitted on the kept trajectories, scored on the held-out ones: train MSE,
    held-out MSE, R^2, RMS lead error (cm), mean per-trajectory constant error after 0.5 s."""
    d = o.shape[-1]
    train, pred = fit_mlp(o[~held].reshape(-1, d), act[~held].reshape(-1, 3),
                          o[held].reshape(-1, d), args, seed)
    pred = pred.reshape(act[held].shape)
    mse = float(np.mean((pred - act[held]) ** 2))
    res = (pred - act[held]) * max_lead_cm
    const = np.linalg.norm(res[:, settle:].mean(axis=1), axis=-1)
    return (train, mse, 1 - 3 * mse / total_var,
            float(np.sqrt(np.mean(np.sum(res ** 2, axis=-1)))), float(const.mean()))


def main(args: Args) -> None:
    sys.path.insert(0, str(ROOT / "studies"))
    from distill import (
        STUDENT_FEATURES,
        column_picker,
        init_from_model,
        record_pairs,
        split,
        student_config,
    )

    from panda_lead.config import OBS_15
    from panda_lead.core import control_dt
    from panda_lead.ilc import ILCConfig, learn_leads
    from panda_lead.models import cpu_name
    from panda_lead.seeds import DISTILL_SEEDS, DISTILL_SLICE

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, cwd=ROOT).stdout.strip()
    flags = "".join(f" {shlex.quote(w)}" for w in sys.argv[1:])  # the stamp: the command as run
    wide = student_config(STUDENT_FEATURES + ("tip_error_avg", "joint_pos", "joint_vel"), 500)
    seeds = list(range(DISTILL_SEEDS.stop - DISTILL_SLICE, DISTILL_SEEDS.stop))[:args.probe_n]
    leads, hist = learn_leads(wide, seeds, None, ILCConfig(),
                              init_from_model(args.init_model, wide))
    obs, act, _, ok = record_pairs(wide, leads, seeds)
    kept = [s for s, k in zip(seeds, ok, strict=True) if k]
    prev = preview_columns(kept, wide.episode_steps, control_dt(), args.preview_times)
    held = split(seeds, args.val_frac)[ok]
    settle = int(round(0.5 / control_dt()))
    print(f"Made by `uv run studies/preview_probe.py{flags}` at commit {commit} "
          f"({os.cpu_count()} cores, {cpu_name()}). "
          f"Teacher: the ILC oracle (ILCConfig defaults) started from {args.init_model.stem} on "
          f"{len(seeds)} distillation trajectories ({seeds[0]}-{seeds[-1]}), {hist[0]:.3f} -> "
          f"{hist[-1]:.3f} cm; {held.sum()} held out. Preview: p(t + h) - p(t) for h in "
          f"{', '.join(f'{h:g}' for h in args.preview_times)} s. Student: 64x64 tanh MLP, "
          f"{args.epochs} epochs, fitted {len(args.fit_seeds)} time(s) from seeds "
          f"{', '.join(map(str, args.fit_seeds))} (R^2's range in parentheses). "
          "Labelled: rows with the preview KNOW THE PLANNED PATH.\n")
    print("| student observation | knows the planned path | train MSE | held-out MSE | "
          "held-out R^2 | RMS lead error (cm) | constant per trajectory, t >= 0.5 s (cm) |")
    print("|---|---|---|---|---|---|---|")
    total_var = act[held].reshape(-1, 3).var(axis=0).sum()
    max_lead_cm = wide.max_lead * 100
    for label, feats in (("v5 (15-D)", OBS_15), ("v5_err (18-D)", STUDENT_FEATURES),
                         ("v5_err + tip_error_avg (21-D)", STUDENT_FEATURES + ("tip_error_avg",))):
        cols = column_picker(student_config(feats), wide)
        for with_preview in (False, True):
            o = np.concatenate([obs[..., cols], prev], axis=-1) if with_preview else obs[..., cols]
            d = o.shape[-1]
            fits = [_scores(o, act, held, settle, max_lead_cm, total_var, args, seed)
                    for seed in args.fit_seeds]
            train, mse, r2, rms, const = np.mean(fits, axis=0)
            spread = (f" ({min(f[2] for f in fits):.3f}-{max(f[2] for f in fits):.3f})"
                      if len(fits) > 1 else "")
            name = f"{label} + preview ({d}-D)" if with_preview else label
            print(f"| {name} | {'yes' if with_preview else 'no'} | {train:.5f} | {mse:.5f} | "
                  f"{r2:.3f}{spread} | {rms:.2f} | {const:.2f} |", flush=True)


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
