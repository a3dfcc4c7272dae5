"""How a study script claims the files it will write: checked before any work, then locked for
the whole run, so of two commands given one --out the second is refused in one line up front
instead of replacing the first's table when it finishes (nothing overwritten without --force)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from .atomicio import file_lock
from .errors import check_output


def output_lock_path(path: Path) -> Path:
    """The lock beside an output: .NAME.lock (git ignores it)."""
    path = Path(path)
    return path.parent / f".{path.name}.lock"


@contextmanager
def claimed_outputs(paths, flag: str, force: bool) -> Iterator[None]:
    """`check_output` for each path (a folder, a file in the way of its folder, an existing
    file without ``force``), then hold a lock per path for the block, and check again under the
    locks (a command that finished in between is not replaced either). Write each path with
    atomicio.atomic_write inside the block."""
    paths = [Path(p) for p in paths]
    for p in paths:
        check_output(p, flag, force)
    with ExitStack() as stack:
        for p in sorted({p.resolve() for p in paths}):
            stack.enter_context(file_lock(output_lock_path(p), f"the output {p.name}"))
        for p in paths:
            check_output(p, flag, force)
        yield
