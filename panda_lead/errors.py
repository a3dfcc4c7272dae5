"""User errors: one type, raised anywhere, caught only at the entry scripts.

A ``UserError`` is a problem with what the user gave (a name, a number, a file): the entry
prints it as one line and exits with status 2. Anything else is a bug and keeps its traceback,
which is why ``UserError`` is not a ``ValueError`` (catching those would hide real bugs).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import sys
from collections.abc import Callable, Iterable
from functools import wraps


class UserError(Exception):
    """Bad input from the user: printed as one line, exit status 2."""


def did_you_mean(name: object, valid: Iterable[str]) -> str:
    """'; did you mean 'v5'? (valid: v1, v2, ...)': the tail of an unknown-name message."""
    valid = list(valid)
    close = difflib.get_close_matches(str(name), valid, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"{hint} (valid: {', '.join(valid)})"


def check_typed_fields(obj, prefix: str = "") -> None:
    """Check (and normalise) a frozen dataclass's plain fields by their annotation: a "float"
    must be a finite number (stored as float), an "int" an int, a "bool" a bool, each within
    ``field.metadata["range"]`` = (low, high) when given. One message format for every config."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        name = prefix + f.name
        if f.type == "float":
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise UserError(f"{name} must be a finite number, got {v!r}")
            object.__setattr__(obj, f.name, float(v))
        elif f.type in ("int", "bool") and type(v) is not (int if f.type == "int" else bool):
            kind = "an integer" if f.type == "int" else "true or false"
            raise UserError(f"{name} must be {kind}, got {v!r}")
        low, high = f.metadata.get("range", (None, None))
        v = getattr(obj, f.name)
        if (low is not None and v < low) or (high is not None and v > high):
            span = (f"in [{low}, {high}]" if low is not None and high is not None
                    else f">= {low}" if low is not None else f"<= {high}")
            raise UserError(f"{name} must be {span}, got {v!r}")


PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def check_plain_name(value: str, flag: str) -> str:
    """A file or folder name without separators or a leading dot (no ../, no /abs): the one
    rule for run names, archive names, rollout prefixes and study names."""
    if not isinstance(value, str) or not PLAIN_NAME.fullmatch(value) or len(value) > 200:
        raise UserError(f"{flag} must be a plain name (letters, digits, _ . + -, not starting "
                        f"with a dot, at most 200 characters), got {value!r}")
    return value


def exit_on_user_error(main: Callable) -> Callable:
    """Wrap an entry point: a UserError becomes 'error: ...' on stderr and exit status 2."""

    @wraps(main)
    def run(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except UserError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    return run
