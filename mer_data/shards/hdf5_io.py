"""HDF5 shards: one dataset per column, one row per window; metadata as root attributes.

Layout choices:

* Every column is a top-level dataset whose first axis is the window, so ``datasets.load_dataset(
  "hdf5", data_files=...)`` maps each to a column (its builder turns every dataset into a column and
  requires one common first dimension; attributes are ignored).
* The large per-window arrays (``pos``, ``q``, ``link_scales``) are chunked one window per chunk:
  reading a sample touches a few contiguous, independently compressed chunks (no fancy indexing).
  The small columns use chunks of :data:`SMALL_CHUNK_ROWS` rows.
  Compression: LZF (fast; what h5py ships) or gzip, with shuffle.
* Metadata are root attributes (:meth:`ShardMeta.to_attrs`); large attributes need the HDF5 1.8
  file format (``libver="v108"``).
* Per-clip *pieces* written by the build workers have the same layout; they are merged by copying
  the compressed per-window chunks verbatim (``read_direct_chunk``/``write_direct_chunk``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import h5py
import numpy as np

from mer_data.base.errors import ShardFormatError

from .schema import BIG_COLUMNS, COLUMNS, ShardMeta

log = logging.getLogger(__name__)

__all__ = ["Hdf5ShardWriter", "Hdf5Shard", "SMALL_CHUNK_ROWS"]

SMALL_CHUNK_ROWS = 256
LIBVER = "v108"
_STR = h5py.string_dtype("utf-8")


def _filters(compression: str) -> dict:
    if compression == "lzf":
        return {"compression": "lzf", "shuffle": True}
    if compression == "gzip":
        return {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    if compression == "none":
        return {}
    raise ValueError(f"unknown compression {compression!r} (lzf, gzip, none)")


class Hdf5ShardWriter:
    """Write a shard (or a piece) row by row. Call :meth:`close` with the final metadata."""

    def __init__(self, path: str | Path, meta: ShardMeta, *, compression: str = "lzf") -> None:
        self.path = Path(path)
        self.meta = meta
        self.shapes = meta.shapes()
        self.file = h5py.File(self.path, "w", libver=LIBVER)
        self.rows = 0
        filt = _filters(compression)
        for name, dtype in COLUMNS.items():
            shape = self.shapes[name]
            if dtype == "str":
                self.file.create_dataset(name, shape=(0,), maxshape=(None,), dtype=_STR, chunks=(SMALL_CHUNK_ROWS,))
                continue
            chunk_rows = 1 if name in BIG_COLUMNS else SMALL_CHUNK_ROWS
            self.file.create_dataset(
                name, shape=(0,) + shape, maxshape=(None,) + shape, dtype=np.dtype(dtype),
                chunks=(chunk_rows,) + shape, **filt,
            )  # fmt: skip

    def _grow(self, n: int) -> int:
        start = self.rows
        for name in COLUMNS:
            self.file[name].resize(start + n, axis=0)
        self.rows += n
        return start

    def append(self, rows: dict[str, np.ndarray]) -> None:
        """Append ``n`` rows given as arrays (n, *shape) per column."""
        n = len(rows["start_frame"])
        if n == 0:
            return
        start = self._grow(n)
        for name, dtype in COLUMNS.items():
            a = rows[name]
            if a.shape[1:] != self.shapes[name]:
                raise ValueError(f"column {name}: rows of shape {a.shape[1:]}, expected {self.shapes[name]}")
            self.file[name][start : start + n] = a if dtype == "str" else np.asarray(a, dtype=dtype)

    def append_piece(self, piece: str | Path) -> int:
        """Append every row of a piece file (same layout and filters); returns the number of rows."""
        with h5py.File(piece, "r") as src:
            n = src["start_frame"].shape[0]
            if n == 0:
                return 0
            start = self._grow(n)
            for name in COLUMNS:
                s, d = src[name], self.file[name]
                if name in BIG_COLUMNS:
                    zeros = (0,) * (len(s.shape) - 1)
                    sid, did = s.id, d.id
                    for i in range(n):
                        mask, data = sid.read_direct_chunk((i,) + zeros)
                        did.write_direct_chunk((start + i,) + zeros, data, mask)
                else:
                    d[start : start + n] = s[...]
        return n

    def close(self, meta: ShardMeta | None = None) -> None:
        meta = meta or self.meta
        meta.num_rows = self.rows
        for k, v in meta.to_attrs().items():
            self.file.attrs[k] = v
        self.file.flush()
        self.file.close()

    def abort(self) -> None:
        try:
            self.file.close()
        finally:
            self.path.unlink(missing_ok=True)


class ProcessLocalH5:
    """A read-only HDF5 file at ``self.path`` with one handle per process: opened on first use in
    each process (DataLoader workers fork or spawn after the parent opened it), closed by
    :meth:`close`, pickled without the handle."""

    path: Path
    _file: h5py.File | None = None
    _pid: int = -1

    def _f(self) -> h5py.File:
        import os

        if self._file is None or self._pid != os.getpid():
            self._file = h5py.File(self.path, "r")
            self._pid = os.getpid()
        return self._file

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_file"], d["_pid"] = None, -1
        return d


class Hdf5Shard(ProcessLocalH5):
    """Read access to an HDF5 shard (opened lazily, once per process)."""

    format = "hdf5"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with h5py.File(self.path, "r") as f:
                self.meta = ShardMeta.from_attrs(dict(f.attrs), self.path)
                missing = [c for c in COLUMNS if c not in f]
                if missing:
                    raise ShardFormatError(f"damaged shard: columns {missing} are missing", path=self.path)
                rows = {f[c].shape[0] for c in COLUMNS}
                if rows != {self.meta.num_rows}:
                    raise ShardFormatError(
                        f"damaged shard: column lengths {sorted(rows)}, metadata says {self.meta.num_rows}",
                        path=self.path,
                    )
        except OSError as exc:
            raise ShardFormatError(
                f"cannot read the HDF5 shard ({exc})", path=self.path, fix="rebuild it with `mer shards build`"
            ) from None

    @property
    def num_rows(self) -> int:
        return self.meta.num_rows

    def column(self, name: str) -> np.ndarray:
        """A whole column (strings as an object array of ``str``)."""
        d = self._f()[name]
        return d.asstr()[...] if COLUMNS[name] == "str" else d[...]

    def row(self, name: str, i: int) -> np.ndarray:
        """Column ``name`` of row ``i`` (one chunk read for the big columns)."""
        d = self._f()[name]
        return d.asstr()[i] if COLUMNS[name] == "str" else d[i]

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Rows ``start:stop`` of every column (a contiguous slice)."""
        f = self._f()
        return {c: (f[c].asstr()[start:stop] if COLUMNS[c] == "str" else f[c][start:stop]) for c in COLUMNS}
