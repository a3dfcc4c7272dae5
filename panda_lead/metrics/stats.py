"""Per-rollout metrics and the paired statistics over seeds: numbers only (no figures, no
terminal output), so any script can import them cheaply.

Every metric is computed per rollout; two sets are paired by seed. For each metric: per set
mean, sample std and median; for the paired differences B - A the mean and the median, each
with a 95% percentile-bootstrap CI, the share of seeds where B is better, and a Wilcoxon
signed-rank p-value. A difference is "shown" (a finding) by one rule, `finding_verdict`: its
95% CI excludes 0, at least MIN_PAIRS_FOR_CLAIM pairs back it, and its Holm-adjusted p over
the metrics of its table is below FINDING_P. metrics.py's claims and tables and the study
comparisons (studies/runs.py compare, `bootstrap_verdicts`) all use it. Every definition,
exactly as computed: docs/metrics.md.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..rollout import Rollout

NAN = float("nan")


LOWER, HIGHER = "lower", "higher"


@dataclass(frozen=True)
class Metric:
    key: str
    label: str  # "{band}" / "{tight}" are filled with the band widths in cm
    fmt: str
    better: str  # LOWER or HIGHER: which direction counts as an improvement
    # A shown difference smaller than this (in the metric's unit) is called negligible: about
    # the printed precision, far below what a user of the arm would notice.
    negligible: float


METRICS = (
    Metric("mean_err", "mean error (cm)", ".2f", LOWER, 0.05),
    Metric("rmse", "RMSE (cm)", ".2f", LOWER, 0.05),
    Metric("max_err", "max error (cm)", ".2f", LOWER, 0.05),
    Metric("p95_err", "p95 error (cm)", ".2f", LOWER, 0.05),
    Metric("settled_err", "settled mean error (cm)", ".2f", LOWER, 0.05),
    Metric("in_band", "time within {band} cm (%)", ".1f", HIGHER, 0.5),
    Metric("in_band_tight", "time within {tight} cm (%)", ".1f", HIGHER, 0.5),
    Metric("in_reach_err", "in-reach error (cm)", ".2f", LOWER, 0.05),
    Metric("out_reach_err", "out-of-reach error (cm)", ".2f", LOWER, 0.05),
    Metric("in_band_reachable", "within {band} cm on reachable (%)", ".1f", HIGHER, 0.5),
    Metric("jerk_rms", "jerk RMS (m/s^3)", ".1f", LOWER, 1.0),
    Metric("self_collision", "self-collision time (%)", ".2f", LOWER, 0.1),
)


BY_KEY = {m.key: m for m in METRICS}


# Out-of-reach time only happens on some seeds, so its mean is over fewer rollouts than n:
# the row label says over how many.
COUNTED = {"out_reach_err"}


# Below this many pairs a percentile-bootstrap CI is too narrow to back a claim.
MIN_PAIRS_FOR_CLAIM = 10
# A finding's Holm-adjusted p (over the metrics of its table) is below this.
FINDING_P = 0.05


def mean_or_nan(x: np.ndarray) -> float:
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
        "mean_err": mean_or_nan(err) * 100,
        "rmse": float(np.sqrt(np.mean(err**2))) * 100,
        "max_err": float(np.max(err)) * 100,
        "p95_err": float(np.percentile(err, 95)) * 100,
        "settled_err": mean_or_nan(err[np.asarray(r.t) >= settle_time]) * 100,
        "in_band": 100.0 * mean_or_nan(err < band_cm / 100.0),
        "in_band_tight": 100.0 * mean_or_nan(err < tight_band_cm / 100.0),
        "in_reach_err": mean_or_nan(err[reach]) * 100,
        "out_reach_err": mean_or_nan(err[~reach]) * 100,
        "in_band_reachable": 100.0 * mean_or_nan(err[reach] < band_cm / 100.0),
        "jerk_rms": jerk,
        "self_collision": 100.0 * mean_or_nan(np.asarray(r.self_collision, dtype=float)),
    }


def peak_speed(r: Rollout) -> float:
    """The target's peak speed over the episode, m/s: max over steps of |target_vel|."""
    return float(np.max(np.linalg.norm(np.asarray(r.target_vel, dtype=float), axis=1)))


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


def two_level_bootstrap(a: np.ndarray, b: np.ndarray, n_boot: int, rng: np.random.Generator,
                        paired: bool = False) -> tuple[tuple[float, float], np.ndarray]:
    """95% CI and resamples of mean(b) - mean(a) for two studies, each (training seeds,
    trajectories) on the same trajectories in the same order. Each resample draws the
    trajectories and both studies' training seeds with replacement, so the CI carries the
    spread across training seeds as well as across trajectories: one over trajectories alone
    would call a lucky seed a finding. (A study of one seed, such as a classical controller,
    resamples its trajectories alone.) With ``paired`` the k-th seed of one study is the k-th
    of the other (one model with and without something added, or two continuations of one
    model): the seeds are drawn once for both, which keeps what the pair shares out of the CI."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if paired and len(a) != len(b):
        raise ValueError(f"paired studies need as many seeds on each side: {len(a)}, {len(b)}")
    n = a.shape[1]
    boots = np.empty(n_boot)
    for i in range(n_boot):
        t = rng.integers(0, n, n)
        sa = rng.integers(0, len(a), len(a))
        sb = sa if paired else rng.integers(0, len(b), len(b))
        boots[i] = b[sb][:, t].mean() - a[sa][:, t].mean()
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return (float(lo), float(hi)), boots


def t_ci(values) -> tuple[float, float]:
    """95% Student-t interval of the mean of a few values (one per training seed), where a
    bootstrap over five values would be too narrow. NaN for fewer than 2 finite values."""
    from scipy import stats

    d = np.asarray(values, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2:
        return NAN, NAN
    half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))
    return float(d.mean() - half), float(d.mean() + half)


def median_ci(deltas, n_boot: int = 10000, seed: int = 0) -> tuple[float, float]:
    """95% percentile-bootstrap CI of the median paired difference."""
    return bootstrap_ci(deltas, np.median, n_boot, seed)


def shown(ci: tuple[float, float]) -> bool:
    """A difference is shown when its 95% CI excludes zero (an n/a CI shows nothing)."""
    lo, hi = ci
    return bool(np.isfinite(lo) and np.isfinite(hi) and (lo > 0 or hi < 0))


def finding_verdict(ci: tuple[float, float], n_pairs: int, p_holm: float) -> str:
    """THE rule for calling a paired difference a finding: "shown" when its 95% CI excludes
    zero, at least MIN_PAIRS_FOR_CLAIM pairs back it (percentile-bootstrap CIs are too narrow
    below that) and its p, Holm-adjusted over the metrics of its table, is below FINDING_P
    (a table tests several metrics at once); else "not shown" with the reason."""
    if n_pairs < MIN_PAIRS_FOR_CLAIM:
        return f"not shown (only {n_pairs} pairs, fewer than {MIN_PAIRS_FOR_CLAIM})"
    if not shown(ci):
        return "not shown"
    if not (np.isfinite(p_holm) and p_holm < FINDING_P):
        return f"not shown (CI excludes 0 but Holm p {p_holm:.2g} is not below {FINDING_P:g})"
    return "shown"


def is_finding(ci: tuple[float, float], n_pairs: int, p_holm: float) -> bool:
    return finding_verdict(ci, n_pairs, p_holm) == "shown"


def bootstrap_p(boots) -> float:
    """Two-sided p of a difference from its bootstrap resamples: twice the share on the
    smaller side of zero (at most 1), the p that matches a percentile CI (the 95% CI excludes
    zero exactly when this is below 0.05, up to ties at zero)."""
    b = np.asarray(boots, dtype=float)
    b = b[np.isfinite(b)]
    if len(b) == 0:
        return NAN
    return float(min(1.0, 2 * min(np.mean(b <= 0), np.mean(b >= 0))))


def bootstrap_verdicts(cis, boots, n_pairs: int) -> list[str]:
    """finding_verdict for each difference of one table whose CIs come from bootstrap
    resamples (studies/runs.py compare): p from each one's resamples (bootstrap_p),
    Holm-adjusted over the table."""
    p_holm = holm([bootstrap_p(b) for b in boots])
    return [finding_verdict(ci, n_pairs, p) for ci, p in zip(cis, p_holm, strict=True)]


def wilcoxon_p(deltas) -> float:
    """Two-sided Wilcoxon signed-rank p-value; NaN when undefined (n < 2 or all zero)."""
    d = np.asarray(deltas, dtype=float)
    d = d[np.isfinite(d)]
    if len(d) < 2 or not np.any(d != 0):
        return NAN
    # Imported here: scipy.stats takes ~2 s to import, which every metrics.py run (a one-line
    # refusal of a bad flag included) would otherwise pay before doing anything.
    from scipy import stats

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
    p: float  # Wilcoxon signed-rank: the test of the mean difference's verdict
    p_holm: float = NAN  # p adjusted (Holm) over the metrics of one table
    p_median: float = NAN  # sign test: the test of the median difference's verdict
    p_median_holm: float = NAN  # p_median adjusted (Holm) over the metrics of one table

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
            len(d), mean_or_nan(d), paired_ci(d, n_boot, ci_seed),
            float(np.median(d)) if len(d) else NAN, median_ci(d, n_boot, ci_seed),
            n_improved(va, vb, m.better), wilcoxon_p(d), p_median=sign_test_p(d)))
    for row, p, pm in zip(rows, holm([r.p for r in rows]), holm([r.p_median for r in rows]),
                          strict=True):
        row.p_holm, row.p_median_holm = p, pm
    return rows


def sign_test_p(deltas) -> float:
    """Two-sided exact sign test that the median difference is zero (ties dropped); NaN when
    undefined. The median's own test: Wilcoxon's assumes a symmetric distribution, which a
    difference with a few large outliers is not (a median of -1 over 25 seeds, five outliers
    at +10, has Wilcoxon p 0.36 and sign-test p 1e-3)."""
    d = np.asarray(deltas, dtype=float)
    d = d[np.isfinite(d) & (d != 0)]
    if len(d) == 0:
        return NAN
    from scipy import stats  # (imported late: see wilcoxon_p)

    return float(stats.binomtest(int((d > 0).sum()), len(d)).pvalue)


def holm(pvalues) -> list[float]:
    """Holm-Bonferroni adjusted p-values of a family of tests (NaN stays NaN): a table tests
    a dozen metrics at once, and the adjusted p-value is what controls the chance of any false
    claim among them at the level it is compared with."""
    p = np.asarray(pvalues, dtype=float)
    ok = np.flatnonzero(np.isfinite(p))
    out = np.full(len(p), NAN)
    m = len(ok)
    running = 0.0
    for rank, i in enumerate(ok[np.argsort(p[ok], kind="stable")]):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out.tolist()


def share_captured(base: np.ndarray, learned: np.ndarray, ceiling: np.ndarray,
                   n_boot: int = 10000, seed: int = 0) -> tuple[float, tuple[float, float]]:
    """(base - learned) / (base - ceiling) of the mean over seeds, and its 95% percentile
    bootstrap CI (the three values of a seed resampled together): the share of the gain the
    ceiling achieves over the base that the learned controller captures."""
    v = np.stack([base, learned, ceiling], axis=1).astype(float)
    v = v[np.isfinite(v).all(axis=1)]
    if len(v) < 2:
        return NAN, (NAN, NAN)

    def ratio(m: np.ndarray) -> np.ndarray:
        return (m[..., 0] - m[..., 1]) / (m[..., 0] - m[..., 2])

    rng = np.random.default_rng(seed)
    boots = np.empty(n_boot)
    chunk = max(1, 2_000_000 // (3 * len(v)))
    for i in range(0, n_boot, chunk):
        k = min(chunk, n_boot - i)
        boots[i:i + k] = ratio(v[rng.integers(0, len(v), size=(k, len(v)))].mean(axis=1))
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(ratio(v.mean(axis=0))), (float(lo), float(hi))


def two_level_share(base: np.ndarray, learned: np.ndarray, ceiling: np.ndarray, n_boot: int,
                    rng: np.random.Generator) -> tuple[float, tuple[float, float]]:
    """share_captured for a study: (base - learned) / (base - ceiling), each side its mean over
    training seeds and trajectories, and the 95% percentile CI of a two-level bootstrap.
    ``base`` (T,) is one reference controller, ``learned`` and ``ceiling`` (K, T) a study's K
    seeds and each seed's own ceiling (the oracle restarted from that seed), on the same T
    trajectories. Each resample draws the trajectories (for all three) and the seeds (a seed
    and its own ceiling together) with replacement."""
    base, learned, ceiling = (np.asarray(x, dtype=float) for x in (base, learned, ceiling))
    if learned.shape != ceiling.shape or learned.shape[1:] != base.shape:
        raise ValueError(f"shapes do not pair: base {base.shape}, learned {learned.shape}, "
                         f"ceiling {ceiling.shape}")

    def ratio(b: float, lead: float, top: float) -> float:
        return (b - lead) / (b - top)

    boots = np.empty(n_boot)
    k, n = learned.shape
    for i in range(n_boot):
        t, s = rng.integers(0, n, n), rng.integers(0, k, k)
        boots[i] = ratio(base[t].mean(), learned[s][:, t].mean(), ceiling[s][:, t].mean())
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return ratio(base.mean(), learned.mean(), ceiling.mean()), (float(lo), float(hi))


def claim(row: Row, label_b: str = "B") -> str:
    """One line: the mean and median differences, each 'shown' or 'not shown' by
    `finding_verdict` (the mean with its Holm-adjusted Wilcoxon p, the median with its
    Holm-adjusted sign-test p), and the share of seeds improved."""
    fmt = BY_KEY[row.key].fmt

    def part(name: str, value: float, ci: tuple[float, float], p_holm: float) -> str:
        if not np.isfinite(value):
            return f"{name} diff n/a"
        verdict = finding_verdict(ci, row.n_pairs, p_holm)
        small = BY_KEY[row.key].negligible
        if verdict == "shown" and abs(value) < small:
            verdict = f"shown, negligible (|diff| < {small:g})"
        return f"{name} diff {fmt_num(value, fmt, True)} {fmt_ci(ci, fmt)} {verdict}"

    share = (f"{label_b} better on {row.improved}/{row.n_pairs} seeds "
             f"({100 * row.share_improved:.0f}%)" if row.n_pairs else "no pairs")
    return (f"{row.label}, {row.better} is better: {part('mean', row.delta, row.ci, row.p_holm)}; "
            f"{part('median', row.median_delta, row.median_ci, row.p_median_holm)}; {share}")


def fmt_num(x: float, fmt: str, sign: bool = False) -> str:
    if not np.isfinite(x):
        return "n/a"
    return format(x, ("+" if sign else "") + fmt)


def fmt_ci(ci: tuple[float, float], fmt: str) -> str:
    lo, hi = (fmt_num(c, fmt, True) for c in ci)
    return "[n/a]" if lo == "n/a" else f"[{lo}, {hi}]"


def diff_text(value: float, ci: tuple[float, float], fmt: str = ".2f", verdict: bool = True,
              *, n_pairs: int | None = None, p_holm: float = NAN) -> str:
    """'+1.23 [+0.45, +2.01] shown': a paired difference, its 95% CI and, with ``verdict``,
    the one rule's word on it (finding_verdict: the CI, the number of pairs and the test's
    Holm-adjusted p, which a verdict cannot be given without)."""
    text = f"{fmt_num(value, fmt, True)} {fmt_ci(ci, fmt)}"
    if not verdict:
        return text
    if n_pairs is None:
        raise TypeError("diff_text's verdict needs n_pairs and p_holm (finding_verdict)")
    return f"{text} {finding_verdict(ci, n_pairs, p_holm)}"


def row_diff(row: Row, median: bool = False, fmt: str | None = None, verdict: bool = True
             ) -> str:
    """diff_text of a Row's mean (or median) difference, judged with its own test's p."""
    fmt = fmt or BY_KEY[row.key].fmt
    if median:
        return diff_text(row.median_delta, row.median_ci, fmt, verdict, n_pairs=row.n_pairs,
                         p_holm=row.p_median_holm)
    return diff_text(row.delta, row.ci, fmt, verdict, n_pairs=row.n_pairs, p_holm=row.p_holm)


def deltas_diffs(cells, n_boot: int = 10000, fmt: str = ".2f") -> list[str]:
    """diff_text of several paired-difference arrays of one table row, ``cells`` as (deltas,
    "mean" or "median") pairs: each its bootstrap CI and its own test (Wilcoxon for a mean, the
    sign test for a median), the p-values Holm-adjusted over the cells."""
    prepared = []
    for d, stat in cells:
        d = np.asarray(d, dtype=float)
        d = d[np.isfinite(d)]
        fn, test = (np.median, sign_test_p) if stat == "median" else (np.mean, wilcoxon_p)
        value = float(fn(d)) if len(d) else NAN
        prepared.append((value, bootstrap_ci(d, fn, n_boot), len(d), test(d)))
    adjusted = holm([p for *_, p in prepared])
    return [diff_text(v, ci, fmt, n_pairs=n, p_holm=p)
            for (v, ci, n, _), p in zip(prepared, adjusted, strict=True)]
