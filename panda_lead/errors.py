"""User errors: one type, raised anywhere, caught only at the entry scripts.

A ``UserError`` is a problem with what the user gave (a name, a number, a file): the entry
prints it as one line and exits with status 2. Anything else is a bug and keeps its traceback,
which is why ``UserError`` is not a ``ValueError`` (catching those would hide real bugs).
A command line tyro cannot parse is one too (`parse_cli`), and so is an output file that
already exists without --force (`check_output`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import io
import math
import os
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


def check_output(path, flag: str, force: bool):
    """The one rule for a file a command is about to write: not a folder, no file in the way of
    its folder, and not an existing file unless ``force`` (nothing is overwritten without
    --force). Checked before any work, so a refusal costs nothing. Returns the path."""
    from pathlib import Path

    path = Path(path)
    if path.is_dir():
        raise UserError(f"{flag} {path} is a folder; give a file path")
    for parent in path.parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise UserError(f"{flag} {path}: {parent} is a file, not a folder")
            break
    if (path.exists() or path.is_symlink()) and not force:
        raise UserError(f"{flag} {path} exists; add --force to replace it, or choose another "
                        "path")
    return path


def exit_on_user_error(main: Callable) -> Callable:
    """Wrap an entry point: a UserError becomes 'error: ...' on stderr and exit status 2; a
    reader that stops reading (`... | head`) ends the command quietly, as any Unix tool,
    with status 141 (128 + SIGPIPE), not a BrokenPipeError traceback."""

    @wraps(main)
    def run(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except UserError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        except BrokenPipeError:
            _silence_stdout()  # (Python flushes stdout at exit: into the closed pipe again)
            raise SystemExit(141) from None

    return run


def _silence_stdout() -> None:
    """Point stdout's file descriptor at /dev/null (the reader of the pipe has gone)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


# What tyro draws around an error: box corners and sides, and the rules between sections.
_BOX_SIDES = "\u2502\u256d\u256e\u2570\u256f"
_RULE = set("\u2500-")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _tyro_error_line(box: str, prog: str) -> str:
    """tyro's error box -> one line: its first section (else its title), any "perhaps you
    meant" flags, and where the full help is."""
    lines = [ln.strip().strip(_BOX_SIDES).strip() for ln in _ANSI.sub("", box).splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        return f"bad command line (see {prog} --help)"
    title = lines[0].strip("".join(_RULE) + " ")
    sections: list[list[str]] = [[]]
    for ln in lines[1:]:
        if set(ln) <= _RULE:
            if sections[-1]:
                sections.append([])
        else:
            sections[-1].append(ln)
    message = " ".join(sections[0]) or title
    message = re.sub(r"^Error parsing ", "", message)  # "Error parsing --x: ..." -> "--x: ..."
    meant = [ln.split()[0] for sec in sections[1:] if sec and sec[0].lower().startswith("perhaps")
             for ln in sec[1:] if ln.startswith("-")]
    if meant:
        message += f"; did you mean {', '.join(dict.fromkeys(meant))}?"
    return f"{message} (see {prog} --help)"


def call_cli(parse: Callable, prog: str):
    """``parse()``, a call that parses a command line with tyro, with a bad command line (an
    unknown flag, a value of the wrong type, a missing one) raised as one UserError line
    instead of tyro's boxed message; ``--help`` is printed by tyro, untouched. On an error the
    call is made a second time with a wide COLUMNS, so the box is drawn unwrapped and the line
    never breaks inside a word (parsing has no side effects)."""

    def attempt(columns: str | None = None):
        err, old = io.StringIO(), os.environ.get("COLUMNS")
        if columns is not None:
            os.environ["COLUMNS"] = columns
        try:
            with contextlib.redirect_stderr(err):
                return parse(), err.getvalue(), False
        except SystemExit as exc:
            if exc.code in (0, None):  # --help: tyro printed it on stdout
                sys.stderr.write(err.getvalue())
                raise
            return None, err.getvalue(), True
        finally:
            if columns is not None:
                if old is None:
                    os.environ.pop("COLUMNS", None)
                else:
                    os.environ["COLUMNS"] = old

    parsed, said, failed = attempt()
    if not failed:
        sys.stderr.write(said)  # tyro's warnings, if any, as it wrote them
        return parsed
    _, wide, _ = attempt(columns="100000")
    raise UserError(_tyro_error_line(wide or said, prog))


def parse_cli(cls, argv: list[str] | None = None, **tyro_kwargs):
    """``tyro.cli(cls, args=argv, **tyro_kwargs)`` through `call_cli`: a bad command line is one
    UserError line (an entry point wrapped in `exit_on_user_error` prints it and exits 2)."""
    import tyro

    prog = tyro_kwargs.get("prog") or os.path.basename(sys.argv[0]) or "the script"
    args = sys.argv[1:] if argv is None else list(argv)
    return call_cli(lambda: tyro.cli(cls, args=args, **tyro_kwargs), prog)


def printable(value: object, limit: int = 200) -> str:
    """Text from a file, safe to print: control characters (terminal escapes, newlines, bidi
    overrides) replaced by '?', at most ``limit`` characters (an ellipsis marks a cut)."""
    import unicodedata

    text = value if isinstance(value, str) else repr(value)
    text = text[:limit + 1]  # never scan a 5 MB line for a 200-character answer
    text = "".join("?" if unicodedata.category(c).startswith("C") else c for c in text)
    return text if len(text) <= limit else text[:limit - 1] + "\u2026"
