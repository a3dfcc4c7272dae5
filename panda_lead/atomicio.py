"""Atomic file writes and folder locks: the repo's one way to write a file and to claim a folder.

A write goes to a temporary name beside the target, then is renamed over it: an interrupted
write (Ctrl-C, a killed process, a full disk) leaves at most a hidden temporary file, never a
half-written file under the final name that a later command trusts; stale temporaries of the
same target (a SIGKILL's leftovers) are removed by the next write. What the user can fix (a
full disk, a read-only or forbidden folder, a folder where a file should be) becomes one
`UserError` line; the previous file under the final name is untouched.

A lock (`folder_lock`, `file_lock`) is an flock held while a command works: a second command
that wants the same run folder, rollout set or archive name is refused in one line instead of
interleaving its files with the first's. The kernel drops the lock when its holder dies.
"""

from __future__ import annotations

import errno
import fcntl
import os
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import UserError

# mkstemp makes its files private (0600); the final file gets the permissions an ordinary
# open() would have given it (0666 less the umask), so archives and rollouts stay readable.
_UMASK = os.umask(0)
os.umask(_UMASK)

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
# The OSErrors a user can fix, with what to do; any other OSError is a bug and keeps its trace.
USER_FIXABLE = {errno.ENOSPC: "free some space", errno.EDQUOT: "free some space",
                errno.EROFS: "write somewhere else", errno.EACCES: "check the permissions",
                errno.EPERM: "check the permissions", errno.EISDIR: "give a file path",
                errno.ENOTDIR: "a file is in the way where a folder is needed"}
# A temporary left by a killed writer is removed once it is this old: no write takes this long.
STALE_TEMP_S = 600.0


def user_error_for(path: Path, exc: OSError) -> UserError | None:
    """The one-line UserError for an OSError the user can fix, else None (a bug: keep it)."""
    hint = USER_FIXABLE.get(exc.errno)
    if hint is None:
        return None
    return UserError(f"cannot write {path}: {os.strerror(exc.errno)} ({hint}); the previous "
                     "file, if any, is intact")


def disk_full_error(path: Path, exc: OSError) -> UserError:
    return user_error_for(path, exc) or UserError(f"cannot write {path}: {exc}")


def _clean_stale_temps(folder: Path, stem: str) -> None:
    now = time.time()
    for tmp in folder.glob(f".{stem}.*.tmp*"):
        try:
            if now - tmp.stat().st_mtime > STALE_TEMP_S:
                tmp.unlink()
        except OSError:
            pass  # another process's, or already gone


@contextmanager
def atomic_write(path: Path, suffix: str) -> Iterator[str]:
    """Yield a temporary path beside ``path`` (ending in ``suffix``, so writers that pick a
    format by extension still work); when the block ends without error, rename it over
    ``path``; on any error, delete it."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"cannot write {path}: it is a folder (give a file path)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _clean_stale_temps(path.parent, path.stem)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    except (OSError, FileExistsError) as exc:
        err = user_error_for(path, exc) if isinstance(exc, OSError) else None
        if isinstance(exc, FileExistsError) or (isinstance(exc, OSError) and exc.errno == errno.EEXIST):
            err = UserError(f"cannot write {path}: a file is in the way where a folder is needed")
        if err is not None:
            raise err from exc
        raise
    os.close(fd)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        err = user_error_for(path, exc) if isinstance(exc, OSError) else None
        if err is not None:
            raise err from exc
        raise


@contextmanager
def file_lock(lock_path: Path, what: str) -> Iterator[None]:
    """Hold an exclusive flock on ``lock_path`` (created if needed) for the block; if another
    process holds it, UserError naming ``what`` and that process."""
    lock_path = Path(lock_path)
    try:
        lock_path.parent.mkdir(parents=True, exist_ok=True)
        f = open(lock_path, "a+")
    except OSError as exc:
        err = user_error_for(lock_path, exc)
        if err is not None:
            raise err from exc
        raise
    try:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "?"
            raise UserError(f"{lock_path.parent}: {what} is in use by another process (pid "
                            f"{holder}); wait for it to finish") from None
        try:  # the holder's pid, for the refusal above; a full disk here is one line too
            f.seek(0)
            f.truncate()
            f.write(str(os.getpid()))
            f.flush()
        except OSError as exc:
            err = user_error_for(lock_path, exc)
            if err is not None:
                raise err from exc
            raise
        yield
    finally:
        f.close()


@contextmanager
def folder_lock(folder: Path, what: str) -> Iterator[None]:
    """file_lock on ``folder/.lock``: one command at a time works in the folder."""
    with file_lock(Path(folder) / ".lock", what):
        yield
