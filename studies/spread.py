"""Seed spread: how much the test result of one configuration moves between training seeds.

    uv run studies/spread.py --baseline analytic --prefixes indep_v5_s1 indep_v5_s2 ...

Each prefix is one trained model's rollout set on the test seeds (eval.py --seeds 0-999). For
each, the mean and median tracking error and the paired difference from the baseline set (95%
bootstrap CIs, metrics.compare); then the mean and std of the per-model test errors across
training seeds, which is the spread a single-seed result hides.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panda_lead.errors import exit_on_user_error, parse_cli


@dataclass
class Args:
    prefixes: list[str] = field(default_factory=list)
    """Rollout sets, one per trained model (e.g. one per training seed)."""
    baseline: str = "analytic"
    """Rollout set every model is compared with."""
    root: Path = Path("rollouts")
    """Folder of rollout sets."""
    bootstrap: int = 10000
    """Bootstrap resamples."""
    runs: list[Path] = field(default_factory=list)
    """Training run folders: also report each one's steps to the quality threshold (the
    classical evaluation error less --margin-cm, as studies/ttq.py) and its best evaluation error."""
    margin_cm: float = 1.5
    """How far below the classical evaluation error the threshold lies."""


def run_table(runs: list[Path], margin_cm: float) -> None:
    import csv

    print("\n| run | steps to threshold | best evaluation error (cm) |\n|---|---|---|")
    for run in runs:
        with open(Path(run) / "tb" / "progress.csv") as f:
            rows = [r for r in csv.DictReader(f) if r.get("eval/mean_error_cm")]
        threshold = float(rows[0]["eval_classical/mean_error_cm"]) - margin_cm
        hit = next((int(float(r["eval/timesteps"])) for r in rows
                    if float(r["eval/mean_error_cm"]) < threshold), None)
        best = min(float(r["eval/mean_error_cm"]) for r in rows)
        print(f"| {Path(run).name} | {hit if hit is not None else 'not reached'} | {best:.2f} |")


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead.metrics import compare, load_set

    if args.runs:
        run_table(args.runs, args.margin_cm)
    if not args.prefixes:
        return

    base = load_set(args.baseline, args.root)
    print(f"| model (rollout set) | test mean error (cm) | median | vs {args.baseline}: mean diff "
          "[95% CI] | median diff [95% CI] | better on |")
    print("|---|---|---|---|---|---|")
    means = []
    for prefix in args.prefixes:
        cmp = compare(base, load_set(prefix, args.root), n_boot=args.bootstrap,
                      label_a=args.baseline, label_b=prefix)
        r = cmp.row("mean_err")
        means.append(r.mean_b)
        print(f"| {prefix} | {r.mean_b:.2f} | {r.median_b:.2f} | {r.delta:+.2f} "
              f"[{r.ci[0]:+.2f}, {r.ci[1]:+.2f}] | {r.median_delta:+.2f} "
              f"[{r.median_ci[0]:+.2f}, {r.median_ci[1]:+.2f}] | "
              f"{100 * r.improved / r.n_pairs:.0f}% |")
    if len(means) > 1:
        print(f"\nacross {len(means)} training seeds: test mean error {np.mean(means):.2f} ± "
              f"{np.std(means, ddof=1):.2f} cm (mean ± std), range {min(means):.2f}-{max(means):.2f}")


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
