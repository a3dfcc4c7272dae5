"""A selection rule that does not wobble (issue 37): size the selection set from the measured
per-trajectory spread, then rank models and studies on it, like for like, with the tie rule.

    uv run studies/selection.py size > results/studies/rank/sizing.md
    uv run studies/selection.py score --models archive/v5_err_decay_s4.zip ...  # -> rank/scores/
    uv run studies/selection.py rank > results/studies/rank/rank.md

**Sizing.** The two closest studies of the old rank (the headline study's chosen model and the
runner-up's) play the first ``--pilot`` trajectories of seeds.SELECT_SEEDS; the standard
deviation s of their paired per-trajectory differences in mean error gives the number of
trajectories at which a true difference of 0.05 cm has a 95% CI that excludes zero 80% of the
time: n = ((1.96 + 0.84) s / 0.05)^2. No test seed is played.

**Scoring.** Every model plays the selection set under the default evaluation env (harness:
training-only randomisations dropped: the delay- and noise-trained models are scored under the
same conditions as the rest); per trajectory its mean error (cm) and tip jerk RMS (m/s^3) are
kept in results/studies/rank/scores/<name>.json (about 40 kB: the rank re-derives from git).

**Ranking** (studies/runs.py tie_ranked): a study is the per-trajectory mean over its seeds'
models (archive/seeds/<study>_s<k>.zip); ordered by mean error; two neighbours whose paired 95%
CI includes 0 are tied and the smoother (lower mean jerk) ranks first. Models archived alone
(archive/<name>.zip, a study's chosen seed) are ranked in a second table, as models.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from panda_lead.config import knows_path
from panda_lead.errors import exit_on_user_error, parse_cli

ROOT = Path(__file__).resolve().parents[1]
SCORES = ROOT / "results" / "studies" / "rank" / "scores"
Z_95, Z_POWER_80 = 1.959964, 0.841621
DELTA_CM = 0.05


@dataclass
class Args:
    command: tyro.conf.Positional[Literal["size", "score", "rank"]]
    models: tuple[Path, ...] = ()
    """score: the model zips to play on the selection set."""
    model_a: Path = Path("archive/v5_err_decay_s4.zip")
    """size: the first model of the pilot pair (the headline when the set was sized)."""
    model_b: Path = Path("archive/v5_err_decay_wide_lr3e-4.zip")
    """size: the second (the runner-up study's chosen seed)."""
    pilot: int = 200
    """size: trajectories of the pilot (the first of the selection set)."""
    duration: float = 5.0
    """Episode length (s), the test rollouts' length."""
    force: bool = False
    """score: replace a model's existing scores."""


def size_for(spread_cm: float, delta_cm: float = DELTA_CM) -> int:
    """Trajectories at which a true paired difference of delta_cm is shown (95% CI excluding 0)
    with 80% power, for a per-trajectory spread (standard deviation) of spread_cm."""
    return int(np.ceil(((Z_95 + Z_POWER_80) * spread_cm / delta_cm) ** 2))


def _commit() -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, cwd=ROOT).stdout.strip()


def _knows_path_of(record: dict) -> bool:
    """A score record's flag; records made before it had one: from the model's sidecar."""
    if "knows_path" in record:
        return bool(record["knows_path"])
    side = json.loads((ROOT / Path(record["model"]).with_suffix(".json")).read_text())
    return knows_path(side["train_config"]["env"])


def _budget(record: dict) -> str:
    """The training steps behind a scored model, from its sidecar: "5M", or "5M + 5M" for a run
    started from another model's weights (train.py --init-from), whose steps are on top of
    that model's ("?" where that model's sidecar is gone). Blank when the sidecar is not there
    or unreadable (models.read_sidecar: size-bounded JSON)."""
    from panda_lead.models import ModelError, read_sidecar

    try:
        side = read_sidecar(ROOT / record["model"])
    except ModelError:  # no sidecar beside it (or one that cannot be read): no budget shown
        return ""
    own = f"{int((side.get('train_config') or {}).get('timesteps', 0)) / 1e6:g}M"
    start = (side.get("init_from") or {}).get("path")
    return f"{_budget({'model': start}) or '?'} + {own}" if start else own


def play(model: Path, seeds, duration: float) -> tuple[np.ndarray, np.ndarray, str, bool]:
    """(per-trajectory mean error cm, tip jerk RMS m/s^3, model sha256, whether it knows the
    planned path) on ``seeds``."""
    from panda_lead.core import control_dt
    from panda_lead.harness import build
    from panda_lead.metrics.pairing import charged
    from panda_lead.metrics.stats import rollout_metrics
    from panda_lead.rollout import iter_record

    ctrl = build("policy", int(round(duration / control_dt())), Path(model))
    err, jerk = [], []
    for r in iter_record(ctrl.config, ctrl.act, list(seeds), None, ctrl.meta):
        m = rollout_metrics(charged(r)[0])
        err.append(m["mean_err"])
        jerk.append(m["jerk_rms"])
    return (np.array(err), np.array(jerk), ctrl.meta["model_sha256"],
            knows_path(ctrl.config))


def size(args: Args) -> None:
    from panda_lead.seeds import SELECT_SEEDS

    seeds = SELECT_SEEDS[:args.pilot]
    ea, ja, *_ = play(args.model_a, seeds, args.duration)
    eb, jb, *_ = play(args.model_b, seeds, args.duration)
    d = eb - ea
    s = float(np.std(d, ddof=1))
    print(f"Made by `uv run studies/selection.py size` at commit {_commit()} (2-core Intel "
          f"Xeon). Pilot: the first {len(seeds)} trajectories of the selection set "
          f"(seeds {seeds[0]}-{seeds[-1]}), {args.duration:g} s episodes, default evaluation "
          "env.\n")
    print("| model | mean error (cm) | tip jerk RMS (m/s^3) |\n|---|---|---|")
    for p, e, j in ((args.model_a, ea, ja), (args.model_b, eb, jb)):
        print(f"| {p.stem} | {e.mean():.3f} | {j.mean():.0f} |")
    print(f"\nPaired per-trajectory difference (B - A): mean {d.mean():+.3f} cm, standard "
          f"deviation s = {s:.3f} cm. Trajectories to show a 0.05 cm difference (95% CI "
          f"excluding 0) with 80% power: n = ((1.96 + 0.84) s / 0.05)^2 = {size_for(s)}.")


def score(args: Args) -> None:
    from panda_lead.seeds import SELECT_SEEDS

    SCORES.mkdir(parents=True, exist_ok=True)
    for model in args.models:
        out = SCORES / f"{Path(model).stem}.json"
        if out.exists() and not args.force:
            print(f"{out} exists (--force to replace)")
            continue
        err, jerk, sha, path_known = play(Path(model), SELECT_SEEDS, args.duration)
        from panda_lead.atomicio import atomic_write

        record = {"model": str(model), "model_sha256": sha, "commit": _commit(),
                  "seeds": [SELECT_SEEDS[0], SELECT_SEEDS[-1]], "duration_s": args.duration,
                  "knows_path": path_known,
                  "mean_err_cm": [round(float(x), 5) for x in err],
                  "jerk_rms": [round(float(x), 2) for x in jerk]}
        with atomic_write(out, ".tmp") as tmp:
            Path(tmp).write_text(json.dumps(record) + "\n")
        print(f"{Path(model).stem}: {err.mean():.3f} cm, jerk {jerk.mean():.0f} -> {out}",
              flush=True)


def _study_of(stem: str) -> tuple[str, int] | None:
    m = re.fullmatch(r"(.+)_s(\d+)", stem)
    return (m.group(1), int(m.group(2))) if m else None


def rank(args: Args) -> None:
    sys.path.insert(0, str(ROOT / "studies"))
    from runs import tie_ranked

    from panda_lead.seeds import SELECT_SEEDS

    scores = {}
    for f in sorted(SCORES.glob("*.json")):
        rec = json.loads(f.read_text())
        if rec["seeds"] != [SELECT_SEEDS[0], SELECT_SEEDS[-1]]:
            raise SystemExit(f"error: {f} was scored on another selection set; score it again")
        scores[f.stem] = rec
    studies: dict[str, list[str]] = {}
    for stem, rec in scores.items():
        if "/seeds/" in rec["model"] and _study_of(stem):
            studies.setdefault(_study_of(stem)[0], []).append(stem)
    print(f"Made by `uv run studies/selection.py rank` at commit {_commit()}, from the scores "
          f"in results/studies/rank/scores/ (selection set: seeds {SELECT_SEEDS[0]}-"
          f"{SELECT_SEEDS[-1]}, {len(SELECT_SEEDS)} trajectories, never trained, tuned or "
          "tested on; every model under the default evaluation env, no delay, no noise).\n")
    print("Rule (2026-11-26): ordered by mean error on the selection set; neighbours whose "
          "paired 95% CI includes 0 are tied, and the smoother (lower mean tip jerk) ranks "
          "first. Training steps: a run started from another model's weights (train.py "
          "--init-from) counts that model's too (5M + 5M); the rank does not weigh budgets, the "
          "reader must.\n")
    print(f"Scored: {len(scores)} models; a study is ranked when at least 3 of its seeds' models "
          "are archived (archive/seeds/<study>_s<k>.zip) and scored: "
          f"{', '.join(sorted(k for k, v in studies.items() if len(v) >= 3)) or 'none'}.")
    summarised = sorted(d.name for d in (ROOT / "results" / "runs").glob("*")
                        if d.is_dir() and any(d.glob("seed_*.json")))
    kept_seeds = {m.stem for m in (ROOT / "archive" / "seeds").glob("*_s*.zip")}
    kept = {m.rsplit("_s", 1)[0] for m in kept_seeds}
    # a study with a kept seed model not scored yet, and one whose every kept seed is scored
    # but which has too few of them to be ranked as a study (its models are in the Models table)
    unscored = sorted({m.rsplit("_s", 1)[0] for m in kept_seeds - set(scores)} & set(summarised))
    few = [d for d in summarised if d in kept and d not in unscored
           and len(studies.get(d, [])) < 3]
    unkept = [d for d in summarised if d not in kept]
    if unscored:
        print(f"Kept but not yet scored: {', '.join(unscored)} (`uv run studies/selection.py "
              "score --models archive/seeds/<study>_s*.zip`).")
    if few:
        print(f"Scored, fewer than 3 seeds kept (not ranked as studies; their seeds are in the "
              f"Models tables): {', '.join(few)}.")
    if unkept:
        print(f"Not ranked as studies: their seeds' models were not kept (run folders are "
              f"machine-local; `studies/runs.py keep` archives them): {', '.join(unkept)}. "
              "Their chosen models are in the Models tables.")
    preview = {k for k, rec in scores.items() if _knows_path_of(rec)}
    tables = []
    for kind, keep in (("causal", lambda k: k not in preview),
                       ("knows the planned path", lambda k: k in preview)):
        tables += [(f"Studies, {kind} (per-trajectory mean over the study's archived seeds)",
                    {k: v for k, v in studies.items() if len(v) >= 3 and keep(v[0])}),
                   (f"Models, {kind}", {k: [k] for k in scores if keep(k)})]
    for title, groups in tables:
        if not groups:
            continue
        errors = {k: np.mean([scores[m]["mean_err_cm"] for m in v], axis=0)
                  for k, v in groups.items()}
        jerks = {k: float(np.mean([scores[m]["jerk_rms"] for m in v])) for k, v in
                 groups.items()}
        order = tie_ranked(errors, jerks)
        print(f"\n{title}\n\n| rank | name | seeds | training steps | mean error (cm) | "
              "tip jerk RMS (m/s^3) | tied with the row above |\n|---|---|---|---|---|---|---|")
        for i, (name, tied) in enumerate(order, 1):
            print(f"| {i} | {name} | {len(groups[name])} | {_budget(scores[groups[name][0]])} | "
                  f"{errors[name].mean():.3f} | {jerks[name]:.0f} | {'yes' if tied else ''} |")


def main(args: Args) -> None:
    {"size": size, "score": score, "rank": rank}[args.command](args)


if __name__ == "__main__":  # a UserError (bad input) is one line and exit 2
    exit_on_user_error(lambda: main(parse_cli(Args, description=__doc__)))()
