"""The share of its own oracles' gain a study captures, over its training seeds.

    uv run studies/oracle_share.py --pairs SEED1_SET:SEED1_ORACLE SEED2_SET:SEED2_ORACLE ...

(studies/results.py runs it on the hardware study's five seeds, with the planner's hand and
without: results/studies/online/hand_with_oracle_study.md, fade_with_oracle_study.md.)

Each pair is one training seed's rollout set and the ILC oracle restarted from that seed's
controller (studies/online_correction.py play --oracle; panda_lead/ilc.py). metrics.py --oracle
gives one model's share of the gain its oracle shows over a reference, with a CI over
trajectories; a study of five seeds has five such shares. This prints them and the study's:
(reference - study) / (reference - oracles), each side its mean over seeds and trajectories,
with the 95% CI of a two-level bootstrap (trajectories and training seeds drawn with
replacement, a seed's set and its own oracle drawn together: metrics.stats.two_level_share).
The mean error and the settled error (from --settle-time), on the trajectories every set shares;
failed episodes charged as metrics.py charges them. An oracle that did not start from its
pair's controller (another model, correction or hand) is refused, as metrics.py refuses it.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panda_lead.errors import UserError, exit_on_user_error, parse_cli


@dataclass
class Args:
    pairs: list[str] = field(default_factory=list)
    """SET:ORACLE rollout-set prefixes, one pair per training seed."""
    reference: str = "analytic"
    """The rollout set the gain is measured from (the analytic lead, as metrics.py --oracle)."""
    root: Path = Path("rollouts")
    """Folder of rollout sets."""
    settle_time: float = 0.5
    """The settled error is the mean from this time on (s)."""
    bootstrap: int = 10000
    """Resamples of the two-level bootstrap."""


KEYS = (("mean_err", "mean error"), ("settled_err", "settled mean error"))


def main(args: Args) -> None:
    from panda_lead.ilc import check_oracle_start
    from panda_lead.metrics.pairing import charged_metrics, check_sets, load_set, seed_set_title
    from panda_lead.metrics.stats import two_level_share

    if not args.pairs or any(p.count(":") != 1 or "" in p.split(":") for p in args.pairs):
        raise UserError("oracle_share.py needs --pairs SET:ORACLE ... (rollout-set prefixes, "
                        "one pair per training seed)")
    if not (np.isfinite(args.settle_time) and args.settle_time >= 0):
        raise UserError(f"--settle-time must be >= 0 s, got {args.settle_time}")
    if args.bootstrap < 1:
        raise UserError(f"--bootstrap must be >= 1, got {args.bootstrap}")
    pairs = [tuple(p.split(":")) for p in args.pairs]
    loaded = {name: load_set(name, args.root)
              for name in dict.fromkeys([args.reference, *(x for p in pairs for x in p)])}
    check_sets(loaded)  # the same trajectory behind every seed number
    meta = {name: next(iter(rollouts.values())).meta for name, rollouts in loaded.items()}
    for lead, oracle in pairs:
        if not (meta[oracle].get("ilc") or {}).get("oracle"):
            raise UserError(f"{oracle} is not an ILC oracle's rollout set (its pair: {lead})")
        check_oracle_start(meta[oracle], {args.reference: meta[args.reference], lead: meta[lead]},
                           oracle)
    seeds = sorted(set.intersection(*(set(r) for r in loaded.values())))
    if len(seeds) < 2:
        raise UserError(f"the sets share {len(seeds)} trajectory seeds; the share needs >= 2")
    scored = {name: charged_metrics({s: loaded[name][s] for s in seeds}, args.settle_time)
              for name in loaded}

    def array(name: str, key: str) -> np.ndarray:
        return np.array([scored[name][s][key] for s in seeds])

    extra = "" if args.reference == Args.reference else f" --reference {args.reference}"
    extra += f" --settle-time {args.settle_time:g}" if args.settle_time != Args.settle_time else ""
    print(f"`uv run studies/oracle_share.py --pairs {shlex.join(args.pairs)}{extra}`: "
          f"{seed_set_title(seeds, 'trajectories')}; errors in cm, settled from "
          f"{args.settle_time:g} s; reference {args.reference}; share = (reference - set) / "
          "(reference - its oracle): 1 = the oracle's error, 0 = no gain over the reference.\n")
    print("| set | oracle | mean error, set / oracle | share | settled, set / oracle | share |\n"
          "|---|---|---|---|---|---|")
    for lead, oracle in pairs:
        cells = []
        for key, _ in KEYS:
            ref, mine, top = (array(n, key).mean() for n in (args.reference, lead, oracle))
            cells += [f"{mine:.2f} / {top:.2f}", f"{(ref - mine) / (ref - top):.0%}"]
        print(f"| {lead} | {oracle} | {' | '.join(cells)} |")
    print()
    rng = np.random.default_rng(0)
    for key, label in KEYS:
        ref = array(args.reference, key)
        lead = np.array([array(p[0], key) for p in pairs])
        top = np.array([array(p[1], key) for p in pairs])
        if not all(np.isfinite(x).all() for x in (ref, lead, top)):
            raise UserError(f"a {label} is undefined (no step from --settle-time "
                            f"{args.settle_time:g} s on): give a time inside the episodes")
        share, (lo, hi) = two_level_share(ref, lead, top, args.bootstrap, rng)
        print(f"- {label}: {args.reference} {ref.mean():.2f}, the {len(pairs)} sets "
              f"{lead.mean():.2f}, their oracles {top.mean():.2f} cm; captured "
              f"**{share:.0%} [{100 * lo:.0f}, {100 * hi:.0f}]** (two-level bootstrap over the "
              "seeds and the trajectories)")


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
