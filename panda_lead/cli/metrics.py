"""Compare rollout sets (e.g. classical IK+PD vs RL+Lead) seed by seed, with paired statistics.

    uv run metrics.py --prefix-a ikpd --prefix-b eval --breakdown --plot out.png
    uv run metrics.py --headline ikpd analytic eval --plot headline.png

The table reports, per set, mean ± std and median; for the paired differences B - A the mean
and the median, each with a 95% percentile-bootstrap CI, the share of seeds where B is better,
and a Wilcoxon signed-rank p-value. A difference is "shown" only when its 95% CI excludes 0,
at least 10 pairs back it and its Holm-adjusted p is below 0.05 (metrics.finding_verdict).
The headline figure (--headline, two or more sets) draws mean and median error against the
target's peak speed. Every definition, exactly as computed: docs/metrics.md.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table

from .. import rollout
from ..errors import UserError, check_output, exit_on_user_error, parse_cli
from ..metrics.figures import headline_data, plot, plot_headline
from ..metrics.pairing import (
    Comparison,
    check_compatible,
    check_options,
    check_sets,
    compare,
    load_set,
    pair,
    require_seeds,
    seed_ranges,
    seed_set_title,
    set_labels,
    unpaired_warning,
)
from ..metrics.stats import (
    BY_KEY,
    FINDING_P,
    MIN_PAIRS_FOR_CLAIM,
    Row,
    claim,
    fmt_ci,
    fmt_num,
    is_finding,
)

# Beyond these a number is a typo (the run would take hours): 10,000 resamples (the default)
# already fix a 95% CI's bounds to about 1% of its width.
MAX_BOOTSTRAP = 100_000
MAX_SPEED_BINS = 100


# The whole table is about 225 columns wide; below this a terminal gets it in two halves
# (the sets, then the paired differences) instead of truncated names and p-values.
FULL_TABLE_COLUMNS = 228


def metrics_table(rows: list[Row], label_a: str, label_b: str, title: str,
                  part: str = "all") -> Table:
    """part: "all" (one wide table), "sets" (each set's mean ± std and median) or "diffs"
    (the paired differences B - A)."""
    names = {"sets": ("Metric", "better", f"{label_a} mean ± std", f"{label_a} median",
                      f"{label_b} mean ± std", f"{label_b} median"),
             "diffs": ("Metric", "mean diff (B - A) [95% CI]", "median diff (B - A) [95% CI]",
                       "B better", "p (Wilcoxon)", "p (Holm)")}
    names["all"] = names["sets"] + names["diffs"][1:]
    table = Table(title=title, title_justify="left")
    for name in names[part]:
        table.add_column(name, justify="left" if name == "Metric" else "right")
    for r in rows:
        f = BY_KEY[r.key].fmt
        ms = [fmt_num(m, f) + ("" if not np.isfinite(s) else f" ± {s:{f}}")
              for m, s in ((r.mean_a, r.std_a), (r.mean_b, r.std_b))]
        share = f"{100 * r.share_improved:.0f}%" if r.n_pairs else "n/a"
        p = "n/a" if not np.isfinite(r.p) else f"{r.p:.3g}"
        p_holm = "n/a" if not np.isfinite(r.p_holm) else f"{r.p_holm:.3g}"
        cells = {"sets": [r.label, r.better, ms[0], fmt_num(r.median_a, f), ms[1],
                          fmt_num(r.median_b, f)],
                 "diffs": [r.label, f"{fmt_num(r.delta, f, True)} {fmt_ci(r.ci, f)}",
                           f"{fmt_num(r.median_delta, f, True)} {fmt_ci(r.median_ci, f)}",
                           share, p, p_holm]}
        cells["all"] = cells["sets"] + cells["diffs"][1:]
        table.add_row(*cells[part])
    return table


def metrics_tables(rows: list[Row], label_a: str, label_b: str, title: str,
                   width: int) -> list[Table]:
    if width >= FULL_TABLE_COLUMNS:
        return [metrics_table(rows, label_a, label_b, title)]
    return [metrics_table(rows, label_a, label_b, f"{title}: the sets", "sets"),
            metrics_table(rows, label_a, label_b, f"{title}: B - A", "diffs")]


def seed_table(cmp: Comparison) -> Table:
    table = Table(title="per seed", title_justify="left")
    for name in ("seed", "shape", f"{cmp.label_a} mean error (cm)",
                 f"{cmp.label_b} mean error (cm)", "diff (B - A)"):
        table.add_column(name, justify="right")
    for s in cmp.seeds:
        ea, eb = cmp.metrics_a[s]["mean_err"], cmp.metrics_b[s]["mean_err"]
        table.add_row(str(s), cmp.shapes[s], f"{ea:.2f}", f"{eb:.2f}", f"{eb - ea:+.2f}")
    return table


def speed_table(cmp: Comparison) -> Table:
    """The paired mean-error difference per equal-count bin of the target's peak speed: where
    B's gain over A grows, vanishes or reverses."""
    table = Table(title="mean error by the target's peak speed (equal-count bins)",
                  title_justify="left")
    for name in ("peak speed (m/s)", "n", f"{cmp.label_a} mean", f"{cmp.label_b} mean",
                 "mean diff (B - A) [95% CI]", "median diff [95% CI]", "B better", "shown"):
        table.add_column(name, justify="right")
    for lo, hi, rows in cmp.by_speed:
        r = next(r for r in rows if r.key == "mean_err")
        shown = "yes" if is_finding(r.ci, r.n_pairs, r.p_holm) else "no"
        table.add_row(f"{lo:.2f}-{hi:.2f}", str(r.n_pairs), f"{r.mean_a:.2f}", f"{r.mean_b:.2f}",
                      f"{r.delta:+.2f} {fmt_ci(r.ci, '.2f')}",
                      f"{r.median_delta:+.2f} {fmt_ci(r.median_ci, '.2f')}",
                      f"{100 * r.share_improved:.0f}%", shown)
    return table


def oracle_lines(args: Args, cmp: Comparison) -> list[str]:
    """The share of the achievable gain over A that B captures, (A - B) / (A - oracle), on the
    seeds all three sets share (the oracle's failures charged like anyone's)."""
    from ..ilc import check_oracle_start
    from ..metrics.pairing import charged
    from ..metrics.stats import rollout_metrics, share_captured

    oracle = load_set(args.oracle, args.root)
    check_oracle_start(next(iter(oracle.values())).meta,
                       {name: next(iter(cmp.pairing.scored[label].values())).meta
                        for name, label in ((f"{args.label_a} ({args.prefix_a})", cmp.label_a),
                                            (f"{args.label_b} ({args.prefix_b})", cmp.label_b))},
                       f"oracle ({args.oracle})")
    check_compatible(oracle, {s: cmp.pairing.scored[cmp.label_a][s] for s in cmp.seeds},
                     f"oracle ({args.oracle})", f"{args.label_a} ({args.prefix_a})")
    seeds = [s for s in cmp.seeds if s in oracle]
    if len(seeds) < 2:
        raise UserError(f"--oracle {args.oracle} shares {len(seeds)} seeds with the compared "
                        "sets; it needs the same seeds")
    om = {s: rollout_metrics(charged(oracle[s])[0], args.settle_time, args.band_cm,
                             args.tight_band_cm) for s in seeds}
    lines = [f"share of the achievable gain captured, {args.label_b} between {args.label_a} "
             f"and the oracle ({args.oracle}, n={len(seeds)} seeds; 1 = the oracle's error, "
             "0 = no gain over A):"]
    groups = [("", seeds)]
    if args.breakdown:  # also per target shape: where the gain left to capture sits
        shape_of = {s: cmp.pairing.scored[cmp.label_a][s].shape for s in seeds}
        for shape in sorted(set(shape_of.values())):
            group = [s for s in seeds if shape_of[s] == shape]
            if len(group) >= 2:
                groups.append((f"shape {shape} (n={len(group)}), ", group))
    for prefix, group in groups:
        for key, name in (("mean_err", "mean error"), ("settled_err", "settled mean error")):
            col = [np.array([m[s][key] for s in group])
                   for m in (cmp.metrics_a, cmp.metrics_b, om)]
            share, ci = share_captured(*col, n_boot=args.bootstrap, seed=args.ci_seed)
            lines.append(f"{prefix}{name}: {args.label_a} {col[0].mean():.2f}, {args.label_b} "
                         f"{col[1].mean():.2f}, oracle {col[2].mean():.2f} cm; captured "
                         f"{100 * share:.0f}% [{100 * ci[0]:.0f}, {100 * ci[1]:.0f}]")
    return lines


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
    --headline, the headline figure). An existing file is kept unless --force."""
    force: bool = False
    """Replace an existing --plot file."""
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
    """Number of bootstrap resamples for the 95% CIs (mean and median), 100 to 100,000."""
    ci_seed: int = 0
    """Seed of the bootstrap random generator (makes CIs reproducible)."""
    markdown: bool = False
    """Print the tables as GitHub markdown (what the results tables are pasted from)."""
    oracle: str | None = None
    """Rollout prefix of a ceiling (the ILC oracle) on the same seeds: also print the share of
    the achievable gain that B captures, (A - B) / (A - oracle), for the mean and the settled
    error, with 95% bootstrap CIs (with --breakdown, also per target shape)."""


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
    if not 1 <= args.speed_bins <= MAX_SPEED_BINS:
        raise UserError(f"--speed-bins must be 1..{MAX_SPEED_BINS}, got {args.speed_bins}")
    check_output(args.plot, "--plot", args.force)
    loaded = [load_set(p, args.root) for p in args.headline]
    labels = list(args.labels) or set_labels(loaded, list(args.headline))
    if len(set(labels)) != len(labels):
        raise UserError(f"labels must differ, got {labels}; use --labels")
    sets = dict(zip(labels, loaded, strict=True))
    check_sets(sets)
    p = pair(sets)
    require_seeds(p, sets)
    _say(console, f"{p.counts()} ({', '.join(labels)})")
    for line in p.warnings():
        _say(console, line)
    data = headline_data(p.scored, p.seeds, args.speed_bins, args.bootstrap, args.ci_seed)
    _say(console, f"wrote {plot_headline(data, p.seeds, args.plot)}")


def run_compare(args: Args, console: Console) -> None:
    if args.plot is not None:
        check_output(args.plot, "--plot", args.force)
    a, b = load_set(args.prefix_a, args.root), load_set(args.prefix_b, args.root)
    if args.label_a is None or args.label_b is None:
        auto_a, auto_b = set_labels([a, b], [args.prefix_a, args.prefix_b])
        args = dataclasses.replace(args, label_a=args.label_a or auto_a,
                                   label_b=args.label_b or auto_b)
        if args.label_a == args.label_b:
            raise UserError(f"both sets would be named {args.label_a!r} (--prefix-a "
                            f"{args.prefix_a}, --prefix-b {args.prefix_b}); give --label-a and "
                            "--label-b different names")
    # Name the prefixes in errors; the Comparison itself keeps the display labels.
    name_a, name_b = f"{args.label_a} ({args.prefix_a})", f"{args.label_b} ({args.prefix_b})"
    check_compatible(a, b, name_a, name_b)
    cmp = compare(a, b, args.settle_time, args.band_cm, args.bootstrap, args.ci_seed,
                  args.label_a, args.label_b, args.tight_band_cm)
    missing = [s for s in args.plot_seeds if s not in cmp.seeds]
    if args.plot and missing:
        raise UserError(f"--plot-seeds {missing} are not compared seeds; compared: "
                        f"{seed_ranges(cmp.seeds)}")

    _say(console, f"{cmp.pairing.counts()}; duration={cmp.duration:.2f}s")
    # On stdout, not stderr, so a saved report also says which seeds it left out.
    for prefix, seeds in ((args.prefix_a, cmp.only_a), (args.prefix_b, cmp.only_b)):
        if seeds:
            _say(console, unpaired_warning(prefix, seeds))
    for line in cmp.pairing.warnings(unpaired=False):
        _say(console, line)
    _say(console, f"A = {args.label_a} ({args.root}/{args.prefix_a}), "
                  f"B = {args.label_b} ({args.root}/{args.prefix_b})")
    caption = (f"{seed_set_title(cmp.seeds)}; settle {args.settle_time:g} s; CIs: paired "
               f"bootstrap over seeds, {args.bootstrap} resamples, seed {args.ci_seed}")
    width = 100_000 if args.markdown else console.width
    tables = metrics_tables(cmp.rows, args.label_a, args.label_b, "all seeds", width)
    tables[0].caption = caption
    if args.breakdown:
        tables.append(seed_table(cmp))
        for shape, rows in cmp.by_shape.items():
            n = sum(1 for s in cmp.seeds if cmp.shapes[s] == shape)
            tables += metrics_tables(rows, args.label_a, args.label_b, f"shape {shape} (n={n})",
                                     width)
        tables.append(speed_table(cmp))
    _print_tables(console, tables, args.markdown)
    bullet = "- " if args.markdown else "  "
    _say(console, f"\nclaims, {args.label_b} vs {args.label_a} (shown = the 95% CI of the paired "
                  f"difference excludes 0, at least {MIN_PAIRS_FOR_CLAIM} pairs and Holm p < "
                  f"{FINDING_P:g}):")
    for row in cmp.rows:
        _say(console, bullet + claim(row, args.label_b))
    if args.oracle:
        for line in oracle_lines(args, cmp):
            _say(console, bullet + line)
    if args.plot:
        scored = cmp.pairing.scored
        path = plot(cmp, scored[cmp.label_a], scored[cmp.label_b], list(args.plot_seeds),
                    args.band_cm, args.plot, args.settle_time, args.tight_band_cm)
        _say(console, f"wrote {path}")


def check_labels(label_a: str | None, label_b: str | None) -> None:
    """Two sets under one name would be folded into one (a dict keyed by label): refused."""
    if label_a is not None and label_a == label_b:
        raise UserError(f"--label-a and --label-b are both {label_a!r}; the two sets need "
                        "different names")


@exit_on_user_error
def run(args: Args) -> int:
    # Validate every number and the output before reading anything: 'nan' must not become
    # '0% in band', and a refused --plot must cost nothing (run_headline, run_compare).
    check_options(args.settle_time, args.band_cm, args.tight_band_cm, args.bootstrap,
                  args.ci_seed)
    if args.bootstrap > MAX_BOOTSTRAP:
        raise UserError(f"--bootstrap must be at most {MAX_BOOTSTRAP:,}, got {args.bootstrap:,}")
    if not args.headline:
        check_labels(args.label_a, args.label_b)
    # Off a terminal rich would wrap at 80 columns and break the table apart.
    console = Console(width=None if sys.stdout.isatty() else 240)
    if args.headline:
        run_headline(args, console)
    else:
        run_compare(args, console)
    return 0


@exit_on_user_error
def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    return run(parse_cli(Args, argv, prog=prog, description=__doc__))
