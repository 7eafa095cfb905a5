"""MCAP shards: the same content as HDF5, viewable in Foxglove.

* ``/mer/windows`` (schema ``mer.ShardWindow``, JSON, every field typed): one message per window
  (row) with every column; numeric arrays are ``{"dtype", "shape", "base64"}`` of their exact
  little-endian bytes, so reading back is lossless.
* ``/tf`` (``foxglove.FrameTransforms``): an animation of the first ``preview`` windows of every
  clip (all windows with ``preview < 0``), laid one after another on the timeline, for Foxglove's 3D
  panel, in TF frames named after the robot's links as the retarget MCAP names them
  (:func:`.foxglove.link_frames`: the registered robot's description links where the shard's
  skeleton is that robot's, else its nodes' links); ``/skeleton`` (``foxglove.SceneUpdate``, once):
  mer's stick figure on those frames; for a registered robot also ``/robot`` (its collision
  shapes, once) and, for a URDF robot, ``/robot_description`` (the URDF, once: Foxglove's URDF layer
  draws its meshes on the link frames). The foxglove.* schemas are Foxglove's official ones
  (:mod:`.foxglove`).
* metadata record ``mer.shard``: :meth:`ShardMeta.to_attrs`, every value a string.

Chunks are zstd-compressed. Reading loads the file's windows into memory (use HDF5 for large-scale
random access during training). Reading is bounded and checked (:func:`read_mcap`): every CRC is
validated, chunks are decompressed by mer with the output capped at their declared (capped) size,
and every window message is checked against the schema before it is decoded.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import struct
import zlib
from pathlib import Path
from typing import Any, Iterator

import lz4.frame
import numpy as np
import zstandard
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, McapRecord, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from mer_data.base.errors import ShardFormatError
from mer_data.base.limits import limit, too_big
from mer_data.base.safe_io import check_regular_file
from mer_data.skeleton import Skeleton

from .foxglove import (
    DESCRIPTION_SCHEMA,
    FRAME_TRANSFORMS_SCHEMA,
    SCENE_UPDATE_SCHEMA,
    description_message,
    motion_frames,
    registered_robot,
    robot_scene,
    skeleton_scene,
    tf_messages,
)
from .schema import COLUMNS, ShardMeta, column_shapes

__all__ = ["McapShardWriter", "McapShard", "WINDOW_TOPIC", "TF_TOPIC", "SCENE_TOPIC", "ROBOT_TOPIC", "DESCRIPTION_TOPIC"]

WINDOW_TOPIC, TF_TOPIC, SCENE_TOPIC = "/mer/windows", "/tf", "/skeleton"
ROBOT_TOPIC, DESCRIPTION_TOPIC = "/robot", "/robot_description"
_META_NAME = "mer.shard"


def _window_schema() -> bytes:
    """JSON schema of a ``/mer/windows`` message, fully typed so that viewers parse it: ``row``,
    the string columns, and per array column ``{dtype (const), shape (rank fixed), base64}``."""
    rank = {c: len(s) for c, s in column_shapes(1, 1, 1, 1).items()}
    props: dict[str, dict] = {"row": {"type": "integer", "minimum": 0, "description": "row (window) index in the shard"}}
    for c, dtype in COLUMNS.items():
        if dtype == "str":
            props[c] = {"type": "string"}
            continue
        props[c] = {
            "type": "object",
            "description": f"numpy array, dtype {dtype}, rank {rank[c]}: the C-order bytes, base64",
            "properties": {
                "dtype": {"type": "string", "const": dtype},
                "shape": {"type": "array", "items": {"type": "integer", "minimum": 0}, "minItems": rank[c], "maxItems": rank[c]},
                "base64": {"type": "string", "contentEncoding": "base64"},
            },
            "required": ["dtype", "shape", "base64"],
            "additionalProperties": False,
        }
    schema = {
        "title": "mer.ShardWindow",
        "description": "One window of a mer training shard (mer_data.shards.schema); arrays are base64 little-endian bytes.",
        "type": "object",
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }
    return json.dumps(schema).encode()


_WINDOW_SCHEMA = _window_schema()


def _enc(a: np.ndarray) -> dict:
    a = np.asarray(a)  # (not ascontiguousarray: it turns 0-d arrays into 1-d ones)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "base64": base64.b64encode(a.tobytes(order="C")).decode()}


def _dec(d: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(d["base64"]), dtype=np.dtype(d["dtype"])).reshape(d["shape"])


class McapShardWriter:
    """Write a shard as MCAP (see module docstring). Call :meth:`close` with the final metadata."""

    def __init__(self, path: str | Path, meta: ShardMeta, *, preview: int = 1) -> None:
        self.path = Path(path)
        self.meta = meta
        self.shapes = meta.shapes()
        self.preview = preview
        self._stream = open(self.path, "xb")  # exclusive: never through a planted link
        self.w = Writer(self._stream, compression=CompressionType.ZSTD, enable_data_crcs=True)  # the metadata record CRC-covered too
        self.w.start(profile="", library="mer")
        sid = self.w.register_schema("mer.ShardWindow", "jsonschema", _WINDOW_SCHEMA)
        self.ch_win = self.w.register_channel(WINDOW_TOPIC, "json", sid)
        sid = self.w.register_schema("foxglove.FrameTransforms", "jsonschema", FRAME_TRANSFORMS_SCHEMA)
        self.ch_tf = self.w.register_channel(TF_TOPIC, "json", sid)
        sid = self.w.register_schema("foxglove.SceneUpdate", "jsonschema", SCENE_UPDATE_SCHEMA)
        self.ch_scene = self.w.register_channel(SCENE_TOPIC, "json", sid)
        self.skel = Skeleton.from_json(meta.skeletons[meta.robot])
        self.robot = registered_robot(self.skel, meta.robot)  # None: the skeleton's nodes' links are the frames
        self.w.add_message(self.ch_scene, 0, skeleton_scene(self.skel, 0), 0)
        if self.robot is not None:
            self.w.add_message(self.w.register_channel(ROBOT_TOPIC, "json", sid), 0, robot_scene(self.robot, 0), 0)
            urdf = description_message(self.robot)
            if urdf is not None:
                sid = self.w.register_schema("std_msgs/String", "jsonschema", DESCRIPTION_SCHEMA)
                self.w.add_message(self.w.register_channel(DESCRIPTION_TOPIC, "json", sid), 0, urdf, 0)
        self.rows = 0
        self.t_ns = 0  # start of the next animation slot
        self._clip, self._shown = None, 0
        self._slot_ns = int(round(meta.window * 1e9 / meta.fps))

    def append(self, rows: dict[str, np.ndarray]) -> None:
        n = len(rows["start_frame"])
        for i in range(n):
            clip = str(rows["clip"][i])
            if clip != self._clip:
                self._clip, self._shown = clip, 0
            animate = self.preview < 0 or self._shown < self.preview
            msg = {"row": self.rows}
            for c, dtype in COLUMNS.items():
                v = rows[c][i]
                if dtype == "str":
                    msg[c] = str(v)
                else:
                    a = np.asarray(v, dtype=dtype)
                    if a.shape != self.shapes[c]:
                        raise ValueError(f"column {c}: row shape {a.shape}, expected {self.shapes[c]}")
                    msg[c] = _enc(a)
            t = self.t_ns
            self.w.add_message(self.ch_win, t, json.dumps(msg).encode(), t, sequence=self.rows)
            if animate:
                pos, rv, q = rows["pos"][i], rows["base_rotvec"][i], rows["q"][i]
                frames = motion_frames(self.skel, self.robot, pos[:, 0], rv, q)
                for ns, data in tf_messages(frames, self.meta.fps, t):
                    self.w.add_message(self.ch_tf, ns, data, ns)
                self.t_ns += self._slot_ns
                self._shown += 1
            self.rows += 1

    def close(self, meta: ShardMeta | None = None) -> None:
        meta = meta or self.meta
        meta.num_rows = self.rows
        self.w.add_metadata(_META_NAME, {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.to_attrs().items()})
        self.w.finish()
        self._stream.flush()
        self._stream.close()

    def abort(self) -> None:
        try:
            self._stream.close()
        finally:
            self.path.unlink(missing_ok=True)


class _BoundedFile:
    """A file read by the MCAP stream reader: a read past the end (a length field from a damaged or
    hostile file) is refused before anything is allocated for it."""

    def __init__(self, fh, size: int, path: Path) -> None:
        self.fh, self.left, self.path = fh, size, path

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or n > self.left:
            raise ShardFormatError(f"a record claims {n:,} bytes, past the end of the file ({self.left:,} bytes left)",
                                   path=self.path, fix="the file is damaged or hostile; rebuild it with mer")  # fmt: skip
        data = self.fh.read(n)
        self.left -= len(data)
        return data


def _inflate(chunk: Chunk, path: Path) -> bytes:
    """The chunk's records, decompressed with the output capped at its declared size (itself capped),
    and checked against its CRC."""
    size = chunk.uncompressed_size
    if size > limit("MER_MAX_MCAP_CHUNK_BYTES"):
        msg, fix = too_big("MER_MAX_MCAP_CHUNK_BYTES", size)
        raise ShardFormatError(msg, path=path, element="MCAP chunk", fix=fix)
    if chunk.compression == "zstd":
        window = 1 << max(20, min(27, max(size, 1).bit_length()))
        dec = zstandard.ZstdDecompressor(max_window_size=window)
        try:
            with dec.stream_reader(io.BytesIO(chunk.data), read_across_frames=True) as r:
                parts, got = [], 0
                while got <= size:
                    b = r.read(size + 1 - got)
                    if not b:
                        break
                    parts.append(b)
                    got += len(b)
            data = b"".join(parts)
        except zstandard.ZstdError as exc:
            raise ShardFormatError(f"an MCAP chunk is not valid zstd data ({exc})", path=path, element="MCAP chunk") from None
    elif chunk.compression == "lz4":
        try:
            d = lz4.frame.LZ4FrameDecompressor()
            data = d.decompress(chunk.data, max_length=size + 1)
        except RuntimeError as exc:
            raise ShardFormatError(f"an MCAP chunk is not valid lz4 data ({exc})", path=path, element="MCAP chunk") from None
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ShardFormatError(f"an MCAP chunk uses compression {chunk.compression!r}; mer reads zstd, lz4 and none",
                               path=path, element="MCAP chunk")  # fmt: skip
    if len(data) != size:
        raise ShardFormatError(f"an MCAP chunk decompresses to {'more than ' if len(data) > size else ''}{len(data):,} bytes, "
                               f"its header says {size:,}", path=path, element="MCAP chunk",
                               fix="the file is damaged or hostile; rebuild it with mer")  # fmt: skip
    if chunk.uncompressed_crc == 0:
        raise ShardFormatError("an MCAP chunk carries no CRC; mer reads only checked chunks", path=path, element="MCAP chunk")
    if zlib.crc32(data) != chunk.uncompressed_crc:
        raise ShardFormatError("an MCAP chunk fails its CRC check (altered or damaged)", path=path, element="MCAP chunk",
                               fix="download or rebuild the file")  # fmt: skip
    return data


def read_mcap(path: Path, *, messages: bool = True) -> Iterator[McapRecord]:
    """Every record of an MCAP file, bounded and checked: CRCs validated (chunks, data section),
    chunk sizes capped before decompression (``MER_MAX_MCAP_CHUNK_BYTES``, ``MER_MAX_MCAP_BYTES``),
    records counted (``MER_MAX_MCAP_RECORDS``). ``messages=False`` skips chunks undecompressed."""
    st = check_regular_file(path, ShardFormatError)
    n, total = 0, 0
    cap_n, cap_total = limit("MER_MAX_MCAP_RECORDS"), limit("MER_MAX_MCAP_BYTES")

    def count() -> None:
        nonlocal n
        n += 1
        if n > cap_n:
            msg, fix = too_big("MER_MAX_MCAP_RECORDS", f"over {cap_n:,}")
            raise ShardFormatError(msg, path=path, fix=fix)

    with open(path, "rb") as fh:
        reader = StreamReader(_BoundedFile(fh, st.st_size, path), emit_chunks=True, validate_crcs=True,
                              record_size_limit=st.st_size)  # fmt: skip
        for rec in reader.records:
            count()
            if not isinstance(rec, Chunk):
                yield rec
                continue
            if not messages:
                continue
            total += rec.uncompressed_size
            if total > cap_total:
                msg, fix = too_big("MER_MAX_MCAP_BYTES", f"over {cap_total:,}")
                raise ShardFormatError(msg, path=path, fix=fix)
            data = _inflate(rec, path)
            plain = Chunk(compression="", data=data, message_end_time=rec.message_end_time,
                          message_start_time=rec.message_start_time, uncompressed_crc=0, uncompressed_size=len(data))  # fmt: skip
            for inner in breakup_chunk(plain):
                count()
                yield inner


_ERRORS = (McapError, OSError, ValueError, KeyError, IndexError, TypeError, EOFError, struct.error, RecursionError,
           UnicodeDecodeError, binascii.Error)  # fmt: skip


class McapShard:
    """Read access to an MCAP shard; the windows are decoded into memory on first use (bounded, checked)."""

    format = "mcap"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        metas = []
        try:
            for rec in read_mcap(self.path, messages=False):
                if isinstance(rec, Metadata) and rec.name == _META_NAME:
                    metas.append(rec)
        except _ERRORS as exc:
            raise ShardFormatError(f"cannot read the MCAP shard ({type(exc).__name__}: {exc})", path=self.path,
                                   fix="rebuild it") from None  # fmt: skip
        if not metas:
            raise ShardFormatError("not a mer shard (no 'mer.shard' metadata record)", path=self.path)
        from .hdf5_io import check_skeletons  # the metadata record has no CRC of its own: check what it holds

        self.meta = check_skeletons(ShardMeta.from_attrs(dict(metas[0].metadata), self.path), self.path)
        self._cols: dict[str, np.ndarray] | None = None

    @property
    def num_rows(self) -> int:
        return self.meta.num_rows

    def _decode(self, d: Any, shapes: dict[str, tuple[int, ...]]) -> tuple[int, dict[str, Any]]:
        """(row, column values) of one ``/mer/windows`` message, every field checked against the schema."""
        if not isinstance(d, dict) or not isinstance(d.get("row"), int) or not 0 <= d["row"] < self.meta.num_rows:
            raise ShardFormatError(f"a window message has no valid row (0..{self.meta.num_rows - 1})", path=self.path,
                                   element=WINDOW_TOPIC)  # fmt: skip
        out: dict[str, Any] = {}
        for c, dtype in COLUMNS.items():
            v = d.get(c)
            where = f"{WINDOW_TOPIC} row {d['row']}, column {c!r}"
            if dtype == "str":
                if not isinstance(v, str) or len(v) > 4096:
                    raise ShardFormatError("is not a string (of at most 4096 characters)", path=self.path, element=where)
                out[c] = v
                continue
            want = np.dtype(dtype)
            nbytes = int(np.prod(shapes[c], dtype=np.int64)) * want.itemsize
            if not (isinstance(v, dict) and v.get("dtype") == want.str and v.get("shape") == list(shapes[c])
                    and isinstance(v.get("base64"), str) and len(v["base64"]) == 4 * ((nbytes + 2) // 3)):  # fmt: skip
                raise ShardFormatError(f"is not an array of dtype {want.str} and shape {list(shapes[c])}", path=self.path,
                                       element=where)  # fmt: skip
            out[c] = np.frombuffer(base64.b64decode(v["base64"], validate=True), dtype=want).reshape(shapes[c])
        return d["row"], out

    def _load(self) -> dict[str, np.ndarray]:
        if self._cols is not None:
            return self._cols
        shapes = self.meta.shapes()
        n = self.meta.num_rows
        cols = {c: (np.empty(n, object) if d == "str" else np.empty((n,) + shapes[c], d)) for c, d in COLUMNS.items()}
        seen = np.zeros(n, bool)
        topics: dict[int, str] = {}
        try:
            for rec in read_mcap(self.path):
                if isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Message) and topics.get(rec.channel_id) == WINDOW_TOPIC:
                    r, vals = self._decode(json.loads(rec.data), shapes)
                    for c, v in vals.items():
                        cols[c][r] = v
                    seen[r] = True
        except ShardFormatError:
            raise
        except _ERRORS as exc:
            raise ShardFormatError(f"damaged MCAP shard ({type(exc).__name__}: {exc})", path=self.path) from None
        if not seen.all():
            raise ShardFormatError(f"damaged MCAP shard: {int((~seen).sum())} of {n} windows missing", path=self.path)
        self._cols = cols
        return cols

    def column(self, name: str) -> np.ndarray:
        return self._load()[name]

    def row(self, name: str, i: int) -> np.ndarray:
        return self._load()[name][i]

    def rows(self, start: int, stop: int) -> dict[str, np.ndarray]:
        return {c: a[start:stop] for c, a in self._load().items()}

    def close(self) -> None:
        self._cols = None
