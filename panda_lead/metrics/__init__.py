"""Metrics of rollouts and their paired comparison: `stats` (numbers), `compare` (pairing sets),
`figures` (matplotlib). The names most callers need are here."""

from .pairing import (  # noqa: F401
    Comparison,
    Pairing,
    charged,
    check_sets,
    compare,
    load_set,
    pair,
    seed_ranges,
    seed_set_title,
    set_labels,
)
from .stats import (  # noqa: F401
    BY_KEY,
    METRICS,
    MIN_PAIRS_FOR_CLAIM,
    Metric,
    Row,
    bootstrap_ci,
    claim,
    diff_text,
    median_ci,
    paired_ci,
    peak_speed,
    rollout_metrics,
    shown,
    summarize,
    wilcoxon_p,
)
