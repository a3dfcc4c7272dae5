"""Where a controller's settled error comes from: a bias or a wobble, per shape.

    uv run studies/bias.py --prefixes analytic v5_5m ilc       # rollout sets under rollouts/

For each rollout, over the settled window (t >= 0.5 s, after the swing from the home pose):
- settled: the mean of |tip - target| (the settled error of docs/metrics.md);
- bias: |mean of (tip - target)|, the part of the error that a constant offset of the lead
  for the whole trajectory would cancel (an integrator's job);
- wobble: the mean of |e - e smoothed over 11 steps (0.11 s)|, the fast part of the error;
- lead step, lead 2nd diff: the mean of |lead(t+1) - lead(t)| and of its second difference
  (mm per control step), how much the lead itself moves: a chattering lead, one that flips
  back and forth, has a second difference larger than its step.
Printed per shape and overall: the mean over rollouts, the median in brackets (cm; the lead
columns mm), on the seeds every set holds. ``--agreement`` adds how far each set's lead is from
the first set's on the same trajectory (settled window): the RMS of the difference and the
length of its mean, beside the first set's lead RMS. Two ILC oracles started from different
leads (`uv run studies/bias.py --prefixes ilc ilc_preview_finetuned --agreement`) say whether
the ceiling's lead is one function of the trajectory or one of many that track as well.
It reads rollout files only, under metrics.py's rules: sets that mix controllers or durations
are refused, failed episodes are charged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panda_lead.errors import UserError, exit_on_user_error, parse_cli

SETTLE_S = 0.5
SMOOTH_STEPS = 11


@dataclass
class Args:
    prefixes: list[str] = field(default_factory=lambda: ["analytic", "v5_5m", "ilc"])
    """Rollout sets (folders under --root) to compare."""
    root: Path = Path("rollouts")
    """Where the rollout sets live."""
    agreement: bool = False
    """Also each set's lead against the first set's, per trajectory (see above)."""


def parts(r) -> tuple[float, float, float]:
    """(settled, bias, wobble) of one rollout, in cm."""
    e = (r.ee_pos - r.target_pos)[r.t >= SETTLE_S - 1e-9]
    if len(e) <= 2 * SMOOTH_STEPS:
        raise UserError(f"seed {r.seed}: too short to split ({len(e)} settled steps)")
    kernel = np.ones(SMOOTH_STEPS) / SMOOTH_STEPS
    smooth = np.stack([np.convolve(e[:, j], kernel, mode="same") for j in range(3)], axis=1)
    inner = slice(SMOOTH_STEPS, -SMOOTH_STEPS)  # away from the convolution's edges
    return (100 * float(np.linalg.norm(e, axis=1).mean()),
            100 * float(np.linalg.norm(e.mean(axis=0))),
            100 * float(np.linalg.norm((e - smooth)[inner], axis=1).mean()))


def lead_steps(r) -> tuple[float, float]:
    """(mean |first difference|, mean |second difference|) of the lead over the settled
    window, in mm per control step."""
    lead = r.lead[r.t >= SETTLE_S - 1e-9]
    return (1000 * float(np.linalg.norm(np.diff(lead, axis=0), axis=1).mean()),
            1000 * float(np.linalg.norm(np.diff(lead, 2, axis=0), axis=1).mean()))


def lead_agreement(r, ref) -> tuple[float, float, float]:
    """(RMS of ref's lead, RMS of r's lead - ref's, |mean of r's lead - ref's|) over the
    settled window, in cm."""
    keep = ref.t >= SETTLE_S - 1e-9
    d = (r.lead - ref.lead)[keep]
    return (100 * float(np.sqrt(np.mean(np.sum(ref.lead[keep] ** 2, axis=1)))),
            100 * float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))),
            100 * float(np.linalg.norm(d.mean(axis=0))))


def load_sets(prefixes: list[str], root: Path):
    """The sets under metrics.py's rules (panda_lead.metrics: one controller per set, one
    duration and dt, one shape per seed; paired on the seeds all hold, each failed episode
    charged as if the arm froze where it failed). Returns the Pairing."""
    from panda_lead.errors import check_plain_name
    from panda_lead.metrics.pairing import check_sets, load_set, pair, require_seeds

    if not prefixes:
        raise UserError("--prefixes needs at least one rollout set")
    if len(set(prefixes)) != len(prefixes):
        raise UserError(f"--prefixes names a set twice: {' '.join(prefixes)}")
    sets = {p: load_set(check_plain_name(p, "--prefixes"), root) for p in prefixes}
    check_sets(sets)
    paired = pair(sets)
    require_seeds(paired, sets)
    return paired


@exit_on_user_error
def main(args: Args) -> None:
    import sys

    paired = load_sets(list(args.prefixes), args.root)
    for line in paired.warnings():
        print(line, file=sys.stderr)
    sets = paired.scored
    shapes = sorted({r.shape for r in sets[args.prefixes[0]].values()})
    print(f"settled window t >= {SETTLE_S} s; {paired.counts()}; mean over rollouts "
          "[median], cm\n")
    print("| shape | n | set | settled | bias | wobble | lead step (mm) | lead 2nd diff (mm) |")
    print("|---|---|---|---|---|---|---|---|")
    for shape in [*shapes, "all"]:
        for p, s in sets.items():
            rows = np.array([(*parts(r), *lead_steps(r)) for r in s.values()
                             if shape in ("all", r.shape)])
            cells = " | ".join(f"{m:.2f} [{md:.2f}]" for m, md in
                               zip(rows.mean(axis=0), np.median(rows, axis=0), strict=True))
            print(f"| {shape} | {len(rows)} | {p} | {cells} |")
    if args.agreement and len(sets) > 1:
        first, ref = args.prefixes[0], sets[args.prefixes[0]]
        print(f"\nEach set's lead against {first}'s on the same trajectory, t >= {SETTLE_S} s; "
              "mean over rollouts [median], cm\n")
        print(f"| shape | n | set | {first}'s lead RMS | RMS of the difference | "
              "constant difference |")
        print("|---|---|---|---|---|---|")
        for shape in [*shapes, "all"]:
            for p in args.prefixes[1:]:
                rows = np.array([lead_agreement(r, ref[seed]) for seed, r in sets[p].items()
                                 if shape in ("all", r.shape)])
                cells = " | ".join(f"{m:.2f} [{md:.2f}]" for m, md in
                                   zip(rows.mean(axis=0), np.median(rows, axis=0), strict=True))
                print(f"| {shape} | {len(rows)} | {p} | {cells} |")


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
