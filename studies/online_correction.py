"""Online corrections on top of a lead (panda_lead/online.py): tune them on the tuning seeds,
then play the tuned one on any seeds as a rollout set that metrics.py compares like any other.

    uv run studies/online_correction.py tune > results/studies/online/tuning_headline.md
    uv run studies/online_correction.py play --kind repetitive --gain 0.3 --advance 15 \\
        --seeds 0-999 --prefix headline_repetitive
    uv run studies/online_correction.py play --kind repetitive --gain 0.3 --advance 15 \\
        --seeds 0-199 --prefix ilc_headline_repetitive --oracle   # its ceiling
    uv run studies/online_correction.py summary --pairs kept_s1:kept_s1_repetitive ...

``tune`` plays every setting of both kinds on the 50 tuning seeds (5 s episodes, one batch
each) on top of the lead (--base policy: the model, the headline by default; --base analytic:
the analytic lead; --base feedforward: no lead, on the model-based feedforward rival), and
prints mean and settled error (t >= 0.5 s) beside the lead alone; the lowest settled error of
each kind is its tuned setting. Both ``tune`` and ``play`` take --condition, one of
studies/deploy.py's (delay1, delay3: the lead's channel late; noise1, noise2: every reading
noisy), applied to the lead and to the correction alike. ``play`` writes the lead with one
correction as rollouts/<prefix>/ (the set's files record the correction; a repetitive one
is labelled as knowing the planned path). ``summary`` reads pairs of rollout sets (each training
seed's model alone and with the correction, the same test seeds) and prints each seed's mean
and settled error, the study's mean over seeds, and corrected minus alone with a two-level
bootstrap CI (trajectories and training seeds resampled, the two sides' seeds independently:
a conservative CI for seeds that are in fact paired; --paired-seeds adds the CI with the seeds
drawn once for both sides, for pairs that share their training seed's model); failed episodes
charged as metrics.py charges them. ``excursions`` counts, per group of sets, the episodes whose
tip is ever more than 30 cm off after the first second, and those with a self-collision: what a
mean error hides (results/studies/online/excursions.md). ``figure`` draws settled error against
tip jerk, one point per group of sets (labelled CONTROLLER @ WORLD), with two-level 95% CIs:
results/studies/online/planned_path.png. ``limits`` counts, per group of sets, the episodes a
real Panda would accept (docs/deploy.md's check), with --against LABEL each group's share minus
that group's, paired by trajectory (results/studies/online/limits_clearance.md), with --by-shape
also per shape (limits_by_shape.md), with --lost-against LABEL the episodes each group loses
against LABEL's and where each loss comes from (lost_to_correction.md). ``windows``
prints, per shape, each group's mean error in consecutive windows of the episode and the
shape's lap times (results/studies/online/windows.md). ``play`` and ``tune`` take --clearance
for the collision-aware IK under the lead and the rival alike, and --fade for a correction that
fades in instead of starting at once (a kink the Panda's limits refuse: tuning_fade.md)."""

from __future__ import annotations

import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from itertools import cycle, pairwise
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))  # preview_rivals.py, deploy.py

from panda_lead.errors import UserError, exit_on_user_error, parse_cli


@dataclass
class Args:
    command: tyro.conf.Positional[Literal["tune", "play", "summary", "excursions", "limits",
                                          "figure", "windows"]]
    """tune: the grid on the tuning seeds; play: one setting as a rollout set; summary: a
    five-seed study's sets with and without a correction (--pairs); excursions: the rare large
    errors and self-collisions of groups of sets (--groups); limits: the episodes a real Panda
    would accept, per group of sets (studies/deploy.py's check, --groups); figure: settled
    error against jerk, one point per group of sets (--groups, --out); windows: per shape, each
    group's mean error in consecutive windows of the episode, and the shape's lap times
    (--groups, --window)."""
    base: Literal["policy", "analytic", "feedforward"] = "policy"
    """The lead the correction adds to: a PPO model (--model), the analytic lead, or none on
    top of the model-based feedforward rival (EnvConfig.feedforward: the correction is then
    the rival's lap-to-lap version, shifting the target its IK aims at)."""
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
    condition: str = "none"
    """tune and play: one of studies/deploy.py's conditions, applied to the lead and the
    correction alike: none, delay1 and delay3 (the lead's channel 1 or 3 control steps late
    both ways: the correction runs where the lead runs), noise1 and noise2 (every reading
    noisy, the IK aiming at the target reading; the correction reads the measured error),
    targetnoise1, targetnoise2 (online.py). The target camera (camera1, camera3) is refused.
    A noise condition with the suffix _plan (noise1_plan) aims the IK at the planned path, the
    readings as noisy: what a controller that knows the plan does. On --base feedforward the IK
    always aims at the plan (it is known, not measured): the noise reaches the rival only
    through the error its correction reads."""
    kind: Literal["integral", "repetitive"] = "repetitive"
    """play: which correction."""
    gain: float = 0.3
    """play: its gain."""
    advance: int = 0
    """play: the repetitive correction's phase lead (control steps)."""
    smooth: int = 0
    """play: the repetitive correction's low-pass half-width (control steps)."""
    max_error: float = 0.0
    """tune and play: the repetitive correction does not learn from errors farther than this
    (m; 0: from all): the gate, the same for every setting of the tuning grid."""
    fade: float = 0.0
    """tune and play: the correction learns from the errors after its start with a weight that
    rises smoothly from 0 to 1 over this time (s; online.OnlineCorrection.weight); 0: at once.
    A correction switched on at once starts with a kink the real arm's limits refuse."""
    clearance: float = 0.0
    """tune and play: the collision-aware IK's clearance (m; --env.ik.clearance, clearance.py),
    for the lead and the rival alike; 0: the plain IK. The correction acts on the target the IK
    aims at, so the IK's damper still has the last word on every joint step."""
    follow_plan: bool = False
    """tune and play: the planner's hand (EnvConfig.follow_plan): an episode whose whole plan
    the arm can follow hands its joint goal over to the plan (the feedforward_plan rival's
    law); the others keep the lead and its correction. Knows the planned path."""
    seeds: str = "0-999"
    """play: trajectory seeds (test seeds only for reported results)."""
    duration: float = 5.0
    """play: the episodes' length (s); 5 s is the test seeds' length, and every result but the
    10 s check's (results_prepare.LONG_EPISODES: what the correction reaches once it has had the
    laps) uses it."""
    prefix: str = ""
    """play: the rollout set's name under rollouts/."""
    force: bool = False
    """play: replace a set played by another controller; figure: replace an existing --out."""
    oracle: bool = False
    """play: the ILC oracle restarted from the lead with the correction (its ceiling, what
    metrics.py --oracle reads for the share of the gain), instead of the lead itself. With
    --follow-plan the start and every replay run with the planner's hand: the oracle learns
    the lead wherever the plan does not hold the arm (an episode it holds ignores the lead);
    with --clearance every replay runs on the collision-aware IK."""
    pairs: list[str] = field(default_factory=list)
    """summary: PLAIN:CORRECTED rollout-set prefixes, one pair per training seed's model."""
    bootstrap: int = 10000
    """summary: resamples of the two-level bootstrap."""
    groups: list[str] = field(default_factory=list)
    """excursions and figure: LABEL=PREFIX,PREFIX,... (a study's sets, counted together), one
    per group; for figure, LABEL is CONTROLLER @ WORLD (one colour per controller, one marker
    per world, a controller's worlds joined)."""
    against: str = ""
    """limits: a group's label; each group's accepted share is also given minus that group's,
    paired by trajectory (each group's sets averaged per trajectory), with a 95% bootstrap CI
    over trajectories (--bootstrap resamples)."""
    lost_against: str = ""
    """limits: a group's label; also list, per other group, the episodes that group's sets accept
    and this group's refuse (set paired with set, or all with its one set): the worst limit, when
    it peaks, when the two sets' leads part, and how far the peak lies from a spline's waypoint
    (where the spline's acceleration steps)."""
    by_shape: bool = False
    """limits: also a table of each group's accepted episodes per shape (where the differences
    between controllers lie)."""
    list_seeds: bool = False
    """excursions: also list, per group, the trajectories with an episode far off: how many of
    the group's sets go far off on it, their mean error there and how many touch themselves."""
    out: Path | None = None
    """figure: the PNG to write."""
    window: float = 0.5
    """windows: their width (s), from 0.5 s (after the swing from home) to the episode's end."""
    paired_seeds: bool = False
    """summary: each pair's two sets come from one training seed's model (one model with and
    without the correction, or two continuations of one model): print a seed-paired CI (the
    seeds drawn once for both sides) beside the conservative one."""
    levels: bool = False
    """summary: also each side's mean and settled error as a level with its 95% CI (the same
    two-level bootstrap over training seeds and trajectories), for a target stated as a level
    (issue 37's settled <= 0.6 cm)."""
    settle_time: float = 0.5
    """summary: the settled error is the mean from this time on (s; 5 for the second half of
    10 s episodes)."""
    names: tuple[str, str] = ("plain", "with the correction")
    """summary: what the two sides of each pair are, for the table (e.g. "added after
    training" "trained with it")."""


PLAN = "_plan"  # a noise condition with the IK aimed at the planned path: noise1_plan


def condition_overrides(name: str, base: str = "policy") -> dict | None:
    """The env overrides of one of studies/deploy.py's conditions for a base (None: the ideal
    world). Under deploy.py's noise the IK aims at the target's reading; NAME_plan (noise1_plan,
    ...) aims it at the planned path instead, the readings as noisy: what a controller that knows
    the plan does. The feedforward rival always does (the plan is known, not measured): the
    noise reaches it only through the error its correction reads."""
    from deploy import overrides  # the deploy table's own definitions

    on_plan = name.endswith(PLAN)
    name = name.removesuffix(PLAN)
    if name.startswith("camera"):
        raise UserError(f"--condition {name}: an online correction reads the tip's error; with a "
                        "late target camera it would read a stale one (not built)")
    late = overrides(name)
    if on_plan and "noisy_ik_target" not in late:
        raise UserError(f"--condition {name}{PLAN}: only a noise condition has an IK to aim at "
                        "the plan instead of the target's reading")
    if (on_plan or base == "feedforward") and "noisy_ik_target" in late:
        late["noisy_ik_target"] = False  # said, not left to the model's own env
    return late or None


def _base(args: Args):
    """The base controller on its evaluation env, --duration s episodes (5 s: the test
    seeds')."""
    from dataclasses import replace

    from panda_lead import harness
    from panda_lead.core import control_dt

    if not (np.isfinite(args.duration) and args.duration > 0):
        raise UserError(f"--duration must be a positive number of seconds, got {args.duration}")
    steps = int(round(args.duration / control_dt()))
    if args.base != "policy" and args.model is not None:
        raise UserError(f"--model is for --base policy; the {args.base} base has none")
    late = _arm_overrides(args, condition_overrides(args.condition, args.base))
    if args.base == "analytic":
        return harness.build("analytic", steps, overrides=late)
    if args.base == "feedforward":  # a zero lead on the feedforward env is that rival (a test)
        ctrl = harness.build("classical", steps, overrides=late)
        meta = {**ctrl.meta, "controller": "feedforward", "knows_path": True}
        return replace(ctrl, config=ctrl.config.replace(feedforward=True), meta=meta)
    return harness.build("policy", steps, model=args.model, overrides=late)


def _oracle(args: Args, correction):
    """The ILC oracle (harness's, its default settings) whose first replay is the lead with the
    correction; its files record that start (model hash and correction: ilc.oracle_meta)."""
    from dataclasses import replace

    from panda_lead import harness
    from panda_lead.core import control_dt
    from panda_lead.ilc import ILCConfig, oracle_meta
    from panda_lead.online import wrap

    ilc = ILCConfig(init="policy" if args.base == "policy" else "analytic")
    ctrl = harness.build("ilc", int(round(5.0 / control_dt())), model=args.model, ilc=ilc,
                         overrides=_arm_overrides(args))  # the start's, every replay's too
    meta = {**ctrl.meta, "ilc": oracle_meta(ilc, ctrl.meta["ilc"]["start_model_sha256"],
                                            correction.meta(), args.follow_plan,
                                            args.clearance)}
    return replace(ctrl, meta=meta, init_act=wrap(ctrl.init_act, correction))


def _arm_overrides(args: Args, late: dict | None = None) -> dict | None:
    """LATE (a condition's env settings) with what --clearance and --follow-plan add: the env
    the base, or the oracle's start and every replay, runs on (a bad --clearance refused
    before anything is played or written)."""
    if not (np.isfinite(args.clearance) and args.clearance >= 0):
        raise UserError(f"--clearance must be a distance >= 0 (m), got {args.clearance}")
    arm = ({"ik": {"clearance": args.clearance}} if args.clearance else {}) | (
        {"follow_plan": True} if args.follow_plan else {})
    return {**(late or {}), **arm} or None


def _check_fade(args: Args) -> None:
    """--fade is a time: refused before anything is played or written."""
    if not (np.isfinite(args.fade) and args.fade >= 0):
        raise UserError(f"--fade must be a time >= 0 (s), got {args.fade:g}")


def tune(args: Args) -> None:
    from preview_rivals import mean_errors  # the same scoring the preview rivals were tuned by

    from panda_lead.online import OnlineCorrection, wrap
    from panda_lead.seeds import TUNE_SEEDS

    _check_fade(args)
    if args.duration != Args.duration:
        raise UserError("--duration is for play: the tuning plays the test seeds' 5 s episodes")
    ctrl = _base(args)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    lead = ctrl.meta.get("model") or {"analytic": "the analytic lead",
                                      "feedforward": "the feedforward rival"}[args.base]
    given = f" --model {args.model}" if args.model is not None else ""
    given += f" --condition {args.condition}" if args.condition != "none" else ""
    given += f" --max-error {args.max_error:g}" if args.max_error else ""
    given += f" --fade {args.fade:g}" if args.fade else ""
    given += f" --clearance {args.clearance:g}" if args.clearance else ""
    given += " --follow-plan" if args.follow_plan else ""
    grid_flags = "".join(f" --{name.replace('_', '-')} {' '.join(f'{v:g}' for v in getattr(args, name))}"
                         for name in ("integral_gains", "repetitive_gains", "advances", "smooths")
                         if getattr(args, name) != getattr(Args, name))
    print(f"`uv run studies/online_correction.py tune --base {args.base}{given}{grid_flags}` at "
          f"commit {commit}: "
          f"online corrections on top of {lead}; tuning seeds {TUNE_SEEDS[0]}-{TUNE_SEEDS[-1]} "
          f"({len(TUNE_SEEDS)}), 5 s episodes; mean / settled (t >= 0.5 s) tracking error, cm. "
          "The lowest settled error of each kind is its tuned setting.\n")
    print("| correction | gain | advance (steps) | smooth (steps) | mean error | settled |\n"
          "|---|---|---|---|---|---|")
    m, alone = mean_errors(ctrl.config, ctrl.act, TUNE_SEEDS)
    print(f"| none (the lead alone) | | | | {m:.3f} | {alone:.3f} |", flush=True)
    grid = [OnlineCorrection("integral", g, fade=args.fade) for g in args.integral_gains]
    grid += [OnlineCorrection("repetitive", g, a, q, max_error=args.max_error, fade=args.fade)
             for q in args.smooths for g in args.repetitive_gains for a in args.advances]
    best: dict[str, tuple[float, OnlineCorrection]] = {}
    for c in grid:
        m, s = mean_errors(ctrl.config, wrap(ctrl.act, c), TUNE_SEEDS)
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
              f"studies/online_correction.py play --base {args.base}{given} --kind {kind} "
              f"--gain {c.gain:g}{extra} --seeds 0-999 --prefix NAME`")


def play(args: Args) -> None:
    from panda_lead import harness
    from panda_lead.online import OnlineCorrection, wrap
    from panda_lead.rollout import ROLLOUT_DIR
    from panda_lead.seeds import parse_seed_range

    if not args.prefix:
        raise UserError("play needs --prefix NAME (the rollout set's folder under rollouts/)")
    _check_fade(args)
    seeds = parse_seed_range(args.seeds)
    try:
        correction = OnlineCorrection(args.kind, args.gain, args.advance, args.smooth,
                                      max_error=args.max_error, fade=args.fade)
    except ValueError as e:
        raise UserError(str(e)) from None
    if args.oracle:
        if args.duration != Args.duration:
            raise UserError("--oracle replays the test seeds' 5 s episodes: drop --duration")
        if args.condition != "none":
            raise UserError("--oracle replays in the ideal world: drop --condition")
        if args.base == "feedforward":
            raise UserError("--oracle starts the ILC oracle from a Cartesian lead on the plain "
                            "env; the feedforward base has none (its oracle is not built)")
        ctrl = _oracle(args, correction)
    else:
        ctrl = _base(args)
        meta = {**ctrl.meta, "online": correction.meta()}
        if correction.knows_path:
            meta["knows_path"] = True
        ctrl = harness.Controller(ctrl.name, ctrl.config, meta, wrap(ctrl.act, correction),
                                  policy=ctrl.policy, dropped=ctrl.dropped)
    n = harness.write_set(ctrl, seeds, None, ROLLOUT_DIR, args.prefix, force=args.force)
    print(f"wrote {n} rollouts to {ROLLOUT_DIR / args.prefix}/")


def _set_metrics(prefix: str, settle_time: float = 0.5) -> dict[int, dict[str, float]]:
    from panda_lead.metrics.pairing import charged_metrics, load_set
    from panda_lead.rollout import ROLLOUT_DIR

    return charged_metrics(load_set(prefix, ROLLOUT_DIR), settle_time)


def summary(args: Args) -> None:
    from panda_lead.metrics.pairing import seed_set_title
    from panda_lead.metrics.stats import shown, two_level_bootstrap

    if not args.pairs or any(p.count(":") != 1 for p in args.pairs):
        raise UserError("summary needs --pairs PLAIN:CORRECTED ... (rollout-set prefixes)")
    if any(not n.strip() for n in args.names):
        raise UserError("summary --names needs two non-empty names")
    if not (np.isfinite(args.settle_time) and args.settle_time >= 0):
        raise UserError(f"--settle-time must be >= 0 s, got {args.settle_time}")
    sets = [tuple(_set_metrics(x, args.settle_time) for x in p.split(":")) for p in args.pairs]
    seeds = sorted(set.intersection(*(set(a) & set(b) for a, b in sets)))
    if not seeds:
        raise UserError("the pairs' rollout sets share no trajectory seed")
    a_name, b_name = args.names
    named = "" if args.names == Args.names else " --names " + shlex.join(args.names)
    flags = named + (" --paired-seeds" if args.paired_seeds else "")
    flags += f" --settle-time {args.settle_time:g}" if args.settle_time != Args.settle_time else ""
    flags += " --levels" if args.levels else ""
    print(f"`uv run studies/online_correction.py summary --pairs {' '.join(args.pairs)}{flags}`: "
          f"{seed_set_title(seeds, 'trajectories')}; errors in cm, settled from "
          f"{args.settle_time:g} s; "
          + ("the corrected minus the plain set" if not named else f"{b_name} minus {a_name}")
          + ".\n")
    print(f"| pair | mean error, {a_name} | {b_name} | settled, {a_name} | {b_name} | "
          "settled diff |\n|---|---|---|---|---|---|")
    arrays = {k: ([], []) for k in ("mean_err", "settled_err", "jerk_rms")}
    for pair, (a, b) in zip(args.pairs, sets, strict=True):
        for k, (plain, corrected) in arrays.items():
            plain.append([a[s][k] for s in seeds])
            corrected.append([b[s][k] for s in seeds])
        m = {k: (np.mean(v[0][-1]), np.mean(v[1][-1])) for k, v in arrays.items()}
        print(f"| {pair} | {m['mean_err'][0]:.3f} | {m['mean_err'][1]:.3f} | "
              f"{m['settled_err'][0]:.3f} | {m['settled_err'][1]:.3f} | "
              f"{m['settled_err'][1] - m['settled_err'][0]:+.3f} |")
    print()
    rng = np.random.default_rng(0)
    paired_rng = np.random.default_rng(1)  # its own stream: the conservative CIs stay as they were
    for k, label in (("mean_err", "mean error (cm)"), ("settled_err", "settled error (cm)"),
                     ("jerk_rms", "tip jerk RMS (m/s^3)")):
        plain, corrected = (np.array(x) for x in arrays[k])
        per_seed = [x.mean(axis=1) for x in (plain, corrected)]
        ci, _ = two_level_bootstrap(plain, corrected, args.bootstrap, rng)
        diff = corrected.mean() - plain.mean()
        paired = ""
        if args.paired_seeds:
            pci, _ = two_level_bootstrap(plain, corrected, args.bootstrap, paired_rng,
                                         paired=True)
            paired = (f"; seed-paired [{pci[0]:+.3f}, {pci[1]:+.3f}] "
                      f"{'shown' if shown(pci) else 'not shown'}")
        spread = [f" +- {x.std(ddof=1):.3f}" if len(x) > 1 else "" for x in per_seed]
        over = (f"mean +- std over the {len(sets)} seeds" if len(sets) > 1
                else "one seed: no spread")  # (one pair: a std over one value is undefined)
        print(f"- {label}: {a_name} {per_seed[0].mean():.3f}{spread[0]}, "
              f"{b_name} {per_seed[1].mean():.3f}{spread[1]} ({over}); "
              f"diff {diff:+.3f} [{ci[0]:+.3f}, "
              f"{ci[1]:+.3f}] {'shown' if shown(ci) else 'not shown'}{paired}")
    if args.levels:
        _print_levels(arrays, (a_name, b_name), args.bootstrap)


def _print_levels(arrays: dict, names: tuple[str, str], n_boot: int) -> None:
    """Each side's mean and settled error as a level, 95% CI by the two-level bootstrap (its
    own random stream: the difference CIs above stay as they were)."""
    from panda_lead.metrics.stats import two_level_bootstrap

    rng = np.random.default_rng(2)
    print()
    for k, label in (("mean_err", "mean error (cm)"), ("settled_err", "settled error (cm)")):
        for name, side in zip(names, arrays[k], strict=True):
            side = np.array(side)
            ci, _ = two_level_bootstrap(np.zeros((1, side.shape[1])), side, n_boot, rng)
            print(f"- level, {label}, {name}: {side.mean():.3f} [{ci[0]:.3f}, {ci[1]:.3f}]")


FAR, AFTER = 0.30, 1.0  # m, s: an excursion is the tip this far off after the swing from home


def _groups(args: Args) -> list[tuple[str, list[str]]]:
    """--groups as (label, rollout-set prefixes)."""
    if not args.groups or any(g.count("=") != 1 or not g.split("=")[1] for g in args.groups):
        raise UserError(f"{args.command} needs --groups LABEL=PREFIX,PREFIX,... (rollout sets)")
    return [(label, prefixes.split(",")) for label, prefixes in
            (g.split("=") for g in args.groups)]


def excursions(args: Args) -> None:
    """Per group of rollout sets: its episodes, those whose tip is ever more than FAR off
    after AFTER s, and those with any self-collision after AFTER s (what a mean hides)."""
    from panda_lead.metrics.pairing import load_set
    from panda_lead.rollout import ROLLOUT_DIR

    groups = _groups(args)
    flag = " --list-seeds" if args.list_seeds else ""
    print(f"`uv run studies/online_correction.py excursions --groups {shlex.join(args.groups)}"
          f"{flag}`: "
          f"episodes whose tip is ever more than {100 * FAR:g} cm off, and with any "
          f"self-collision, after the first {AFTER:g} s.\n")
    print(f"| group | episodes | > {100 * FAR:g} cm off | self-collision |\n|---|---|---|---|")
    listed = {}
    for label, prefixes in groups:
        episodes = far = touched = 0
        seeds: dict[int, list] = {}  # trajectory -> (mean error, touched) of each far episode
        for prefix in prefixes:
            for seed, r in load_set(prefix, ROLLOUT_DIR).items():
                late = r.t >= AFTER
                episodes += 1
                is_far = bool(r.error[late].max() > FAR)
                touches = bool(np.asarray(r.self_collision)[late].any())
                far += is_far
                touched += touches
                if is_far:
                    seeds.setdefault(seed, []).append((100 * r.error.mean(), touches))
        print(f"| {label} | {episodes} | {far} | {touched} |")
        listed[label] = (seeds, len(prefixes))
    if not args.list_seeds:
        return
    print("\nThe trajectories far off: seed (sets far off on it / the group's sets; their mean "
          "error there, cm; how many of them touch themselves).\n")
    for label, (seeds, n_sets) in listed.items():
        items = [f"{seed} ({len(v)}/{n_sets}; {np.mean([e for e, _ in v]):.1f}; "
                 f"{sum(t for _, t in v)})" for seed, v in sorted(seeds.items())]
        print(f"- {label}: {', '.join(items) or 'none'}")


def limits(args: Args) -> None:
    """Per group of rollout sets: its episodes and those a real Panda would accept from the
    swing's end on (studies/deploy.py's check: the 100 Hz joint goals interpolated to 1 kHz,
    low-passed as libfranka does, every joint's and the tip's velocity, acceleration and jerk
    within the published limits)."""
    from deploy import SKIP_S, accepted_by_arm

    from panda_lead.metrics.pairing import load_set
    from panda_lead.metrics.stats import paired_ci, shown
    from panda_lead.rollout import ROLLOUT_DIR

    groups = _groups(args)
    labels = [label for label, _ in groups]
    for flag, label in (("--against", args.against), ("--lost-against", args.lost_against)):
        if label and label not in labels:
            raise UserError(f"{flag} {label!r} is not a group's label; the groups: "
                            + ", ".join(labels))
    shares: dict[str, dict[int, float]] = {}  # label -> trajectory -> accepted share of its sets
    counts: dict[str, tuple[int, int]] = {}  # label -> (episodes, accepted)
    shapes: dict[int, str] = {}  # trajectory -> its shape
    per_set: dict[str, dict[int, list[bool]]] = {}  # label -> trajectory -> accepted, per set
    checked: dict[str, dict] = {}  # set -> trajectory -> its check (for --lost-against)
    leads: dict[str, dict] = {}  # set -> trajectory -> (lead, t), kept for --lost-against only
    for label, prefixes in groups:
        per_seed: dict[int, list[bool]] = {}
        for prefix in prefixes:
            rollouts = load_set(prefix, ROLLOUT_DIR)
            shapes.update((seed, r.meta.get("shape", "?")) for seed, r in rollouts.items())
            checked[prefix] = accepted_by_arm(rollouts)
            if args.lost_against:
                leads[prefix] = {seed: (r.lead, r.t) for seed, r in rollouts.items()}
            for seed, c in checked[prefix].items():
                per_seed.setdefault(seed, []).append(bool(c.accepted))
        per_set[label] = per_seed
        shares[label] = {seed: float(np.mean(v)) for seed, v in per_seed.items()}
        counts[label] = (sum(map(len, per_seed.values())), sum(map(sum, per_seed.values())))
    flag = f" --against {shlex.quote(args.against)}" if args.against else ""
    flag += " --by-shape" if args.by_shape else ""
    flag += f" --lost-against {shlex.quote(args.lost_against)}" if args.lost_against else ""
    print(f"`uv run studies/online_correction.py limits --groups {shlex.join(args.groups)}{flag}`: "
          f"episodes a real Panda would accept from {SKIP_S:g} s on (docs/deploy.md's check)"
          + (f"; each group minus {args.against!r}, paired by trajectory (each group's sets "
             f"averaged per trajectory), 95% bootstrap CI over trajectories ({args.bootstrap} "
             "resamples)" if args.against else "") + ".\n")
    extra = f" | minus {args.against} (points) |" if args.against else " |"
    print(f"| group | episodes | accepted | share{extra}\n|---|---|---|---|"
          + ("---|" if args.against else ""))
    for label in labels:
        episodes, accepted = counts[label]
        row = f"| {label} | {episodes} | {accepted} | {100 * accepted / episodes:.1f}% |"
        if args.against and label != args.against:
            ref = shares[args.against]
            seeds = sorted(set(ref) & set(shares[label]))
            diff = 100 * np.array([shares[label][s] - ref[s] for s in seeds])
            ci = paired_ci(diff, args.bootstrap)
            row += (f" {diff.mean():+.1f} [{ci[0]:+.1f}, {ci[1]:+.1f}] "
                    f"{'shown' if shown(ci) else 'not shown'} |")
        elif args.against:
            row += " |"
        print(row)
    if args.by_shape:  # each group's accepted episodes per shape, its sets summed
        names = sorted(set(shapes.values()))
        print(f"\nAccepted episodes per shape (of the group's episodes on that shape):\n\n"
              f"| group | {' | '.join(names)} |\n|---|{'---|' * len(names)}")
        for label in labels:
            cells = []
            for name in names:
                runs = [ok for seed, oks in per_set[label].items() if shapes[seed] == name
                        for ok in oks]
                cells.append(f"{sum(runs)} of {len(runs)}")
            print(f"| {label} | {' | '.join(cells)} |")
    if args.lost_against:
        _lost_episodes(groups, args.lost_against, checked, leads, shapes)


def _lost_episodes(groups: list[tuple[str, list[str]]], against: str, checked: dict,
                   leads: dict, shapes: dict) -> None:
    """limits --lost-against: per group, the episodes ``against``'s sets accept and the group's
    refuse, with where the refusal comes from (``checked``: each set's checks, ``leads``: its
    (lead, t) per trajectory, ``shapes``: each trajectory's shape; all read once, by limits)."""
    from collections import Counter

    from panda_lead.trajectory import sample

    reference = dict(groups)[against]
    for label, prefixes in groups:
        if label == against:
            continue
        if len(reference) not in (1, len(prefixes)):
            raise UserError(f"--lost-against {against!r}: its {len(reference)} sets pair neither "
                            f"with {label!r}'s {len(prefixes)} nor all with one")
        rows = []
        for i, prefix in enumerate(prefixes):
            ref_prefix = reference[i if len(reference) > 1 else 0]
            mine, theirs = leads[prefix], leads[ref_prefix]
            checks, ref_checks = checked[prefix], checked[ref_prefix]
            for seed in sorted(set(checks) & set(ref_checks)):
                if not ref_checks[seed].accepted or checks[seed].accepted:
                    continue
                c, (lead, t) = checks[seed], mine[seed]
                apart = np.flatnonzero(np.any(lead != theirs[seed][0], axis=1))
                part = t[apart[0]] if len(apart) and apart[0] > 0 else None
                traj = sample(seed)
                seg = traj.params.get("segment_time") if traj.shape == shapes[seed] else None
                waypoint = (min(c.worst_time % seg, seg - c.worst_time % seg) if seg else None)
                rows.append((prefix, seed, shapes[seed], c, part, waypoint))
        print(f"\nEpisodes {against!r} accepts and {label!r} refuses (set paired with set): "
              f"the worst limit, its peak / limit, when it peaks (s), when the two leads part (s; "
              f"- where they differ from the start), the peak's distance to the nearest spline "
              f"waypoint (s).\n\n| set | seed | shape | worst limit | margin | peaks at | leads part "
              f"at | to a waypoint |\n|---|---|---|---|---|---|---|---|")
        for prefix, seed, shape, c, part, waypoint in rows:
            cells = [f"{x:.2f}" if x is not None else "-" for x in (part, waypoint)]
            print(f"| {prefix} | {seed} | {shape} | {c.worst_limit} | {c.worst_margin:.2f} | "
                  f"{c.worst_time:.2f} | {cells[0]} | {cells[1]} |")
        parted = [abs(c.worst_time - part) <= 0.1 for *_, c, part, _ in rows if part is not None]
        near = [w <= 0.05 for *_, w in rows if w is not None]
        kinds = ", ".join(f"{k} {n}" for k, n in Counter(row[3].worst_limit for row in rows)
                          .most_common())
        print(f"\n{label}: {len(rows)} episodes lost ({kinds or 'none'}); the worst peak within "
              f"0.1 s of the leads parting in {sum(parted)} of {len(parted)}, within 0.05 s of a "
              f"spline waypoint in {sum(near)} of {len(near)}.")


def figure_points(groups: list[tuple[str, list[str]]], n_boot: int) -> tuple[list[dict], list]:
    """Each group's point (controller, world, settled error with its two-level CI, jerk, number
    of sets) over the trajectories its sets share, and the seeds every group shares."""
    from panda_lead.metrics.stats import two_level_bootstrap

    rng, points, shared = np.random.default_rng(0), [], None
    for label, prefixes in groups:
        controller, _, world = (x.strip() for x in label.partition(" @ "))
        sets = [_set_metrics(p) for p in prefixes]
        seeds = sorted(set.intersection(*(set(m) for m in sets)))
        if not seeds:
            raise UserError(f"figure: the sets of {label!r} share no trajectory seed")
        shared = seeds if shared is None else sorted(set(shared) & set(seeds))
        settled, jerk = (np.array([[m[k][key] for k in seeds] for m in sets])
                         for key in ("settled_err", "jerk_rms"))
        points.append(dict(controller=controller, world=world or "ideal world",
                           # the level's CI: its difference from a study that is all zeros
                           err=float(settled.mean()), ci=two_level_bootstrap(
                               np.zeros((1, len(seeds))), settled, n_boot, rng)[0],
                           jerk=float(jerk.mean()), sets=len(sets)))
    return points, shared or []


def figure(args: Args) -> None:
    """Settled error (95% CI, two levels) against tip jerk, one point per group of sets (the
    mean over its sets of the mean over the trajectories all of them share); lower left is
    better."""
    from panda_lead.metrics.figures import pyplot, save_figure
    from panda_lead.metrics.pairing import seed_set_title

    groups = _groups(args)
    if args.out is None or args.out.suffix != ".png":
        raise UserError("figure needs --out PATH.png")
    if args.out.exists() and not args.force:
        raise UserError(f"{args.out} exists: --force replaces it")
    points, shared = figure_points(groups, args.bootstrap // 5)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(13, 6), constrained_layout=True)
    controllers = list(dict.fromkeys(p["controller"] for p in points))
    worlds = list(dict.fromkeys(p["world"] for p in points))
    # strong hues in the order the groups come (rivals first, say): light shades vanish
    colours = dict(zip(controllers, cycle(["C3", "C4", "C0", "C2", "C1", "C5", "C6", "C9"]),
                       strict=False))
    markers = dict(zip(worlds, cycle("osD^v<>"), strict=False))
    for name in controllers:
        mine = [p for p in points if p["controller"] == name]
        ax.plot([p["jerk"] for p in mine], [p["err"] for p in mine], "-", color=colours[name],
                alpha=0.35)
        for p in mine:
            lo, hi = p["ci"]
            ax.errorbar(p["jerk"], p["err"], yerr=[[p["err"] - lo], [hi - p["err"]]],
                        fmt=markers[p["world"]], color=colours[name], capsize=2, ms=7,
                        mec="black", mew=0.5)
        sets = max(p["sets"] for p in mine)
        ax.plot([], [], "-", color=colours[name], lw=4,
                label=name + (f" (mean of {sets} seeds)" if sets > 1 else ""))
    for world in worlds:
        ax.plot([], [], markers[world], color="grey", label=world)
    ax.set(xlabel="tip jerk RMS (m/s^3)", ylabel="settled tracking error, t >= 0.5 s (cm), 95% CI",
           title=f"Settled error against jerk ({seed_set_title(shared, 'trajectories')}); "
                 "lower left is better\n(each CI is of a level; differences are paired in the "
                 "tables, with narrower CIs)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_figure(fig, args.out)
    print(f"wrote {args.out}")


def windows(args: Args) -> None:
    """Per shape, each group's mean tracking error (cm) in consecutive windows from 0.5 s, over
    the trajectory seeds all groups share (a group of several sets: their mean), and the lap
    times of that shape's trajectories there: where in the episode a correction's gain comes."""
    from panda_lead import trajectory
    from panda_lead.metrics.pairing import load_set, seed_set_title
    from panda_lead.rollout import ROLLOUT_DIR

    groups = _groups(args)
    if not (np.isfinite(args.window) and args.window > 0):
        raise UserError(f"--window must be a positive number of seconds, got {args.window}")
    sets = {label: [load_set(p, ROLLOUT_DIR) for p in prefixes] for label, prefixes in groups}
    seeds = sorted(set.intersection(*(set(s) for group in sets.values() for s in group)))
    if not seeds:
        raise UserError("windows: the groups' sets share no trajectory seed")
    first = next(iter(sets.values()))[0]
    end = min(min(s[k].t[-1] for k in seeds) for group in sets.values() for s in group)
    edges = np.arange(0.5, end + 1e-9, args.window)
    print(f"`uv run studies/online_correction.py windows --groups {shlex.join(args.groups)}"
          f"{'' if args.window == Args.window else f' --window {args.window:g}'}`: "
          f"{seed_set_title(seeds, 'trajectories')}; mean tracking error (cm) per window.\n")
    for shape in sorted({first[k].shape for k in seeds}):
        mine = [k for k in seeds if first[k].shape == shape]
        laps = np.array([trajectory.sample(k, shape).params["lap_time"] for k in mine])
        print(f"**{shape}** ({len(mine)} trajectories; lap time median {np.median(laps):.2f} s, "
              f"{np.mean(laps <= 2.5):.0%} within 2.5 s)\n")
        print("| group | " + " | ".join(f"{a:g}-{b:g} s" for a, b in pairwise(edges))
              + " |\n|---|" + "---|" * (len(edges) - 1))
        for label, group in sets.items():
            cells = [np.mean([100 * s[k].error[(s[k].t >= a) & (s[k].t < b)].mean()
                              for s in group for k in mine])
                     for a, b in pairwise(edges)]
            print(f"| {label} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
        print()


def main() -> None:
    args = parse_cli(Args, description=__doc__)
    {"tune": tune, "play": play, "summary": summary, "excursions": excursions, "limits": limits,
     "figure": figure, "windows": windows}[args.command](args)


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(main)()
