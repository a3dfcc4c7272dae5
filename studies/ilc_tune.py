"""Choose the ILC oracle's settings on the tuning seeds (never the test seeds).

    uv run studies/ilc_tune.py                       # the grid below, ~30 min on 2 cores
    uv run studies/ilc_tune.py --gains 0.5 --shifts 3 --inits analytic --iterations 10

For every (first replay's lead, gain, shift) of the grid, the oracle (panda_lead/ilc.py) runs
``--iterations`` replays of all tuning trajectories at once and records the mean tracking error
after each replay. The table (results/studies/ilc/ilc_tuning.md) gives the error after 10, 20
and the last replay; the chosen setting is the lowest error at the last replay, ties to the
fewer replays, and becomes ILCConfig's defaults.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from panda_lead.errors import UserError, exit_on_user_error, parse_cli


@dataclass
class Args:
    inits: list[str] = field(default_factory=lambda: ["analytic", "policy"])
    """First replays to try: analytic, zero, policy (the --model's lead)."""
    gains: list[float] = field(default_factory=lambda: [0.5, 1.0])
    """ILC gains to try."""
    shifts: list[int] = field(default_factory=lambda: [2, 3, 4, 5, 6])
    """Error shifts (control steps) to try."""
    taps: int = 5
    """Smoothing taps (fixed)."""
    iterations: int = 40
    """Replays per grid point (the table reads off the error after 10, 20 and this many)."""
    model: Path = Path("archive/indep_v5.zip")
    """The policy whose lead starts the 'policy' runs."""
    duration: float = 5.0
    """Episode length (s)."""
    out: Path = Path("results/studies/ilc/ilc_tuning.md")
    """The table."""
    force: bool = False
    """Replace an existing --out."""


MAX_DURATION_S = 1000.0  # eval.py's bound


def grid(args: Args) -> list:
    """Every grid point's ILCConfig, each value checked (ILCConfig's bounds, the first replays
    known, nothing named twice) before the first of ~30 minutes of replays."""
    from panda_lead.ilc import INITS, ILCConfig

    for flag, values in (("--inits", args.inits), ("--gains", args.gains),
                         ("--shifts", args.shifts)):
        if not values:
            raise UserError(f"{flag} needs at least one value")
        if len(set(values)) != len(values):
            raise UserError(f"{flag} names a value twice: {' '.join(map(str, values))}")
    for init in args.inits:
        if init not in INITS:
            raise UserError(f"--inits: unknown first replay {init!r} (valid: {', '.join(INITS)})")
    if not (math.isfinite(args.duration) and 0 < args.duration <= MAX_DURATION_S):
        raise UserError(f"--duration must be a number of seconds in (0, {MAX_DURATION_S:g}], got "
                        f"{args.duration}")
    try:
        return [ILCConfig(gain=gain, shift=shift, taps=args.taps, iterations=args.iterations,
                          init=init)
                for init, gain, shift in itertools.product(args.inits, args.gains, args.shifts)]
    except UserError as exc:  # "ilc.shift must be in [0, 50]" -> the flag given here
        raise UserError(str(exc).replace("ilc.", "--", 1).replace("--shift ", "--shifts ")
                        .replace("--gain ", "--gains ")) from None


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.config import EnvConfig
    from panda_lead.controllers import classical, make_analytic, make_policy
    from panda_lead.core import control_dt
    from panda_lead.models import load_policy
    from panda_lead.outputs import claimed_outputs
    from panda_lead.seeds import TUNE_SEEDS

    points = grid(args)
    steps = int(round(args.duration / control_dt()))
    if steps < 1:
        raise UserError(f"--duration {args.duration} s is shorter than one control step")
    with claimed_outputs([args.out], "--out", args.force):  # a second run on --out stops here
        policy, env_config, side = load_policy(args.model)
        config = EnvConfig.from_dict(env_config).replace(episode_steps=steps)
        starts = {"analytic": make_analytic(), "zero": classical, "policy": make_policy(policy)}
        seeds = list(TUNE_SEEDS)
        rows = [tune_point(config, seeds, ilc, starts[ilc.init]) for ilc in points]
        write_table(args, rows, seeds, side)


def tune_point(config, seeds: list[int], ilc, start) -> tuple:
    """(error after the last replay, init, gain, shift, {replay: error}) of one grid point."""
    from panda_lead.ilc import learn_leads

    t0 = time.time()
    _, history = learn_leads(config, seeds, None, ilc, start)
    at = {k: history[min(k, len(history) - 1)] for k in (0, 10, 20, ilc.iterations)}
    print(f"init {ilc.init:8s} gain {ilc.gain:g} shift {ilc.shift}: {at[0]:.3f} -> "
          f"{at[10]:.3f} (10) -> {at[20]:.3f} (20) -> {at[ilc.iterations]:.3f} cm "
          f"({ilc.iterations}); {time.time() - t0:.0f} s", flush=True)
    return at[ilc.iterations], ilc.init, ilc.gain, ilc.shift, at


def write_table(args: Args, rows: list, seeds: list[int], side: dict) -> None:
    from panda_lead.atomicio import atomic_write

    best = min(rows, key=lambda r: (round(r[0], 3), r[4][20]))
    lines = [f"# ILC oracle tuning: tuning seeds {seeds[0]}-{seeds[-1]} (n={len(seeds)}), "
             f"{args.duration:g} s episodes", "",
             f"`uv run studies/ilc_tune.py` (model for the policy start: {args.model}, sha256 "
             f"{side['model_sha256'][:12]}). Mean tracking error over all trajectories (cm) "
             "after the first replay and after 10, 20 and "
             f"{args.iterations} ILC replays; smoothing {args.taps} taps.", "",
             "| first replay | gain | shift | start | 10 | 20 | "
             f"{args.iterations} |", "|---|---|---|---|---|---|---|"]
    for final, init, gain, shift, at in sorted(rows, key=lambda r: r[0]):
        lines.append(f"| {init} | {gain:g} | {shift} | {at[0]:.3f} | {at[10]:.3f} | "
                     f"{at[20]:.3f} | {final:.3f} |")
    lines += ["", f"Chosen (lowest error after {args.iterations} replays): first replay "
              f"{best[1]}, gain {best[2]:g}, shift {best[3]}."]
    with atomic_write(args.out, ".tmp.md") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
