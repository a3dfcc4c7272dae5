"""Compare rollout sets (e.g. classical IK+PD vs RL+Lead) seed by seed, with paired statistics.

    uv run metrics.py --prefix-a ikpd --prefix-b eval --breakdown --plot out.png
    uv run metrics.py --headline ikpd analytic eval --plot headline.png

Every metric is computed per rollout; the two sets are paired by seed. The table reports, per
set, mean ± std and median; and for the paired differences B - A the mean and the median, each
with a 95% percentile-bootstrap CI, the share of seeds where B is better, and a Wilcoxon
signed-rank p-value. A difference is "shown" only when its 95% CI excludes 0 (and at least 10
pairs back it). Seeds with non-finite values or a failed episode in either set are left out of
both sets (one warning line names them). The headline figure (--headline, two or more sets)
draws mean and median error against the target's peak speed. Every definition, exactly as
computed: docs/metrics.md.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tyro
from rich import box
from rich.console import Console
from rich.table import Table
from scipy import stats

import rollout
from atomicio import atomic_write
from errors import UserError, exit_on_user_error
from rollout import Rollout

NAN = float("nan")
LOWER, HIGHER = "lower", "higher"


@dataclass(frozen=True)
class Metric:
    key: str
    label: str  # "{band}" / "{tight}" are filled with the band widths in cm
    fmt: str
    better: str  # LOWER or HIGHER: which direction counts as an improvement


METRICS = (
    Metric("mean_err", "mean error (cm)", ".2f", LOWER),
    Metric("rmse", "RMSE (cm)", ".2f", LOWER),
    Metric("max_err", "max error (cm)", ".2f", LOWER),
    Metric("p95_err", "p95 error (cm)", ".2f", LOWER),
    Metric("settled_err", "settled mean error (cm)", ".2f", LOWER),
    Metric("in_band", "time within {band} cm (%)", ".1f", HIGHER),
    Metric("in_band_tight", "time within {tight} cm (%)", ".1f", HIGHER),
    Metric("in_reach_err", "in-reach error (cm)", ".2f", LOWER),
    Metric("out_reach_err", "out-of-reach error (cm)", ".2f", LOWER),
    Metric("in_band_reachable", "within {band} cm on reachable (%)", ".1f", HIGHER),
    Metric("jerk_rms", "jerk RMS (m/s^3)", ".1f", LOWER),
    Metric("self_collision", "self-collision time (%)", ".2f", LOWER),
)
BY_KEY = {m.key: m for m in METRICS}
# Out-of-reach time only happens on some seeds, so its mean is over fewer rollouts than n:
# the row label says over how many.
COUNTED = {"out_reach_err"}
# One colour per controller label in every figure; other labels take the next free colour.
COLOURS = {"Classical": "tab:blue", "Analytic": "tab:orange", "RL+Lead": "tab:green"}
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
SHAPES = ("circle", "fig8", "fly")
# Headline bins hold at least this many rollouts (fewer bins in a small panel): a CI from
# fewer values means little.
MIN_PER_BIN = 5
# Below this many pairs a percentile-bootstrap CI is too narrow to back a claim.
MIN_PAIRS_FOR_CLAIM = 10


# ---- per-rollout metrics --------------------------------------------------------------------


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else NAN


def rollout_metrics(r: Rollout, settle_time: float = 0.5, band_cm: float = 5.0,
                    tight_band_cm: float = 2.0) -> dict[str, float]:
    """Per-rollout metrics; NaN where a metric has no steps to average over."""
    err = r.error
    reach = np.asarray(r.reachable, dtype=bool)
    ee = np.asarray(r.ee_pos, dtype=float)
    if len(ee) >= 4:
        j = np.diff(ee, n=3, axis=0) / r.dt**3
        jerk = float(np.sqrt(np.mean(np.sum(j**2, axis=1))))
    else:
        jerk = NAN
    return {
        "mean_err": _mean(err) * 100,
        "rmse": float(np.sqrt(np.mean(err**2))) * 100,
        "max_err": float(np.max(err)) * 100,
        "p95_err": float(np.percentile(err, 95)) * 100,
        "settled_err": _mean(err[np.asarray(r.t) >= settle_time]) * 100,
        "in_band": 100.0 * _mean(err < band_cm / 100.0),
        "in_band_tight": 100.0 * _mean(err < tight_band_cm / 100.0),
        "in_reach_err": _mean(err[reach]) * 100,
        "out_reach_err": _mean(err[~reach]) * 100,
        "in_band_reachable": 100.0 * _mean(err[reach] < band_cm / 100.0),
        "jerk_rms": jerk,
        "self_collision": 100.0 * _mean(np.asarray(r.self_collision, dtype=float)),
    }


def peak_speed(r: Rollout) -> float:
    """The target's peak speed over the episode, m/s: max over steps of |target_vel|."""
    return float(np.max(np.linalg.norm(np.asarray(r.target_vel, dtype=float), axis=1)))


# ---- statistics -----------------------------------------------------------------------------


def bootstrap_ci(values, stat: Callable = np.mean, n_boot: int = 10000,
                 seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap CI of stat(values), resampling values with replacement.

    NaN for fewer than 2 finite values: resampling one value would fake a zero-width CI.
    The same seed draws the same resamples, so mean and median CIs use the same draws."""
    d = np.asarray(values, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2:
        return NAN, NAN
    rng = np.random.default_rng(seed)
    out = np.empty(n_boot)
    chunk = max(1, 2_000_000 // len(d))  # bounded memory at n = 1000 and 10000 resamples
    for i in range(0, n_boot, chunk):
        k = min(chunk, n_boot - i)
        out[i:i + k] = stat(d[rng.integers(0, len(d), size=(k, len(d)))], axis=1)
    lo, hi = np.percentile(out, [2.5, 97.5])
    return float(lo), float(hi)


def paired_ci(deltas, n_boot: int = 10000, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap CI of the mean paired difference."""
    return bootstrap_ci(deltas, np.mean, n_boot, seed)


def median_ci(deltas, n_boot: int = 10000, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap CI of the median paired difference."""
    return bootstrap_ci(deltas, np.median, n_boot, seed)


def shown(ci: tuple[float, float]) -> bool:
    """A difference is shown when its 95% CI excludes zero (an n/a CI shows nothing)."""
    lo, hi = ci
    return bool(np.isfinite(lo) and np.isfinite(hi) and (lo > 0 or hi < 0))


def wilcoxon_p(deltas) -> float:
    """Two-sided Wilcoxon signed-rank p-value; NaN when undefined (n < 2 or all zero)."""
    d = np.asarray(deltas, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2 or not np.any(d != 0):
        return NAN
    with warnings.catch_warnings():
        # scipy warns about small n / ties; the p-value is still the right one to report.
        warnings.simplefilter("ignore")
        try:
            return float(stats.wilcoxon(d).pvalue)
        except ValueError:
            return NAN


def n_improved(va: np.ndarray, vb: np.ndarray, better: str) -> int:
    """Seeds (both values finite) where B is strictly better than A; ties are not improved."""
    ok = np.isfinite(va) & np.isfinite(vb)
    return int(np.sum(vb[ok] < va[ok]) if better == LOWER else np.sum(vb[ok] > va[ok]))


@dataclass
class Row:
    """One metric over a group of paired seeds."""

    key: str
    label: str
    better: str  # LOWER or HIGHER
    mean_a: float
    std_a: float
    median_a: float
    mean_b: float
    std_b: float
    median_b: float
    n_a: int  # rollouts where the metric is defined
    n_b: int
    n_pairs: int  # seeds where both are defined: what the differences use
    delta: float  # mean of B - A
    ci: tuple[float, float]
    median_delta: float  # median of B - A
    median_ci: tuple[float, float]
    improved: int  # seeds where B is better than A
    p: float

    @property
    def share_improved(self) -> float:
        return self.improved / self.n_pairs if self.n_pairs else NAN


def _stats(v: np.ndarray) -> tuple[float, float, float, int]:
    """(mean, sample std, median, n) of the finite values."""
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return NAN, NAN, NAN, 0
    # Sample std (ddof=1): the spread across seeds; undefined for a single rollout.
    std = float(v.std(ddof=1)) if len(v) > 1 else NAN
    return float(v.mean()), std, float(np.median(v)), len(v)


def metric_label(m: Metric, band_cm: float = 5.0, tight_band_cm: float = 2.0) -> str:
    return m.label.format(band=f"{band_cm:g}", tight=f"{tight_band_cm:g}")


def summarize(
    ma: dict[int, dict[str, float]], mb: dict[int, dict[str, float]], seeds: list[int],
    label_a: str = "A", label_b: str = "B", n_boot: int = 10000, ci_seed: int = 0,
    band_cm: float = 5.0, tight_band_cm: float = 2.0,
) -> list[Row]:
    """One Row per metric over the given paired seeds."""
    rows = []
    for m in METRICS:
        va = np.array([ma[s][m.key] for s in seeds], dtype=float)
        vb = np.array([mb[s][m.key] for s in seeds], dtype=float)
        mean_a, std_a, med_a, n_a = _stats(va)
        mean_b, std_b, med_b, n_b = _stats(vb)
        d = (vb - va)[np.isfinite(va) & np.isfinite(vb)]
        label = metric_label(m, band_cm, tight_band_cm)
        if m.key in COUNTED:
            n = len(seeds)
            same = n_a == n_b
            label += f" ({n_a}/{n})" if same else f" ({label_a} {n_a}/{n}, {label_b} {n_b}/{n})"
        rows.append(Row(
            m.key, label, m.better, mean_a, std_a, med_a, mean_b, std_b, med_b, n_a, n_b,
            len(d), _mean(d), paired_ci(d, n_boot, ci_seed),
            float(np.median(d)) if len(d) else NAN, median_ci(d, n_boot, ci_seed),
            n_improved(va, vb, m.better), wilcoxon_p(d)))
    return rows


def claim(row: Row, label_b: str = "B") -> str:
    """One line: the mean and median differences, each 'shown' (95% CI excludes 0 and at least
    MIN_PAIRS_FOR_CLAIM pairs) or 'not shown', and the share of seeds improved."""
    fmt = BY_KEY[row.key].fmt

    def part(name: str, value: float, ci: tuple[float, float]) -> str:
        if not np.isfinite(value):
            return f"{name} diff n/a"
        verdict = "shown" if shown(ci) else "not shown"
        if row.n_pairs < MIN_PAIRS_FOR_CLAIM:
            verdict = f"not shown (only {row.n_pairs} pairs, fewer than {MIN_PAIRS_FOR_CLAIM})"
        return f"{name} diff {_num(value, fmt, True)} {_ci(ci, fmt)} {verdict}"

    share = (f"{label_b} better on {row.improved}/{row.n_pairs} seeds "
             f"({100 * row.share_improved:.0f}%)" if row.n_pairs else "no pairs")
    return (f"{row.label}, {row.better} is better: {part('mean', row.delta, row.ci)}; "
            f"{part('median', row.median_delta, row.median_ci)}; {share}")


# ---- checking and pairing the sets ----------------------------------------------------------


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


def _seed_list(seeds) -> str:
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
        mix = "; ".join(f"controller={c} model={m} (seeds {_seed_list(ss)})"
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
        desc = ", ".join(f"{name} has {_seed_list(rs)}" for name, rs in sets.items())
        raise UserError(f"no seeds in common: {desc}")
    raise UserError("no seeds left to compare: " + " ".join(p.warnings()).replace("warning: ", ""))


# ---- two-set comparison ---------------------------------------------------------------------


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


# ---- tables ---------------------------------------------------------------------------------


def _num(x: float, fmt: str, sign: bool = False) -> str:
    if not np.isfinite(x):
        return "n/a"
    return format(x, ("+" if sign else "") + fmt)


def _ci(ci: tuple[float, float], fmt: str) -> str:
    lo, hi = (_num(c, fmt, True) for c in ci)
    return "[n/a]" if lo == "n/a" else f"[{lo}, {hi}]"


def diff_text(value: float, ci: tuple[float, float], fmt: str = ".2f", verdict: bool = True
              ) -> str:
    """'+1.23 [+0.45, +2.01] shown': a paired difference, its 95% CI and whether it is shown
    (the studies' tables use it)."""
    text = f"{_num(value, fmt, True)} {_ci(ci, fmt)}"
    return text + (" shown" if shown(ci) else " not shown") if verdict else text


def metrics_table(rows: list[Row], label_a: str, label_b: str, title: str) -> Table:
    table = Table(title=title, title_justify="left")
    for name in ("Metric", "better", f"{label_a} mean ± std", f"{label_a} median",
                 f"{label_b} mean ± std", f"{label_b} median", "mean diff (B - A) [95% CI]",
                 "median diff (B - A) [95% CI]", "B better", "p (Wilcoxon)"):
        table.add_column(name, justify="left" if name == "Metric" else "right")
    for r in rows:
        f = BY_KEY[r.key].fmt
        ms = [_num(m, f) + ("" if not np.isfinite(s) else f" ± {s:{f}}")
              for m, s in ((r.mean_a, r.std_a), (r.mean_b, r.std_b))]
        share = f"{100 * r.share_improved:.0f}%" if r.n_pairs else "n/a"
        p = "n/a" if not np.isfinite(r.p) else f"{r.p:.3g}"
        table.add_row(r.label, r.better, ms[0], _num(r.median_a, f), ms[1], _num(r.median_b, f),
                      f"{_num(r.delta, f, True)} {_ci(r.ci, f)}",
                      f"{_num(r.median_delta, f, True)} {_ci(r.median_ci, f)}", share, p)
    return table


def seed_table(cmp: Comparison) -> Table:
    table = Table(title="per seed", title_justify="left")
    for name in ("seed", "shape", f"{cmp.label_a} mean error (cm)",
                 f"{cmp.label_b} mean error (cm)", "diff (B - A)"):
        table.add_column(name, justify="right")
    for s in cmp.seeds:
        ea, eb = cmp.metrics_a[s]["mean_err"], cmp.metrics_b[s]["mean_err"]
        table.add_row(str(s), cmp.shapes[s], f"{ea:.2f}", f"{eb:.2f}", f"{eb - ea:+.2f}")
    return table


def seed_set_title(seeds: list[int], unit: str = "pairs") -> str:
    """'test seeds 0-999, n=1000 pairs': which seed set a figure or table is about."""
    from seeds import POOL_SEEDS, TUNE_SEEDS

    eval_seeds = {900_000 + i for i in range(15)}
    s = set(seeds)
    pool = POOL_SEEDS.start <= min(s) and max(s) < POOL_SEEDS.stop
    kind = ("test " if max(s) < 1000 else "eval " if s <= eval_seeds
            else "tuning " if s <= set(TUNE_SEEDS) else "pool " if pool else "")
    return f"{kind}seeds {_seed_list(seeds)}, n={len(seeds)} {unit}"


# ---- figures --------------------------------------------------------------------------------


def colours_for(labels) -> dict[str, str]:
    """One colour per label: the fixed COLOURS where known, else the next unused tab10 colour."""
    free = iter(c for c in (f"C{i}" for i in range(3, 10)) if c not in COLOURS.values())
    return {lab: COLOURS[lab] if lab in COLOURS else next(free) for lab in dict.fromkeys(labels)}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # headless: no display on cluster nodes
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    path = Path(path)
    plt = _pyplot()
    try:
        with atomic_write(path, ".tmp.png") as tmp, open(tmp, "wb") as f:
            fig.savefig(f, format="png", dpi=120)
    finally:
        plt.close(fig)
    return path


def plot_paired_differences(ax, cmp: Comparison, colour: str, key: str = "mean_err") -> None:
    """Histogram of the per-seed differences B - A with zero, median and mean marked."""
    m = BY_KEY[key]
    d = np.array([cmp.metrics_b[s][key] - cmp.metrics_a[s][key] for s in cmp.seeds])
    d = d[np.isfinite(d)]
    row = cmp.row(key)
    bins = int(np.clip(np.sqrt(len(d)) * 2, 10, 60))
    ax.hist(d, bins=bins, color=colour, alpha=0.6, edgecolor="white", linewidth=0.5)
    ax.axvline(0, color="black", linewidth=1.2, label="zero (no difference)")
    ax.axvline(row.median_delta, color="black", linestyle="--",
               label=f"median {row.median_delta:+.2f} {_ci(row.median_ci, '.2f')}")
    ax.axvline(row.delta, color="black", linestyle=":",
               label=f"mean {row.delta:+.2f} {_ci(row.ci, '.2f')}")
    ax.plot([], [], " ", label=f"{cmp.label_b} better ({m.better}) on {row.improved}/"
            f"{row.n_pairs} seeds ({100 * row.share_improved:.0f}%)")
    unit = metric_label(m).rsplit("(", 1)[-1].rstrip(")")
    ax.set(xlabel=f"{metric_label(m)}: {cmp.label_b} - {cmp.label_a} ({unit})",
           ylabel="seeds",
           title=f"paired difference in {metric_label(m).split(' (')[0]} per seed, "
                 f"{seed_set_title(cmp.seeds)}")
    ax.legend(fontsize="small")


def plot_error_over_time(ax, sets: dict[str, dict[int, Rollout]], seeds: list[int],
                         colours: dict[str, str], settle_time: float, bands_cm: tuple[float, ...],
                         highlight: list[int] = ()) -> None:
    """Median and inter-quartile band of the error across seeds, per set. The y axis stops a
    little above the 99th percentile of the settled upper quartile, so the start-up transient
    does not flatten the rest; t = settle_time is marked."""
    top, peak = 0.0, 0.0
    for label, rs in sets.items():
        err = np.stack([rs[s].error for s in seeds]) * 100
        t = np.asarray(rs[seeds[0]].t)
        q25, q50, q75 = np.percentile(err, [25, 50, 75], axis=0)
        c = colours[label]
        ax.fill_between(t, q25, q75, color=c, alpha=0.25, linewidth=0)
        ax.plot(t, q50, color=c, label=f"{label}: median, IQR shaded")
        for k, s in enumerate(highlight):
            ax.plot(t, rs[s].error * 100, color=c, linewidth=0.6, alpha=0.6,
                    label=f"{label}: seed {_seed_list(highlight)}" if k == 0 else None)
        settled = t >= settle_time
        ref = q75[settled] if settled.any() else q75
        top = max(top, float(np.percentile(ref, 99)))
        peak = max(peak, float(q50.max()))
    top = 1.3 * top if top > 0 else 1.0
    for b, style in zip(bands_cm, ("--", ":"), strict=False):
        if b < top:
            ax.axhline(b, color="grey", linestyle=style, linewidth=0.8, label=f"{b:g} cm band")
    ax.axvline(settle_time, color="black", linestyle="-.", linewidth=0.8,
               label=f"t = {settle_time:g} s (settled after)")
    ax.set_ylim(0, top)
    clipped = f"\ny axis clipped: the start-up median peaks at {peak:.1f} cm" if peak > top else ""
    ax.set(xlabel="time (s)", ylabel="tracking error (cm)",
           title=f"tracking error over time, {seed_set_title(seeds)}{clipped}")
    ax.legend(fontsize="small", ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.13))


def plot(cmp: Comparison, a: dict[int, Rollout], b: dict[int, Rollout], seeds: list[int],
         band_cm: float, path: Path, settle_time: float = 0.5,
         tight_band_cm: float = 2.0) -> Path:
    """Paired differences in mean error (top) and error over time, median and IQR across the
    compared seeds, with `seeds` drawn as thin lines (bottom); atomic write."""
    plt = _pyplot()
    colours = colours_for([cmp.label_a, cmp.label_b])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 10), constrained_layout=True)
    plot_paired_differences(top, cmp, colours[cmp.label_b])
    plot_error_over_time(bottom, {cmp.label_a: a, cmp.label_b: b}, cmp.seeds, colours,
                         settle_time, (band_cm, tight_band_cm), list(seeds))
    return _save(fig, path)


# ---- headline: error against the target's peak speed ----------------------------------------


def speed_bin_edges(speeds: np.ndarray, n_bins: int) -> np.ndarray:
    """Quantile edges (equal counts per bin); repeated edges are merged."""
    return np.unique(np.quantile(speeds, np.linspace(0, 1, n_bins + 1)))


def binned_errors(speeds: np.ndarray, errors: np.ndarray, edges: np.ndarray, n_boot: int,
                  ci_seed: int) -> list[dict]:
    """Per speed bin: x (median peak speed), n, mean and median error, each with its 95%
    bootstrap CI. The last bin includes its upper edge."""
    idx = np.clip(np.searchsorted(edges, speeds, side="right") - 1, 0, max(len(edges) - 2, 0))
    out = []
    for k in range(max(len(edges) - 1, 1)):
        e = errors[idx == k]
        if len(e) == 0:
            continue
        out.append(dict(x=float(np.median(speeds[idx == k])), n=len(e),
                        mean=float(np.mean(e)), mean_ci=bootstrap_ci(e, np.mean, n_boot, ci_seed),
                        median=float(np.median(e)),
                        median_ci=bootstrap_ci(e, np.median, n_boot, ci_seed)))
    return out


def headline_data(sets: dict[str, dict[int, Rollout]], seeds: list[int], n_bins: int = 5,
                  n_boot: int = 10000, ci_seed: int = 0) -> dict[str, dict[str, list[dict]]]:
    """panel ('all', then each shape) -> set label -> binned_errors over that panel's seeds.
    The bins are shared by every set within a panel (the same seeds give the same targets);
    a panel gets at most n_bins bins and at least MIN_PER_BIN rollouts per bin."""
    first = next(iter(sets.values()))
    shapes = {s: first[s].shape for s in seeds}
    panels = ["all"] + [sh for sh in SHAPES if sh in shapes.values()] + sorted(
        set(shapes.values()) - set(SHAPES))
    out: dict[str, dict[str, list[dict]]] = {}
    for panel in panels:
        ps = [s for s in seeds if panel == "all" or shapes[s] == panel]
        speeds = np.array([peak_speed(first[s]) for s in ps])
        edges = speed_bin_edges(speeds, max(1, min(n_bins, len(ps) // MIN_PER_BIN)))
        out[panel] = {
            label: binned_errors(speeds, np.array([100 * _mean(rs[s].error) for s in ps]),
                                 edges, n_boot, ci_seed)
            for label, rs in sets.items()
        }
    return out


def plot_headline(data: dict[str, dict[str, list[dict]]], seeds: list[int], path: Path) -> Path:
    """Rows: mean, median error per speed bin with 95% CIs; columns: all, then each shape."""
    plt = _pyplot()
    panels = list(data)
    labels = list(next(iter(data.values())))
    colours = colours_for(labels)
    fig, axes = plt.subplots(2, len(panels), figsize=(4.2 * len(panels), 7.5), sharey="row",
                             sharex=True, constrained_layout=True, squeeze=False)
    xs = [b["x"] for p in panels for lab in labels for b in data[p][lab]]
    span = max(xs) - min(xs) or 1.0
    for j, panel in enumerate(panels):
        n = sum(b["n"] for b in data[panel][labels[0]])
        for i, stat in enumerate(("mean", "median")):
            ax = axes[i, j]
            for k, label in enumerate(labels):
                bins = data[panel][label]
                x = np.array([b["x"] for b in bins])
                y = np.array([b[stat] for b in bins])
                lo, hi = (np.array([b[f"{stat}_ci"][q] for b in bins]) for q in (0, 1))
                # A small sideways nudge per set keeps overlapping error bars apart.
                dx = (k - (len(labels) - 1) / 2) * 0.008 * span
                ax.errorbar(x + dx, y, yerr=[np.nan_to_num(y - lo), np.nan_to_num(hi - y)],
                            color=colours[label], marker="o", capsize=3, label=label)
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_title(f"{panel} (n={n} per set)")
            if i == 1:
                ax.tick_params(labelbottom=True)
                ax.set_xlabel("target peak speed (m/s), bin median")
            if j == 0:
                ax.set_ylabel(f"{stat} of per-rollout mean error (cm)")
    for i, stat in enumerate(("mean", "median")):  # shared y per row, from 0 to the top CI
        vals = [v for p in panels for lab in labels for b in data[p][lab]
                for v in (b[stat], b[f"{stat}_ci"][1]) if np.isfinite(v)]
        axes[i, 0].set_ylim(0, 1.08 * max(vals))
    axes[0, 0].legend(fontsize="small")
    fig.suptitle(f"tracking error against target peak speed, 95% bootstrap CIs; "
                 f"{seed_set_title(seeds, 'per set')}")
    return _save(fig, path)


# ---- command line ---------------------------------------------------------------------------


def load_set(prefix: str, root: Path) -> dict[int, Rollout]:
    """rollout.load_prefix with its input errors (no such prefix, unreadable file) as
    UserError; only those two, so anything else keeps its traceback."""
    try:
        return rollout.load_prefix(prefix, root)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from exc


@dataclass
class Args:
    prefix_a: str = "ikpd"
    """Rollout prefix of set A (the baseline), read from <root>/<prefix>/seed_*.npz."""
    prefix_b: str = "eval"
    """Rollout prefix of set B (compared against A: differences are B - A)."""
    label_a: str | None = None
    """Display name of set A (also picks its colour in figures); default: from the rollouts'
    controller (Classical, Analytic or RL+Lead), the prefix where both sets share one."""
    label_b: str | None = None
    """Display name of set B; default as for A."""
    root: Path = rollout.ROLLOUT_DIR
    """Folder that holds the rollout prefixes."""
    breakdown: bool = False
    """Also print a per-seed table and one table per target shape."""
    plot: Path | None = None
    """Write a PNG: paired differences in mean error and error over time (or, with
    --headline, the headline figure)."""
    plot_seeds: tuple[int, ...] = ()
    """Seeds also drawn as thin lines in the error-over-time panel (default: none)."""
    headline: tuple[str, ...] = ()
    """Headline figure instead of the A/B table: mean and median error against the target's
    peak speed for these 2 or more prefixes (e.g. ikpd analytic eval); needs --plot."""
    labels: tuple[str, ...] = ()
    """Display names for the --headline prefixes, in order (default: from each set's
    controller, as for --label-a; the prefixes where two sets would share a name)."""
    speed_bins: int = 5
    """Number of equal-count peak-speed bins in the headline figure."""
    settle_time: float = 0.5
    """Seconds of start-up transient excluded from 'settled mean error' (steps with t >= this)."""
    band_cm: float = 5.0
    """Error band in cm for 'time within band' and 'within band on reachable'."""
    tight_band_cm: float = 2.0
    """The second, tighter error band in cm ('time within' this band)."""
    bootstrap: int = 10000
    """Number of bootstrap resamples for the 95% CIs (mean and median)."""
    ci_seed: int = 0
    """Seed of the bootstrap random generator (makes CIs reproducible)."""
    markdown: bool = False
    """Print the tables as GitHub markdown (what the results tables are pasted from)."""


def _print_tables(console: Console, tables: list[Table], markdown: bool) -> None:
    for table in tables:
        if not markdown:
            console.print(table)
            continue
        console.print(f"\n{table.title}" + (f" ({table.caption})" if table.caption else ""),
                      markup=False, highlight=False)
        table.title = table.caption = None
        table.box = box.MARKDOWN
        # Wide enough that no cell wraps: a wrapped cell would split a markdown row in two.
        wide = Console(width=100_000)
        with wide.capture() as captured:
            wide.print(table)
        # rich pads the markdown box with blank rows of spaces: keep only the table lines
        print("\n".join(ln.rstrip() for ln in captured.get().splitlines() if ln.strip()))


def _say(console: Console, line: str) -> None:
    console.print(line, markup=False, highlight=False, soft_wrap=True)


def run_headline(args: Args, console: Console) -> None:
    if len(args.headline) < 2:
        raise UserError(f"--headline needs 2 or more prefixes, got {list(args.headline)}")
    if args.plot is None:
        raise UserError("--headline draws a figure: give --plot PATH.png")
    if args.labels and len(args.labels) != len(args.headline):
        raise UserError(f"--labels has {len(args.labels)} names for "
                        f"{len(args.headline)} --headline prefixes")
    if args.speed_bins < 1:
        raise UserError(f"--speed-bins must be at least 1, got {args.speed_bins}")
    loaded = [load_set(p, args.root) for p in args.headline]
    labels = list(args.labels) or set_labels(loaded, list(args.headline))
    if len(set(labels)) != len(labels):
        raise UserError(f"labels must differ, got {labels}; use --labels")
    sets = dict(zip(labels, loaded, strict=True))
    check_sets(sets)
    p = pair(sets)
    require_seeds(p, sets)
    _say(console, f"n={len(p.seeds)} seeds in every set ({', '.join(labels)})")
    for line in p.warnings():
        _say(console, line)
    data = headline_data(sets, p.seeds, args.speed_bins, args.bootstrap, args.ci_seed)
    _say(console, f"wrote {plot_headline(data, p.seeds, args.plot)}")




def run_compare(args: Args, console: Console) -> None:
    a, b = load_set(args.prefix_a, args.root), load_set(args.prefix_b, args.root)
    if args.label_a is None or args.label_b is None:
        auto_a, auto_b = set_labels([a, b], [args.prefix_a, args.prefix_b])
        args = dataclasses.replace(args, label_a=args.label_a or auto_a,
                                   label_b=args.label_b or auto_b)
    # Name the prefixes in errors; the Comparison itself keeps the display labels.
    name_a, name_b = f"{args.label_a} ({args.prefix_a})", f"{args.label_b} ({args.prefix_b})"
    check_compatible(a, b, name_a, name_b)
    cmp = compare(a, b, args.settle_time, args.band_cm, args.bootstrap, args.ci_seed,
                  args.label_a, args.label_b, args.tight_band_cm)
    missing = [s for s in args.plot_seeds if s not in cmp.seeds]
    if args.plot and missing:
        raise UserError(f"--plot-seeds {missing} are not compared seeds; compared: "
                        f"{_seed_list(cmp.seeds)}")

    _say(console, f"n={len(cmp.seeds)} pairs duration={cmp.duration:.2f}s")
    # On stdout, not stderr, so a saved report also says which seeds it left out.
    for prefix, seeds in ((args.prefix_a, cmp.only_a), (args.prefix_b, cmp.only_b)):
        if seeds:
            _say(console, f"warning: seeds only in {prefix}, not compared: {seeds}")
    for line in cmp.pairing.warnings(unpaired=False):
        _say(console, line)
    _say(console, f"A = {args.label_a} ({args.root}/{args.prefix_a}), "
                  f"B = {args.label_b} ({args.root}/{args.prefix_b})")
    caption = (f"{seed_set_title(cmp.seeds)}; settle {args.settle_time:g} s; CIs: paired "
               f"bootstrap over seeds, {args.bootstrap} resamples, seed {args.ci_seed}")
    tables = [metrics_table(cmp.rows, args.label_a, args.label_b, "all seeds")]
    tables[0].caption = caption
    if args.breakdown:
        tables.append(seed_table(cmp))
        for shape, rows in cmp.by_shape.items():
            n = sum(1 for s in cmp.seeds if cmp.shapes[s] == shape)
            tables.append(metrics_table(rows, args.label_a, args.label_b, f"shape {shape} (n={n})"))
    _print_tables(console, tables, args.markdown)
    bullet = "- " if args.markdown else "  "
    _say(console, f"\nclaims, {args.label_b} vs {args.label_a} (shown = the 95% CI of the paired "
                  "difference excludes 0):")
    for row in cmp.rows:
        _say(console, bullet + claim(row, args.label_b))
    if args.plot:
        path = plot(cmp, a, b, list(args.plot_seeds), args.band_cm, args.plot, args.settle_time,
                    args.tight_band_cm)
        _say(console, f"wrote {path}")


@exit_on_user_error
def main(args: Args) -> int:
    # Validate every number before reading anything: 'nan' must not become '0% in band'.
    check_options(args.settle_time, args.band_cm, args.tight_band_cm, args.bootstrap,
                  args.ci_seed)
    # Off a terminal rich would wrap at 80 columns and break the table apart.
    console = Console(width=None if sys.stdout.isatty() else 240)
    if args.headline:
        run_headline(args, console)
    else:
        run_compare(args, console)
    return 0


if __name__ == "__main__":
    sys.exit(main(tyro.cli(Args, description=__doc__)))
