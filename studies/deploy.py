"""Deployability: tracking, smoothness and the real arm's limits under every condition, one table.

    uv run studies/deploy.py --models archive/v5_err_decay_s4.zip archive/delayed_5m.zip \\
        --seeds 0-499
    uv run studies/deploy.py --studies deploy_large_batch_continued_5m \\
        deploy_large_batch_curv10_continued_5m --seeds 0-999 --conditions none delay1

Every controller plays the test seeds under each condition (rows): no delay; 1 and 3 control
steps of latency; 1 and 2 cm of observation noise. Per controller and condition: mean, median
and settled tracking error, tip jerk (RMS at 100 Hz), and whether a real Panda would accept the
motion (panda_lead.limits: the commanded joint goals as the 1 kHz command libfranka sends,
against the published joint and tip limits, after the first 0.5 s swing from home): the share
of trajectories accepted and the median worst margin. Paired differences against the analytic
lead under the same condition come from panda_lead.metrics.compare (95% bootstrap CIs).
Writes <out>/deploy.md and <out>/deploy.png (error against jerk, one point per controller per
condition: the Pareto picture). With --studies A B, every archived seed of both studies plays
too, and a table gives B minus A per condition, each study the mean over its seeds per
trajectory (CIs: metrics.two_level_bootstrap, training seeds and trajectories resampled).

The conditions (docs/deploy.md says what each means physically):
- latency k: the lead's channel is k control steps late both ways (its observation and the
  lead it returns), the IK aims at the present target and reads the present joint state: a
  slow lead computer or bus. Every controller sees it; the classical controller, which has no
  lead, is unaffected by construction.
- target camera k: the target is seen k control steps late by every controller, for the IK's
  aim point as well as for what a lead observes (EnvConfig.target_delay): the classical
  controller lags by k steps more, and the rival predicts through the delay.
- noise s cm: Gaussian noise on every measured input of the observation, positions s, velocities
  10 s per second, the target's acceleration 100 s per second squared; the tip error a learned
  lead observes is the tip reading minus the target reading, noise and all (sqrt(2) s, the
  same draws as its ee_pos and target_pos), and the IK aims at the target reading.
- target noise s cm (targetnoise1, targetnoise2, targetnoise0.1; not in the default rows): the
  same noise on the target's readings only, the arm's state exact: a camera sees the target while the tip
  comes from the joint encoders through the kinematics, as on a real Panda. It separates the
  jerk that the target's noise causes from the jerk that a noisy tip reading causes.
The rivals a good engineer would field: under noise the analytic lead with a Kalman filter on
the target's position, velocity and acceleration (controllers.make_filtered_analytic, tuned on
the tuning seeds: --tune-filter); under latency the analytic lead that predicts through the
known delay (controllers.make_predicting_analytic).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
from robustness import condition as robustness_condition  # noqa: E402

from panda_lead.errors import UserError, exit_on_user_error  # noqa: E402
from panda_lead.seeds import set_name  # noqa: E402

CONDITIONS = ("none", "delay1", "delay3", "camera1", "camera3", "noise1", "noise2",
              "targetnoise1", "targetnoise2", "targetnoise0.1")
DEFAULT_CONDITIONS = CONDITIONS[:7]
LABELS = {"none": "no delay, no noise", "delay1": "latency 1 step (10 ms)",
          "delay3": "latency 3 steps (30 ms)", "camera1": "target camera 1 step (10 ms)",
          "camera3": "target camera 3 steps (30 ms)", "noise1": "noise 1 cm",
          "noise2": "noise 2 cm", "targetnoise1": "target noise 1 cm (arm exact)",
          "targetnoise2": "target noise 2 cm (arm exact)",
          "targetnoise0.1": "target noise 1 mm (arm exact)"}
SKIP_S = 0.5  # the swing from home, as the settled error leaves it out
# the figure's marker per condition (strict: a new condition without one fails on import)
MARKERS = dict(zip(CONDITIONS, ("o", "s", "D", "<", ">", "^", "v", "P", "X", "*"), strict=True))


@dataclass
class Args:
    models: list[Path] = field(default_factory=list)
    """Archived models to evaluate beside the classical and analytic controllers."""
    seeds: str = "0-499"
    """Test seeds."""
    conditions: list[str] = field(default_factory=lambda: list(DEFAULT_CONDITIONS))
    """Rows, from: none delay1 delay3 camera1 camera3 noise1 noise2 targetnoise1
    targetnoise2 targetnoise0.1."""
    out: Path = Path("results/studies/deploy")
    """Folder for deploy.md and deploy.png."""
    bootstrap: int = 10000
    """Bootstrap resamples for the CIs."""
    duration: float = 5.0
    """Seconds per episode."""
    force: bool = False
    """Replace an existing deploy.md and deploy.png."""
    noisy_lead_filter_hz: float | None = None
    """Run every model with this lead low-pass under noise (EnvConfig.noisy_lead_filter_hz;
    off without noise), over each model's own setting; the models' labels say so."""
    tune_filter: bool = False
    """Instead of the table: tune the Kalman filter's jerk density on the tuning seeds at 1 cm
    of noise and print each candidate's mean error."""
    tune_lead_filter: Path | None = None
    """Instead of the table: tune this model's lead low-pass under noise (EnvConfig.
    noisy_lead_filter_hz) on the tuning seeds at 1 cm of noise: each cutoff's mean error and
    jerk, and the rule's choice, the lowest jerk at no more error than without the filter."""
    tune_on: int = 0
    """With --tune-lead-filter or --tune-filter: tune on the first N selection-set trajectories
    (seeds from 5,000,000: never trained, tuned or tested on) instead of the 50 tuning seeds;
    0: the tuning seeds. More trajectories make the rule's error criterion steadier."""
    studies: list[str] = field(default_factory=list)
    """Two study names, A then B: every archived seed's model of each (archive/seeds/
    <study>_s<k>.zip) joins --models, and a further table gives B minus A per condition
    (accepted share, mean error, jerk), each study the mean over its seeds per trajectory, 95%
    CIs by the two-level bootstrap over training seeds and trajectories (studies/runs.py
    compare's)."""
    check_from: list[float] = field(default_factory=list)
    """Also check the arm's limits from these later times (s, each > 0.5 and < the episode):
    a third table, the share accepted by when the check starts, to see how much of a
    difference lies in the end of the swing from home rather than in the tracking."""


def overrides(cond: str) -> dict:
    if cond not in CONDITIONS:
        raise UserError(f"unknown condition {cond!r}; choose from {', '.join(CONDITIONS)}")
    if cond == "none":
        return {}
    if cond.startswith("delay"):
        return robustness_condition("delay", float(cond[5:]))
    if cond.startswith("camera"):  # the target seen k steps late by every controller's IK too
        return {"target_delay": int(cond[6:]), "random_delay": False}
    level = float(cond.removeprefix("target")[5:])
    settings = robustness_condition("noise", level)  # (the tip error: the two readings')
    if cond.startswith("target"):  # the arm's readings exact: the encoders'
        settings["obs_noise"] = {k: v for k, v in settings["obs_noise"].items()
                                 if k.startswith("target")}
    settings["noisy_ik_target"] = True  # the IK aims at the measured target too
    return settings


def controllers_for(cond: str, models: list[Path], steps: int,
                    lead_hz: float | None = None) -> dict:
    """label -> harness.Controller under one condition: the baselines, the rival an engineer
    would field under this condition, and each model."""
    from panda_lead import controllers, harness

    settings = overrides(cond)
    out = {"Classical": harness.build("classical", steps, None, settings),
           "Analytic": harness.build("analytic", steps, None, settings)}
    analytic = out["Analytic"]
    if "noise" in cond:
        out["Analytic+filter"] = harness.Controller(
            "analytic+filter", analytic.config,
            {**analytic.meta, "controller": "analytic+filter",
             "jerk_psd": controllers.DEFAULT_JERK_PSD},
            controllers.make_filtered_analytic())
    if cond.startswith(("delay", "camera")):
        out["Analytic+predict"] = harness.Controller(
            "analytic+predict", analytic.config,
            {**analytic.meta, "controller": "analytic+predict"},
            controllers.make_predicting_analytic())
    for path, label in zip(models, harness.model_labels(models), strict=True):
        if lead_hz is not None:
            label = f"{label} + lead low-pass {lead_hz:g} Hz under noise"
        out[label] = harness.build("policy", steps, path, settings if lead_hz is None else
                                   {**settings, "noisy_lead_filter_hz": lead_hz})
    return out


def accepted_by_arm(rollouts: dict, skip: float = SKIP_S) -> dict[int, object]:
    """seed -> limits.Check from ``skip`` seconds on; an episode that failed (ended early) is
    not accepted."""
    from panda_lead.core import home_qpos
    from panda_lead.limits import Check, check_many

    home = home_qpos()
    full = {s: r for s, r in rollouts.items() if not r.meta.get("failure")}
    by_len: dict[int, list[int]] = {}
    for s, r in full.items():
        by_len.setdefault(len(r.t), []).append(s)
    out = {s: Check(False, float("inf"), "episode failed", {}) for s in rollouts
           if s not in full}
    for seeds in by_len.values():
        for start in range(0, len(seeds), 64):
            chunk = seeds[start:start + 64]
            q = np.stack([full[s].q_goal for s in chunk])
            for s, c in zip(chunk, check_many(q, full[chunk[0]].dt, home, skip=skip),
                            strict=True):
                out[s] = c
    return out


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.core import control_dt
    from panda_lead.seeds import parse_seed_range

    for c in args.conditions:
        overrides(c)
    for t in args.check_from:
        if not SKIP_S < t < args.duration:
            raise UserError(f"--check-from {t:g}: must lie after {SKIP_S:g} s and before the "
                            f"episode's end ({args.duration:g} s)")
    for m in args.models:
        if not m.is_file():
            raise UserError(f"no model file {m}")
    by_study = study_models(args.studies)
    models = args.models + [m for paths in by_study.values() for m in paths]
    seeds = parse_seed_range(args.seeds)
    steps = int(round(args.duration / control_dt()))
    if args.tune_filter:
        return tune_filter(steps, args.tune_on)
    if args.tune_lead_filter is not None:
        if not args.tune_lead_filter.is_file():
            raise UserError(f"no model file {args.tune_lead_filter}")
        return tune_lead_filter(args.tune_lead_filter, steps, args.tune_on)
    outputs = [args.out / "deploy.md", args.out / "deploy.png"]
    if any(p.exists() for p in outputs) and not args.force:
        raise UserError(f"{outputs[0]} or its figure exists; add --force to replace them")
    rows, rival_rows, window_rows, t0 = [], [], [], time.perf_counter()
    label_of: dict[Path, str] = {}
    for cond in args.conditions:
        ctrls = controllers_for(cond, models, steps, args.noisy_lead_filter_hz)
        sets = {name: _play(c, seeds) for name, c in ctrls.items()}
        checks = {name: accepted_by_arm(rs) for name, rs in sets.items()}
        rival = next((r for r in RIVALS if r in sets), None)
        labels = list(sets)[len(sets) - len(models):]  # (controllers_for puts them last)
        label_of = dict(zip(models, labels, strict=True))  # each row's name for a model
        rival_rows += [_rival_row(cond, rival, name, sets, args.bootstrap)
                       for name in (labels if rival else [])]
        for name, rs in sets.items():
            rows.append(_row(cond, name, sets["Analytic"], rs, checks["Analytic"],
                             checks[name], args.bootstrap))
            r = rows[-1]
            print(f"{cond:7s} {name:28s} error {r['err'].mean_b:5.2f} cm, jerk "
                  f"{r['jerk'].mean_b:7.1f}, accepted {100 * r['share']:3.0f}% "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
        if args.check_from:  # each controller checked once per start (0.5 s: done above)
            by_start = {SKIP_S: checks, **{t: {name: accepted_by_arm(rs, t)
                                               for name, rs in sets.items()}
                                           for t in args.check_from}}
            window_rows += [_window_row(cond, name, at, t, args.bootstrap)
                            for name in sets for t, at in by_start.items()]
        del sets
    from panda_lead.atomicio import atomic_write

    text = (table(args, rows, seeds) + rival_table(rival_rows)
            + study_table(rows, by_study, label_of, args.bootstrap) + window_table(window_rows))
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_write(outputs[0], ".tmp.md") as tmp:
        Path(tmp).write_text(text)
    figure(args, rows, seeds, outputs[1])
    print(text)


def _play(ctrl, seeds: list[int]) -> dict:
    from panda_lead.rollout import iter_record

    return {r.seed: r for r in iter_record(ctrl.config, ctrl.act, seeds, meta=ctrl.meta)}


def _row(cond: str, name: str, analytic: dict, rollouts: dict, checks_a: dict, checks: dict,
         n_boot: int) -> dict:
    """One controller under one condition, paired by seed with the analytic lead."""
    from panda_lead.metrics import bootstrap_ci, compare, sign_test_p

    cmp = compare(analytic, rollouts, n_boot=n_boot, label_a="Analytic", label_b=name)
    ok = np.array([float(checks[s].accepted) for s in cmp.seeds])
    ok_a = np.array([float(checks_a[s].accepted) for s in cmp.seeds])
    hit: dict[str, int] = {}
    for s in cmp.seeds:
        hit[checks[s].worst_limit] = hit.get(checks[s].worst_limit, 0) + 1
    errs = [cmp.metrics_b[s]["mean_err"] for s in cmp.seeds]
    # per trajectory, in cmp.seeds' order (every seed, failures charged): what study_table pairs
    per_traj = {"accepted": ok, "mean_err": np.array(errs),
                "jerk_rms": np.array([cmp.metrics_b[s]["jerk_rms"] for s in cmp.seeds])}
    return {"cond": cond, "name": name, "per_traj": per_traj, "err": cmp.row("mean_err"),
            "err_ci": bootstrap_ci(errs, n_boot=n_boot),
            "settled": cmp.row("settled_err"), "jerk": cmp.row("jerk_rms"),
            "share": float(ok.mean()), "share_ci": bootstrap_ci(ok, n_boot=n_boot),
            "share_delta": float((ok - ok_a).mean()),
            "share_delta_ci": bootstrap_ci(ok - ok_a, n_boot=n_boot),
            # accepted or not, paired by seed: the sign test of the differences is McNemar's
            # exact test (one test per cell, as the error's and jerk's)
            "share_p": sign_test_p(ok - ok_a),
            "margin": float(np.median([checks[s].worst_margin for s in cmp.seeds])),
            "limit": max(hit, key=hit.get), "n": len(cmp.seeds),
            "charged": len(cmp.pairing.charged[name])}


def _window_row(cond: str, name: str, checks_at: dict, start: float, n_boot: int) -> dict:
    """The share accepted when the check starts at ``start`` s (``checks_at``: controller ->
    seed -> limits.Check from then), against the analytic lead's share from the same start,
    paired by seed (McNemar's exact test, as the main table)."""
    from panda_lead.metrics import bootstrap_ci, sign_test_p

    checks, checks_a = checks_at[name], checks_at["Analytic"]
    seeds = sorted(checks_a)
    ok = np.array([float(checks[s].accepted) for s in seeds])
    delta = ok - np.array([float(checks_a[s].accepted) for s in seeds])
    return {"cond": cond, "name": name, "start": start, "share": float(ok.mean()),
            "delta": float(delta.mean()), "delta_ci": bootstrap_ci(delta, n_boot=n_boot),
            "p": sign_test_p(delta), "n": len(seeds)}


def window_table(rows: list[dict]) -> str:
    """The accepted shares by when the check starts (--check-from)."""
    from panda_lead.metrics import diff_text

    if not rows:
        return ""
    lines = ["", "Accepted by when the check starts (the main table's is "
             f"{SKIP_S:g} s; later starts leave more of the swing from home out; each share "
             "against the analytic lead's from the same start, paired, McNemar's exact test):",
             "", "| condition | controller | check from (s) | accepted | vs analytic |",
             "|---|---|---|---|---|"]
    for r in rows:
        vs = "-" if r["name"] == "Analytic" else diff_text(
            100 * r["delta"], tuple(100 * np.asarray(r["delta_ci"])), ".1f", n_pairs=r["n"],
            p_holm=r["p"])
        lines.append(f"| {LABELS[r['cond']]} | {r['name']} | {r['start']:g} | "
                     f"{100 * r['share']:.1f}% | {vs} |")
    return "\n".join(lines) + "\n"


RIVALS = ("Analytic+filter", "Analytic+predict")  # the rival each condition calls for


def _rival_row(cond: str, rival: str, name: str, sets: dict, n_boot: int) -> dict:
    """A model against the rival a good engineer would field under this condition, paired."""
    from panda_lead.metrics import compare

    cmp = compare(sets[rival], sets[name], n_boot=n_boot, label_a=rival, label_b=name)
    return {"cond": cond, "rival": rival, "name": name, "err": cmp.row("mean_err"),
            "settled": cmp.row("settled_err"), "jerk": cmp.row("jerk_rms")}


def rival_table(rows: list[dict]) -> str:
    """Each model minus the condition's rival (the filtered analytic lead under noise, the
    predicting one under latency and a late camera): the targets of issue 36 compare there."""
    from panda_lead.metrics import row_diff

    if not rows:
        return ""
    lines = ["", "Against the rival each condition calls for (model - rival, paired by seed, "
             "95% bootstrap CIs, the same rule):", "",
             "| condition | model | rival | error (cm) | settled (cm) | jerk (m/s^3) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {LABELS[r['cond']]} | {r['name']} | {r['rival']} | {row_diff(r['err'])}"
                     f" | {row_diff(r['settled'])} | {row_diff(r['jerk'], fmt='.0f')} |")
    return "\n".join(lines) + "\n"


def study_models(studies: list[str]) -> dict[str, list[Path]]:
    """--studies A B -> each study's archived seeds' models in seed order (none: {})."""
    from runs import SEEDS_DIR, seed_models

    if not studies:
        return {}
    if len(studies) != 2 or studies[0] == studies[1]:
        raise UserError(f"--studies takes two different study names, A then B (got "
                        f"{' '.join(studies) or 'none'})")
    out = {}
    for study in studies:
        found = seed_models(study)
        if len(found) < 2:
            raise UserError(f"--studies {study}: {len(found)} archived seed model(s) in "
                            f"{SEEDS_DIR}/{study}_s<k>.zip; a study needs at least 2 "
                            "(`uv run studies/runs.py keep` archives them)")
        out[study] = [found[k] for k in sorted(found)]
    return out


STUDY_METRICS = (("accepted", "accepted (points)", 100.0, ".1f"),
                 ("mean_err", "mean error (cm)", 1.0, ".3f"),
                 ("jerk_rms", "jerk (m/s^3)", 1.0, ".0f"))


def study_table(rows: list[dict], by_study: dict[str, list[Path]], label: dict[Path, str],
                n_boot: int) -> str:
    """B minus A per condition, each study the mean over its seeds per trajectory, with
    metrics.two_level_bootstrap's CIs and the findings rule over the condition's three
    metrics (Holm), as studies/runs.py compare."""
    from panda_lead.metrics import bootstrap_verdicts, two_level_bootstrap

    if not by_study:
        return ""
    (a, paths_a), (b, paths_b) = by_study.items()
    lines = ["", f"Between studies: `{b}` ({len(paths_b)} seeds) minus `{a}` ({len(paths_a)} "
             "seeds), each the mean over its seeds per trajectory, under the same condition; "
             "95% CI: two-level bootstrap over training seeds and trajectories "
             f"({n_boot} resamples; the findings rule, Holm over each row's three):", "",
             f"| condition | accepted {a} | accepted {b} | "
             + " | ".join(f"{title}, B - A" for _, title, _, _ in STUDY_METRICS) + " |",
             "|---|---|---|" + "---|" * len(STUDY_METRICS)]
    rng = np.random.default_rng(0)
    for cond in dict.fromkeys(r["cond"] for r in rows):
        per = {r["name"]: r["per_traj"] for r in rows if r["cond"] == cond}
        cells, cis, boots = [], [], []
        for key, _, scale, fmt in STUDY_METRICS:
            va = scale * np.array([per[label[p]][key] for p in paths_a])  # (seeds, traj)
            vb = scale * np.array([per[label[p]][key] for p in paths_b])
            ci, resampled = two_level_bootstrap(va, vb, n_boot, rng)
            cis.append(ci)
            boots.append(resampled)
            cells.append((vb.mean() - va.mean(), ci, fmt))
            if key == "accepted":
                shares = f"{va.mean():.1f}% | {vb.mean():.1f}%"
        verdicts = bootstrap_verdicts(cis, boots, len(next(iter(per.values()))["accepted"]))
        diffs = " | ".join(f"{d:+{fmt}} [{lo:+{fmt}}, {hi:+{fmt}}] {v}"
                           for (d, (lo, hi), fmt), v in zip(cells, verdicts, strict=True))
        lines.append(f"| {LABELS[cond]} | {shares} | {diffs} |")
    return "\n".join(lines) + "\n"


def table(args: Args, rows: list[dict], seeds: list[int]) -> str:
    from panda_lead.metrics import diff_text, row_diff

    models = f" --models {' '.join(map(str, args.models))}" if args.models else ""
    extra = "" if args.conditions == list(DEFAULT_CONDITIONS) else \
        f" --conditions {' '.join(args.conditions)}"
    if args.noisy_lead_filter_hz is not None:
        extra += f" --noisy-lead-filter-hz {args.noisy_lead_filter_hz:g}"
    if args.studies:
        extra += f" --studies {' '.join(args.studies)}"
    if args.check_from:
        extra += f" --check-from {' '.join(f'{t:g}' for t in args.check_from)}"
    lines = [f"`uv run studies/deploy.py{models} --seeds {args.seeds}{extra}` "
             f"({len(seeds)} {set_name(seeds)} seeds, {time.strftime('%Y-%m-%d')}, commit "
             f"{_commit()}).",
             "",
             "Differences are controller - analytic lead under the same condition, paired by "
             "seed, 95% bootstrap CIs (panda_lead.metrics.compare); a difference is *shown* "
             "by the repo's one rule (metrics.finding_verdict: CI excludes 0, >= 10 pairs, "
             "Holm-adjusted p < 0.05; the accepted share by McNemar's exact test). Latency: "
             "the lead's channel k steps late both ways, IK "
             "and joint state current (docs/deploy.md). Noise reaches every measured input "
             "incl. the tip error" + ("; target noise: the target's readings alone, the "
             "arm's exact (encoders)" if any(c.startswith("target") for c in args.conditions)
             else "") + ". *Accepted*: the commanded joint goals, as the 1 kHz command "
             "(cubic spline + libfranka's 100 Hz low-pass), within the Panda's joint and tip "
             "velocity/acceleration/jerk limits after the first 0.5 s; *margin*: the median "
             "over seeds of the worst peak / limit (1 = at the limit); *binds*: the limit "
             "worst most often. Failed episodes are charged (metrics) and not accepted.", "",
             "| condition | controller | mean error (cm) | median | settled | error vs analytic "
             "| median diff | jerk (m/s^3) | jerk vs analytic | accepted | vs analytic | "
             "margin | binds |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        err, jerk, base = r["err"], r["jerk"], r["name"] == "Analytic"
        dash = "-"
        lines.append(
            f"| {LABELS[r['cond']]} | {r['name']} | {err.mean_b:.2f} | {err.median_b:.2f} | "
            f"{r['settled'].mean_b:.2f} | {dash if base else row_diff(err)} | "
            f"{dash if base else row_diff(err, median=True)} | "
            f"{jerk.mean_b:,.0f} | "
            f"{dash if base else row_diff(jerk, fmt='.0f')} | "
            f"{100 * r['share']:.1f}% [{100 * r['share_ci'][0]:.1f}, "
            f"{100 * r['share_ci'][1]:.1f}] | "
            f"{dash if base else diff_text(100 * r['share_delta'], tuple(100 * np.asarray(r['share_delta_ci'])), '.1f', n_pairs=r['n'], p_holm=r['share_p'])} | "  # noqa: E501
            f"{r['margin']:.2f} | {r['limit']} |")
    return "\n".join(lines) + "\n"


def _commit() -> str:
    import subprocess

    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def figure(args: Args, rows: list[dict], seeds: list[int], path: Path) -> None:
    """Mean error against mean tip jerk: one point per controller per condition, 95% CIs of
    the error; a controller's points joined in condition order. Lower left is better."""
    from panda_lead.metrics.figures import family_colours, pyplot, save_figure

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(13, 6.5), constrained_layout=True)
    names = list(dict.fromkeys(r["name"] for r in rows))
    colours = family_colours(names)  # a study's seeds one hue; the baselines the repo's colours
    for name in names:
        pts = [r for r in rows if r["name"] == name]
        x = [r["jerk"].mean_b for r in pts]
        y = [r["err"].mean_b for r in pts]
        ax.plot(x, y, "-", color=colours[name], alpha=0.35)
        for r in pts:
            e = r["err"]
            lo, hi = r["err_ci"]
            ax.errorbar(r["jerk"].mean_b, e.mean_b, yerr=[[e.mean_b - lo], [hi - e.mean_b]],
                        fmt=MARKERS[r["cond"]], color=colours[name], capsize=2, ms=7,
                        mec="black", mew=0.5)
    for name in names:
        ax.plot([], [], "-", color=colours[name], lw=4, label=name)
    for cond in dict.fromkeys(r["cond"] for r in rows):
        ax.plot([], [], MARKERS[cond], color="grey", label=LABELS[cond])
    ax.set_xscale("log")
    ax.set(xlabel="tip jerk RMS (m/s^3, log scale)", ylabel="mean tracking error (cm), 95% CI",
           title=f"Error against jerk per controller and condition ({set_name(seeds)} seeds "
                 f"{seeds[0]}-"
                 f"{seeds[-1]}, n={len(seeds)}); lower left is better")
    ax.grid(alpha=0.3, which="both")
    # beside the axes, not on them: with many controllers an inside legend hides points
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save_figure(fig, path)


def tune_filter(steps: int, on_selection: int = 0) -> None:
    """The filter's jerk density on the tuning seeds (never the test seeds), at 1 cm; or on the
    first ``on_selection`` selection-set seeds."""
    from panda_lead import controllers, harness

    analytic = harness.build("analytic", steps, None, overrides("noise1"))
    seeds = _tuning_seeds(on_selection)
    for psd in (1e1, 1e2, 1e3, 1e4, 1e5):
        act = controllers.make_filtered_analytic(jerk_psd=psd)
        err, jerk = _error_and_jerk(harness.Controller("f", analytic.config, {}, act), seeds)
        print(f"jerk_psd {psd:8.0e}: mean error {err:.3f} cm, jerk {jerk:.0f} m/s^3", flush=True)


def _error_and_jerk(ctrl, seeds: list[int]) -> tuple[float, float]:
    """A controller's mean tracking error (cm) and tip jerk (m/s^3) on seeds, after the swing."""
    from panda_lead.metrics.stats import rollout_metrics

    m = [rollout_metrics(r, SKIP_S) for r in _play(ctrl, seeds).values()]
    return float(np.mean([x["mean_err"] for x in m])), float(np.mean([x["jerk_rms"] for x in m]))


def _tuning_seeds(on_selection: int) -> list[int]:
    """The 50 tuning seeds, or the first ``on_selection`` of the selection set."""
    from panda_lead.seeds import SELECT_SEEDS, TUNE_SEEDS

    if not 0 <= on_selection <= len(SELECT_SEEDS):
        raise UserError(f"--tune-on must be 0..{len(SELECT_SEEDS)}, got {on_selection}")
    return list(SELECT_SEEDS[:on_selection] if on_selection else TUNE_SEEDS)


def choose_cutoff(found: dict[float, tuple[float, float]]) -> float:
    """cutoff (Hz; 0: none) -> (mean error, jerk): of the cutoffs whose error is no higher than
    without the filter, the one with the least jerk."""
    return min((hz for hz in found if found[hz][0] <= found[0.0][0]), key=lambda h: found[h][1])


LEAD_FILTER_HZ = (0.0, 40.0, 30.0, 20.0, 15.0, 12.0, 10.0, 9.0, 8.0, 6.0, 5.0)


def tune_lead_filter(model: Path, steps: int, on_selection: int = 0) -> float:
    """The model's lead low-pass under noise (noisy_lead_filter_hz), chosen on the tuning seeds
    (or the first ``on_selection`` selection-set seeds) at 1 cm: of the cutoffs whose mean
    error is no higher than without the filter (0 Hz), the one with the least jerk. Without
    noise the filter is off, so no other row can move."""
    from panda_lead import harness

    seeds = _tuning_seeds(on_selection)
    found = {}
    for hz in LEAD_FILTER_HZ:
        ctrl = harness.build("policy", steps, model, {**overrides("noise1"),
                                                      "noisy_lead_filter_hz": hz})
        found[hz] = _error_and_jerk(ctrl, seeds)
        print(f"noisy_lead_filter_hz {hz:4.0f}: mean error {found[hz][0]:.3f} cm, jerk "
              f"{found[hz][1]:.0f} m/s^3", flush=True)
    best = choose_cutoff(found)
    print(f"chosen: {best:g} Hz (the least jerk at no more error than without the filter; "
          f"{'selection' if on_selection else 'tuning'} seeds {seeds[0]}-{seeds[-1]})")
    return best


if __name__ == "__main__":
    main(tyro.cli(Args, description=__doc__))
