"""Figures: paired differences, error over time, and the headline (error against the target's
peak speed with 95% bootstrap CIs). matplotlib is imported only here, headless (Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomicio import atomic_write
from ..rollout import Rollout
from ..trajectory import SHAPES
from .pairing import Comparison, seed_ranges, seed_set_title
from .stats import BY_KEY, bootstrap_ci, fmt_ci, mean_or_nan, metric_label, peak_speed

# One colour per controller label in every figure; other labels take the next free colour.
# The deploy table's rivals are fixed too: as the next free colour the predicting rival
# landed in brown beside the first study's red family.
COLOURS = {"Classical": "C0", "Analytic": "C1", "RL+Lead": "C2",
           "Analytic+filter": "C8", "Analytic+predict": "C9"}


# Headline bins hold at least this many rollouts (fewer bins in a small panel): a CI from
# fewer values means little.
MIN_PER_BIN = 5


def colours_for(labels) -> dict[str, str]:
    """One colour per label: the fixed COLOURS where known, else the next unused tab10 colour
    (never C7, grey: the colour of the reference lines; a fixed rival's or RL+Lead's colour only
    when that label is not in the figure, the baselines' never), then tab20's lighter shades,
    then tab20b's dark hues, then around again (a figure of many labels repeats colours; it
    does not fail)."""
    from itertools import cycle

    labels = list(dict.fromkeys(labels))
    taken = {COLOURS[lab] for lab in labels if lab in COLOURS}
    spare = [f"C{i}" for i in (3, 4, 5, 6, 8, 9)]
    spare = [c for c in spare if c not in COLOURS.values()]
    # then the colours of fixed labels absent here (green, RL+Lead's, before tab20's pale
    # blue: a fifth model in the deploy figure read as a shade of the classical controller)
    spare += [c for lab, c in COLOURS.items()
              if lab not in ("Classical", "Analytic") and c not in taken]
    spare += [f"tab20:{i}" for i in range(1, 20, 2) if i != 15]  # tab20's light shades, no grey
    spare += [f"tab20b:{i}" for i in range(0, 20, 4)]  # then tab20b's five dark hues
    free = cycle(spare)
    return {lab: COLOURS[lab] if lab in COLOURS else _colour(next(free)) for lab in labels}


def family_colours(labels) -> dict[str, tuple]:
    """One hue per study, one shade per seed: labels ``<study>_s<seed>`` of one study share
    the colour colours_for gives the study, from dark to light in the order given; any other
    label is a family of one at its own colour. A figure of two five-seed studies beside the
    baselines then reads as three groups, where one colour per label ran out of distinct hues
    (the palette's light shades sat beside the colours they lighten)."""
    import re

    from matplotlib.colors import to_rgb

    labels = list(dict.fromkeys(labels))
    family = {lab: re.sub(r"_s\d+$", "", lab) for lab in labels}
    base = colours_for(family.values())
    members: dict[str, list[str]] = {}
    for lab in labels:
        members.setdefault(family[lab], []).append(lab)
    out = {}
    for fam, labs in members.items():
        rgb = np.array(to_rgb(base[fam]))
        # shade k of n: from 30% towards black to 45% towards white; hue unchanged
        for k, lab in enumerate(labs):
            t = 0.0 if len(labs) == 1 else -0.30 + 0.75 * k / (len(labs) - 1)
            shade = rgb * (1 + t) if t < 0 else rgb + (1 - rgb) * t
            out[lab] = tuple(float(v) for v in shade)
    return out


def _colour(name: str):
    """A matplotlib colour spec: "C3" as is, "tab20:k" as that colormap's k-th RGB tuple."""
    if ":" not in name:
        return name
    from matplotlib import colormaps

    cmap, k = name.split(":")
    return colormaps[cmap](int(k))


def pyplot():
    import matplotlib

    matplotlib.use("Agg")  # headless: no display on cluster nodes
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    path = Path(path)
    plt = pyplot()
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
    # Differences equal up to float rounding (the same offset on every seed): numpy cannot cut
    # that range into bins, so draw them in a unit-wide range as it does for equal values.
    lo, hi = (float(d.min()), float(d.max())) if len(d) else (0.0, 0.0)
    span = (lo - 0.5, hi + 0.5) if hi - lo <= 1e-9 * max(1.0, abs(lo), abs(hi)) else None
    ax.hist(d, bins=bins, range=span, color=colour, alpha=0.6, edgecolor="white", linewidth=0.5)
    ax.axvline(0, color="black", linewidth=1.2, label="zero (no difference)")
    ax.axvline(row.median_delta, color="black", linestyle="--",
               label=f"median {row.median_delta:+.2f} {fmt_ci(row.median_ci, '.2f')}")
    ax.axvline(row.delta, color="black", linestyle=":",
               label=f"mean {row.delta:+.2f} {fmt_ci(row.ci, '.2f')}")
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
                    label=f"{label}: seed {seed_ranges(highlight)}" if k == 0 else None)
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
    plt = pyplot()
    colours = colours_for([cmp.label_a, cmp.label_b])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 10), constrained_layout=True)
    plot_paired_differences(top, cmp, colours[cmp.label_b])
    plot_error_over_time(bottom, {cmp.label_a: a, cmp.label_b: b}, cmp.seeds, colours,
                         settle_time, (band_cm, tight_band_cm), list(seeds))
    return save_figure(fig, path)


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
            label: binned_errors(speeds, np.array([100 * mean_or_nan(rs[s].error) for s in ps]),
                                 edges, n_boot, ci_seed)
            for label, rs in sets.items()
        }
    return out


def plot_headline(data: dict[str, dict[str, list[dict]]], seeds: list[int], path: Path) -> Path:
    """Rows: mean, median error per speed bin with 95% CIs; columns: all, then each shape."""
    plt = pyplot()
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
    return save_figure(fig, path)
