"""Robustness study: tracking error and jerk against observation noise or latency, per controller.

    uv run studies/robustness.py --question noise --models archive/best.zip archive/noisy.zip
    uv run studies/robustness.py --question delay --models archive/best.zip archive/delayed.zip

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

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import tyro

from panda_lead.errors import UserError, exit_on_user_error


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
    out: Path = Path("results")
    """Folder for <question>.md and <question>.png."""
    bootstrap: int = 10000
    """Bootstrap resamples for the CIs."""


def condition(question: str, level: float) -> dict:
    """The env settings of one level (applied over each controller's own env)."""
    if question == "noise":
        s = level / 100.0
        return {"obs_noise": {"ee_pos": s, "target_pos": s, "ee_vel": 10 * s,
                              "target_vel": 10 * s, "target_acc": 100 * s}}
    k = int(level)
    if k != level or k < 0:
        raise UserError(f"delay levels are whole control steps >= 0, got {level}")
    return {"obs_delay": k, "action_delay": k}


def controllers_for(models: list[Path]) -> dict[str, tuple]:
    """label -> (act_fn, base env settings) for classical, analytic and each model."""
    from panda_lead import controllers
    from panda_lead.models import load_policy

    out = {"Classical": (controllers.classical, {}), "Analytic": (controllers.make_analytic(), {})}
    for path in models:
        policy, env_config, _ = load_policy(path)
        out[f"RL lead ({Path(path).stem})"] = (controllers.make_policy(policy), env_config)
    return out


def play(act, base: dict, extra: dict, seeds: list[int]) -> dict:
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many

    config = EnvConfig.from_dict({**base, **extra, "episode_steps": 500})
    return {r.seed: r for r in record_many(config, act, seeds)}


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.metrics import compare
    from panda_lead.seeds import parse_seed_range

    levels = args.levels or ([0, 0.5, 1, 2] if args.question == "noise" else [0, 1, 2, 3])
    seeds = parse_seed_range(args.seeds)
    ctrls = controllers_for(args.models)
    unit = "cm" if args.question == "noise" else "steps"
    rows, curves = [], {name: [] for name in ctrls}
    t0 = time.perf_counter()
    for level in levels:
        extra = condition(args.question, level)
        sets = {name: play(act, base, extra, seeds) for name, (act, base) in ctrls.items()}
        for name, rs in sets.items():
            cmp = compare(sets["Analytic"], rs, n_boot=args.bootstrap, label_a="Analytic",
                          label_b=name)
            err, jerk = cmp.row("mean_err"), cmp.row("jerk_rms")
            curves[name].append((level, err.mean_b, err.ci, jerk.mean_b))
            rows.append((level, name, err, jerk))
            print(f"{args.question} {level:g} {unit}: {name:24s} error {err.mean_b:5.2f} cm, "
                  f"jerk {jerk.mean_b:6.1f} ({time.perf_counter() - t0:.0f} s)", flush=True)
        del sets
    args.out.mkdir(parents=True, exist_ok=True)
    table = _table(args, rows, unit, seeds)
    (args.out / f"{args.question}.md").write_text(table)
    _figure(args, curves, unit, seeds)
    print(table)


def _fmt(x: float, ci: tuple[float, float]) -> str:
    from panda_lead.metrics import diff_text

    return diff_text(x, ci)


def _table(args: Args, rows, unit: str, seeds: list[int]) -> str:
    lines = [f"`uv run studies/robustness.py --question {args.question} --models "
             f"{' '.join(map(str, args.models))} --seeds {args.seeds}` ({len(seeds)} test seeds, "
             f"{time.strftime('%Y-%m-%d')}); differences are controller - analytic at the same "
             "level, paired by seed, 95% bootstrap CIs.", "",
             f"| {args.question} ({unit}) | controller | mean error (cm) | vs analytic: mean diff | "
             "median diff | better on | jerk RMS (m/s^3) | jerk vs analytic: mean diff |",
             "|---|---|---|---|---|---|---|---|"]
    for level, name, err, jerk in rows:
        if name == "Analytic":
            lines.append(f"| {level:g} | {name} | {err.mean_b:.2f} | - | - | - | "
                         f"{jerk.mean_b:.1f} | - |")
            continue
        lines.append(f"| {level:g} | {name} | {err.mean_b:.2f} | {_fmt(err.delta, err.ci)} | "
                     f"{_fmt(err.median_delta, err.median_ci)} | "
                     f"{100 * err.improved / err.n_pairs:.0f}% | {jerk.mean_b:.1f} | "
                     f"{_fmt(jerk.delta, jerk.ci)} |")
    return "\n".join(lines) + "\n"


def _figure(args: Args, curves: dict, unit: str, seeds: list[int]) -> None:
    from panda_lead.metrics.figures import colours_for, pyplot, save_figure

    plt = pyplot()
    fig, (ax_e, ax_j) = plt.subplots(1, 2, figsize=(12, 4.5))
    colours = colours_for(list(curves))
    for name, pts in curves.items():
        x = [p[0] for p in pts]
        ax_e.plot(x, [p[1] for p in pts], "o-", color=colours[name], label=name)
        ax_j.plot(x, [p[3] for p in pts], "o-", color=colours[name], label=name)
    ax_e.set(xlabel=f"{args.question} ({unit})", ylabel="mean tracking error (cm)")
    ax_j.set(xlabel=f"{args.question} ({unit})", ylabel="tip jerk RMS (m/s^3)")
    for ax in (ax_e, ax_j):
        ax.grid(alpha=0.3)
    ax_e.legend()
    fig.suptitle(f"{args.question}: test seeds {seeds[0]}-{seeds[-1]}, n={len(seeds)} per point")
    fig.tight_layout()
    save_figure(fig, args.out / f"{args.question}.png")


if __name__ == "__main__":
    main(tyro.cli(Args, description=__doc__))
