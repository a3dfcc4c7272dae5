"""Compare two rollout sets (e.g. classical IK+PD vs RL+Lead) seed by seed.

    uv run metrics.py --prefix-a ikpd --prefix-b eval --breakdown --plot out.png

Every metric is computed per rollout, then the two sets are paired by seed: the table reports
mean ± std per set, the mean paired difference B - A, its 95% bootstrap CI and a Wilcoxon
signed-rank p-value. Definitions are in the README section "metrics.py".
"""

from __future__ import annotations

import sys
import warnings
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
from rollout import Rollout

# (key, row label, number format), in table order.
METRICS = (
    ("mean_err", "mean error (cm)", ".2f"),
    ("rmse", "RMSE (cm)", ".2f"),
    ("max_err", "max error (cm)", ".2f"),
    ("p95_err", "p95 error (cm)", ".2f"),
    ("settled_err", "settled mean error (cm)", ".2f"),
    ("in_band", "time within band (%)", ".1f"),
    ("in_reach_err", "in-reach error (cm)", ".2f"),
    ("out_reach_err", "out-of-reach error (cm)", ".2f"),
    ("in_band_reachable", "in-band on reachable (%)", ".1f"),
    ("jerk_rms", "jerk RMS (m/s^3)", ".1f"),
    ("self_collision", "self-collision time (%)", ".2f"),
)
# Out-of-reach time only happens on some seeds, so its mean is over fewer rollouts than n:
# the row label says over how many.
COUNTED = {"out_reach_err"}
NAN = float("nan")


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else NAN


def rollout_metrics(r: Rollout, settle_time: float = 0.5, band_cm: float = 5.0) -> dict[str, float]:
    """Per-rollout metrics; NaN where a metric has no steps to average over."""
    err = r.error
    band = band_cm / 100.0
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
        "in_band": 100.0 * _mean(err < band),
        "in_reach_err": _mean(err[reach]) * 100,
        "out_reach_err": _mean(err[~reach]) * 100,
        "in_band_reachable": 100.0 * _mean(err[reach] < band),
        "jerk_rms": jerk,
        "self_collision": 100.0 * _mean(np.asarray(r.self_collision, dtype=float)),
    }


def paired_ci(deltas, n_boot: int = 10000, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap CI of the mean delta, resampling seeds with replacement.

    NaN for fewer than 2 finite deltas: resampling one value would fake a zero-width CI."""
    d = np.asarray(deltas, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2:
        return NAN, NAN
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), size=(n_boot, len(d)))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


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


@dataclass
class Row:
    """One metric over a group of paired seeds."""

    key: str
    label: str
    mean_a: float
    std_a: float
    mean_b: float
    std_b: float
    n_a: int  # rollouts where the metric is defined
    n_b: int
    n_pairs: int  # seeds where both are defined: what delta, CI and p use
    delta: float
    ci: tuple[float, float]
    p: float


@dataclass
class Comparison:
    label_a: str
    label_b: str
    seeds: list[int]  # paired seeds, sorted
    only_a: list[int]  # seeds with no partner in B, reported, not compared
    only_b: list[int]
    duration: float
    dt: float
    shapes: dict[int, str]
    metrics_a: dict[int, dict[str, float]]
    metrics_b: dict[int, dict[str, float]]
    rows: list[Row]
    by_shape: dict[str, list[Row]] = field(default_factory=dict)

    def row(self, key: str, shape: str | None = None) -> Row:
        rows = self.rows if shape is None else self.by_shape[shape]
        return next(r for r in rows if r.key == key)


def _mean_std(v: np.ndarray) -> tuple[float, float, int]:
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return NAN, NAN, 0
    # Sample std (ddof=1): the spread across seeds; undefined for a single rollout.
    return float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else NAN, len(v)


def summarize(
    ma: dict[int, dict[str, float]], mb: dict[int, dict[str, float]], seeds: list[int],
    label_a: str = "A", label_b: str = "B", n_boot: int = 10000, ci_seed: int = 0,
) -> list[Row]:
    """One Row per metric over the given paired seeds."""
    rows = []
    for key, label, _ in METRICS:
        va = np.array([ma[s][key] for s in seeds], dtype=float)
        vb = np.array([mb[s][key] for s in seeds], dtype=float)
        mean_a, std_a, n_a = _mean_std(va)
        mean_b, std_b, n_b = _mean_std(vb)
        d = (vb - va)[np.isfinite(va) & np.isfinite(vb)]
        if key in COUNTED:
            n = len(seeds)
            same = n_a == n_b
            label += f" ({n_a}/{n})" if same else f" ({label_a} {n_a}/{n}, {label_b} {n_b}/{n})"
        rows.append(Row(key, label, mean_a, std_a, mean_b, std_b, n_a, n_b, len(d),
                        _mean(d), paired_ci(d, n_boot, ci_seed), wilcoxon_p(d)))
    return rows


def check_compatible(a: dict[int, Rollout], b: dict[int, Rollout], name_a: str, name_b: str):
    """Raise ValueError unless both sets share duration and dt and paired seeds share a shape."""
    for attr in ("duration", "dt"):
        va, vb = ({round(getattr(r, attr), 9) for r in rs.values()} for rs in (a, b))
        if len(va | vb) > 1:
            fmt = lambda v: "/".join(f"{x:g} s" for x in sorted(v))  # noqa: E731
            raise ValueError(f"{attr} differs: {name_a} has {fmt(va)}, {name_b} has {fmt(vb)}")
    # The same seed on a different shape is a different target: pairing it would be meaningless.
    bad = [s for s in sorted(a.keys() & b.keys()) if a[s].shape != b[s].shape]
    if bad:
        raise ValueError(f"shape differs for seed(s) {bad}: seed {bad[0]} is {a[bad[0]].shape} "
                         f"in {name_a} but {b[bad[0]].shape} in {name_b}")


def compare(
    a: dict[int, Rollout], b: dict[int, Rollout], settle_time: float = 0.5,
    band_cm: float = 5.0, n_boot: int = 10000, ci_seed: int = 0,
    label_a: str = "A", label_b: str = "B",
) -> Comparison:
    """Pair the two sets by seed and summarise every metric overall and per shape."""
    check_compatible(a, b, label_a, label_b)
    seeds = sorted(a.keys() & b.keys())
    if not seeds:
        raise ValueError(f"no seeds in common: {label_a} has {sorted(a)}, "
                         f"{label_b} has {sorted(b)}")
    ma = {s: rollout_metrics(a[s], settle_time, band_cm) for s in seeds}
    mb = {s: rollout_metrics(b[s], settle_time, band_cm) for s in seeds}
    shapes = {s: a[s].shape for s in seeds}
    summ = dict(label_a=label_a, label_b=label_b, n_boot=n_boot, ci_seed=ci_seed)
    by_shape = {
        sh: summarize(ma, mb, [s for s in seeds if shapes[s] == sh], **summ)
        for sh in sorted(set(shapes.values()))
    }
    first = a[seeds[0]]
    return Comparison(
        label_a, label_b, seeds, sorted(a.keys() - b.keys()), sorted(b.keys() - a.keys()),
        first.duration, first.dt, shapes, ma, mb, summarize(ma, mb, seeds, **summ), by_shape,
    )


def _num(x: float, fmt: str, sign: bool = False) -> str:
    if not np.isfinite(x):
        return "n/a"
    return format(x, ("+" if sign else "") + fmt)


def metrics_table(rows: list[Row], label_a: str, label_b: str, title: str) -> Table:
    table = Table(title=title, title_justify="left")
    for name in ("Metric", f"{label_a} (mean ± std)", f"{label_b} (mean ± std)",
                 "delta mean (B - A)", "95% CI", "p (Wilcoxon)"):
        table.add_column(name, justify="left" if name == "Metric" else "right")
    fmts = {k: f for k, _, f in METRICS}
    for r in rows:
        f = fmts[r.key]
        ms = [_num(m, f) + ("" if not np.isfinite(s) else f" ± {s:{f}}")
              for m, s in ((r.mean_a, r.std_a), (r.mean_b, r.std_b))]
        lo, hi = (_num(c, f, True) for c in r.ci)
        ci = "n/a" if lo == "n/a" else f"[{lo}, {hi}]"
        p = "n/a" if not np.isfinite(r.p) else f"{r.p:.3g}"
        table.add_row(r.label, *ms, _num(r.delta, f, True), ci, p)
    return table


def seed_table(cmp: Comparison) -> Table:
    table = Table(title="per seed", title_justify="left")
    for name in ("seed", "shape", f"{cmp.label_a} mean error (cm)",
                 f"{cmp.label_b} mean error (cm)", "delta (B - A)"):
        table.add_column(name, justify="right")
    for s in cmp.seeds:
        ea, eb = cmp.metrics_a[s]["mean_err"], cmp.metrics_b[s]["mean_err"]
        table.add_row(str(s), cmp.shapes[s], f"{ea:.2f}", f"{eb:.2f}", f"{eb - ea:+.2f}")
    return table


def plot(cmp: Comparison, a: dict[int, Rollout], b: dict[int, Rollout], seeds: list[int],
         band_cm: float, path: Path) -> Path:
    """Per-seed mean-error bars (top), error over time for `seeds` (bottom); atomic write."""
    import matplotlib

    matplotlib.use("Agg")  # headless: no display on cluster nodes
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 8), constrained_layout=True)
    x = np.arange(len(cmp.seeds))
    for i, (label, m) in enumerate(((cmp.label_a, cmp.metrics_a), (cmp.label_b, cmp.metrics_b))):
        top.bar(x + (i - 0.5) * 0.4, [m[s]["mean_err"] for s in cmp.seeds], 0.4, label=label)
    top.set_xticks(x, [str(s) for s in cmp.seeds])
    top.set(xlabel="seed", ylabel="mean error (cm)", title="mean tracking error per seed")
    top.legend()
    for k, s in enumerate(seeds):
        for label, rs, style in ((cmp.label_a, a, "-"), (cmp.label_b, b, "-.")):
            bottom.plot(rs[s].t, rs[s].error * 100, style, color=f"C{k}", label=f"{label} seed {s}")
    bottom.axhline(band_cm, color="grey", linestyle="--", label=f"band {band_cm:g} cm")
    bottom.set_ylim(bottom=0)
    bottom.set(xlabel="time (s)", ylabel="error (cm)", title="tracking error over time")
    bottom.legend(fontsize="small", ncol=2)
    path = Path(path)
    try:
        with atomic_write(path, ".tmp.png") as tmp, open(tmp, "wb") as f:
            fig.savefig(f, format="png", dpi=120)
    finally:
        plt.close(fig)
    return path


@dataclass
class Args:
    prefix_a: str = "ikpd"
    """Rollout prefix of set A (the baseline), read from <root>/<prefix>/seed_*.npz."""
    prefix_b: str = "eval"
    """Rollout prefix of set B (compared against A: deltas are B - A)."""
    label_a: str = "Classical"
    """Display name of set A."""
    label_b: str = "RL+Lead"
    """Display name of set B."""
    root: Path = rollout.ROLLOUT_DIR
    """Folder that holds the rollout prefixes."""
    breakdown: bool = False
    """Also print a per-seed table and one table per target shape."""
    plot: Path | None = None
    """Write a PNG: per-seed mean-error bars and error-over-time curves."""
    plot_seeds: tuple[int, ...] | None = None
    """Seeds whose error-over-time curves are drawn (default: the first 3 paired seeds)."""
    settle_time: float = 0.5
    """Seconds of start-up transient excluded from 'settled mean error' (steps with t >= this)."""
    band_cm: float = 5.0
    """Error band in cm for 'time within band' and 'in-band on reachable'."""
    bootstrap: int = 10000
    """Number of bootstrap resamples for the 95% CI of the mean paired difference."""
    ci_seed: int = 0
    """Seed of the bootstrap random generator (makes CIs reproducible)."""
    markdown: bool = False
    """Print the tables as GitHub markdown (what the README's tables are pasted from)."""


def main(args: Args) -> int:
    # Plain print for errors and warnings: one unwrapped line, easy to grep.
    try:
        if args.bootstrap < 1:
            raise ValueError(f"--bootstrap must be at least 1, got {args.bootstrap}")
        a = rollout.load_prefix(args.prefix_a, args.root)
        b = rollout.load_prefix(args.prefix_b, args.root)
        # Name the prefixes here; compare() itself only knows the display labels.
        name_a, name_b = f"{args.label_a} ({args.prefix_a})", f"{args.label_b} ({args.prefix_b})"
        check_compatible(a, b, name_a, name_b)
        cmp = compare(a, b, args.settle_time, args.band_cm, args.bootstrap, args.ci_seed,
                      args.label_a, args.label_b)
        plot_seeds = list(args.plot_seeds) if args.plot_seeds is not None else cmp.seeds[:3]
        missing = [s for s in plot_seeds if s not in cmp.seeds]
        if args.plot and missing:
            raise ValueError(f"--plot-seeds {missing} are not paired seeds; paired: {cmp.seeds}")
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    # Off a terminal rich would wrap at 80 columns and break the table apart.
    console = Console(width=None if sys.stdout.isatty() else 160)
    console.print(f"n={len(cmp.seeds)} pairs duration={cmp.duration:.2f}s", markup=False,
                  highlight=False)
    # On stdout, not stderr, so a saved report also says which seeds it left out.
    for name, seeds in ((args.prefix_a, cmp.only_a), (args.prefix_b, cmp.only_b)):
        if seeds:
            console.print(f"warning: seeds only in {name}, not compared: {seeds}", markup=False)
    console.print(f"A = {args.label_a} ({args.root}/{args.prefix_a}), "
                  f"B = {args.label_b} ({args.root}/{args.prefix_b})", markup=False)
    caption = (f"settle {args.settle_time:g} s, band {args.band_cm:g} cm; CI: bootstrap over "
               f"seeds, {args.bootstrap} resamples, seed {args.ci_seed}")
    tables = [metrics_table(cmp.rows, args.label_a, args.label_b, "all seeds")]
    tables[0].caption = caption
    if args.breakdown:
        tables.append(seed_table(cmp))
        for shape, rows in cmp.by_shape.items():
            n = sum(1 for s in cmp.seeds if cmp.shapes[s] == shape)
            tables.append(metrics_table(rows, args.label_a, args.label_b, f"shape {shape} (n={n})"))
    for table in tables:
        if not args.markdown:
            console.print(table)
            continue
        console.print(f"\n{table.title}" + (f" ({table.caption})" if table.caption else ""),
                      markup=False, highlight=False)
        table.title = table.caption = None
        table.box = box.MARKDOWN
        with console.capture() as captured:
            console.print(table)
        # rich pads the markdown box with blank rows of spaces: keep only the table lines
        print("\n".join(ln.rstrip() for ln in captured.get().splitlines() if ln.strip()))
    if args.plot:
        console.print(f"wrote {plot(cmp, a, b, plot_seeds, args.band_cm, args.plot)}", markup=False)
    return 0


if __name__ == "__main__":
    sys.exit(main(tyro.cli(Args)))
