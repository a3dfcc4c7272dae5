"""Committed run summaries (results/runs/<study>/seed_<N>.json) and the baselines file, read as
files anyone can edit: one bounded reader for studies/runs.py and studies/rederive.py, and the
checks of every field a command uses, all made before any work.

A summary is about 100 kB (1,000 test trajectories x 3 metrics); the reader refuses anything
over MAX_SUMMARY_BYTES before holding it (a symlink to /dev/zero is not a file at all), nesting
deeper than MAX_NESTING, and any NaN or infinity: no number a table shows or a choice is made
on may be non-finite, so a summary that holds one is refused whole, naming the file.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from .errors import UserError, check_plain_name

MAX_SUMMARY_BYTES = 8 << 20
MAX_NESTING = 32
TEST_KEYS = ("mean_err", "settled_err", "jerk_rms")
SHA256 = re.compile(r"[0-9a-f]{64}")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:20]} is not finite")
    return value


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a number a summary may hold")


def _depth(value) -> int:
    """How deeply lists and objects nest in ``value`` (iterative: no recursion to exhaust)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict | list):
            deepest = max(deepest, d)
            if d > MAX_NESTING:
                return d
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def read_bounded(path: Path, what: str, limit: int) -> bytes:
    """The bytes of the regular file at ``path``, at most ``limit`` of them; UserError (naming
    the file and ``what`` it should be) for a folder, a device (/dev/zero), a dangling link,
    nothing, or a file over the limit."""
    if not path.is_file():
        raise UserError(f"{path}: no such file (or not a regular file), expected {what}")
    with open(path, "rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise UserError(f"{path}: over {limit:,} bytes, not {what}")
    return data


def read_json(path: Path, what: str, limit: int = MAX_SUMMARY_BYTES):
    """The JSON value of the file at ``path``, read with a size bound; UserError (naming the
    file and ``what`` it should be) for anything else: not a regular file, too large, not
    UTF-8 JSON, NaN or infinity anywhere, nested deeper than MAX_NESTING."""
    path = Path(path)
    data = read_bounded(path, what, limit)
    try:
        value = json.loads(data.decode("utf-8"), parse_float=_finite_float,
                           parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise UserError(f"{path}: not {what} ({str(exc)[:120]})") from None
    if _depth(value) > MAX_NESTING:
        raise UserError(f"{path}: nested more than {MAX_NESTING} levels deep, not {what}")
    return value


def _bad(path: Path, message: str) -> UserError:
    return UserError(f"{path}: not a usable run summary: {message}")


def _number(value, path: Path, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _bad(path, f"{name} must be a finite number, got {str(value)[:60]!r}")
    return float(value)


def _count(value, path: Path, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise _bad(path, f"{name} must be a whole number >= 0, got {str(value)[:60]!r}")
    return value


def test_seed_count(test_seeds, path: Path) -> int:
    """How many test trajectories the summary's (or baselines') ``test_seeds`` names."""
    from .seeds import parse_seed_range

    if not isinstance(test_seeds, str):
        raise _bad(path, f"test_seeds must be a seed range such as '0-999', got {test_seeds!r}")
    try:
        return len(parse_seed_range(test_seeds))
    except UserError as exc:
        raise _bad(path, f"test_seeds: {exc}") from None


def check_test_lists(test, path: Path, test_seeds, name: str = "test") -> None:
    """``test`` holds one finite number per test seed for each of TEST_KEYS: a short list would
    otherwise be broadcast against the baseline's (one seed's number reported for all)."""
    n = test_seed_count(test_seeds, path)
    if not isinstance(test, dict):
        raise _bad(path, f"{name} must be an object of per-trajectory lists")
    for key in TEST_KEYS:
        values = test.get(key)
        if not isinstance(values, list) or len(values) != n:
            got = len(values) if isinstance(values, list) else type(values).__name__
            raise _bad(path, f"{name}.{key} must hold {n} values (test seeds {test_seeds}), "
                             f"got {got}")
        for v in values:
            _number(v, path, f"{name}.{key}")


# What each field a command uses must be (checked by `check_summary` when asked for).
def _check_best(s: dict, path: Path) -> None:
    best = s.get("best")
    if not isinstance(best, dict):
        raise _bad(path, "best must be an object (the run's best evaluation)")
    _number(best.get("mean_error_cm"), path, "best.mean_error_cm")
    _count(best.get("timesteps"), path, "best.timesteps")


def _check_test(s: dict, path: Path) -> None:
    check_test_lists(s.get("test"), path, s.get("test_seeds", "0-999"))
    _count(s.get("timesteps"), path, "timesteps")


def _check_model(s: dict, path: Path) -> None:
    """The run folder's name and the best model's hash: what binds a summary to its run."""
    run = s.get("run")
    try:
        check_plain_name(run, "run")
    except UserError as exc:
        raise _bad(path, str(exc)) from None
    if not isinstance(s.get("best_model_sha256"), str) or not SHA256.fullmatch(
            s["best_model_sha256"]):
        raise _bad(path, "best_model_sha256 must be 64 hex digits")


def check_curve_points(curve, path: Path) -> list[tuple[int, float]]:
    """A summary's eval_curve: a non-empty list of [whole steps >= 0, positive finite error]."""
    if not isinstance(curve, list) or not curve:
        raise _bad(path, "eval_curve must be a non-empty list of [steps, error] points")
    for point in curve:
        if not isinstance(point, list) or len(point) != 2:
            raise _bad(path, f"eval_curve point {str(point)[:60]} is not [steps, error]")
        _count(point[0], path, "an eval_curve step")
        if _number(point[1], path, "an eval_curve error") <= 0:
            raise _bad(path, f"eval_curve error {point[1]} is not positive")
    return [(int(step), float(error)) for step, error in curve]


def _check_curve(s: dict, path: Path) -> None:
    check_curve_points(s.get("eval_curve"), path)
    config = s.get("train_config")
    if not isinstance(config, dict):
        raise _bad(path, "train_config must be an object")
    if _count(config.get("eval_steps"), path, "train_config.eval_steps") < 1:
        raise _bad(path, "train_config.eval_steps must be at least 1")


CHECKS = {"best": _check_best, "test": _check_test, "model": _check_model, "curve": _check_curve}


def check_summary(summary, path: Path, needs=()) -> dict:
    """A summary's seed (it must match its file's name: two files never claim one seed) and the
    fields named in ``needs`` (keys of CHECKS), else UserError naming the file."""
    path = Path(path)
    if not isinstance(summary, dict):
        raise _bad(path, "it is not a JSON object")
    seed = _count(summary.get("seed"), path, "seed")
    if path.name != f"seed_{seed}.json":
        raise _bad(path, f"it says seed {seed}; its file must be seed_{seed}.json")
    for need in needs:
        CHECKS[need](summary, path)
    return summary


def read_summary(path: Path, needs=()) -> dict:
    """A run summary, read (bounded) and checked for ``needs``."""
    return check_summary(read_json(path, "a run summary"), path, needs)
