"""Robustness study: tracking error and jerk against observation noise or latency, per controller.

    uv run studies/robustness.py --question noise --models archive/indep_v5.zip archive/noisy.zip
    uv run studies/robustness.py --question delay --models archive/indep_v5.zip archive/delayed.zip

Every controller (classical, the analytic lead fed the same noisy or late observations, and each
model, with its own sidecar's env) plays the test seeds at each level, as one batch per
(controller, level). Each is compared with the analytic lead at the same level by the repo's
paired statistics (metrics.compare: mean and median differences with 95% bootstrap CIs, share
of seeds improved). Writes a markdown table and a figure.

Levels. noise: sigma in cm is the std of the position features (ee_pos, target_pos); velocity
features get 10 sigma per second (m/s), target_acc 100 sigma per second squared (m/s^2), so 1 cm
means 0.1 m/s and 1 m/s^2. delay: k control steps (10 ms each) of both observation and action
latency.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from panda_lead.errors import UserError, check_output, exit_on_user_error, parse_cli


@dataclass
class Args:
    question: Literal["noise", "delay"] = "noise"
    """Which condition to vary."""
    models: list[Path] = field(default_factory=list)
    """Archived models to evaluate beside the classical and analytic controllers."""
    levels: list[float] = field(default_factory=list)
    """Levels (noise: sigma in cm; delay: control steps). Default: 0 0.5 1 2 / 0 1 2 3."""
    seeds: str = "0-999"
    """Test seeds."""
    out: Path | None = None
    """Folder for <question>.md and <question>.png (default: results/studies/<question>/)."""
    bootstrap: int = 10000
    """Bootstrap resamples for the CIs."""
    force: bool = False
    """Replace existing <question>.md and .png."""


MAX_NOISE_CM = 100.0  # a metre of noise on a 1 m workspace: beyond it a level is a typo
MAX_DELAY_STEPS = 50  # the env's bound (EnvConfig)
MIN_BOOTSTRAP, MAX_BOOTSTRAP = 100, 100_000  # metrics.py's bounds


def condition(question: str, level: float) -> dict:
    """The env settings of one level. An evaluation starts from none of a model's own
    training-only settings (harness.evaluation_config), so the level is exactly what every
    controller sees: a policy trained with randomised delays gets exactly k steps here."""
    if question == "noise":
        if not (math.isfinite(level) and 0 <= level <= MAX_NOISE_CM):
            raise UserError(f"noise levels are sigmas in cm in [0, {MAX_NOISE_CM:g}], got {level}")
        s = level / 100.0
        return {"obs_noise": {"ee_pos": s, "target_pos": s, "ee_vel": 10 * s,
                              "target_vel": 10 * s, "target_acc": 100 * s}}
    if not (math.isfinite(level) and level == int(level) and 0 <= level <= MAX_DELAY_STEPS):
        raise UserError(f"delay levels are whole control steps in 0..{MAX_DELAY_STEPS}, got "
                        f"{level}")
    k = int(level)
    return {"obs_delay": k, "action_delay": k, "random_delay": False}


def controllers_at(models: list[Path], level_settings: dict, steps: int) -> dict:
    """label -> harness.Controller at one level: classical, analytic and each model."""
    from panda_lead import harness

    out = {"Classical": harness.build("classical", steps, None, level_settings),
           "Analytic": harness.build("analytic", steps, None, level_settings)}
    for path, label in zip(models, harness.model_labels(models), strict=True):
        out[f"RL lead ({label})"] = harness.build("policy", steps, path, level_settings)
    return out


def play(ctrl, seeds: list[int]) -> dict:
    from panda_lead.rollout import iter_record

    return {r.seed: r for r in iter_record(ctrl.config, ctrl.act, seeds, meta=ctrl.meta)}


def plan(args: Args) -> tuple[Args, list[tuple[float, dict]], list[int], list[Path]]:
    """Every value checked before any play (a bad level found after the first level's plays
    would waste them): the levels and their env settings, seeds, bootstrap count and the output
    paths (a folder, not a file; not replaced without --force)."""
    from panda_lead.seeds import parse_seed_range

    if args.out is None:
        args = replace(args, out=_default_out(args.question))
    levels = list(args.levels) or ([0, 0.5, 1, 2] if args.question == "noise" else [0, 1, 2, 3])
    if len(set(levels)) != len(levels):
        raise UserError(f"--levels names a level twice: {' '.join(f'{x:g}' for x in levels)}")
    if not MIN_BOOTSTRAP <= args.bootstrap <= MAX_BOOTSTRAP:
        raise UserError(f"--bootstrap must be {MIN_BOOTSTRAP}..{MAX_BOOTSTRAP:,}, got "
                        f"{args.bootstrap}")
    seeds = parse_seed_range(args.seeds)
    if len(seeds) < 2:
        raise UserError(f"--seeds must name at least 2 seeds for a CI, got {args.seeds!r}")
    settings = [condition(args.question, level) for level in levels]
    outputs = [args.out / f"{args.question}.md", args.out / f"{args.question}.png"]
    for path in outputs:
        check_output(path, "--out", args.force)
    return args, list(zip(levels, settings, strict=True)), seeds, outputs


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.atomicio import atomic_write
    from panda_lead.core import control_dt
    from panda_lead.metrics import bootstrap_ci, compare
    from panda_lead.outputs import claimed_outputs

    args, levels, seeds, outputs = plan(args)
    unit = "cm" if args.question == "noise" else "steps"
    with claimed_outputs(outputs, "--out", args.force):  # a second run on --out stops here
        steps = int(round(5.0 / control_dt()))
        planned = [(level, controllers_at(args.models, settings, steps))  # models load here,
                   for level, settings in levels]  # all before the first play
        rows, curves = [], {}
        t0 = time.perf_counter()
        for level, ctrls in planned:
            sets = {name: play(c, seeds) for name, c in ctrls.items()}
            for name, rs in sets.items():
                cmp = compare(sets["Analytic"], rs, n_boot=args.bootstrap, label_a="Analytic",
                              label_b=name)
                err, jerk = cmp.row("mean_err"), cmp.row("jerk_rms")
                errs = [cmp.metrics_b[s]["mean_err"] for s in cmp.seeds]
                jerks = [cmp.metrics_b[s]["jerk_rms"] for s in cmp.seeds]
                curves.setdefault(name, []).append(
                    (level, err.mean_b, bootstrap_ci(errs, n_boot=args.bootstrap), jerk.mean_b,
                     bootstrap_ci(jerks, n_boot=args.bootstrap)))
                rows.append((level, name, err, jerk, len(cmp.pairing.charged[name])))
                print(f"{args.question} {level:g} {unit}: {name:24s} error {err.mean_b:5.2f} "
                      f"cm, jerk {jerk.mean_b:6.1f} ({time.perf_counter() - t0:.0f} s)",
                      flush=True)
            del sets
        table = _table(args, rows, unit, seeds)
        with atomic_write(outputs[0], ".tmp.md") as tmp:
            Path(tmp).write_text(table)
        _figure(args, curves, unit, seeds)
    print(table)


def _default_out(question: str) -> Path:
    return Path("results/studies") / question


def _fmt(row, median: bool = False) -> str:
    from panda_lead.metrics import row_diff

    return row_diff(row, median, fmt=".2f")


def _table(args: Args, rows, unit: str, seeds: list[int]) -> str:
    extra = (f" --levels {' '.join(f'{x:g}' for x in args.levels)}" if args.levels else "") + (
        f" --out {args.out}" if args.out != _default_out(args.question) else "")
    lines = [f"`uv run studies/robustness.py --question {args.question} --models "
             f"{' '.join(map(str, args.models))} --seeds {args.seeds}{extra}` ({len(seeds)} "
             "test seeds, "
             f"{time.strftime('%Y-%m-%d')}); differences are controller - analytic at the same "
             "level, paired by seed, 95% bootstrap CIs. Every controller sees exactly the "
             "level (a model's own training noise or delay is not inherited); n = "
             f"{len(seeds)} per row, failed episodes charged, none dropped.", "",
             f"| {args.question} ({unit}) | controller | mean error (cm) | vs analytic: mean diff | "
             "median diff | better on | jerk RMS (m/s^3) | jerk vs analytic: mean diff | "
             "failures charged |",
             "|---|---|---|---|---|---|---|---|---|"]
    for level, name, err, jerk, failed in rows:
        if name == "Analytic":
            lines.append(f"| {level:g} | {name} | {err.mean_b:.2f} | - | - | - | "
                         f"{jerk.mean_b:.1f} | - | {failed} |")
            continue
        lines.append(f"| {level:g} | {name} | {err.mean_b:.2f} | {_fmt(err)} | "
                     f"{_fmt(err, median=True)} | "
                     f"{100 * err.improved / err.n_pairs:.0f}% | {jerk.mean_b:.1f} | "
                     f"{_fmt(jerk)} | {failed} |")
    return "\n".join(lines) + "\n"


def _figure(args: Args, curves: dict, unit: str, seeds: list[int]) -> None:
    """Mean error and jerk against the level, each point with its 95% bootstrap CI."""
    from panda_lead.metrics.figures import colours_for, pyplot, save_figure

    plt = pyplot()
    fig, (ax_e, ax_j) = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    colours = colours_for(list(curves))
    span = max(p[0] for pts in curves.values() for p in pts) or 1.0
    for k, (name, pts) in enumerate(curves.items()):
        dx = (k - (len(curves) - 1) / 2) * 0.012 * span  # keep overlapping bars apart
        x = np.array([p[0] for p in pts]) + dx
        for ax, i in ((ax_e, 1), (ax_j, 3)):
            y = np.array([p[i] for p in pts])
            lo, hi = (np.array([p[i + 1][q] for p in pts]) for q in (0, 1))
            ax.errorbar(x, y, yerr=[y - lo, hi - y], fmt="o-", capsize=3, color=colours[name],
                        label=name)
    ax_e.set(xlabel=f"{args.question} ({unit})", ylabel="mean tracking error (cm), 95% CI")
    ax_j.set(xlabel=f"{args.question} ({unit})", ylabel="tip jerk RMS (m/s^3), 95% CI")
    levels = sorted({p[0] for pts in curves.values() for p in pts})
    for ax in (ax_e, ax_j):
        ax.grid(alpha=0.3)
        ax.set_xticks(levels)  # whole steps for the delay: no fractional ticks
    fig.legend(*ax_e.get_legend_handles_labels(), loc="outside lower center",
               ncol=min(4, len(curves)), fontsize="small")
    fig.suptitle(f"{args.question}: test seeds {seeds[0]}-{seeds[-1]}, n={len(seeds)} per point")
    save_figure(fig, args.out / f"{args.question}.png")


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
