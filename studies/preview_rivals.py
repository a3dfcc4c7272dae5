"""Tune the two classical rivals that know the planned path on the tuning seeds (never the test
seeds): the future-target lead's tau, and the model-based feedforward's tau, gain and IK
look-ahead (panda_lead/preview.py).

    uv run studies/preview_rivals.py > results/studies/preview/rivals_tuning.md
    uv run studies/preview_rivals.py --no-future --plan-settings 0:0:half 0.2:0.4:half
    uv run studies/preview_rivals.py --followable 0-999   # which episodes the arm can follow

(--plan-settings: the feedforward that follows its plan, feedforward_plan, its grid and what
rivals_tuning_plan.md records; --followable: results/studies/preview/followable.md.)

Every setting plays all 50 tuning seeds (5 s episodes) as one batch; the lowest mean error
wins and is what controllers.FUTURE_TAU / FEEDFORWARD_* hold. The analytic lead at its tuned
tau is printed alongside for scale.
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass

import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    duration: float = 5.0
    """Episode length in seconds."""
    future_taus: tuple[float, ...] = (0.02, 0.03, 0.04, 0.05, 0.06, 0.08)
    """Candidate look-aheads of the future-target lead (s)."""
    ff_settings: tuple[str, ...] = ("0.01:1.0:0.01", "0.0:1.0:0.01", "0.02:1.0:0.01",
                                    "0.01:0.8:0.01", "0.01:1.2:0.01", "0.01:1.0:0.0",
                                    "0.01:1.0:0.02", "0.01:1.0:none")
    """Feedforward settings tau:gain:tau_ik (s, -, s; tau_ik 'none': the planned joint path
    alone, no IK at run time)."""
    clip: bool = False
    """The feedforward's servo correction clipped to what each motor can push (the rival in
    use: controllers.FEEDFORWARD_CLIP; off by default, as the first two rounds were run)."""
    future: bool = True
    """Also tune the future-target lead (--no-future: the feedforward's grid alone)."""
    followable: str = ""
    """A seed range (e.g. 0-999): instead of tuning, count per shape the episodes whose whole
    planned path the arm can follow (the ones feedforward_plan and EnvConfig.follow_plan hand
    over to the plan)."""
    plan_settings: tuple[str, ...] = ()
    """Settings of the feedforward that follows its plan where the arm can (feedforward_plan,
    its fallback the feedforward in use), start:ramp:ahead (s; ahead 'half': half a control
    period); when given, these are tuned instead of the feedforward's grid."""


def mean_errors(config, act, seeds, median: bool = False) -> tuple[float, ...]:
    """Mean and settled (t >= 0.5 s) tracking error over ``seeds`` (cm); with ``median``, also
    the median trajectory's settled error (what a typical path gets, where fast circles the
    controller cannot follow dominate the mean)."""
    from panda_lead.rollout import record_many

    rollouts = record_many(config, act, seeds)
    settled = [r.error[r.t >= 0.5].mean() for r in rollouts]
    out = 100 * float(np.mean([r.error.mean() for r in rollouts])), 100 * float(np.mean(settled))
    return (*out, 100 * float(np.median(settled))) if median else out


def followable(seeds: str, duration: float) -> None:
    """Per shape: how many of the episodes on ``seeds`` the arm can follow all the way (every
    step of the plan within the motors' force ranges and the joint limits)."""
    from panda_lead import preview
    from panda_lead.config import EnvConfig
    from panda_lead.core import control_dt
    from panda_lead.seeds import parse_seed_range
    from panda_lead.task import LeadTask

    picked = list(parse_seed_range(seeds))
    steps = int(round(duration / control_dt()))
    flags, shapes = [], []
    for i in range(0, len(picked), 250):  # a batch's plans at once, 250 arms at a time
        batch = picked[i:i + 250]
        task = LeadTask(EnvConfig(episode_steps=steps), len(batch))
        task.reset(None, batch)
        cache = preview._PathCache(0.0, joint_path=True)
        cache.update(task)
        flags += cache.followable.tolist()
        shapes += [t.shape for t in task.trajs]
    length = f" --duration {duration:g}" if duration != Args.duration else ""
    print(f"`uv run studies/preview_rivals.py --followable {seeds}{length}`: seeds {seeds} "
          f"({len(picked)}), {duration:g} s episodes; an episode is followable when every step "
          "of its planned path asks no motor for more than its force range and keeps every "
          "joint goal inside the limits (preview._PathCache.within)\n")
    print("| shape | episodes | followable | share |\n|---|---|---|---|")
    flags, shapes = np.array(flags), np.array(shapes)
    for shape in (*sorted(set(shapes)), "all"):
        mask = shapes == shape if shape != "all" else np.ones_like(flags)
        print(f"| {shape} | {mask.sum()} | {flags[mask].sum()} | {flags[mask].mean():.1%} |")


def main(args: Args) -> None:
    if args.followable:
        followable(args.followable, args.duration)
        return
    from panda_lead import controllers, preview
    from panda_lead.config import EnvConfig
    from panda_lead.core import control_dt
    from panda_lead.seeds import TUNE_SEEDS

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    flags = " --clip" if args.clip else ""
    flags += "" if args.future else " --no-future"
    if args.ff_settings != Args.ff_settings:
        flags += " --ff-settings " + " ".join(args.ff_settings)
    if args.plan_settings:
        flags += " --plan-settings " + " ".join(args.plan_settings)
    print(f"`uv run studies/preview_rivals.py{flags}` at commit {commit}; tuning seeds "
          f"{TUNE_SEEDS[0]}-{TUNE_SEEDS[-1]} ({len(TUNE_SEEDS)}), {args.duration:g} s episodes; "
          "mean / settled (t >= 0.5 s) tracking error, cm\n")
    config = EnvConfig(episode_steps=int(round(args.duration / control_dt())))
    print("| controller | setting | mean error | settled |\n|---|---|---|---|")
    m, s = mean_errors(config, controllers.make_analytic(), TUNE_SEEDS)
    print(f"| analytic lead | tau {controllers.DEFAULT_TAU} s | {m:.2f} | {s:.2f} |", flush=True)
    future = {}
    for tau in args.future_taus if args.future else ():
        future[tau] = mean_errors(config, preview.make_future_target(tau), TUNE_SEEDS)
        print(f"| future target | tau {tau} s | {future[tau][0]:.2f} | {future[tau][1]:.2f} |",
              flush=True)
    joint = config.replace(action="joint_target")
    if args.plan_settings:
        _tune_plan(args, joint)
        return
    ff = {}
    for setting in args.ff_settings:
        tau, gain, tau_ik = setting.split(":")
        ik = None if tau_ik == "none" else float(tau_ik)
        ff[setting] = mean_errors(joint, preview.make_feedforward(float(tau), float(gain), ik,
                                                                  args.clip), TUNE_SEEDS)
        clipped = ", clipped to the motors" if args.clip else ""
        print(f"| model-based feedforward | tau {tau} s, gain {gain}, IK look-ahead {tau_ik}{clipped} "
              f"| {ff[setting][0]:.2f} | {ff[setting][1]:.2f} |", flush=True)
    best_ff = min(ff, key=lambda k: ff[k][0])
    best = ""
    if future:
        best_f = min(future, key=lambda k: future[k][0])
        best = f"future target tau {best_f} s ({future[best_f][0]:.2f} cm); "
    print(f"\nbest: {best}feedforward {best_ff} ({ff[best_ff][0]:.2f} cm). In use: future "
          f"target tau {controllers.FUTURE_TAU} s; feedforward tau {controllers.FEEDFORWARD_TAU}, "
          f"gain {controllers.FEEDFORWARD_GAIN}, IK look-ahead {controllers.FEEDFORWARD_TAU_IK}, "
          f"clipped {controllers.FEEDFORWARD_CLIP}.")


def _tune_plan(args: Args, joint) -> None:
    from panda_lead import controllers, preview
    from panda_lead.seeds import TUNE_SEEDS

    fallback = controllers.FEEDFORWARD_SETTINGS
    print("\n(the plan-following grid: the settled error's median trajectory too)\n\n"
          "| controller | setting | mean error | settled | median settled |\n|---|---|---|---|---|")
    m, s, med = mean_errors(joint, controllers.make_feedforward(), TUNE_SEEDS, median=True)
    print(f"| model-based feedforward (in use) | tau {fallback['tau']} s, gain {fallback['gain']}, "
          f"IK look-ahead {fallback['tau_ik']} | {m:.2f} | {s:.2f} | {med:.2f} |", flush=True)
    plan = {}
    for setting in args.plan_settings:
        start, ramp, ahead = setting.split(":")
        act = preview.make_planned_feedforward((float(start), float(ramp)), fallback,
                                               None if ahead == "half" else float(ahead))
        plan[setting] = mean_errors(joint, act, TUNE_SEEDS, median=True)
        print(f"| feedforward that follows its plan | handover from {start} s over {ramp} s, "
              f"plan read {ahead if ahead == 'half' else ahead + ' s'} ahead | "
              f"{plan[setting][0]:.2f} | {plan[setting][1]:.2f} | {plan[setting][2]:.2f} |",
              flush=True)
    best = min(plan, key=lambda k: plan[k][0])
    print(f"\nbest: {best} ({plan[best][0]:.2f} cm). In use: handover "
          f"{controllers.PLAN_HANDOVER}, plan read half a control period ahead.")


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
