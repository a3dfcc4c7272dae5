"""Self-collision study: can a bounded lead keep the arm out of itself, and at what cost?

    uv run studies/collision.py --models archive/indep_v5.zip archive/collision_v7.zip

The collision-prone subset: every trajectory of the seed pool (seeds.POOL_SEEDS, 10,000
trajectories from the test distribution that nothing trains, tunes or selects on) whose
classical rollout touches itself at least once: 249 of them (2.5%). Finding it takes 5M control
steps (about 4 minutes on 2 cores); the list is written beside the table, and ``--subset`` reads
it back. On that subset each controller plays the episode with early termination switched off
(every episode runs its full 5 s and is compared whole), and is compared with the first model
by the repo's paired statistics: time in self-collision, episodes that touch at all, and mean
tracking error. Beside the learned leads: the classical IK and the analytic lead, each also
with the collision-aware IK (``--env.ik.clearance``, clearance.py), and the first model on it.

Every controller is built by the evaluation harness (panda_lead/harness.py), as eval.py builds
it: a model plays on its sidecar's env without its training-only settings (a model trained with
a random delay plays with none), and a "+ clearance" row differs from its plain row in
ik.clearance alone (the model's other IK settings kept).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panda_lead.errors import UserError, exit_on_user_error, parse_cli, printable

STEPS = 500  # 5 s episodes, compared whole
MIN_SUBSET = 10
MAX_SUBSET_BYTES = 1 << 20  # a seed per line: 10,000 pool seeds are ~80 kB


@dataclass
class Args:
    models: list[Path] = field(default_factory=list)
    """Archived models; the first is the reference every other controller is compared with."""
    clearance: float = 0.02
    """The collision-aware IK's clearance (m) for the "+ clearance" rows."""
    subset: Path | None = None
    """Read the collision-prone seeds from this file (one per line) instead of finding them."""
    out: Path = Path("results/studies/collision/collision.md")
    """Where the table goes; the subset's seeds go beside it (<out stem>_seeds.txt)."""
    force: bool = False
    """Replace an existing table (and seeds file, when this run finds the subset)."""


def find_subset(chunk: int = 1000) -> list[int]:
    """Pool seeds whose classical rollout touches itself (in chunks: 10k rollouts at once
    would hold 1.6 GB)."""
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.rollout import record_many
    from panda_lead.seeds import POOL_SEEDS

    config = EnvConfig(episode_steps=500, terminate_on_collision=False)
    found = []
    for start in range(0, len(POOL_SEEDS), chunk):
        seeds = POOL_SEEDS[start:start + chunk]
        found += [r.seed for r in record_many(config, controllers.classical, seeds)
                  if r.self_collision.any()]
        print(f"  scanned {start + len(seeds):,} of {len(POOL_SEEDS):,}: {len(found)} collide",
              flush=True)
    return found


def build_controllers(models: list[Path], clearance: float) -> tuple[dict, list[str]]:
    """label -> harness.Controller, each on its evaluation env (harness.evaluation_config:
    no training-only noise, delay or termination; every episode runs its full 5 s); the
    "+ clearance" rows are the same controller with ik.clearance set and nothing else changed.
    Returns them and the models' labels (the first is the reference)."""
    from panda_lead import harness

    if not models:
        raise UserError("name at least one --models archive/NAME.zip")
    if not (math.isfinite(clearance) and clearance > 0):
        raise UserError(f"--clearance must be a positive distance in metres, got {clearance}")
    aware = {"ik": {"clearance": clearance}}
    ctrls = {"Classical": harness.build("classical", STEPS),
             "Classical + clearance": harness.build("classical", STEPS, None, aware),
             "Analytic": harness.build("analytic", STEPS),
             "Analytic + clearance": harness.build("analytic", STEPS, None, aware)}
    labels = harness.model_labels(models)
    for i, (path, label) in enumerate(zip(models, labels, strict=True)):
        ctrls[label] = harness.build("policy", STEPS, path)
        if ctrls[label].dropped:
            print(f"note: {label} plays without its training-only settings "
                  f"{', '.join(ctrls[label].dropped)} (as eval.py plays it)")
        if i == 0:
            ctrls[f"{label} + clearance"] = harness.build("policy", STEPS, path, aware)
    return ctrls, labels


def read_subset(path: Path) -> list[int]:
    """The collision-prone seeds of a --subset file: one seed per line, each a valid seed,
    none twice (bounded read)."""
    from panda_lead.seeds import check_seed

    try:
        with open(path, "rb") as f:
            data = f.read(MAX_SUBSET_BYTES + 1)
        if len(data) > MAX_SUBSET_BYTES:
            raise UserError(f"--subset {path}: over {MAX_SUBSET_BYTES:,} bytes, not a seed list")
        seeds = [int(word) for word in data.decode("ascii").split()]
    except (OSError, ValueError) as exc:  # (UnicodeDecodeError is a ValueError)
        raise UserError(f"cannot read the subset {path}: {printable(exc, 120)}") from None
    for s in seeds:
        check_seed(s, f"--subset {path}: a seed")
    if len(set(seeds)) != len(seeds):
        raise UserError(f"--subset {path} names a seed twice")
    if len(seeds) < MIN_SUBSET:
        raise UserError(f"only {len(seeds)} collision-prone seeds in {path}: too few to compare")
    return seeds


@exit_on_user_error
def main(args: Args) -> None:
    from panda_lead import controllers
    from panda_lead.config import EnvConfig
    from panda_lead.outputs import claimed_outputs
    from panda_lead.rollout import record_many

    seeds_file = args.out.with_name(args.out.stem + "_seeds.txt")
    write_seeds = args.subset is None or args.subset.resolve() != seeds_file.resolve()
    outputs = [args.out, *([seeds_file] if write_seeds else [])]
    seeds = read_subset(args.subset) if args.subset is not None else None
    with claimed_outputs(outputs, "--out", args.force):  # a second run on --out stops here
        ctrls, labels = build_controllers(list(args.models), args.clearance)  # before any play
        if seeds is None:
            print("finding the collision-prone subset of the seed pool (classical rollouts)")
            seeds = find_subset()
            if len(seeds) < MIN_SUBSET:
                raise UserError(f"only {len(seeds)} collision-prone seeds: too few to compare")
        record_many(EnvConfig(episode_steps=5), controllers.classical, seeds[:2])  # warm-up
        sets, cpu_us = {}, {}
        for name, ctrl in ctrls.items():
            start = time.process_time()
            sets[name] = {r.seed: r for r in record_many(ctrl.config, ctrl.act, seeds,
                                                         meta=ctrl.meta, nthread=1)}
            cpu_us[name] = (time.process_time() - start) / (len(seeds) * STEPS) * 1e6
            print(f"  played {name}: {cpu_us[name]:.0f} us CPU per env step", flush=True)
        table = _table(args, sets, cpu_us, labels[0], seeds, seeds_file)
        _write(args.out, table)
        if write_seeds:
            _write(seeds_file, "".join(f"{s}\n" for s in seeds))
    print(table)


def _write(path: Path, text: str) -> None:
    from panda_lead.atomicio import atomic_write

    with atomic_write(path, path.suffix) as tmp:
        Path(tmp).write_text(text)


def _table(args: Args, sets: dict, cpu_us: dict, ref: str, seeds: list[int],
           seeds_file: Path) -> str:
    from panda_lead.metrics import compare, row_diff

    command = ("uv run studies/collision.py --models " + " ".join(map(str, args.models))
               + (f" --clearance {args.clearance}" if args.clearance != 0.02 else "")
               + (f" --subset {args.subset}" if args.subset else "")
               + (f" --out {args.out}" if args.out != Args.out else ""))
    lines = [f"`{command}`: the {len(seeds)} trajectories of the seed pool (seeds 1000000-1009999, "
             f"test distribution) whose classical rollout touches itself "
             f"([{seeds_file.name}]({seeds_file.name})); 5 s episodes, early termination off. "
             f"Differences are controller - {ref}, paired by seed, 95% bootstrap CIs; "
             f"\"+ clearance\": the collision-aware IK at {args.clearance * 100:g} cm.", "",
             "| controller | self-collision time (%) | vs ref: mean diff | seeds with less | "
             "episodes touching (%) | mean error (cm) | vs ref: mean diff | CPU per step (us) |",
             "|---|---|---|---|---|---|---|---|"]
    for name, rs in sets.items():
        cmp = compare(sets[ref], rs, label_a=ref, label_b=name)
        col, err = cmp.row("self_collision"), cmp.row("mean_err")
        touching = 100 * np.mean([r.self_collision.any() for r in rs.values()])
        if name == ref:
            lines.append(f"| {name} (ref) | {col.mean_b:.2f} | - | - | {touching:.0f} "
                         f"| {err.mean_b:.2f} | - | {cpu_us[name]:.0f} |")
            continue
        lines.append(f"| {name} | {col.mean_b:.2f} | {row_diff(col)} "
                     f"| {col.improved}/{col.n_pairs} | {touching:.0f} | {err.mean_b:.2f} "
                     f"| {row_diff(err)} | {cpu_us[name]:.0f} |")
    lines += ["", "What the collision-aware IK does to each controller: with it minus without it, "
              "paired by seed.", "",
              "| controller | self-collision time: mean diff (points) | mean error: mean diff "
              "(cm) | median error diff (cm) | CPU per step |", "|---|---|---|---|---|"]
    for name in [n for n in sets if n.endswith(" + clearance")]:
        plain = name.removesuffix(" + clearance")
        cmp = compare(sets[plain], sets[name], label_a=plain, label_b=name)
        col, err = cmp.row("self_collision"), cmp.row("mean_err")
        median = row_diff(err, median=True, verdict=False)
        lines.append(f"| {plain} | {row_diff(col)} | {row_diff(err)} "
                     f"| {median} | {cpu_us[name] / cpu_us[plain]:.2f}x |")
    lines += ["", f"CPU per step: one thread, {len(seeds)} arms in one batch, the whole loop "
              "(controller, IK, physics, recording); a shared machine, so read the ratios."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
