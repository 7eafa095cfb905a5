"""Exclusive ownership of output files across processes: one lock file per output, owner recorded.

``OUT/.<name>.lock`` holds ``<host>~<pid>`` of the process writing ``<name>``. A lock whose owner is
gone (same host, pid not running) is taken over; a live one is refused with an error that names the
owner and how to proceed. Locks are files, not ``flock``: they work on every platform and show who
holds them.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

from .atomic import disk_full_as_error, owner_alive, owner_tag
from .errors import MerError

__all__ = ["hold_locks"]


def _owner(lock: Path) -> tuple[str, int] | None:
    try:
        host, _, pid = lock.read_text().strip().rpartition("~")
        return host, int(pid)
    except (OSError, ValueError):
        return None


def _take(lock: Path, error: type[MerError], what: str) -> None:
    for _ in range(3):
        try:
            with disk_full_as_error(lock):  # O_EXCL: never through a link planted under the name
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY | getattr(os, "O_NOFOLLOW", 0), 0o644)
        except FileExistsError:
            owner = _owner(lock)
            try:
                mtime = lock.stat().st_mtime
            except FileNotFoundError:
                continue  # released meanwhile
            if owner is not None and not owner_alive(owner[0], owner[1], mtime):
                lock.unlink(missing_ok=True)  # its process is gone: take it over
                continue
            who = f"process {owner[1]} on {owner[0]}" if owner else "another process"
            raise error(
                f"{who} is writing {what} (lock {lock.name})",
                path=lock.parent,
                fix=f"wait for it to finish, or write elsewhere; if no such process runs, delete {lock}",
            ) from None
        try:
            with disk_full_as_error(lock), os.fdopen(fd, "w") as fh:
                fh.write(owner_tag() + "\n")
        except BaseException:
            lock.unlink(missing_ok=True)
            raise
        return
    raise error(f"could not take the lock {lock}", path=lock.parent, fix="try again")


@contextlib.contextmanager
def hold_locks(folder: Path, names: Sequence[str], error: type[MerError]) -> Iterator[None]:
    """Hold ``folder/.<name>.lock`` for every name (all or none) while the block runs."""
    taken: list[Path] = []
    try:
        for name in sorted(names):
            lock = folder / f".{name}.lock"
            _take(lock, error, name)
            taken.append(lock)
        yield
    finally:
        for lock in taken:
            lock.unlink(missing_ok=True)
