"""Opening shards of either format, and finding them in folders."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Union

from mer_data.base.errors import ShardFormatError

from .hdf5_io import Hdf5Shard
from .mcap_io import McapShard
from .schema import detect_format

__all__ = ["open_shard", "find_shards", "ShardFile", "SHARD_SUFFIXES"]

ShardFile = Union[Hdf5Shard, McapShard]
SHARD_SUFFIXES = (".h5", ".hdf5", ".mcap")
PathsLike = Union[str, Path, Iterable[Union[str, Path]]]


def open_shard(path: str | Path) -> ShardFile:
    """Open one shard file (format detected from its first bytes); metadata are read at once."""
    fmt = detect_format(path)
    return Hdf5Shard(path) if fmt == "hdf5" else McapShard(path)


def find_shards(paths: PathsLike) -> list[Path]:
    """Shard files from a file, a folder (its ``*.h5``, ``*.hdf5``, ``*.mcap``) or a list of either."""
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix in SHARD_SUFFIXES and q.is_file() and not q.name.startswith("."))
            if not found:
                raise ShardFormatError("no shard files (*.h5, *.mcap) in this folder", path=p)
            out += found
        elif p.is_file():
            out.append(p)
        else:
            raise ShardFormatError("no such file or folder", path=p)
    if not out:
        raise ShardFormatError("no shard files given")
    return out
