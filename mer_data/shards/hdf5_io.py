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
* A full disk: HDF5 does not survive ``ENOSPC`` (h5py segfaults closing the file), so a piece is
  built in memory (the core driver) and written to disk in one checked write
  (:func:`~mer_data.base.atomic.atomic_write`); a shard file written to disk directly first claims
  its room (:func:`~mer_data.base.atomic.reserve_space`, by the builder). Either way a full disk is
  a :class:`~mer_data.base.errors.DiskFullError`, and nothing is left under a final name.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import ShardFormatError

from .h5safe import attr, dataset, open_h5, read
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
    """Write a shard (or a piece) row by row. Call :meth:`close` with the final metadata.

    ``in_memory``: build the file in memory and write it to ``path`` atomically on :meth:`close`
    (``below``: the folder the user named, see :func:`~mer_data.base.atomic.atomic_write`); else it is
    written at ``path`` as it grows (created exclusively: never through a planted link).
    """

    def __init__(self, path: str | Path, meta: ShardMeta, *, compression: str = "lzf", in_memory: bool = False,
                 below: str | Path | None = None) -> None:  # fmt: skip
        self.path = Path(path)
        self.meta = meta
        self.shapes = meta.shapes()
        self.in_memory, self.below = in_memory, below
        if in_memory:  # nothing touches the disk before close(): ENOSPC surfaces in one checked write
            self.file = h5py.File(f"mer-{uuid.uuid4().hex}.h5", "w", driver="core", backing_store=False, libver=LIBVER)
        else:
            # "x": created exclusively, so a symbolic link or a file planted under the name is never written through
            self.file = h5py.File(self.path, "x", libver=LIBVER)
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
        src = Hdf5Shard(piece)
        try:
            n = src.num_rows
            if n == 0:
                return 0
            for name in COLUMNS:
                if src.schema[name][1][1:] != self.shapes[name]:
                    raise ShardFormatError(f"the piece's column {name} has rows of shape {src.schema[name][1][1:]}, "
                                           f"expected {self.shapes[name]}", path=piece)  # fmt: skip
            start = self._grow(n)
            for name in COLUMNS:
                s, d = src._ds(name), self.file[name]
                if name in BIG_COLUMNS:
                    if s.chunks != d.chunks:
                        raise ShardFormatError(f"the piece's column {name} has chunks {s.chunks}, expected {d.chunks}",
                                               path=piece)  # fmt: skip
                    zeros = (0,) * (len(s.shape) - 1)
                    sid, did = s.id, d.id
                    for i in range(n):
                        mask, data = sid.read_direct_chunk((i,) + zeros)
                        did.write_direct_chunk((start + i,) + zeros, data, mask)
                else:
                    d[start : start + n] = src._read(name)
        finally:
            src.close()
        return n

    def close(self, meta: ShardMeta | None = None) -> None:
        meta = meta or self.meta
        meta.num_rows = self.rows
        for k, v in meta.to_attrs().items():
            self.file.attrs[k] = v
        self.file.flush()
        if not self.in_memory:
            self.file.close()
            return
        image = self.file.id.get_file_image()
        self.file.close()
        atomic_write(self.path, image, below=self.below)

    def abort(self) -> None:
        try:
            self.file.close()
        finally:
            if not self.in_memory:
                self.path.unlink(missing_ok=True)


class ProcessLocalH5:
    """A read-only HDF5 file at ``self.path`` with one handle per process: opened on first use in
    each process (DataLoader workers fork or spawn after the parent opened it), closed by
    :meth:`close`, pickled without the handle. Opened and read through :mod:`.h5safe`: datasets are
    checked against :attr:`schema` (name -> (dtype, shape)) before their first read."""

    path: Path
    what: str = "HDF5 file"
    schema: dict[str, tuple[str, tuple[int | None, ...]]] = {}
    _file: h5py.File | None = None
    _pid: int = -1
    _checked: dict[str, h5py.Dataset] | None = None

    def _f(self) -> h5py.File:
        import os

        if self._file is None or self._pid != os.getpid():
            self._file = open_h5(self.path, what=self.what)
            self._pid = os.getpid()
            self._checked = {}
        return self._file

    def _ds(self, name: str) -> h5py.Dataset:
        """The dataset ``name``, checked against :attr:`schema` (once per process)."""
        f = self._f()
        assert self._checked is not None
        if name not in self._checked:
            dtype, shape = self.schema[name]
            self._checked[name] = dataset(f, name, dtype, shape, path=self.path)
        return self._checked[name]

    def _read(self, name: str, index: int | slice | tuple = slice(None)):
        return read(self._ds(name), index, path=self.path)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
            self._checked = None

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_file"], d["_pid"], d["_checked"] = None, -1, None
        return d


class _LazyAttrs(Mapping):
    """Root attributes read one at a time by name, bounded (:func:`.h5safe.attr`); absent: KeyError."""

    def __init__(self, f: h5py.File, path: Path) -> None:
        self.f, self.path = f, path

    def __getitem__(self, k: str):
        v = attr(self.f, k, path=self.path, default=None)
        if v is None:
            raise KeyError(k)
        return v

    def __iter__(self):
        return iter(())

    def __len__(self) -> int:
        return 0


def check_skeletons(meta: ShardMeta, path: Path) -> ShardMeta:
    """``meta`` if every skeleton it stores builds (a flipped byte in one is a ``ShardFormatError``
    naming it, not a ``TypeError`` later)."""
    from mer_data.skeleton import Skeleton

    for name, text in meta.skeletons.items():
        try:
            Skeleton.from_json(text)
        except (TypeError, ValueError, KeyError, IndexError, AttributeError, RecursionError) as exc:
            raise ShardFormatError(f"the skeleton {name!r} in the metadata is damaged ({type(exc).__name__}: {str(exc)[:200]})",
                                   path=path, element=f"skeleton:{name}", fix="rebuild the shard with mer") from None  # fmt: skip
    return meta


def read_meta(f: h5py.File, path: Path) -> ShardMeta:
    """The :class:`ShardMeta` of an open shard or piece (only the attributes it names are read; its
    skeletons checked)."""
    return check_skeletons(ShardMeta.from_attrs(_LazyAttrs(f, path), path), path)


class Hdf5Shard(ProcessLocalH5):
    """Read access to an HDF5 shard (opened lazily, once per process; every read checked, :mod:`.h5safe`)."""

    format = "hdf5"
    what = "HDF5 shard"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        f = self._f()
        try:
            self.meta = read_meta(f, self.path)
            shapes = self.meta.shapes()
            self.schema = {c: (d, (self.meta.num_rows,) + shapes[c]) for c, d in COLUMNS.items()}
            for c in COLUMNS:
                self._ds(c)
        except BaseException:
            self.close()
            raise

    @property
    def num_rows(self) -> int:
        return self.meta.num_rows

    def column(self, name: str) -> np.ndarray:
        """A whole column (strings as an object array of ``str``)."""
        return self._read(name)

    def row(self, name: str, i: int) -> np.ndarray:
        """Column ``name`` of row ``i`` (one chunk read for the big columns)."""
        return self._read(name, int(i))

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Rows ``start:stop`` of every column (a contiguous slice)."""
        return {c: self._read(c, slice(start, stop)) for c in COLUMNS}
