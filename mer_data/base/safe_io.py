"""Reading untrusted input files: regular files only, size-limited, gunzip with an output cap.

Every reader of user files (URDFs, robot cards, key-point files, motion CSVs, checkpoint configs)
goes through :func:`read_regular_file`, so the same messages come out of every command:

* a directory, a named pipe (FIFO), a socket or a device is refused *before* it is opened for
  reading (a FIFO would block forever), and again on the open descriptor (no race);
* a dangling symbolic link, a symbolic-link loop, a missing or unreadable file: one message each;
* a file over its size limit (:mod:`mer_data.base.limits`) is refused without being read.
"""

from __future__ import annotations

import errno
import os
import stat
import zlib
from pathlib import Path
from typing import Any

import yaml

from .errors import MerError
from .limits import limit, too_big

__all__ = ["read_regular_file", "check_regular_file", "gunzip_limited", "decode_utf8", "safe_yaml_load", "strict_json_loads",
           "DuplicateKeyError"]

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def _kind(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def _not_regular(path: Path, mode: int, error: type[MerError], fix: str | None) -> MerError:
    return error(
        f"is {_kind(mode)}, not a regular file; mer reads only regular files",
        path=path,
        fix=fix or "pass a regular file (copy the data out of a pipe or device first)",
    )


def check_regular_file(path: str | Path, error: type[MerError] = MerError, *, fix: str | None = None) -> os.stat_result:
    """``os.stat`` of ``path`` if it is a regular file (symbolic links followed); else ``error``."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise error(
                f"is a dangling symbolic link (to {os.readlink(path)!r}, which does not exist)",
                path=path,
                fix=fix or "point the link at an existing file, or remove it",
            ) from None
        raise error("file not found", path=path, fix=fix or "check the path") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error("is a symbolic link loop", path=path, fix=fix or "make the link point at a real file") from None
        if exc.errno == errno.ENAMETOOLONG:
            raise error("the path is too long for the file system", path=path, fix=fix or "use a shorter path") from None
        raise error(f"cannot access the file ({exc.strerror})", path=path, fix=fix) from None
    if not stat.S_ISREG(st.st_mode):
        raise _not_regular(path, st.st_mode, error, fix)
    return st


def read_regular_file(
    path: str | Path, error: type[MerError], size_limit: str, *, fix: str | None = None
) -> bytes:
    """The bytes of ``path``, a regular file of at most ``limit(size_limit)`` bytes; else ``error``.

    Args:
        path: the file (symbolic links are followed).
        error: the :class:`MerError` subclass to raise (e.g. ``MalformedURDFError``).
        size_limit: name of the limit in :data:`mer_data.base.limits.LIMITS`, e.g. ``MER_MAX_URDF_BYTES``.
        fix: the fix shown for missing / non-regular files (default: a generic one).
    """
    path = Path(path)
    st = check_regular_file(path, error, fix=fix)
    cap = limit(size_limit)
    if st.st_size > cap:
        msg, how = too_big(size_limit, st.st_size)
        raise error(msg, path=path, fix=how)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise error(f"cannot open the file ({exc.strerror})", path=path, fix=fix) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):  # swapped for a pipe after the check above
            raise _not_regular(path, mode, error, fix)
        chunks, total = [], 0
        while total <= cap:
            chunk = os.read(fd, min(1 << 20, cap + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except OSError as exc:
        raise error(f"cannot read the file ({exc.strerror})", path=path, fix=fix) from None
    finally:
        os.close(fd)
    if total > cap:  # grew while being read
        msg, how = too_big(size_limit, f"over {cap:,}")
        raise error(msg, path=path, fix=how)
    return b"".join(chunks)


def gunzip_limited(raw: bytes, path: str | Path, error: type[MerError], size_limit: str) -> bytes:
    """Decompress gzip bytes (one or several members), refusing output past ``limit(size_limit)``.

    The output is capped while decompressing: a small "zip bomb" is refused after reading at most
    the limit, never expanded into memory.
    """
    cap = limit(size_limit)
    out: list[bytes] = []
    total = 0
    data = raw
    try:
        while data:
            d = zlib.decompressobj(16 + zlib.MAX_WBITS)
            part = d.decompress(data, cap + 1 - total)
            total += len(part)
            out.append(part)
            if total > cap or d.unconsumed_tail:
                msg, how = too_big(size_limit, f"over {cap:,}")
                raise error(msg, path=path, fix=how)
            if not d.eof:
                raise error(
                    "not a valid gzip file (it ends before the compressed data does)",
                    path=path,
                    fix="re-download it, or decompress it yourself to check",
                )
            data = d.unused_data.lstrip(b"\0")  # members may be followed by zero padding
    except zlib.error as exc:
        raise error(
            f"not a valid gzip file ({exc})", path=path, fix="re-download it, or decompress it yourself to check"
        ) from None
    return b"".join(out)


def decode_utf8(data: bytes, path: str | Path, error: type[MerError]) -> str:
    """UTF-8 text (a byte-order mark is dropped); other encodings → ``error`` with the line."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(
            f"the file is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})",
            path=path,
            line=line,
            fix="save the file as UTF-8",
        ) from None


class DuplicateKeyError(ValueError):
    """A mapping names the same key twice (JSON and YAML parsers silently keep the last)."""


def _no_duplicates(pairs: list[tuple[Any, Any]]) -> dict:
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise DuplicateKeyError(f"the key {k!r} appears twice in one mapping (only one value can hold)")
        out[k] = v
    return out


def strict_json_loads(text: str | bytes) -> Any:
    """``json.loads`` that refuses a key given twice in one object (:class:`DuplicateKeyError`, a
    ``ValueError``) and the non-standard constants ``NaN``, ``Infinity``, ``-Infinity``."""
    import json

    def constant(name: str) -> Any:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, object_pairs_hook=_no_duplicates, parse_constant=constant)


class _NoAliasLoader(yaml.SafeLoader):
    """PyYAML's safe loader without aliases: ``*ref`` can expand a small file exponentially
    (a "billion laughs"); nothing mer reads needs them. A key given twice in one mapping is refused."""

    def construct_mapping(self, node, deep=False):  # type: ignore[override]
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) or key is None:
                if key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"the key {key!r} appears twice in one mapping",
                                                            key_node.start_mark)  # fmt: skip
                seen.add(key)
        return super().construct_mapping(node, deep=deep)

    def compose_node(self, parent, index):  # type: ignore[override]
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not accepted", mark)
        return super().compose_node(parent, index)


def safe_yaml_load(text: str) -> Any:
    """``yaml.safe_load`` that refuses aliases and duplicate keys (raises ``yaml.YAMLError`` with the position)."""
    return yaml.load(text, Loader=_NoAliasLoader)  # noqa: S506 - a SafeLoader subclass
