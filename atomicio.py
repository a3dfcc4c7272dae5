"""Atomic file writes: write under a temporary name beside the target, then rename over it.

An interrupted write (Ctrl-C, a killed process, a full disk) leaves at most a hidden
temporary file, never a half-written file under the final name that a later command trusts.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# mkstemp makes its files private (0600); the final file gets the permissions an ordinary
# open() would have given it (0666 less the umask), so archives and rollouts stay readable.
_UMASK = os.umask(0)
os.umask(_UMASK)


@contextmanager
def atomic_write(path: Path, suffix: str) -> Iterator[str]:
    """Yield a temporary path beside ``path`` (ending in ``suffix``, so writers that pick a
    format by extension still work); when the block ends without error, rename it over
    ``path``; on any error, delete it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
