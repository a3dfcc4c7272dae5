"""Online corrections on top of a lead (panda_lead/online.py): tune them on the tuning seeds,
then play the tuned one on any seeds as a rollout set that metrics.py compares like any other.

    uv run studies/online_correction.py tune > results/studies/online/tuning.md
    uv run studies/online_correction.py play --kind repetitive --gain 0.3 --advance 15 \\
        --seeds 0-999 --prefix headline_repetitive

``tune`` plays every setting of both kinds on the 50 tuning seeds (5 s episodes, one batch
each) on top of the lead (--base policy: the model, the headline by default; --base analytic:
the analytic lead), and prints mean and settled error (t >= 0.5 s) beside the lead alone;
the lowest settled error of each kind is its tuned setting. ``play`` writes the lead with one
correction as rollouts/<prefix>/ (the set's files record the correction; a repetitive one
is labelled as knowing the planned path).
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from panda_lead.errors import UserError, exit_on_user_error, parse_cli


@dataclass
class Args:
    command: tyro.conf.Positional[Literal["tune", "play"]]
    """tune: the grid on the tuning seeds; play: one setting as a rollout set."""
    base: Literal["policy", "analytic"] = "policy"
    """The lead the correction adds to: a PPO model (--model) or the analytic lead."""
    model: Path | None = None
    """The model for --base policy (default: the headline, archive/<DEFAULT_MODEL>.zip)."""
    integral_gains: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0)
    """tune: integral gains k_i (1/s)."""
    repetitive_gains: tuple[float, ...] = (0.2, 0.3, 0.5)
    """tune: lap-to-lap gains k."""
    advances: tuple[int, ...] = (0, 5, 10, 15, 20)
    """tune: the repetitive correction's phase lead (control steps)."""
    smooths: tuple[int, ...] = (0, 3)
    """tune: the repetitive correction's low-pass half-width (control steps)."""
    kind: Literal["integral", "repetitive"] = "repetitive"
    """play: which correction."""
    gain: float = 0.3
    """play: its gain."""
    advance: int = 0
    """play: the repetitive correction's phase lead (control steps)."""
    smooth: int = 0
    """play: the repetitive correction's low-pass half-width (control steps)."""
    seeds: str = "0-999"
    """play: trajectory seeds (test seeds only for reported results)."""
    prefix: str = ""
    """play: the rollout set's name under rollouts/."""
    force: bool = False
    """play: replace a set played by another controller."""


def _base(args: Args):
    """The base controller on its evaluation env, 5 s episodes."""
    from panda_lead import harness
    from panda_lead.core import control_dt

    steps = int(round(5.0 / control_dt()))
    if args.base == "analytic":
        return harness.build("analytic", steps)
    return harness.build("policy", steps, model=args.model)


def _errors(config, act, seeds) -> tuple[float, float]:
    from panda_lead.rollout import record_many

    rollouts = record_many(config, act, seeds)
    settled = [r.error[r.t >= 0.5].mean() for r in rollouts]
    return 100 * float(np.mean([r.error.mean() for r in rollouts])), 100 * float(np.mean(settled))


def tune(args: Args) -> None:
    from panda_lead.online import OnlineCorrection, wrap
    from panda_lead.seeds import TUNE_SEEDS

    ctrl = _base(args)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    lead = ctrl.meta.get("model") or "the analytic lead"
    print(f"`uv run studies/online_correction.py tune --base {args.base}` at commit {commit}: "
          f"online corrections on top of {lead}; tuning seeds {TUNE_SEEDS[0]}-{TUNE_SEEDS[-1]} "
          f"({len(TUNE_SEEDS)}), 5 s episodes; mean / settled (t >= 0.5 s) tracking error, cm. "
          "The lowest settled error of each kind is its tuned setting.\n")
    print("| correction | gain | advance (steps) | smooth (steps) | mean error | settled |\n"
          "|---|---|---|---|---|---|")
    m, alone = _errors(ctrl.config, ctrl.act, TUNE_SEEDS)
    print(f"| none (the lead alone) | | | | {m:.3f} | {alone:.3f} |", flush=True)
    grid = [OnlineCorrection("integral", g) for g in args.integral_gains]
    grid += [OnlineCorrection("repetitive", g, a, q) for q in args.smooths
             for g in args.repetitive_gains for a in args.advances]
    best: dict[str, tuple[float, OnlineCorrection]] = {}
    for c in grid:
        m, s = _errors(ctrl.config, wrap(ctrl.act, c), TUNE_SEEDS)
        adv, q = (c.advance, c.smooth) if c.kind == "repetitive" else ("", "")
        print(f"| {c.kind} | {c.gain:g} | {adv} | {q} | {m:.3f} | {s:.3f} |", flush=True)
        if c.kind not in best or s < best[c.kind][0]:
            best[c.kind] = (s, c)
    print()
    for kind, (s, c) in best.items():
        if s >= alone:
            print(f"Tuned {kind}: off; no setting settles closer than the lead alone (best: gain "
                  f"{c.gain:g}, {s:.3f} cm against {alone:.3f})")
            continue
        extra = f" --advance {c.advance} --smooth {c.smooth}" if kind == "repetitive" else ""
        print(f"Tuned {kind}: gain {c.gain:g}{extra} (settled {s:.3f} cm): `uv run "
              f"studies/online_correction.py play --base {args.base} --kind {kind} --gain "
              f"{c.gain:g}{extra} --seeds 0-999 --prefix NAME`")


def play(args: Args) -> None:
    from panda_lead import harness
    from panda_lead.online import OnlineCorrection, wrap
    from panda_lead.rollout import ROLLOUT_DIR
    from panda_lead.seeds import parse_seed_range

    if not args.prefix:
        raise UserError("play needs --prefix NAME (the rollout set's folder under rollouts/)")
    seeds = parse_seed_range(args.seeds)
    try:
        correction = OnlineCorrection(args.kind, args.gain, args.advance, args.smooth)
    except ValueError as e:
        raise UserError(str(e)) from None
    ctrl = _base(args)
    meta = {**ctrl.meta, "online": correction.meta()}
    if correction.knows_path:
        meta["knows_path"] = True
    ctrl = harness.Controller(ctrl.name, ctrl.config, meta, wrap(ctrl.act, correction),
                              policy=ctrl.policy, dropped=ctrl.dropped)
    n = harness.write_set(ctrl, seeds, None, ROLLOUT_DIR, args.prefix, force=args.force)
    print(f"wrote {n} rollouts to {ROLLOUT_DIR / args.prefix}/")


def main() -> None:
    args = parse_cli(Args, description=__doc__)
    (tune if args.command == "tune" else play)(args)


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(main)()
