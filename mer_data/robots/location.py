"""Where user robots live, and the one-time move out of the cache folder.

User robots are data the user made, not a cache: they live in the platform's user-data folder
(``platformdirs.user_data_dir("mer")/robots``: ``~/.local/share/mer/robots`` on Linux,
``~/Library/Application Support/mer/robots`` on macOS, ``%LOCALAPPDATA%\\mer\\robots`` on Windows),
or under ``$MER_HOME/robots`` when ``MER_HOME`` is set. Before, they were kept in the user *cache*
folder, which cache cleaners empty; robots found there are moved once, each folder in one rename
(a copy into a temporary folder and a rename when the two are on different file systems), with a
message saying where they went.
"""

from __future__ import annotations

import errno
import logging
import os
import shutil
import sys
import threading
from pathlib import Path

import platformdirs

from mer_data.base.atomic import atomic_dir, sweep_stale

log = logging.getLogger(__name__)

__all__ = ["robots_dir", "legacy_robots_dir", "move_legacy_robots"]

_moved = False
_lock = threading.Lock()


def legacy_robots_dir() -> Path:
    """Where mer kept user robots before: the user cache folder + ``mer/robots``."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA", Path.home() / "AppData" / "Local")) / "mer" / "Cache"
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches" / "mer"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mer"
    return base / "robots"


def robots_dir() -> Path:
    """Folder of the user robots: ``$MER_HOME/robots``, else the user-data folder (moved there once)."""
    env = os.environ.get("MER_HOME")
    if env:
        return Path(env).expanduser() / "robots"
    new = Path(platformdirs.user_data_dir("mer", appauthor=False)) / "robots"
    global _moved
    if not _moved:
        with _lock:
            if not _moved:
                move_legacy_robots(legacy_robots_dir(), new)
                _moved = True
    return new


def move_legacy_robots(old: Path, new: Path) -> list[str]:
    """Move every robot folder of ``old`` into ``new`` (names already in ``new`` are left); returns the moved names.

    Safe against a concurrent move: each folder is renamed on its own, and a name another process
    moved first is skipped. ``old`` is removed when it is left empty.
    """
    if not old.is_dir() or old.resolve() == new.resolve():
        return []
    entries = sorted(p for p in old.iterdir() if p.is_dir() and not p.name.startswith("."))
    moved, kept = [], []
    for src in entries:
        dst = new / src.name
        if dst.exists():
            kept.append(src.name)
            continue
        new.mkdir(parents=True, exist_ok=True)
        try:
            os.rename(src, dst)
        except FileNotFoundError:
            continue  # another process moved it meanwhile
        except OSError as exc:
            if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
                kept.append(src.name)
                continue
            if exc.errno != errno.EXDEV:
                raise
            try:  # another file system: copy beside the target, rename into place, then remove
                atomic_dir(dst, lambda tmp, src=src: shutil.copytree(src, tmp, symlinks=True, dirs_exist_ok=True), replace=False)
            except FileExistsError:
                kept.append(src.name)
                continue
            shutil.rmtree(src, ignore_errors=True)
        moved.append(src.name)
    if moved:
        log.warning(
            "moved %d registered robot(s) (%s) from the cache folder %s to %s: cache cleaners empty the cache",
            len(moved), ", ".join(moved), old, new,
        )  # fmt: skip
    if kept:
        log.warning(
            "robot(s) %s in the old registry %s were not moved: %s has robots of the same names "
            "(remove or re-register them by hand)",
            ", ".join(kept), old, new,
        )  # fmt: skip
    try:
        sweep_stale(old)  # leftovers of interrupted registrations (never those of a live process)
        old.rmdir()
    except OSError:
        pass  # not empty (robots kept): left for the user
    return moved
