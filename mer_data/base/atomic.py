"""Atomic writes: nothing half-written is ever visible under the final name.

A file is written to a temporary file in the same folder, flushed to disk and renamed over the
target. A folder is built in a temporary sibling and swapped in: on Linux with one atomic exchange
(``renameat2(RENAME_EXCHANGE)``), elsewhere with two renames whose intermediate state is
recoverable (:func:`recover_dir` puts the old folder back if a process dies between them). On any
error the temporary is removed and the target is left as it was.

Temporary siblings carry their owner (``.tmp-<name>~<host>~<pid>~<random>``), so a sweep of stale
leftovers (:func:`sweep_stale`) removes only those of processes that are gone and never the
folder another process is still writing.
"""

from __future__ import annotations

import ctypes
import errno
import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_dir", "owner_tag", "owner_alive", "recover_dir", "sweep_stale", "trash_dir"]

#: Leftovers of another host (whose processes cannot be checked) are swept after this long [s].
FOREIGN_STALE_SECONDS = 24 * 3600
# written by mer before owners were recorded: no process of this version makes them, so they are stale
_LEGACY = re.compile(r"^\.(?P<kind>tmp|old)-(?P<name>[^~]+)-[^-~]+$")
_OWNED = re.compile(r"^\.(?P<kind>tmp|old|trash)-(?P<name>.+)~(?P<host>[A-Za-z0-9.-]*)~(?P<pid>\d+)~[A-Za-z0-9_]+$")


def owner_tag() -> str:
    """``<host>~<pid>`` of this process, as embedded in temporary names."""
    host = re.sub(r"[^A-Za-z0-9.-]", "-", socket.gethostname())[:64]
    return f"{host}~{os.getpid()}"


def owner_alive(host: str, pid: int, mtime: float | None = None) -> bool:
    """Whether the process ``pid`` on ``host`` may still be running (unknown hosts: until 24 h old)."""
    if host != owner_tag().split("~")[0]:
        return mtime is None or time.time() - mtime < FOREIGN_STALE_SECONDS
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _owned_name(kind: str, final: Path) -> Path:
    return final.parent / f".{kind}-{final.name}~{owner_tag()}~{os.urandom(4).hex()}"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _chmod_like_open(path: str | Path, *, folder: bool) -> None:
    """``mkstemp``/``mkdtemp`` create 0600/0700; give what ``open``/``mkdir`` would (0666/0777 & ~umask)."""
    os.chmod(path, (0o777 if folder else 0o666) & ~_umask())


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (bytes, or text as UTF-8 with ``\\n`` newlines) to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    # owner-tagged, so that sweep_stale can tell a dead writer's leftover from a live one's file
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{path.name}~{owner_tag()}~", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        _chmod_like_open(tmp, folder=False)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two existing paths (Linux ``renameat2``); False where that is unavailable."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EPERM):
        return False  # kernel or file system without the flag
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def _swap_in(tmp: Path, final: Path, replace: bool) -> None:
    """Make ``tmp`` visible as ``final``; the old ``final`` (if any) is removed."""
    for _ in range(100):  # another process may create or remove ``final`` between the steps
        try:
            os.rename(tmp, final)  # fails if ``final`` is a non-empty folder
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.EISDIR, errno.ENOTDIR):
                raise
        if not replace:
            raise FileExistsError(errno.EEXIST, "already exists", str(final))
        try:
            if _exchange(tmp, final):  # one atomic step: readers see the old or the new folder
                shutil.rmtree(tmp, ignore_errors=True)
                return
        except FileNotFoundError:
            continue  # ``final`` vanished meanwhile: plain rename
        old = _owned_name("old", final)  # two renames; recover_dir() undoes a death between them
        try:
            os.rename(final, old)
        except FileNotFoundError:
            continue
        os.rename(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
        return
    raise OSError(errno.EBUSY, "could not swap the folder in (too much contention)", str(final))


def atomic_dir(final: str | Path, write: Callable[[Path], None], *, replace: bool = True) -> Path:
    """Build a folder with ``write(tmp_folder)`` and swap it in as ``final``.

    Every file ``write`` leaves at the top level is fsynced before the folder becomes visible.
    ``replace=False`` raises :class:`FileExistsError` (and writes nothing) if ``final`` exists by
    the time the new folder is complete: the check and the rename are one atomic step.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{final.name}~{owner_tag()}~", dir=final.parent))
    try:
        write(tmp)
        _chmod_like_open(tmp, folder=True)
        for f in tmp.iterdir():
            if f.is_file():
                with open(f, "rb") as fh:
                    os.fsync(fh.fileno())
        _swap_in(tmp, final, replace)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _leftovers(folder: Path):
    """(path, kind, name, alive) of every owner-tagged leftover in ``folder``."""
    try:
        entries = list(folder.iterdir())
    except OSError:
        return
    for p in entries:
        m = _OWNED.match(p.name)
        legacy = _LEGACY.match(p.name) if m is None else None
        if m is None and legacy is None:
            continue
        try:
            mtime = p.lstat().st_mtime
        except OSError:
            continue
        if legacy is not None:
            yield p, "trash", legacy["name"], False  # removed, never restored (old unregisters used .old-)
        else:
            yield p, m["kind"], m["name"], owner_alive(m["host"], int(m["pid"]), mtime)


def recover_dir(final: str | Path) -> bool:
    """Put back the old folder of a replacement that died between its two renames.

    Returns True if ``final`` was missing and has been restored from a ``.old-`` leftover of a
    process that is gone.
    """
    final = Path(final)
    if final.exists():
        return False
    olds = [p for p, kind, name, alive in _leftovers(final.parent) if kind == "old" and name == final.name and not alive]
    for old in sorted(olds, key=lambda p: p.lstat().st_mtime, reverse=True):
        try:
            os.rename(old, final)
            return True
        except OSError:
            continue
    return False


def sweep_stale(folder: str | Path) -> list[Path]:
    """Recover interrupted replacements, then remove the leftovers of processes that are gone.

    Leftovers of live processes (on this host: checked by pid; elsewhere: younger than 24 h) are
    never touched. Returns the paths removed.
    """
    folder = Path(folder)
    for p, kind, name, alive in list(_leftovers(folder)):
        if kind == "old" and not alive:
            recover_dir(folder / name)
    removed = []
    for p, kind, name, alive in list(_leftovers(folder)):
        if alive:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


def trash_dir(folder: str | Path) -> None:
    """Remove a folder: renamed away in one step (its name disappears at once), then deleted."""
    folder = Path(folder)
    trash = _owned_name("trash", folder)
    os.rename(folder, trash)
    shutil.rmtree(trash, ignore_errors=True)
