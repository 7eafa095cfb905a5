"""Reading HDF5 files from strangers: nothing outside the file, nothing unbounded, nothing unchecked.

Every reader of shards, pieces and teacher files opens them here (:func:`open_h5`) and reaches a
dataset only through :func:`dataset`, which refuses, before a byte of data is read:

* links that are not plain (hard) links: external links (another file), soft links (which may
  chain to one), and objects that are not datasets;
* *external storage* (the data are bytes of another file, e.g. ``/etc/passwd``) and *virtual
  datasets* (the data are another file's datasets);
* filters other than what mer writes (deflate, shuffle, LZF, Fletcher-32; szip, n-bit, scale-offset
  and every plugin are refused: no plugin is ever loaded), more than one compression filter, a
  compression filter that is not the outermost (only Fletcher-32 may follow it), LZF parameters
  that announce chunks larger than the dataset's;
* a dtype, rank or shape other than the format's schema, more rows than ``MER_MAX_SHARD_ROWS``,
  a declared size (the product of the shape) past ``MER_MAX_HDF5_DATASET_BYTES``, and chunks whose
  declared size exceeds ``MER_MAX_HDF5_CHUNK_BYTES``.

Reads go through :func:`read`: the bytes of one read, and the decompressed bytes of every chunk it
touches, are capped (``MER_MAX_HDF5_READ_BYTES``), and so is the number of chunks it touches
(``MER_MAX_HDF5_READ_CHUNKS``: HDF5 keeps state per chunk of a read); every chunk it touches must be stored in at most
its declared size, and a compressed chunk is decompressed by mer first with its output capped at
the declared size (deflate: zlib; LZF: h5py's own ``lzf_decompress`` with a bounded buffer), so a
compression bomb is refused instead of expanded (HDF5's filters grow their buffers without bound;
LZF's loop also takes quadratic time). Shuffle and Fletcher-32 do not change sizes. Attributes are
read one by one by name (:func:`attr`), scalar and size-capped (``MER_MAX_HDF5_ATTR_BYTES``); a string
attribute (whose size HDF5 tells only by reading it) is read with the process's data segment
capped a few times that limit above what it holds, so a huge one is refused, not read.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import itertools
import logging
import math
import zlib
from pathlib import Path
from typing import Any, Iterable, Iterator

import h5py
import numpy as np

from mer_data.base.errors import MerError, ShardFormatError
from mer_data.base.limits import limit, too_big
from mer_data.base.safe_io import check_regular_file

log = logging.getLogger(__name__)

__all__ = ["open_h5", "dataset", "read", "attr", "require_values"]

_FILTER_LZF = 32000
_ALLOWED_FILTERS = {
    h5py.h5z.FILTER_DEFLATE: "deflate",
    h5py.h5z.FILTER_SHUFFLE: "shuffle",
    h5py.h5z.FILTER_FLETCHER32: "fletcher32",
    _FILTER_LZF: "lzf",
}
_COMPRESSORS = (h5py.h5z.FILTER_DEFLATE, _FILTER_LZF)
#: slack on a stored chunk over its declared size (deflate's worst-case overhead, headers)
_STORED_SLACK = 1024


def _load_lzf():
    """h5py's own ``lzf_decompress`` (exported by its h5z extension), or None where it is not."""
    try:
        fn = ctypes.CDLL(h5py.h5z.__file__, use_errno=True).lzf_decompress
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_char_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_uint]
    fn.restype = ctypes.c_uint
    return fn


_LZF = _load_lzf()


def _lzf_size(raw: bytes, cap: int) -> int | None:
    """The decompressed size of an LZF stream if it is valid and at most ``cap`` bytes; None if it is
    larger; -1 if it is not valid LZF. Decompressed into a buffer of ``cap`` bytes, never more."""
    if _LZF is not None:
        out = ctypes.create_string_buffer(max(cap, 1))
        ctypes.set_errno(0)
        n = _LZF(raw, len(raw), out, cap)
        if n:
            return int(n)
        err = ctypes.get_errno()
        return None if err == errno.E2BIG else (0 if not raw else -1)
    ip, op, n = 0, 0, len(raw)  # no h5py symbol: walk the tokens (liblzf's format), stopping past the cap
    while ip < n:
        ctrl = raw[ip]
        ip += 1
        if ctrl < 32:
            ip += ctrl + 1
            op += ctrl + 1
            if ip > n:
                return -1
        else:
            length = ctrl >> 5
            if length == 7:
                if ip >= n:
                    return -1
                length += raw[ip]
                ip += 1
            if ip >= n or ((ctrl & 0x1F) << 8) + raw[ip] + 1 > op:
                return -1
            ip += 1
            op += length + 2
        if op > cap:
            return None
    return op


def open_h5(path: str | Path, error: type[MerError] = ShardFormatError, *, what: str = "HDF5 file") -> h5py.File:
    """Open ``path`` read-only (a regular file; symbolic links to one are followed); else ``error``."""
    path = Path(path)
    check_regular_file(path, error)
    try:
        return h5py.File(path, "r")
    except (OSError, ValueError) as exc:
        raise error(f"cannot read the {what} ({exc})", path=path, fix="rebuild it, or download it again") from None


def _fail(path: Path, name: str, message: str, error: type[MerError], fix: str | None = None) -> MerError:
    return error(message, path=path, element=f"dataset {name!r}",
                 fix=fix or "mer reads only files it wrote itself; rebuild the file with mer")  # fmt: skip


def dataset(
    f: h5py.File,
    name: str,
    dtype: str,
    shape: tuple[int | None, ...],
    *,
    path: str | Path | None = None,
    error: type[MerError] = ShardFormatError,
) -> h5py.Dataset:
    """The top-level dataset ``name`` of ``f`` after every check of the module docstring.

    Args:
        dtype: numpy dtype string, or ``"str"`` for variable-length UTF-8 strings.
        shape: the expected shape; ``None`` entries are free (the row count, still capped).
    """
    p = Path(path if path is not None else f.filename)
    link = f.get(name, getlink=True)
    if link is None:
        raise _fail(p, name, "missing", error)
    if isinstance(link, h5py.ExternalLink):
        raise _fail(p, name, f"is an external link to {link.filename!r}:{link.path}; mer reads nothing outside the file",
                    error)  # fmt: skip
    if isinstance(link, h5py.SoftLink):
        raise _fail(p, name, f"is a soft link (to {link.path!r}); mer reads only plain datasets", error)
    if not isinstance(link, h5py.HardLink):
        raise _fail(p, name, f"is a link of an unknown kind ({type(link).__name__})", error)
    try:
        d = f[name]
    except (KeyError, OSError, ValueError) as exc:
        raise _fail(p, name, f"cannot be opened ({exc})", error) from None
    if not isinstance(d, h5py.Dataset):
        raise _fail(p, name, f"is a {type(d).__name__}, not a dataset", error)
    if d.is_virtual:
        raise _fail(p, name, "is a virtual dataset (its data live in other files); mer reads nothing outside the file", error)
    dcpl = d.id.get_create_plist()
    if dcpl.get_external_count() > 0:
        ext = dcpl.get_external(0)[0]
        ext = ext.decode(errors="replace") if isinstance(ext, bytes) else str(ext)
        raise _fail(p, name, f"has external storage (its bytes are read from {ext!r}); mer reads nothing outside the file",
                    error)  # fmt: skip
    filters = [dcpl.get_filter(i) for i in range(dcpl.get_nfilters())]
    codes = [f[0] for f in filters]
    for code in codes:
        if code not in _ALLOWED_FILTERS:
            raise _fail(p, name, f"uses HDF5 filter {code}; mer reads only {', '.join(sorted(_ALLOWED_FILTERS.values()))}",
                        error)  # fmt: skip
    comp = [i for i, c in enumerate(codes) if c in _COMPRESSORS]
    if len(comp) > 1:
        raise _fail(p, name, "uses two compression filters; mer writes one", error)
    if comp and codes[comp[0] + 1 :] not in ([], [h5py.h5z.FILTER_FLETCHER32]):
        raise _fail(p, name, f"applies {_ALLOWED_FILTERS[codes[comp[0] + 1]]} after compressing; mer checks compressed "
                    "chunks only when compression is the outermost filter", error)  # fmt: skip
    if dtype == "str":
        info = h5py.check_string_dtype(d.dtype)
        if info is None or info.length is not None:
            raise _fail(p, name, f"has dtype {d.dtype}, expected variable-length strings", error)
        itemsize = 16
    else:
        want = np.dtype(dtype)
        if d.dtype != want:
            raise _fail(p, name, f"has dtype {d.dtype}, expected {want}", error)
        itemsize = want.itemsize
    if len(d.shape) != len(shape) or any(e is not None and e != s for e, s in zip(shape, d.shape)):
        shown = tuple("N" if e is None else e for e in shape)
        raise _fail(p, name, f"has shape {d.shape}, expected {shown}", error)
    if d.shape and d.shape[0] > limit("MER_MAX_SHARD_ROWS"):
        msg, fix = too_big("MER_MAX_SHARD_ROWS", d.shape[0])
        raise _fail(p, name, msg, error, fix)
    total = math.prod(d.shape) * itemsize
    if total > limit("MER_MAX_HDF5_DATASET_BYTES"):
        msg, fix = too_big("MER_MAX_HDF5_DATASET_BYTES", total)
        raise _fail(p, name, msg, error, fix)
    if d.chunks is not None:
        cbytes = math.prod(d.chunks) * itemsize
        if cbytes > limit("MER_MAX_HDF5_CHUNK_BYTES"):
            msg, fix = too_big("MER_MAX_HDF5_CHUNK_BYTES", cbytes)
            raise _fail(p, name, msg, error, fix)
        for code, _, cd, _ in filters:
            if code == _FILTER_LZF and len(cd) >= 3 and cd[2] > cbytes:  # its first buffer: cd[2] bytes
                raise _fail(p, name, f"its LZF parameters announce chunks of {cd[2]:,} bytes, more than the declared "
                            f"{cbytes:,}", error)  # fmt: skip
    return d


def _chunk_origins(d: h5py.Dataset, chunk_rows: Iterable[int]) -> Iterator[tuple[int, ...]]:
    """Offsets of the chunks of the chunk rows ``chunk_rows`` (every chunk along the other axes)."""
    chunks = d.chunks
    grids = [[r * chunks[0] for r in chunk_rows]]
    grids += [range(0, n, c) for n, c in zip(d.shape[1:], chunks[1:])]
    return itertools.product(*grids)


def _checked_rows(d: h5py.Dataset) -> np.ndarray:
    """Which chunk rows of ``d`` were checked already (one flag per row of chunks, kept on the open
    dataset: a chunk is decompressed by mer once, not at every read of it)."""
    flags = getattr(d, "_mer_checked", None)
    if flags is None:
        flags = np.zeros(-(-d.shape[0] // d.chunks[0]) if d.shape else 1, bool)  # untouched pages stay unallocated
        try:
            d._mer_checked = flags
        except AttributeError:
            pass
    return flags


def _chunks_touched(d: h5py.Dataset, start: int, stop: int) -> int:
    """How many chunks a read of rows ``start:stop`` (every other index whole) touches."""
    if d.chunks is None or stop <= start:
        return 0
    rows = (stop - 1) // d.chunks[0] - start // d.chunks[0] + 1
    return rows * math.prod(-(-n // c) for n, c in zip(d.shape[1:], d.chunks[1:]))


def _check_chunks(d: h5py.Dataset, start: int, stop: int, p: Path, error: type[MerError]) -> None:
    """Every stored chunk of rows ``start:stop`` is at most its declared size, and a compressed chunk
    decompresses to at most that (checked by mer, with the output capped, before HDF5 sees it)."""
    if d.chunks is None or stop <= start:
        return
    dcpl = d.id.get_create_plist()
    codes = [dcpl.get_filter(i)[0] for i in range(dcpl.get_nfilters())]
    if not codes:
        return
    done = _checked_rows(d)
    first, last = start // d.chunks[0], (stop - 1) // d.chunks[0]
    todo = [r for r in range(first, last + 1) if not done[r]]
    if not todo:
        return
    itemsize = 16 if h5py.check_string_dtype(d.dtype) is not None else d.dtype.itemsize
    cbytes = math.prod(d.chunks) * itemsize
    at = next((i for i, c in enumerate(codes) if c in _COMPRESSORS), -1)  # dataset(): at most one, outermost
    name = d.name.lstrip("/")
    for origin in _chunk_origins(d, todo):
        try:
            info = d.id.get_chunk_info_by_coord(origin)
        except (ValueError, RuntimeError, OSError):
            continue
        size = getattr(info, "size", 0) or 0
        if size == 0:
            continue  # not allocated: the fill value
        if size > cbytes + cbytes // 100 + _STORED_SLACK:
            raise _fail(p, name, f"a chunk at {origin} is stored in {size:,} bytes, more than its declared "
                        f"{cbytes:,} bytes (damaged or hostile)", error)  # fmt: skip
        mask, raw = d.id.read_direct_chunk(origin)
        fletcher = codes[-1] == h5py.h5z.FILTER_FLETCHER32 and not mask & (1 << (len(codes) - 1))
        if fletcher:  # HDF5 reads its 4 bytes from the chunk's end without checking there are 4
            if len(raw) < 4:
                raise _fail(p, name, f"a chunk at {origin} is stored in {len(raw)} bytes, too few for its checksum", error)
            raw = raw[:-4]
        if at < 0 or mask & (1 << at):  # not compressed: stored as is, whole
            if len(raw) != cbytes:
                raise _fail(p, name, f"a chunk at {origin} is stored in {len(raw):,} bytes, not its {cbytes:,} (damaged or "
                            "hostile)", error)  # fmt: skip
            continue
        if codes[at] == h5py.h5z.FILTER_DEFLATE:
            z = zlib.decompressobj()
            try:
                out = z.decompress(raw, cbytes + 1)
            except zlib.error as exc:
                raise _fail(p, name, f"a chunk at {origin} is not valid deflate data ({exc})", error) from None
            n = None if len(out) > cbytes or z.unconsumed_tail else len(out) if z.eof else -1
        else:
            n = _lzf_size(raw, cbytes)
        if n is None:
            raise _fail(p, name, f"a chunk at {origin} inflates to more than its declared {cbytes:,} bytes "
                        "(a compression bomb)", error)  # fmt: skip
        if n != cbytes:
            what = "is not valid compressed data" if n == -1 else f"decompresses to {n:,} bytes, not its {cbytes:,}"
            raise _fail(p, name, f"a chunk at {origin} {what} (damaged or hostile)", error)
    done[todo] = True


def read(
    d: h5py.Dataset,
    index: int | slice | tuple = slice(None),
    *,
    path: str | Path | None = None,
    error: type[MerError] = ShardFormatError,
) -> Any:
    """``d[index]`` (strings decoded), with the bytes of the read capped and its chunks checked first.

    ``index``: a row, a slice of rows, or a tuple whose first entry is a row (the rest are taken
    as the whole extent for the size bound).
    """
    p = Path(path if path is not None else d.file.filename)
    first = index[0] if isinstance(index, tuple) else index
    n = d.shape[0] if d.shape else 1
    if isinstance(first, slice):
        start, stop, _ = first.indices(n)
    else:
        row = int(first)
        if not 0 <= row < n:
            raise _fail(p, d.name.lstrip("/"), f"row {row} is out of range ({n} rows)", error)
        start, stop = row, row + 1
    # a string costs HDF5 16 bytes and Python ~64 (its object): the read is capped at what it will hold
    itemsize = 64 if h5py.check_string_dtype(d.dtype) is not None else d.dtype.itemsize
    nbytes = max(stop - start, 0) * math.prod(d.shape[1:]) * itemsize
    if d.chunks is not None:  # what HDF5 decompresses: every chunk the read touches, whole
        touched = _chunks_touched(d, start, stop)
        if touched > limit("MER_MAX_HDF5_READ_CHUNKS"):  # HDF5 keeps ~1 kB of state per chunk of a read
            msg, fix = too_big("MER_MAX_HDF5_READ_CHUNKS", touched)
            raise _fail(p, d.name.lstrip("/"), msg, error, fix)
        nbytes = max(nbytes, touched * math.prod(d.chunks) * itemsize)
    if nbytes > limit("MER_MAX_HDF5_READ_BYTES"):
        msg, fix = too_big("MER_MAX_HDF5_READ_BYTES", nbytes)
        raise _fail(p, d.name.lstrip("/"), msg, error, fix)
    _check_chunks(d, start, stop, p, error)
    try:
        if h5py.check_string_dtype(d.dtype) is not None:
            return d.asstr()[index]
        return d[index]
    except (OSError, ValueError, IndexError, TypeError, UnicodeDecodeError) as exc:
        raise _fail(p, d.name.lstrip("/"), f"cannot be read ({type(exc).__name__}: {exc})", error) from None


@contextlib.contextmanager
def _memory_headroom(nbytes: int) -> Iterator[None]:
    """Within the block, allocations past ``nbytes`` more than the process holds fail (Linux ``RLIMIT_DATA``,
    restored after): HDF5 reads a variable-length string attribute whole (about 5x its size in
    buffers) before its size can be known, so a huge one fails to allocate instead of being read."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
        with open("/proc/self/status") as fh:
            held = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmData:"))
    except (ImportError, OSError, StopIteration, ValueError, AttributeError):
        yield  # not Linux: the size is checked after the read only
        return
    want = held + nbytes
    inf = resource.RLIM_INFINITY
    if (soft != inf and soft <= want) or (hard != inf and want > hard):
        yield  # already tighter than this
        return
    resource.setrlimit(resource.RLIMIT_DATA, (want, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


def attr(obj: h5py.File | h5py.Group, name: str, *, path: str | Path | None = None, error: type[MerError] = ShardFormatError,
         default: Any = KeyError) -> Any:  # fmt: skip
    """One scalar attribute (str, int, float or bool), its size capped; ``default`` if absent (else ``error``)."""
    p = Path(path if path is not None else obj.file.filename)
    if name not in obj.attrs:
        if default is KeyError:
            raise error(f"attribute {name!r} is missing", path=p, element=f"attribute {name!r}")
        return default
    cap = limit("MER_MAX_HDF5_ATTR_BYTES")
    try:
        aid = obj.attrs.get_id(name)
        if aid.shape not in ((), None):
            raise error(f"attribute {name!r} has shape {aid.shape}, expected a scalar", path=p, element=f"attribute {name!r}")
        if aid.get_storage_size() > cap:
            msg, fix = too_big("MER_MAX_HDF5_ATTR_BYTES", aid.get_storage_size())
            raise error(msg, path=p, element=f"attribute {name!r}", fix=fix)
        dt = aid.dtype
        if h5py.check_string_dtype(dt) is None and dt.kind not in "iufb":
            raise error(f"attribute {name!r} has dtype {dt}, expected a string or a number", path=p,
                        element=f"attribute {name!r}")  # fmt: skip
        try:
            with _memory_headroom(6 * cap + (16 << 20)):
                v = obj.attrs[name]
        except (OSError, MemoryError, RuntimeError) as exc:
            if "alloc" not in str(exc).lower() and not isinstance(exc, MemoryError):
                raise
            msg, fix = too_big("MER_MAX_HDF5_ATTR_BYTES", f"over {cap:,}")
            raise error(msg, path=p, element=f"attribute {name!r}", fix=fix) from None
    except MerError:
        raise
    except (OSError, ValueError, TypeError, KeyError, UnicodeDecodeError, RuntimeError) as exc:
        raise error(f"attribute {name!r} cannot be read ({type(exc).__name__}: {exc})", path=p,
                    element=f"attribute {name!r}") from None  # fmt: skip
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bytes):
        try:
            v = v.decode("utf-8")
        except UnicodeDecodeError:
            raise error(f"attribute {name!r} is not UTF-8 text", path=p, element=f"attribute {name!r}") from None
    if isinstance(v, str) and len(v) > cap:  # variable-length strings: their size is known only once read
        msg, fix = too_big("MER_MAX_HDF5_ATTR_BYTES", len(v))
        raise error(msg, path=p, element=f"attribute {name!r}", fix=fix)
    return v


def require_values(a: np.ndarray, name: str, *, path: str | Path, row: int | None = None, low: float | None = None,
                   high: float | None = None, error: type[MerError] = ShardFormatError) -> np.ndarray:  # fmt: skip
    """``a`` if every value is finite and within ``[low, high]``; else ``error`` naming the first bad one."""
    a = np.asarray(a)
    bad = ~np.isfinite(a) if a.dtype.kind == "f" else np.zeros(a.shape, bool)
    if low is not None:
        bad |= a < low
    if high is not None:
        bad |= a > high
    if bad.any():
        at = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"row {row}, " if row is not None else ""
        rng = f" (allowed {low:g} .. {high:g})" if low is not None and high is not None else ""
        raise error(f"{int(bad.sum())} value(s) of {name!r} are not finite or out of range{rng}: {a[at]!r} at "
                    f"{where}index {at}", path=path, element=f"dataset {name!r}",
                    fix="the file is damaged or hostile; rebuild it with mer")  # fmt: skip
    return a
