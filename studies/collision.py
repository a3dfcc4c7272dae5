"""Self-collision study: can a bounded lead keep the arm out of itself, and at what cost?

    uv run studies/collision.py --models archive/indep_v5.zip archive/collision_v7.zip

The collision-prone subset is every test seed whose classical rollout (rollouts/ikpd, from
`uv run ikpd.py --seeds 0-999 --prefix ikpd`) touches itself at least once. On that subset,
each controller plays the episode with early termination switched off (so every episode runs
its full 5 s and is compared whole), and is compared with the first model by the repo's paired
statistics: time in self-collision and mean tracking error.
"""

from __future__ import annotations

import sys
from pathlib import Path

# Studies import the pipeline, which lives at the repo root (nothing imports a study).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dataclasses import dataclass, field

import tyro

from errors import UserError, exit_on_user_error


@dataclass
class Args:
    models: list[Path] = field(default_factory=list)
    """Archived models; the first is the reference every other controller is compared with."""
    classical: str = "ikpd"
    """Rollout set of the classical controller on the test seeds (defines the subset)."""
    root: Path = Path("rollouts")
    """Folder of rollout sets."""
    out: Path = Path("results/collision.md")
    """Where the table goes."""


@exit_on_user_error
def main(args: Args) -> None:
    import controllers
    from env import EnvConfig
    from metrics import compare, load_set
    from models import load_policy
    from rollout import record_many

    if not args.models:
        raise UserError("name at least one --models archive/NAME.zip")
    classical_set = load_set(args.classical, args.root)
    seeds = sorted(s for s, r in classical_set.items() if r.self_collision.any())
    if len(seeds) < 10:
        raise UserError(f"only {len(seeds)} collision-prone seeds in {args.classical}: too few")
    ctrls = {"Classical": (controllers.classical, {}), "Analytic": (controllers.make_analytic(), {})}
    for path in args.models:
        policy, env_config, _ = load_policy(path)
        ctrls[Path(path).stem] = (controllers.make_policy(policy), env_config)
    sets = {}
    for name, (act, base) in ctrls.items():
        config = EnvConfig.from_dict({**base, "episode_steps": 500,
                                      "terminate_on_collision": False})
        sets[name] = {r.seed: r for r in record_many(config, act, seeds)}
    ref = Path(args.models[0]).stem
    lines = [f"`uv run studies/collision.py --models {' '.join(map(str, args.models))}`: "
             f"{len(seeds)} collision-prone test seeds (the classical rollout touches itself); "
             f"differences are controller - {ref}, paired by seed, 95% bootstrap CIs.", "",
             "| controller | self-collision time (%) | vs ref: mean diff | seeds with less | "
             "mean error (cm) | vs ref: mean diff |", "|---|---|---|---|---|---|"]
    for name, rs in sets.items():
        cmp = compare(sets[ref], rs, label_a=ref, label_b=name)
        col, err = cmp.row("self_collision"), cmp.row("mean_err")
        if name == ref:
            lines.append(f"| {name} (ref) | {col.mean_b:.2f} | - | - | {err.mean_b:.2f} | - |")
            continue
        lines.append(f"| {name} | {col.mean_b:.2f} | {_diff(col)} | {col.improved}/{col.n_pairs} "
                     f"| {err.mean_b:.2f} | {_diff(err)} |")
    table = "\n".join(lines) + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table)
    print(table)


def _diff(row) -> str:
    shown = "shown" if row.ci[0] > 0 or row.ci[1] < 0 else "not shown"
    return f"{row.delta:+.2f} [{row.ci[0]:+.2f}, {row.ci[1]:+.2f}] {shown}"


if __name__ == "__main__":
    main(tyro.cli(Args, description=__doc__))
