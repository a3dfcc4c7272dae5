"""Checking and pairing rollout sets, and the two-set comparison (`compare`).

Seeds with non-finite values or a failed episode in either set are reported; see `pair` for
what is done with them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import rollout
from ..errors import UserError
from ..rollout import Rollout
from .stats import Row, rollout_metrics, summarize

# Display names for the usual prefixes (--headline without --labels).
CONTROLLER_LABELS = {"classical": "Classical", "analytic": "Analytic", "policy": "RL+Lead"}


DEFAULT_LABELS = {"ikpd": "Classical", "analytic": "Analytic", "eval": "RL+Lead"}


def controller_label(rollouts: dict, prefix: str) -> str:
    """A set's display name: from the controller its rollouts record, else from its usual
    prefix (ikpd, analytic, eval), else the prefix itself."""
    kinds = {r.meta.get("controller") for r in rollouts.values()}
    known = CONTROLLER_LABELS.get(kinds.pop()) if len(kinds) == 1 else None
    return known or DEFAULT_LABELS.get(prefix, prefix)


def set_labels(sets: list[dict], prefixes: list[str]) -> list[str]:
    """controller_label for each set; sets that would share a name (two policies, say) are
    named by their prefixes instead."""
    labels = [controller_label(s, p) for s, p in zip(sets, prefixes, strict=True)]
    return [p if labels.count(lab) > 1 else lab for lab, p in zip(labels, prefixes, strict=True)]


def check_option(name: str, value: float, allow_zero: bool = False) -> None:
    """A numeric option must be finite and positive (or >= 0 with allow_zero): else UserError."""
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        need = "finite and >= 0" if allow_zero else "finite and positive"
        raise UserError(f"{name} must be {need}, got {value!r}")


def check_options(settle_time: float, band_cm: float, tight_band_cm: float, n_boot: int,
                  ci_seed: int) -> None:
    check_option("--settle-time", settle_time, allow_zero=True)
    check_option("--band-cm", band_cm)
    check_option("--tight-band-cm", tight_band_cm)
    if n_boot < 100:
        raise UserError(f"--bootstrap must be at least 100, got {n_boot}")
    if ci_seed < 0:
        raise UserError(f"--ci-seed must be >= 0, got {ci_seed}")


def seed_ranges(seeds) -> str:
    """[0, 1, 2, 5, 7, 8] -> '0-2, 5, 7-8'."""
    seeds = sorted(seeds)
    parts, i = [], 0
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(str(seeds[i]) if i == j else f"{seeds[i]}-{seeds[j]}")
        i = j + 1
    return ", ".join(parts)


def check_one_controller(rs: dict[int, Rollout], name: str) -> None:
    """UserError if a set mixes (controller, model) pairs in its rollouts' meta."""
    groups: dict[tuple, list[int]] = {}
    for s, r in rs.items():
        groups.setdefault((r.meta.get("controller"), r.meta.get("model")), []).append(s)
    if len(groups) > 1:
        mix = "; ".join(f"controller={c} model={m} (seeds {seed_ranges(ss)})"
                        for (c, m), ss in sorted(groups.items(), key=lambda kv: min(kv[1])))
        raise UserError(f"{name} mixes {len(groups)} controllers, one set must hold one: {mix}")


def check_sets(sets: dict[str, dict[int, Rollout]]) -> None:
    """UserError unless every set holds one controller, all share duration and dt, and a seed
    has the same shape in every set."""
    for name, rs in sets.items():
        check_one_controller(rs, name)
    for attr in ("duration", "dt"):
        vals = {name: {round(getattr(r, attr), 9) for r in rs.values()} for name, rs in sets.items()}
        if len(set().union(*vals.values())) > 1:
            desc = ", ".join(f"{name} has {'/'.join(f'{x:g} s' for x in sorted(v))}"
                             for name, v in vals.items())
            raise UserError(f"{attr} differs: {desc}")
    # The same seed on a different shape is a different target: pairing it would be meaningless.
    names = list(sets)
    common = sorted(set.intersection(*(set(rs) for rs in sets.values())))
    for s in common:
        shapes = {name: sets[name][s].shape for name in names}
        if len(set(shapes.values())) > 1:
            desc = ", ".join(f"{sh} in {name}" for name, sh in shapes.items())
            raise UserError(f"shape differs for seed {s}: {desc}")


def check_compatible(a: dict[int, Rollout], b: dict[int, Rollout], name_a: str, name_b: str):
    """check_sets for two sets (kept for callers of the two-set API)."""
    check_sets({name_a: a, name_b: b})


def nonfinite_arrays(r: Rollout) -> list[str]:
    """Names of the rollout's arrays that hold NaN or inf."""
    return [k for k in rollout.ARRAY_KEYS
            if not np.all(np.isfinite(np.asarray(getattr(r, k), dtype=float)))]


def failure_reason(r: Rollout) -> str | None:
    """Why an episode is not a full one: its meta failure, or fewer steps than its duration."""
    if r.meta.get("failure"):
        return str(r.meta["failure"])
    expected = int(round(r.duration / r.dt))
    if len(r.t) < expected:
        return f"{len(r.t)} of {expected} steps"
    return None


@dataclass
class Pairing:
    """Which seeds every set can be compared on, and why the others were left out."""

    seeds: list[int]  # used: in every set, finite, full episodes
    unpaired: dict[str, list[int]]  # per set: seeds missing from some other set
    nonfinite: dict[int, list[str]]  # seed -> "set: arrays" (left out of every set)
    failed: dict[int, list[str]]  # seed -> "set: reason" (left out of every set)

    def warnings(self, unpaired: bool = True) -> list[str]:
        """One line per kind of exclusion, naming the seeds."""
        both = "both sets" if len(self.unpaired) == 2 else "every set"
        lines = [f"warning: seeds only in {name}, not compared: {seeds}"
                 for name, seeds in self.unpaired.items() if seeds and unpaired]
        for what, bad in (("non-finite values", self.nonfinite), ("failed episodes", self.failed)):
            if bad:
                desc = ", ".join(f"{s} ({'; '.join(v)})" for s, v in sorted(bad.items()))
                lines.append(f"warning: {what}, seeds left out of {both}: {desc}")
        return lines


def pair(sets: dict[str, dict[int, Rollout]]) -> Pairing:
    """Seeds present in every set, minus any seed whose rollout in any set has non-finite
    values or is a failed episode: such a seed is left out of every set, so all sets are
    always compared on the same seeds."""
    keys = [set(rs) for rs in sets.values()]
    common = sorted(set.intersection(*keys))
    unpaired = {name: sorted(set(rs) - set(common)) for name, rs in sets.items()}
    nonfinite: dict[int, list[str]] = {}
    failed: dict[int, list[str]] = {}
    for s in common:
        for name, rs in sets.items():
            bad = nonfinite_arrays(rs[s])
            if bad:
                nonfinite.setdefault(s, []).append(f"{name}: {', '.join(bad)}")
            reason = failure_reason(rs[s])
            if reason:
                failed.setdefault(s, []).append(f"{name}: {reason}")
    used = [s for s in common if s not in nonfinite and s not in failed]
    return Pairing(used, unpaired, nonfinite, failed)


def require_seeds(p: Pairing, sets: dict[str, dict[int, Rollout]]) -> None:
    if p.seeds:
        return
    if not any(p.nonfinite) and not any(p.failed):
        desc = ", ".join(f"{name} has {seed_ranges(rs)}" for name, rs in sets.items())
        raise UserError(f"no seeds in common: {desc}")
    raise UserError("no seeds left to compare: " + " ".join(p.warnings()).replace("warning: ", ""))


@dataclass
class Comparison:
    label_a: str
    label_b: str
    seeds: list[int]  # paired seeds actually compared, sorted
    only_a: list[int]  # seeds with no partner in B, reported, not compared
    only_b: list[int]
    duration: float
    dt: float
    shapes: dict[int, str]
    metrics_a: dict[int, dict[str, float]]
    metrics_b: dict[int, dict[str, float]]
    rows: list[Row]
    by_shape: dict[str, list[Row]] = field(default_factory=dict)
    pairing: Pairing | None = None  # with the non-finite and failed seeds left out of both

    def row(self, key: str, shape: str | None = None) -> Row:
        rows = self.rows if shape is None else self.by_shape[shape]
        return next(r for r in rows if r.key == key)


def compare(
    a: dict[int, Rollout], b: dict[int, Rollout], settle_time: float = 0.5,
    band_cm: float = 5.0, n_boot: int = 10000, ci_seed: int = 0,
    label_a: str = "A", label_b: str = "B", tight_band_cm: float = 2.0,
) -> Comparison:
    """Pair the two sets by seed and summarise every metric overall and per shape."""
    check_options(settle_time, band_cm, tight_band_cm, n_boot, ci_seed)
    sets = {label_a: a, label_b: b}
    check_sets(sets)
    p = pair(sets)
    require_seeds(p, sets)
    seeds = p.seeds
    ma = {s: rollout_metrics(a[s], settle_time, band_cm, tight_band_cm) for s in seeds}
    mb = {s: rollout_metrics(b[s], settle_time, band_cm, tight_band_cm) for s in seeds}
    shapes = {s: a[s].shape for s in seeds}
    summ = dict(label_a=label_a, label_b=label_b, n_boot=n_boot, ci_seed=ci_seed,
                band_cm=band_cm, tight_band_cm=tight_band_cm)
    by_shape = {
        sh: summarize(ma, mb, [s for s in seeds if shapes[s] == sh], **summ)
        for sh in sorted(set(shapes.values()))
    }
    first = a[seeds[0]]
    return Comparison(
        label_a, label_b, seeds, p.unpaired[label_a], p.unpaired[label_b],
        first.duration, first.dt, shapes, ma, mb, summarize(ma, mb, seeds, **summ), by_shape, p,
    )


def seed_set_title(seeds: list[int], unit: str = "pairs") -> str:
    """'test seeds 0-999, n=1000 pairs': which seed set a figure or table is about."""
    from ..seeds import EVAL_SET, POOL_SEEDS, TUNE_SEEDS

    eval_seeds = {s for s, _ in EVAL_SET}
    s = set(seeds)
    pool = POOL_SEEDS.start <= min(s) and max(s) < POOL_SEEDS.stop
    kind = ("test " if max(s) < 1000 else "eval " if s <= eval_seeds
            else "tuning " if s <= set(TUNE_SEEDS) else "pool " if pool else "")
    return f"{kind}seeds {seed_ranges(seeds)}, n={len(seeds)} {unit}"


def load_set(prefix: str, root: Path) -> dict[int, Rollout]:
    """rollout.load_prefix with its input errors (no such prefix, unreadable file) as
    UserError; only those two, so anything else keeps its traceback."""
    try:
        return rollout.load_prefix(prefix, root)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from exc
