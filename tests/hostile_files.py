"""Hostile HDF5 pieces for the tests and ``tools/hostile_inputs.py``: LZF streams (and bombs), a
shard's ``pos`` re-made with any filter pipeline and raw chunk bytes, teacher files with edits."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import h5py
import numpy as np

__all__ = ["lzf_compress", "lzf_bomb", "replace_pos", "write_teacher"]


def _lzf(fn: str):
    """A function of the LZF library h5py bundles (``lzf_compress`` / ``lzf_decompress``)."""
    import ctypes

    f = getattr(ctypes.CDLL(h5py.h5z.__file__), fn)
    f.argtypes = [ctypes.c_char_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_uint]
    f.restype = ctypes.c_uint
    return f


def lzf_compress(data: bytes) -> bytes:
    """``data`` as an LZF stream (the one h5py's LZF filter reads)."""
    import ctypes

    out = ctypes.create_string_buffer(len(data) + 64)
    n = _lzf("lzf_compress")(data, len(data), out, len(out))
    assert n, "incompressible"
    return out.raw[:n]


def lzf_bomb(n_out: int) -> bytes:
    """An LZF stream of ``n_out`` zero bytes at LZF's best ratio (3 bytes -> 264)."""
    return b"\x00\x00" + b"\xe0\xff\x00" * (-(-(n_out - 1) // 264))


def replace_pos(f: h5py.File, pipeline: tuple[str, ...] | list[str], payload: bytes | None, chunk_rows: int = 1) -> None:
    """Replace dataset ``pos`` of the open shard ``f`` by one with the filters of ``pipeline`` (in
    order: lzf, gzip, shuffle, fletcher32, scaleoffset, nbit), chunks of ``chunk_rows`` rows (more
    than it has: it is extensible) and ``payload`` as the stored bytes of its first chunk (None:
    nothing stored)."""
    shape = f["pos"].shape
    del f["pos"]
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_chunk((chunk_rows,) + shape[1:])
    for name in pipeline:
        if name == "lzf":
            dcpl.set_filter(32000, h5py.h5z.FLAG_OPTIONAL, (4, 261, chunk_rows * int(np.prod(shape[1:])) * 4))
        elif name == "gzip":
            dcpl.set_deflate(4)
        elif name == "shuffle":
            dcpl.set_shuffle()
        elif name == "fletcher32":
            dcpl.set_fletcher32()
        elif name == "scaleoffset":
            dcpl.set_scaleoffset(h5py.h5z.SO_FLOAT_DSCALE, 3)
        elif name == "nbit":
            dcpl.set_filter(h5py.h5z.FILTER_NBIT, h5py.h5z.FLAG_OPTIONAL, ())
        else:
            raise ValueError(f"unknown filter {name!r}")
    space = h5py.h5s.create_simple(shape, (h5py.h5s.UNLIMITED,) + shape[1:])
    d = h5py.h5d.create(f.id, b"pos", h5py.h5t.IEEE_F32LE, space, dcpl=dcpl)
    if payload is not None:
        d.write_direct_chunk((0,) * len(shape), payload, 0)


def write_teacher(shard: Path, build: str | None = None, **edits: Callable[[np.ndarray], np.ndarray | None]) -> Path:
    """A complete teacher file of ``shard`` (zeros, every sample solved) for build ``build`` (default:
    the shard's), with ``edits`` applied as name -> fn(array), which edits in place or returns the new array."""
    from mer_data.shards import open_shard
    from mer_data.shards.teacher import TEACHER_FORMAT, TEACHER_VERSION, teacher_path

    f = open_shard(shard)
    meta = f.meta
    f.close()
    path = teacher_path(shard)
    path.parent.mkdir(exist_ok=True)
    R, S, T, J = meta.num_rows, meta.samples_per_row, meta.window, meta.max_target_nodes
    schema = {"q": ("<f4", (R, S, T, J)), "base_pos": ("<f4", (R, S, T, 3)), "base_rotvec": ("<f4", (R, S, T, 3)),
              "energy": ("<f4", (R, S)), "solved": ("|b1", (R, S))}  # fmt: skip
    with h5py.File(path, "w") as h:
        for name, (dtype, shape) in schema.items():
            a = np.ones(shape, bool) if name == "solved" else np.zeros(shape, dtype)
            if name in edits:
                out = edits[name](a)
                a = a if out is None else out
            h.create_dataset(name, data=a)
        h.attrs.update({"format": TEACHER_FORMAT, "format_version": TEACHER_VERSION, "shard_build_id": build or meta.build_id,
                        "solver": "{}", "seconds": 1.0, "frames": 1, "rows": R})  # fmt: skip
    return path
