"""Atomic writes: nothing half-written is ever visible under the final name.

A file is written to a temporary file in the same folder, flushed to disk and renamed over the
target. A folder is built in a temporary sibling and swapped in: on Linux with one atomic exchange
(``renameat2(RENAME_EXCHANGE)``), elsewhere with two renames whose intermediate state is
recoverable (:func:`recover_dir` puts the old folder back if a process dies between them). On any
error the temporary is removed and the target is left as it was.

Temporary siblings carry their owner (``.tmp-<name>~<host>~<pid>~<random>``), so a sweep of stale
leftovers (:func:`sweep_stale`) removes only those of processes that are gone and never the
folder another process is still writing.

Nothing is written through a planted name: temporary files are created exclusively and without
following links (``O_CREAT | O_EXCL | O_NOFOLLOW``), the final rename replaces the name itself
(never what a link there points to), and folders mer chooses below one the user named
(:func:`real_folder`: ``teacher/``, ``.partial/``) must be real folders, not symbolic links. A full
disk is one :class:`~mer_data.base.errors.DiskFullError` naming the path, the bytes the write needs
and the bytes free (:func:`disk_full`), never a traceback; :func:`reserve_space` claims the room of
a file written by a library that cannot survive ``ENOSPC`` (HDF5) before it writes a byte.
"""

from __future__ import annotations

import ctypes
import errno
import os
import re
import shutil
import socket
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import DiskFullError, OutputPathError
from .outputs import os_refusal

__all__ = [
    "atomic_write",
    "atomic_dir",
    "owner_tag",
    "owner_alive",
    "recover_dir",
    "sweep_stale",
    "trash_dir",
    "real_folder",
    "create_new",
    "disk_full",
    "is_disk_full",
    "disk_full_as_error",
    "reserve_space",
    "release_reserve",
    "free_bytes",
]

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
    return not _zombie(pid)


def _zombie(pid: int) -> bool:
    """Whether ``pid`` has exited but is not yet reaped (Linux ``/proc``: state Z or X). A killed
    writer whose parent died too waits for init to reap it: its files are already abandoned."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rfind(")") + 2 : stat.rfind(")") + 3] in ("Z", "X")


def _owned_name(kind: str, final: Path) -> Path:
    return final.parent / f".{kind}-{final.name}~{owner_tag()}~{os.urandom(4).hex()}"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _chmod_like_open(path: str | Path, *, folder: bool) -> None:
    """``mkstemp``/``mkdtemp`` create 0600/0700; give what ``open``/``mkdir`` would (0666/0777 & ~umask)."""
    os.chmod(path, (0o777 if folder else 0o666) & ~_umask())


_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


def free_bytes(path: str | Path) -> int | None:
    """Bytes free to this user on the file system of ``path`` (its nearest existing folder); None if unknown."""
    p = Path(path)
    for q in (p, *p.parents):
        try:
            st = os.statvfs(q)
        except (OSError, AttributeError):
            continue
        return st.f_bavail * st.f_frsize
    return None


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or the quota) is full: ``ENOSPC``/``EDQUOT``, or HDF5's text of it."""
    if isinstance(exc, DiskFullError):
        return True
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    return isinstance(exc, (OSError, RuntimeError)) and ("No space left on device" in text or "errno = 28," in text)


def disk_full(path: str | Path, need: int | None = None) -> DiskFullError:
    """The one-line error for a full disk at ``path``: the bytes the write needs and the bytes free."""
    free = free_bytes(Path(path).parent)
    needs = f"writing it needs about {_size(need)}" if need else "no room to write it"
    has = f", {_size(free)} free there" if free is not None else ""
    return DiskFullError(f"the disk is full: {needs}{has}; free space (or quota) or write elsewhere, then run again",
                         path=path)  # fmt: skip


@contextmanager
def disk_full_as_error(path: str | Path, need: int | None = None) -> Iterator[None]:
    """Within the block, an ``ENOSPC``/``EDQUOT`` (or HDF5's report of it) becomes :func:`disk_full`,
    a refused write (read-only, permission, a file in the way) :class:`OutputPathError` (:func:`~.outputs.os_refusal`)."""
    try:
        yield
    except (DiskFullError, FileExistsError):  # O_EXCL and no-replace renames: the caller's own answer (a lock held,
        raise  # a name taken meanwhile); one left to the command line becomes OutputPathError there
    except (OSError, RuntimeError) as exc:
        if is_disk_full(exc):
            raise disk_full(path, need) from None
        refused = os_refusal(exc, path)  # a read-only folder, a file where a folder is: one clear error
        if refused is not None:
            raise refused from None
        raise


def real_folder(folder: str | Path, below: str | Path) -> Path:
    """``folder`` (created if missing), refusing any component below ``below`` that is a symbolic link
    or not a folder: a folder mer chooses (``teacher/``, ``.partial/``) in one a user or a stranger
    made may not lead elsewhere. ``below`` itself, the folder the user named, is taken as it is.
    """
    folder, below = Path(folder), Path(below)
    try:
        rel = folder.relative_to(below)
    except ValueError:
        raise ValueError(f"{folder} is not below {below}") from None
    below.mkdir(parents=True, exist_ok=True)
    cur = below
    for part in rel.parts:
        cur = cur / part
        try:
            os.mkdir(cur)  # never follows a link: an existing name (link included) is EEXIST
            continue
        except FileExistsError:
            pass
        st = os.lstat(cur)
        if stat.S_ISLNK(st.st_mode):
            raise OutputPathError(f"is a symbolic link (to {os.readlink(cur)!r}); mer writes only into a real folder here",
                                  path=cur, fix="remove the link (it is not a folder mer made) and run again")  # fmt: skip
        if not stat.S_ISDIR(st.st_mode):
            raise OutputPathError("is not a folder; mer keeps its files in a folder of this name", path=cur,
                                  fix="move it away and run again")  # fmt: skip
    return folder


def create_new(path: str | Path, mode: int = 0o666) -> int:
    """A new file at ``path`` opened for writing: created exclusively, never through a link (``O_EXCL |
    O_NOFOLLOW``); permissions ``mode & ~umask``, as ``open`` gives. Returns the descriptor."""
    return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC, mode)


def _new_temp(final: Path) -> tuple[int, Path]:
    """An exclusive owner-tagged temporary file beside ``final`` (see :func:`sweep_stale`)."""
    for _ in range(100):
        tmp = _owned_name("tmp", final)
        try:
            return create_new(tmp), tmp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(final))


def _refuse_non_file(path: Path) -> None:
    """A final name that is a folder or a special file is not replaced (a link or a file is: the name itself)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode)):
        raise OutputPathError("exists and is not a regular file; mer does not replace it", path=path,
                              fix="move it away or choose another output name")  # fmt: skip


def atomic_write(path: str | Path, data: bytes | str, *, below: str | Path | None = None) -> Path:
    """Write ``data`` (bytes, or text as UTF-8 with ``\\n`` newlines) to ``path`` atomically.

    The temporary file is created exclusively without following links; the rename replaces the
    name ``path`` itself (a symbolic link there is replaced, its target never written). ``below``:
    the folder the user named; the folders between it and ``path`` must be real folders
    (:func:`real_folder`). A full disk raises :class:`~mer_data.base.errors.DiskFullError`.
    """
    path = Path(path)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    with disk_full_as_error(path, len(payload)):
        if below is not None:
            real_folder(path.parent, below)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
        _refuse_non_file(path)
        fd, tmp = _new_temp(path)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    return path


def reserve_space(fd: int, nbytes: int, path: str | Path) -> bool:
    """Claim ``nbytes`` of disk beyond the end of the open file ``fd`` without changing its size
    (Linux ``fallocate(FALLOC_FL_KEEP_SIZE)``), so that writes within them cannot fail with ``ENOSPC``.

    Raises :class:`DiskFullError` (naming ``path``) when the room is not there. Where the file system
    cannot reserve, the free space is checked instead (False is returned: not a guarantee).
    Unused room is given back by :func:`release_reserve`.
    """
    nbytes = max(int(nbytes), 1)
    try:
        fn = ctypes.CDLL(None, use_errno=True).fallocate
        fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_longlong, ctypes.c_longlong]
    except (AttributeError, OSError):
        fn = None
    if fn is not None:
        if fn(fd, 1, os.fstat(fd).st_size, nbytes) == 0:  # 1: FALLOC_FL_KEEP_SIZE
            return True
        err = ctypes.get_errno()
        if err in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            raise disk_full(path, nbytes)
        if err not in (errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EINVAL):
            raise OSError(err, os.strerror(err), str(path))
    free = free_bytes(Path(path).parent)
    if free is not None and free < nbytes:
        raise disk_full(path, nbytes)
    return False


def release_reserve(fd: int) -> None:
    """Give back the room :func:`reserve_space` claimed and the writes did not use (a truncation to
    the file's own size frees the blocks past its end)."""
    os.ftruncate(fd, os.fstat(fd).st_size)


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
    with disk_full_as_error(final):
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{final.name}~{owner_tag()}~", dir=final.parent))
        try:
            write(tmp)
            _chmod_like_open(tmp, folder=True)
            for f in tmp.iterdir():
                if f.is_file() and not f.is_symlink():
                    fd = os.open(f, os.O_RDONLY | _NOFOLLOW | _CLOEXEC)
                    try:
                        os.fsync(fd)
                    finally:
                        os.close(fd)
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
