"""MCAP shards: the same content as HDF5, viewable in Foxglove.

* ``/mer/windows`` (schema ``mer.ShardWindow``, JSON, every field typed): one message per window
  (row) with every column; numeric arrays are ``{"dtype", "shape", "base64"}`` of their exact
  little-endian bytes, so reading back is lossless.
* ``/tf`` (``foxglove.FrameTransforms``) and ``/skeleton`` (``foxglove.SceneUpdate``): an animation
  of the first ``preview`` windows of every clip (all windows with ``preview < 0``), laid one after
  another on the timeline, for Foxglove's 3D panel; their schemas are Foxglove's official ones
  (:mod:`.foxglove`).
* metadata record ``mer.shard``: :meth:`ShardMeta.to_attrs`, every value a string.

Chunks are zstd-compressed. Reading loads the file's windows into memory (use HDF5 for large-scale
random access during training).
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from mer_data.base.errors import ShardFormatError
from mer_data.skeleton import Skeleton

from .foxglove import FRAME_TRANSFORMS_SCHEMA, SCENE_UPDATE_SCHEMA, frame_transforms, scene_update
from .schema import COLUMNS, ShardMeta, column_shapes

__all__ = ["McapShardWriter", "McapShard", "WINDOW_TOPIC", "TF_TOPIC", "SCENE_TOPIC"]

WINDOW_TOPIC, TF_TOPIC, SCENE_TOPIC = "/mer/windows", "/tf", "/skeleton"
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
        self._stream = open(self.path, "wb")
        self.w = Writer(self._stream, compression=CompressionType.ZSTD)
        self.w.start(profile="", library="mer")
        sid = self.w.register_schema("mer.ShardWindow", "jsonschema", _WINDOW_SCHEMA)
        self.ch_win = self.w.register_channel(WINDOW_TOPIC, "json", sid)
        sid = self.w.register_schema("foxglove.FrameTransforms", "jsonschema", FRAME_TRANSFORMS_SCHEMA)
        self.ch_tf = self.w.register_channel(TF_TOPIC, "json", sid)
        sid = self.w.register_schema("foxglove.SceneUpdate", "jsonschema", SCENE_UPDATE_SCHEMA)
        self.ch_scene = self.w.register_channel(SCENE_TOPIC, "json", sid)
        self.skel = Skeleton.from_json(meta.skeletons[meta.robot])
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
                self.w.add_message(self.ch_scene, t, scene_update(self.skel, self.meta.robot, t), t)
                pos, rv, q = rows["pos"][i], rows["base_rotvec"][i], rows["q"][i]
                for ns, data in frame_transforms(self.skel, self.meta.robot, pos[:, 0], rv, q, t, self.meta.fps):
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


class McapShard:
    """Read access to an MCAP shard; the windows are decoded into memory on first use."""

    format = "mcap"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                reader = make_reader(f)
                metas = [m for m in reader.iter_metadata() if m.name == _META_NAME]
        except (McapError, OSError, ValueError, EOFError) as exc:
            raise ShardFormatError(f"cannot read the MCAP shard ({exc})", path=self.path, fix="rebuild it") from None
        if not metas:
            raise ShardFormatError("not a mer shard (no 'mer.shard' metadata record)", path=self.path)
        self.meta = ShardMeta.from_attrs(dict(metas[0].metadata), self.path)
        self._cols: dict[str, np.ndarray] | None = None

    @property
    def num_rows(self) -> int:
        return self.meta.num_rows

    def _load(self) -> dict[str, np.ndarray]:
        if self._cols is not None:
            return self._cols
        shapes = self.meta.shapes()
        n = self.meta.num_rows
        cols = {c: (np.empty(n, object) if d == "str" else np.empty((n,) + shapes[c], d)) for c, d in COLUMNS.items()}
        seen = np.zeros(n, bool)
        try:
            with open(self.path, "rb") as f:
                for _, _, m in make_reader(f).iter_messages(topics=[WINDOW_TOPIC], log_time_order=False):
                    d = json.loads(m.data)
                    r = int(d["row"])
                    for c, dtype in COLUMNS.items():
                        cols[c][r] = d[c] if dtype == "str" else _dec(d[c])
                    seen[r] = True
        except (McapError, OSError, ValueError, KeyError, IndexError, EOFError) as exc:
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
