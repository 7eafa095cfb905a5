"""What a file is, from its first bytes, before any reader parses it (motions and robot descriptions).

Every motion reader's dispatch (:func:`mer_data.motion.sources.read_source`) and the robot
registration input pass a file through :func:`sniff` first, so a file of the wrong type gets a
message naming what it is and what to give instead, not the wrong reader's complaint ("UTF-16
text", "repair the XML", "1 values on this line").

Kinds: ``bvh`` (``HIERARCHY``), ``npz`` (a zip holding ``.npy`` members), ``npy``, ``pickle``,
``urdf`` (XML with ``<robot``), ``mjcf`` (XML with ``<mujoco``), ``xml``, ``gzip``, ``zip``,
``hdf5``, ``mcap``, ``gif``, ``png``, ``jpeg``, ``mp4``, ``pdf``, ``text`` (anything else that
decodes as UTF-8: CSV, YAML...), ``binary``, ``empty``.
"""

from __future__ import annotations

from pathlib import Path

from mer_data.base.errors import MerError

__all__ = ["sniff", "sniff_bytes", "describe", "expect", "HEAD_BYTES", "MOTION_KINDS"]

#: Bytes read to decide.
HEAD_BYTES = 4096

_MAGIC = (
    (b"\x93NUMPY", "npy"),
    (b"\x89HDF\r\n\x1a\n", "hdf5"),
    (b"\x89MCAP", "mcap"),
    (b"GIF87a", "gif"),
    (b"GIF89a", "gif"),
    (b"\x89PNG", "png"),
    (b"\xff\xd8\xff", "jpeg"),
    (b"%PDF", "pdf"),
    (b"\x1f\x8b", "gzip"),
)

_NAMES = {
    "bvh": "a BVH motion capture file",
    "npz": "a NumPy .npz archive",
    "npy": "a NumPy .npy array",
    "pickle": "a Python pickle",
    "urdf": "a URDF robot description",
    "mjcf": "a MuJoCo MJCF model",
    "xml": "an XML file",
    "gzip": "a gzip file",
    "zip": "a zip archive",
    "hdf5": "an HDF5 file (a shard?)",
    "mcap": "an MCAP file",
    "gif": "a GIF image",
    "png": "a PNG image",
    "jpeg": "a JPEG image",
    "mp4": "an MP4 video",
    "pdf": "a PDF document",
    "text": "a text file",
    "binary": "a binary file of unknown type",
    "empty": "an empty file",
}

#: What each motion kind is read as by ``mer retarget FILE``.
MOTION_KINDS = ("bvh", "npz", "npy", "text", "gzip")


def sniff_bytes(head: bytes) -> str:
    """The kind of a file that starts with ``head`` (module docstring)."""
    if not head:
        return "empty"
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if head[:1] == b"\x80" and len(head) > 1 and 2 <= head[1] <= 5:
        return "pickle"
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz" if b".npy" in head[:256] else "zip"
    if head[4:8] == b"ftyp":
        return "mp4"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # a cut multi-byte character at the end is still text
            return "binary"
        text = head[: exc.start].decode("utf-8")
    if "\x00" in text:
        return "binary"
    low = text.lstrip("\ufeff \t\r\n").lower()
    if low.startswith("hierarchy"):
        return "bvh"
    if low.startswith("<"):
        if "<robot" in low:
            return "urdf"
        if "<mujoco" in low:
            return "mjcf"
        return "xml"
    return "text"


def sniff(path: str | Path) -> str:
    """The kind of the file at ``path`` from its first :data:`HEAD_BYTES` (module docstring); a
    missing, unreadable or not regular file (a FIFO, a device) is left to the reader (``"text"``)."""
    import os
    import stat

    try:  # regular files only (a FIFO would block): anything else is left to the reader, which refuses it
        if not stat.S_ISREG(os.stat(path).st_mode):
            return "text"
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                return "text"
            return sniff_bytes(os.read(fd, HEAD_BYTES))
        finally:
            os.close(fd)
    except OSError:
        return "text"


def describe(head_or_kind: bytes | str) -> str:
    """``"a GIF image"``... for a kind or a file's first bytes."""
    kind = head_or_kind if isinstance(head_or_kind, str) else sniff_bytes(head_or_kind)
    return "it looks like " + _NAMES.get(kind, kind)


_FIXES = {
    "urdf": "register it as a robot: mer robots register --urdf FILE; give a motion file as the input",
    "mjcf": "register it as a robot: mer robots register --mjcf FILE; give a motion file as the input",
    "bvh": "a BVH is a human motion: mer retarget FILE.bvh --target ROBOT (robots are registered from a URDF or MJCF)",
    "hdf5": "inspect a shard with mer shards inspect FILE",
    "mcap": "an MCAP is an output; give the motion it was written from",
    "gif": "a GIF is a video output; give the motion it was written from",
    "png": "a PNG is a plot; give the motion itself",
    "mp4": "an MP4 is a video output; give the motion it was written from",
    "pickle": "mer never unpickles (it could run code): save the arrays with numpy.savez and give the .npz",
}


def expect(path: str | Path, allowed: tuple[str, ...], what: str, fix: str, error: type[MerError] = MerError) -> str:
    """The file's kind if it is one of ``allowed``; else ``error`` saying what the file is instead
    (``what``: what was expected, e.g. ``"a motion (CSV, BVH, SMPL .npz, joint .npy)"``)."""
    kind = sniff(path)
    if kind in allowed:
        return kind
    raise error(f"is not {what}: {describe(kind)}", path=path, fix=_FIXES.get(kind, fix))
