"""Checksums: every file the zoo hands out is checked first, and a bad copy is removed, never used.

Two kinds of check:

* against a card (``verify_record``): size, then sha256, must equal what the card recorded when the
  model was published. This is the only check that also catches a tampered Hub repository.
* against the Hub's own content id (``verify_hub_blob``), for a plain ``org/repo`` that has no card:
  the Hub cache names every blob by its ETag, which is the sha256 of the content for an LFS file
  and the git blob sha1 for a regular file; the file must hash to its blob's name. This catches a
  truncated or altered cache entry, not a repository that was changed upstream.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path

from mer_data.base.errors import ChecksumError

from .card import FileRecord

log = logging.getLogger(__name__)

__all__ = ["sha256_file", "git_blob_sha1", "file_record", "verify_record", "verify_hub_blob", "remove_cached_file"]

_CHUNK = 1 << 20


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def git_blob_sha1(path: str | Path) -> str:
    """The git object id of a file (``sha1(b"blob <size>\\0" + content)``), as the Hub reports it."""
    size = os.path.getsize(path)
    h = hashlib.sha1(f"blob {size}\0".encode())
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def file_record(path: str | Path) -> FileRecord:
    """The (sha256, size) of a file, as a card records it."""
    return FileRecord(sha256_file(path), os.path.getsize(path))


def remove_cached_file(path: str | Path) -> list[Path]:
    """Delete a snapshot entry of the Hub cache and the blob it points to; returns what was removed.

    A snapshot entry is a symlink ``snapshots/<commit>/<file> -> ../../blobs/<etag>`` (or a plain
    copy where symlinks are unsupported). Both are removed so the next download fetches it again.
    """
    path = Path(path)
    removed = []
    target = None
    if path.is_symlink():
        target = (path.parent / os.readlink(path)).resolve()
    try:
        path.unlink()
        removed.append(path)
    except FileNotFoundError:
        pass
    if target is not None and target.parent.name == "blobs":
        try:
            target.unlink()
            removed.append(target)
        except FileNotFoundError:
            pass
    return removed


def _fail(path: Path, what: str, *, name: str, fix: str, cached: bool) -> None:
    removed = remove_cached_file(path) if cached else []
    note = f" The bad copy was removed from the cache ({', '.join(map(str, removed))})." if removed else ""
    raise ChecksumError(f"{what}; the file was not used.{note}", path=path, element=name, fix=fix)


def verify_record(path: str | Path, record: FileRecord, *, name: str, fix: str, cached: bool = True) -> None:
    """Check size then sha256 against the card; on mismatch remove the cached copy and raise."""
    path = Path(path)
    size = os.path.getsize(path)
    if size != record.size:
        _fail(path, f"{name} has {size} bytes, its card records {record.size} (truncated or altered)",
              name=name, fix=fix, cached=cached)
    digest = sha256_file(path)
    if digest != record.sha256:
        _fail(path, f"{name} has sha256 {digest}, its card records {record.sha256} (altered or corrupted)",
              name=name, fix=fix, cached=cached)


def verify_hub_blob(path: str | Path, *, name: str, fix: str) -> str:
    """Check a Hub-cache file against its blob name (sha256 for LFS, git sha1 otherwise); returns it."""
    path = Path(path)
    blob = (path.parent / os.readlink(path)).resolve().name if path.is_symlink() else None
    if blob is None:
        log.warning("%s is not a symlink into the Hub cache's blobs; it cannot be checked without a card", path)
        return ""
    got = sha256_file(path) if len(blob) == 64 else git_blob_sha1(path)
    if got != blob:
        _fail(path, f"{name} hashes to {got}, but the Hub served it as {blob}", name=name, fix=fix, cached=True)
    return got
