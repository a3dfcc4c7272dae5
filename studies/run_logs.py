"""A training run's SB3 log as committed evidence (studies/runs.py's `diagnostics` and the
curves of `curve`): the diagnostics CSV (PPO's health, small enough to commit, all that remains
in git of a run that came apart), the evaluation curve of a stopped run read from it, and the
time-to-quality table of the committed evaluation curves. Split from studies/runs.py, which
imports these back for its subcommands."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from panda_lead.errors import UserError, check_output, printable
from panda_lead.summaries import read_bounded


def first_below(curve: list[list[float]], threshold: float) -> float:
    """Training steps at the first evaluation under `threshold` cm (inf if never)."""
    return next((step for step, cm in curve if cm < threshold), float("inf"))


def time_to_quality(studies: dict[str, list[dict]], classical_cm: float, margin_cm: float) -> str:
    """Markdown: each seed's steps to the first evaluation under `threshold` (studies/ttq.py's
    quality bar: the classical evaluation error less a margin), and for the first two studies a
    one-sided Mann-Whitney test that the first gets there sooner (exact without ties, else
    the normal approximation)."""
    from scipy import stats

    threshold = classical_cm - margin_cm
    hits = {name: [first_below(s["eval_curve"], threshold) for s in runs]
            for name, runs in studies.items()}
    lines = [f"\nSteps to the first evaluation under {threshold:.2f} cm (the classical evaluation "
             f"error {classical_cm:.2f} less {margin_cm:g}):\n",
             "| study | per seed (1k steps) | median |", "|---|---|---|"]
    for name, h in hits.items():
        per = ", ".join("never" if x == float("inf") else f"{x / 1e3:.0f}" for x in h)
        median = np.median(h)  # (the median of "never" is "never", not "infk")
        median = "never" if median == float("inf") else f"{median / 1e3:.0f}k"
        lines.append(f"| {name} | {per} | {median} |")
    if len(hits) >= 2:
        (a, ha), (b, hb) = list(hits.items())[:2]
        if min(len(ha), len(hb)) < 2:  # (a rank test of one seed has nothing to rank)
            lines.append(f"\n{a} against {b}: one seed each side is too few for a rank test")
            return "\n".join(lines)
        p = stats.mannwhitneyu(ha, hb, alternative="less").pvalue
        lines.append(f"\n{a} sooner than {b}: one-sided Mann-Whitney p = {p:.3g} "
                     f"(n = {len(ha)}, {len(hb)})")
    return "\n".join(lines)


# A committed diagnostics file is ~100 kB; a 50M-step run's SB3 log a few MB.
MAX_CSV_BYTES = 64 << 20


def _read_csv(path: Path, what: str) -> list[dict]:
    """A CSV file's rows, read with a size bound; not UTF-8 or too large is one line."""
    data = read_bounded(path, what, MAX_CSV_BYTES)
    try:
        return list(csv.DictReader(data.decode("utf-8").splitlines()))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UserError(f"{path}: not {what} ({printable(exc, 120)})") from None


def _read_diagnostics(path: Path) -> list[dict]:
    """The rows of a diagnostics file (`diagnostics --csv`), its columns checked and each cell
    a finite number or empty (None)."""
    if not path.is_file():
        raise UserError(f"{path}: no such file (write it with `runs diagnostics --runs RUN "
                        "--csv FILE`)")
    rows = _read_csv(path, "a diagnostics file")
    if not rows or set(DIAGNOSTICS) - set(rows[0]):
        raise UserError(f"{path}: not a diagnostics file (columns {', '.join(DIAGNOSTICS)})")
    out = []
    for i, row in enumerate(rows, start=2):  # line 1 is the header
        cells = {}
        for col in DIAGNOSTICS:
            text = row.get(col) or ""
            try:
                value = float(text) if text.strip() else None
            except ValueError:
                value = float("nan")
            if value is not None and not np.isfinite(value):
                raise UserError(f"{path}, line {i}: {col} {printable(text, 40)!r} is not a "
                                "finite number")
            cells[col] = value
        out.append(cells)
    return out


def stopped_curve(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(steps, evaluation error) from a diagnostics file's evaluation rows."""
    rows = [r for r in _read_diagnostics(path)
            if r["mean_error_cm"] is not None and r["eval_timesteps"] is not None]
    if not rows:
        raise UserError(f"--stopped {path}: no evaluation rows")
    return (np.array([r["eval_timesteps"] for r in rows]),
            np.array([r["mean_error_cm"] for r in rows]))


DIAGNOSTICS = {"total_timesteps": "time/total_timesteps", "eval_timesteps": "eval/timesteps",
               "mean_error_cm": "eval/mean_error_cm", "std": "train/std",
               "approx_kl": "train/approx_kl", "clip_fraction": "train/clip_fraction",
               "ep_rew_mean": "rollout/ep_rew_mean"}


def diagnostics(args) -> None:
    """PPO's health over a run, small enough to commit: from a run's SB3 log (tb/progress.csv)
    every evaluation row and every 8th update's policy std, KL per update and clip fraction,
    then (from that file alone) their means per window of training steps. A run that came
    apart is stopped and never summarized; this file is what remains of it in git. ``args``:
    studies/runs.py's Args (runs, csv, window, force)."""
    from panda_lead.atomicio import atomic_write
    from panda_lead.outputs import claimed_outputs

    if args.csv is None or len(args.runs) > 1:
        raise UserError("diagnostics needs --csv FILE (and --runs RUN, one run folder, to write it)")
    if args.window < 1:
        raise UserError(f"--window must be a whole number of training steps >= 1, got "
                        f"{args.window}")
    if args.runs:
        log = args.runs[0] / "tb" / "progress.csv"
        if not log.is_file():
            raise UserError(f"{log}: no such file (is {args.runs[0]} a run folder?)")
        check_output(args.csv, "--csv", args.force)
        rows = _read_csv(log, "an SB3 training log")
        updates = [r for r in rows if r.get("train/std") and not r.get("eval/mean_error_cm")]
        kept = {id(r) for r in updates[::8]}
        with claimed_outputs([args.csv], "--csv", args.force), \
                atomic_write(args.csv, ".tmp.csv") as tmp, open(tmp, "w", newline="") as f:
            out = csv.writer(f, lineterminator="\n")
            out.writerow(DIAGNOSTICS)
            out.writerows([r.get(c, "") for c in DIAGNOSTICS.values()] for r in rows
                          if r.get("eval/mean_error_cm") or id(r) in kept)
        print(f"wrote {args.csv}")
    rows = _read_diagnostics(args.csv)

    def windowed(step_key: str, key: str) -> dict[int, float]:
        by: dict[int, list[float]] = {}
        for r in rows:
            if r[step_key] is not None and r[key] is not None:
                by.setdefault(int(r[step_key] - 1) // args.window, []).append(r[key])
        return {w: float(np.mean(v)) for w, v in by.items()}

    cols = {"evaluation error (cm)": windowed("eval_timesteps", "mean_error_cm"),
            "policy std": windowed("total_timesteps", "std"),
            "KL per update": windowed("total_timesteps", "approx_kl"),
            "clip fraction": windowed("total_timesteps", "clip_fraction")}
    print(f"{args.csv}: means per {args.window:,} training steps\n")
    print("| steps (M) | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for w in sorted(set().union(*cols.values())):
        cells = [f"{c[w]:.3g}" if w in c else "" for c in cols.values()]
        span = f"{w * args.window / 1e6:g}-{(w + 1) * args.window / 1e6:g}"
        print(f"| {span} | " + " | ".join(cells) + " |")
