"""Where mer may write: outputs checked before a job runs, the operating system's refusals as one
clear error, and files mer did not write never overwritten.

* :func:`check_output_dir` / :func:`check_output_file`: called by the command line before a job
  starts (a retarget, a shard build, a registration), so a read-only folder, a name that is a file
  where a folder is wanted (or the reverse) is refused in a second, not after an hour of work.
* :func:`os_refusal`: an ``EACCES``/``EPERM``/``EROFS``/``ENOTDIR``/``EISDIR``/``EEXIST`` of a write
  as :class:`~mer_data.base.errors.OutputPathError` naming the path (the atomic writers use it, and
  the command line for anything else), never a traceback.
* :func:`refuse_foreign`: a file mer would replace that it did not write (no mark of mer's in it,
  e.g. a project's README.md under ``--out .``) is refused with the way out.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from .errors import OutputPathError

__all__ = ["check_output_dir", "check_output_file", "os_refusal", "refuse_foreign", "WRITE_FIX"]

WRITE_FIX = "choose an output in a folder you can write to, or fix the folder's permissions (or mount)"
_REFUSALS = {errno.EACCES: "permission denied", errno.EPERM: "operation not permitted", errno.EROFS: "read-only file system",
             errno.ENOTDIR: "a part of the path is a file, not a folder", errno.EISDIR: "is a folder",
             errno.EEXIST: "exists already"}  # fmt: skip


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not os.path.lexists(p) and p != p.parent:
        p = p.parent
    return p


def _writable_folder(folder: Path, path: Path, what: str) -> None:
    try:
        st = os.stat(folder)
    except OSError as exc:
        raise OutputPathError(f"{what}: cannot reach {folder} ({exc.strerror})", path=path, fix=WRITE_FIX) from None
    if not stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"{what}: {folder} is a file, not a folder", path=path,
                              fix="choose an output below a folder, or move the file away")  # fmt: skip
    if not os.access(folder, os.W_OK | os.X_OK):
        ro = _read_only_fs(folder)
        raise OutputPathError(f"{what}: cannot write in {folder} ({'read-only file system' if ro else 'permission denied'})",
                              path=path, fix=WRITE_FIX)  # fmt: skip


def _read_only_fs(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def check_output_dir(path: str | Path, what: str = "output folder") -> Path:
    """``path`` can be made (or is) a folder mer writes into; else :class:`OutputPathError` at once."""
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        raise OutputPathError(f"{what}: exists and is not a folder", path=path,
                              fix="name a folder (new or existing), or move the file away")  # fmt: skip
    _writable_folder(path if path.is_dir() else _existing_ancestor(path), path, what)
    return path


def check_output_file(path: str | Path, what: str = "output file") -> Path:
    """``path`` can be written as a file (its folder exists or can be made, and is writable)."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{what}: is a folder, not a file name", path=path, fix="name a file to write, not a folder")
    _writable_folder(_existing_ancestor(path.parent), path, what)
    return path


def os_refusal(exc: BaseException, path: str | Path) -> OutputPathError | None:
    """The :class:`OutputPathError` for an OS refusal of a write (None for any other error)."""
    if not isinstance(exc, OSError) or exc.errno not in _REFUSALS:
        return None
    where = exc.filename if exc.filename else path
    return OutputPathError(f"cannot write: {_REFUSALS[exc.errno]}", path=where, fix=WRITE_FIX)


def refuse_foreign(path: str | Path, mark: str, *, what: str, fix: str) -> None:
    """Refuse to replace ``path`` if it exists and does not contain ``mark`` (mer's signature in the
    files it writes): it is someone else's file. A missing file, or one mer wrote, passes."""
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    head = b""
    if stat.S_ISREG(st.st_mode):
        with open(path, "rb") as fh:
            head = fh.read(4096)
    if mark.encode() not in head:
        raise OutputPathError(f"{what} exists and was not written by mer; it is not overwritten", path=path, fix=fix)
