"""Reading a mesh file from a stranger: one regular file, size-capped, never an archive.

Every mesh mer reads with trimesh (collision hulls at registration, the viewer's and exporters'
visual meshes) goes through :func:`read_mesh`. trimesh opens ``.zip``, ``.tar.gz``, ``.zae`` and the
like by unpacking them **in memory** (a 1 MB zip of zeros became 3.1 GB): mer gives it the file's
bytes with the format named by the extension, and refuses compressed containers by their first
bytes, whatever the name says. A mesh is capped at ``MER_MAX_MESH_BYTES`` before it is read.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from mer_data.base.errors import MalformedURDFError
from mer_data.base.safe_io import read_regular_file

__all__ = ["MESH_FORMATS", "MeshArchiveError", "read_mesh", "archive_kind"]

#: Extensions read (lower case), each trimesh's own single-file loader; anything else is refused.
MESH_FORMATS = ("stl", "obj", "ply", "off", "dae", "glb")
_MAGIC = ((b"PK\x03\x04", "a zip archive"), (b"PK\x05\x06", "a zip archive"), (b"\x1f\x8b", "gzip-compressed"),
          (b"BZh", "bzip2-compressed"), (b"\xfd7zXZ\x00", "xz-compressed"), (b"7z\xbc\xaf\x27\x1c", "a 7-zip archive"),
          (b"\x28\xb5\x2f\xfd", "zstd-compressed"), (b"Rar!", "a RAR archive"))  # fmt: skip


class MeshArchiveError(MalformedURDFError):
    """A mesh file that is a compressed container: refused (a hard error, not a missing mesh)."""


_FIX = "unpack it yourself and point the description at the mesh file (STL, OBJ, PLY, OFF, DAE or GLB)"


def archive_kind(head: bytes) -> str | None:
    """What compressed container the first bytes of a file are (``"a zip archive"``...), or None."""
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if len(head) >= 262 and head[257:262] == b"ustar":
        return "a tar archive"
    return None


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangles (T, 3) int64 of one mesh file, as written (no scale).

    Raises:
        MeshArchiveError: a compressed archive (zip, gzip, tar, ...), whatever its name.
        MalformedURDFError: not a regular file, over ``MER_MAX_MESH_BYTES``, or an extension mer
            does not read; naming the file and the fix.
        Exception: whatever trimesh raises on a file it cannot parse (callers log it and fall back).
    """
    path = Path(path)
    data = read_regular_file(path, MalformedURDFError, "MER_MAX_MESH_BYTES", fix="check the mesh path")
    kind = archive_kind(data[:512])
    if kind is not None:
        raise MeshArchiveError(f"the mesh file is {kind}; mer never unpacks archives (their content may be any size)",
                                 path=path, fix=_FIX)  # fmt: skip
    ext = path.suffix.lower().lstrip(".")
    if ext not in MESH_FORMATS:
        raise MalformedURDFError(f"mesh format {path.suffix or '(no extension)'!r} is not read by mer", path=path,
                                 fix=f"convert it to one of {', '.join(MESH_FORMATS)}")  # fmt: skip
    import trimesh

    # bytes and a named type: no resolver, so nothing beside the file (textures, .mtl, buffers) is opened
    mesh = trimesh.load(file_obj=io.BytesIO(data), file_type=ext, force="mesh", process=False)
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
