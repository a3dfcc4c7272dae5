"""The probes behind docs/deploy.md's explanations (tuning seeds only, never the test seeds):
what a low-pass does to the filtered rival, where the arm's limits bind on the paths near them,
and how much of the limit term a lead could change.

    uv run studies/deploy_probes.py rival-lowpass      # the rival with a low-pass on its lead
    uv run studies/deploy_probes.py margins --models \\
        archive/seeds/deploy_large_batch_continued_5m_s3.zip \\
        archive/seeds/deploy_large_batch_limit_continued_5m_s3.zip
    uv run studies/deploy_probes.py margins --conditions none delay1 --lead-filter-hz 0 40 25 15
    uv run studies/deploy_probes.py limit-excess   # the limit term's excess per 2 s episode

Each prints a few lines; about a minute each on the 2-core AMD EPYC.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
from deploy import SKIP_S, _error_and_jerk, _play, accepted_by_arm, controllers_for, overrides

from panda_lead.errors import UserError, exit_on_user_error


@dataclass
class Args:
    probe: tyro.conf.Positional[Literal["rival-lowpass", "margins", "limit-excess"]]
    """Which probe to run."""
    models: list[Path] = field(
        default_factory=lambda: [Path("archive/deploy_large_batch_10m.zip")])
    """margins: the models beside the analytic leads; limit-excess: the first is played."""
    conditions: list[str] = field(default_factory=lambda: ["delay1"])
    """margins: the conditions (studies/deploy.py's names)."""
    lead_filter_hz: list[float] = field(default_factory=lambda: [0.0])
    """margins: a low-pass on the models' lead (EnvConfig.lead_filter_hz), one pass per value."""


def rival_lowpass(steps: int, seeds: list[int]) -> None:
    """The filtered analytic lead at 1 cm with lead_filter_hz on its lead: its lead carries the
    correction of the IK's aim from the noisy reading to the estimate, which the low-pass
    delays."""
    from panda_lead import controllers, harness

    for hz in (0.0, 20.0, 10.0, 5.0):
        base = harness.build("analytic", steps, None,
                             {**overrides("noise1"), "lead_filter_hz": hz})
        ctrl = harness.Controller("f", base.config, {}, controllers.make_filtered_analytic())
        err, jerk = _error_and_jerk(ctrl, seeds)
        print(f"filtered analytic lead, lead low-pass {hz:4.0f} Hz: mean error {err:.3f} cm, "
              f"jerk {jerk:.0f} m/s^3", flush=True)


def margins(args: Args, steps: int, seeds: list[int]) -> None:
    """Share accepted and the worst peak / limit of the paths near the limits (<= 2.2), beside
    the 100 Hz joint goals' own peak acceleration / limit (what the limit term measures)."""
    from panda_lead import harness
    from panda_lead.limits import JOINT_ACC

    for cond in args.conditions:
        for hz in args.lead_filter_hz:
            # without a low-pass: the baselines and the models; with one: the models alone
            ctrls = ({f"{p.stem} + {hz:g} Hz": harness.build(
                "policy", steps, p, {**overrides(cond), "lead_filter_hz": hz})
                for p in args.models} if hz else controllers_for(cond, args.models, steps))
            for name, ctrl in ctrls.items():
                rs = _play(ctrl, seeds)
                checks = accepted_by_arm(rs)
                worst = np.array([checks[s].worst_margin for s in seeds])
                peak = np.array([(np.abs(np.diff(rs[s].q_goal, 2, axis=0)) / rs[s].dt ** 2
                                  / JOINT_ACC)[int(SKIP_S / rs[s].dt):].max() for s in seeds])
                near = " ".join(f"{s}:{w:.2f}/{p:.2f}"
                                for s, w, p in zip(seeds, worst, peak, strict=True) if w <= 2.2)
                print(f"{cond} {name}: accepted {100 * np.mean(worst <= 1):.0f}%, median worst "
                      f"peak/limit {np.median(worst):.2f}; near the limits (seed: 1 kHz / 100 Hz): "
                      f"{near}", flush=True)


def limit_excess(args: Args, seeds: list[int]) -> None:
    """The w_limit term's clipped excess summed over a 2 s training-length episode from 0.5 s,
    for a trained lead (deterministic) under each condition."""
    from panda_lead import harness
    from panda_lead.limits import JOINT_ACC

    for cond in ("none", "delay1", "delay3", "noise1"):
        ctrl = harness.build("policy", 200, args.models[0], overrides(cond))
        rs = _play(ctrl, seeds)
        per = [np.clip(np.abs(np.diff(r.q_goal, 2, axis=0))[int(SKIP_S / r.dt) - 2:]
                       / r.dt ** 2 / JOINT_ACC - 1, 0, 1).sum() for r in rs.values()]
        print(f"{cond}: excess per episode median {np.median(per):.1f}, mean {np.mean(per):.1f}",
              flush=True)


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.core import control_dt
    from panda_lead.seeds import TUNE_SEEDS

    for m in args.models:
        if not m.is_file():
            raise UserError(f"no model file {m}")
    for c in args.conditions:
        overrides(c)
    steps = int(round(5.0 / control_dt()))
    if args.probe == "rival-lowpass":
        rival_lowpass(steps, list(TUNE_SEEDS))
    elif args.probe == "margins":
        margins(args, steps, list(TUNE_SEEDS))
    else:
        limit_excess(args, list(TUNE_SEEDS)[:30])


if __name__ == "__main__":
    main(tyro.cli(Args, description=__doc__))
