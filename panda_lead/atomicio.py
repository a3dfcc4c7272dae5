"""Atomic file writes: write under a temporary name beside the target, then rename over it.

An interrupted write (Ctrl-C, a killed process, a full disk) leaves at most a hidden
temporary file, never a half-written file under the final name that a later command trusts.
A full disk (or quota) is the user's to fix, so it becomes one `UserError` line; the previous
file under the final name is untouched.
"""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import UserError

# mkstemp makes its files private (0600); the final file gets the permissions an ordinary
# open() would have given it (0666 less the umask), so archives and rollouts stay readable.
_UMASK = os.umask(0)
os.umask(_UMASK)

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def disk_full_error(path: Path, exc: OSError) -> UserError:
    return UserError(f"cannot write {path}: {os.strerror(exc.errno)} (free some space; the "
                     "previous file, if any, is intact)")


@contextmanager
def atomic_write(path: Path, suffix: str) -> Iterator[str]:
    """Yield a temporary path beside ``path`` (ending in ``suffix``, so writers that pick a
    format by extension still work); when the block ends without error, rename it over
    ``path``; on any error, delete it. A full disk raises `UserError`."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    except OSError as exc:
        if exc.errno in DISK_FULL:
            raise disk_full_error(path, exc) from exc
        raise
    os.close(fd)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno in DISK_FULL:
            raise disk_full_error(path, exc) from exc
        raise
