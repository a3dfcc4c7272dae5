"""Checking and pairing rollout sets, and the two-set comparison (`compare`).

Seeds with non-finite values or a failed episode in either set are reported; see `pair` for
what is done with them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import rollout, trajectory
from ..errors import UserError
from ..rollout import Rollout
from .stats import Row, peak_speed, rollout_metrics, summarize

# Display names for the usual prefixes (--headline without --labels).
CONTROLLER_LABELS = {"classical": "Classical", "analytic": "Analytic", "policy": "RL+Lead",
                     "feedforward": "Feedforward", "future_target": "Future target",
                     "feedforward_plan": "Feedforward, plan"}


DEFAULT_LABELS = {"ikpd": "Classical", "analytic": "Analytic", "eval": "RL+Lead"}


# A policy whose action is not a lead is not called one (its rollouts record the env).
POLICY_ACTION_LABELS = {"joint": "RL+Joint residual", "joint_target": "RL joint goals (no IK)"}


def controller_label(rollouts: dict, prefix: str) -> str:
    """A set's display name: from the controller its rollouts record (a policy by its action,
    an online correction after it, played on top or in its env's loop), else from its usual
    prefix (ikpd, analytic, eval), else the prefix itself."""
    kinds = {r.meta.get("controller") for r in rollouts.values()}
    known = CONTROLLER_LABELS.get(kinds.pop()) if len(kinds) == 1 else None
    if known == "RL+Lead":
        envs = [r.meta.get("env") for r in rollouts.values()]
        actions = {e.get("action", "lead") if isinstance(e, dict) else "lead" for e in envs}
        known = POLICY_ACTION_LABELS.get(actions.pop(), known) if len(actions) == 1 else known
    looped = {bool((r.meta.get("env") or {}).get("repetitive_gain")) for r in rollouts.values()}
    if known and looped == {True}:  # trained and played with it in the loop (EnvConfig)
        known = f"{known} + repetitive in the loop"
    online = {(r.meta.get("online") or {}).get("kind") for r in rollouts.values()}
    if known and len(online) == 1 and None not in online:  # panda_lead/online.py's corrections
        known = f"{known} + {online.pop()}"
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


def unpaired_warning(name: str, seeds) -> str:
    """One line naming the seeds of one set that have no partner, as ranges (a 200-seed oracle
    set against 1,000-seed sets leaves 800 unpaired)."""
    return (f"warning: {len(seeds)} seed{'s' * (len(seeds) != 1)} only in {name}, not "
            f"compared: {seed_ranges(seeds)}")


def check_one_controller(rs: dict[int, Rollout], name: str) -> None:
    """UserError if a set mixes identities (rollout.identity: controller, model hash,
    controller settings, env): the same rule the rollout writer applies."""
    groups: dict[tuple, list[int]] = {}
    for s, r in rs.items():
        groups.setdefault(rollout.identity(r.meta), []).append(s)
    if len(groups) > 1:
        items = sorted(groups.items(), key=lambda kv: min(kv[1]))
        names = [f"controller={k[0]}" + (f" model {k[1][:12]}" if k[1] else "") for k, _ in items]
        same = "" if len(set(names)) == len(names) else " (the same controller, other settings)"
        mix = "; ".join(f"{n} (seeds {seed_ranges(ss)})"
                        for n, (_, ss) in zip(names, items, strict=True))
        raise UserError(f"{name} mixes {len(groups)} controllers{same}, one set must hold "
                        f"one: {mix}")


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


# A failed episode that has no finite tip at all is charged this error (m) at every step.
NO_TIP_CHARGE_M = 1.0


def charged(r: Rollout) -> tuple[Rollout, str | None]:
    """A full-length rollout to score, and why it was charged (None: played in full).

    An episode that ended early (an unstable simulation, or self-collision when the env
    terminates on it) or holds non-finite values from some step on is never excused: it is
    scored as if the arm froze where it last had a finite tip while the target went on along
    its path (recomputed from the trajectory's seed and shape), so every step it missed counts
    with that error. A controller that fails pays for it in every metric."""
    expected = int(round(r.duration / r.dt))
    rows = np.ones(len(r.t), dtype=bool)
    for k in rollout.ARRAY_KEYS:
        a = np.asarray(getattr(r, k), dtype=float).reshape(len(r.t), -1)
        rows &= np.isfinite(a).all(axis=1)
    ok = len(r.t) if rows.all() else int(np.argmin(rows))
    failure = r.meta.get("failure")
    if ok >= expected and not failure:
        return r, None
    if failure:
        reason = f"{failure} at {ok * r.dt:.2f} s"
    elif ok < len(r.t):
        reason = f"non-finite {', '.join(nonfinite_arrays(r))} from {ok * r.dt:.2f} s"
    else:
        reason = f"ended after {len(r.t)} of {expected} steps"
    times = np.arange(1, expected + 1) * r.dt
    pos, vel, acc = trajectory.sample(r.seed, r.shape).at(times[ok:])
    n_more = expected - ok

    def grow(key: str, tail) -> np.ndarray:
        head = np.asarray(getattr(r, key))[:ok]
        tail = np.broadcast_to(tail, (n_more, *head.shape[1:])).astype(head.dtype)
        return np.concatenate([head, tail])

    frozen_tip = (np.asarray(r.ee_pos)[ok - 1] if ok
                  else pos[0] + np.array([NO_TIP_CHARGE_M, 0.0, 0.0]))
    q = np.asarray(r.qpos)[ok - 1] if ok else np.zeros(np.asarray(r.qpos).shape[1:])
    fields = dict(t=times, ee_pos=grow("ee_pos", frozen_tip), target_pos=grow("target_pos", pos),
                  target_vel=grow("target_vel", vel), target_acc=grow("target_acc", acc),
                  lead=grow("lead", 0.0), qpos=grow("qpos", q), qvel=grow("qvel", 0.0),
                  self_collision=grow("self_collision", False),
                  collision_depth=grow("collision_depth", 0.0),
                  reachable=grow("reachable", trajectory.reachable(pos)))
    return Rollout(**fields, meta={**r.meta, "charged": reason}), reason


def charged_metrics(rollouts: dict[int, Rollout], settle_time: float = 0.5
                    ) -> dict[int, dict[str, float]]:
    """Each seed's rollout_metrics, a failed episode charged (`charged`): how the study
    scripts score a set outside metrics.py's pairing."""
    return {seed: rollout_metrics(charged(r)[0], settle_time) for seed, r in rollouts.items()}


@dataclass
class Pairing:
    """Which seeds the sets are compared on (every seed in all of them), the rollouts to score
    (failed episodes charged, see `charged`), and which seeds were charged and why."""

    seeds: list[int]  # in every set: all compared, none left out
    unpaired: dict[str, list[int]]  # per set: seeds missing from some other set
    scored: dict[str, dict[int, Rollout]]  # per set: the rollouts metrics are computed on
    charged: dict[str, dict[int, str]]  # per set: seed -> why it was charged

    def warnings(self, unpaired: bool = True) -> list[str]:
        """One line per kind of irregularity, naming the seeds: unpaired seeds, and failures
        charged in each set (counted, never left out)."""
        lines = [unpaired_warning(name, seeds)
                 for name, seeds in self.unpaired.items() if seeds and unpaired]
        for name, bad in self.charged.items():
            if bad:
                desc = ", ".join(f"{s} ({why})" for s, why in sorted(bad.items()))
                lines.append(f"warning: {name}: {len(bad)} failed episode(s) charged as if the "
                             f"arm froze where it failed: {desc}")
        return lines

    def counts(self) -> str:
        """'n=1000 seeds; failures charged: A 0, B 3'."""
        parts = ", ".join(f"{name} {len(bad)}" for name, bad in self.charged.items())
        return f"n={len(self.seeds)} seeds; failures charged: {parts}"


def pair(sets: dict[str, dict[int, Rollout]]) -> Pairing:
    """Every seed present in all sets is compared; a failed episode stays in, charged (see
    `charged`), so all sets are compared on the same seeds and no failure is excused."""
    common = sorted(set.intersection(*(set(rs) for rs in sets.values())))
    unpaired = {name: sorted(set(rs) - set(common)) for name, rs in sets.items()}
    scored: dict[str, dict[int, Rollout]] = {}
    charges: dict[str, dict[int, str]] = {}
    for name, rs in sets.items():
        scored[name], charges[name] = {}, {}
        for s in common:
            scored[name][s], why = charged(rs[s])
            if why:
                charges[name][s] = why
    return Pairing(common, unpaired, scored, charges)


def require_seeds(p: Pairing, sets: dict[str, dict[int, Rollout]]) -> None:
    if not p.seeds:
        desc = ", ".join(f"{name} has {seed_ranges(rs)}" for name, rs in sets.items())
        raise UserError(f"no seeds in common: {desc}")


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
    pairing: Pairing | None = None  # the scored rollouts, failures charged
    # (low, high peak speed in m/s, rows over the seeds whose target peaks in [low, high])
    by_speed: list[tuple[float, float, list[Row]]] = field(default_factory=list)

    def row(self, key: str, shape: str | None = None) -> Row:
        rows = self.rows if shape is None else self.by_shape[shape]
        return next(r for r in rows if r.key == key)


def compare(
    a: dict[int, Rollout], b: dict[int, Rollout], settle_time: float = 0.5,
    band_cm: float = 5.0, n_boot: int = 10000, ci_seed: int = 0,
    label_a: str = "A", label_b: str = "B", tight_band_cm: float = 2.0, speed_bins: int = 5,
) -> Comparison:
    """Pair the two sets by seed and summarise every metric overall, per shape and per
    equal-count bin of the target's peak speed."""
    check_options(settle_time, band_cm, tight_band_cm, n_boot, ci_seed)
    sets = {label_a: a, label_b: b}
    check_sets(sets)
    p = pair(sets)
    require_seeds(p, sets)
    seeds = p.seeds
    a, b = p.scored[label_a], p.scored[label_b]
    ma = {s: rollout_metrics(a[s], settle_time, band_cm, tight_band_cm) for s in seeds}
    mb = {s: rollout_metrics(b[s], settle_time, band_cm, tight_band_cm) for s in seeds}
    shapes = {s: a[s].shape for s in seeds}
    summ = dict(label_a=label_a, label_b=label_b, n_boot=n_boot, ci_seed=ci_seed,
                band_cm=band_cm, tight_band_cm=tight_band_cm)
    by_shape = {
        sh: summarize(ma, mb, [s for s in seeds if shapes[s] == sh], **summ)
        for sh in sorted(set(shapes.values()))
    }
    speed = {s: peak_speed(a[s]) for s in seeds}
    edges = np.unique(np.quantile(list(speed.values()), np.linspace(0, 1, speed_bins + 1)))
    by_speed = []
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        last = k == len(edges) - 2
        group = [s for s in seeds if lo <= speed[s] and (speed[s] < hi or last)]
        if group:
            by_speed.append((float(lo), float(hi), summarize(ma, mb, group, **summ)))
    first = a[seeds[0]]
    return Comparison(
        label_a, label_b, seeds, p.unpaired[label_a], p.unpaired[label_b],
        first.duration, first.dt, shapes, ma, mb, summarize(ma, mb, seeds, **summ), by_shape, p,
        by_speed,
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
    """rollout.load_prefix: its input errors (no such prefix, a damaged or inconsistent file)
    are already UserErrors (NoRollouts, RolloutError); anything else is a bug and keeps its
    traceback (no ValueError is turned into a user error here)."""
    return rollout.load_prefix(prefix, root)
