"""What a shard holds, independent of the file format (HDF5 or MCAP).

A shard file holds the windows of **one source robot**, one split (train/eval) and one shard index.
Each *row* is one window; the row carries the window's stored arrays (:mod:`mer_data.motion.windows`),
its provenance and its ``K = len(targets) * variants`` training samples::

    pos            (T, J, 3)   float32  node positions, origin-normalized [m]
    q              (T, J)      float32  node angles [rad] (0 at the base and sites)
    base_rotvec    (T, 3)      float32  base orientation, axis-angle [rad]
    origin_xy      (2,)        float64  world x, y subtracted from the window [m]
    robot, clip, source_sha256  str     provenance (with start_frame)
    start_frame    ()          int64    first frame of the window in the 30 Hz clip
    sample_target  (K,)        int16    index into ``targets`` of each sample
    sample_variant (K,)        int16    0 = the URDF skeleton, 1.. = augmented copies
    link_scales    (K, Jmax)   float32  per target node link scale (1 = unchanged; padded with 1)
    dropped        (K, 14)     bool     dropped key point correspondences, KEYPOINTS order

Sample ``k`` of a row is target ``targets[k // variants]``, variant ``k % variants``. File-level
metadata (:class:`ShardMeta`) carries the format version, the resolved build configuration, every
skeleton used (``Skeleton.to_json``) and the per-clip source records, so a shard is self-contained.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mer_data.base.errors import ShardFormatError

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ShardMeta",
    "BIG_COLUMNS",
    "COLUMNS",
    "column_shapes",
    "detect_format",
    "HDF5_MAGIC",
    "MCAP_MAGIC",
]

FORMAT_NAME = "mer-shards"
#: Bumped on any incompatible change of the layout below.
FORMAT_VERSION = 1

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"

#: column -> numpy dtype ("str" for variable-length UTF-8 strings)
COLUMNS: dict[str, str] = {
    "pos": "<f4",
    "q": "<f4",
    "base_rotvec": "<f4",
    "origin_xy": "<f8",
    "robot": "str",
    "clip": "str",
    "start_frame": "<i8",
    "source_sha256": "str",
    "sample_target": "<i2",
    "sample_variant": "<i2",
    "link_scales": "<f4",
    "dropped": "|b1",
}
#: columns stored one window per chunk (the large per-window arrays); the others in blocks of rows
BIG_COLUMNS = ("pos", "q", "link_scales")


def column_shapes(window: int, num_nodes: int, num_samples: int, max_target_nodes: int) -> dict[str, tuple[int, ...]]:
    """Per-row shape of every column."""
    T, J, K, Jm = window, num_nodes, num_samples, max_target_nodes
    return {
        "pos": (T, J, 3), "q": (T, J), "base_rotvec": (T, 3), "origin_xy": (2,), "robot": (), "clip": (),
        "start_frame": (), "source_sha256": (), "sample_target": (K,), "sample_variant": (K,),
        "link_scales": (K, Jm), "dropped": (K, 14),
    }  # fmt: skip


@dataclass
class ShardMeta:
    """File-level metadata of one shard (JSON-serialisable).

    ``sources``: one record per clip assigned to this shard (``clip``, ``file``, ``sha256``,
    ``frames_in``, ``fps_in``, ``frames``, ``windows``, ``status`` = ok | short | failed, ``error``).
    """

    robot: str
    split: str
    shard_index: int
    num_shards: int
    window: int
    fps: float
    targets: list[str]
    variants: int
    skeletons: dict[str, str]
    config: dict[str, Any]
    build_id: str
    part_key: str = ""
    sources: list[dict[str, Any]] = field(default_factory=list)
    num_rows: int = 0
    format: str = FORMAT_NAME
    format_version: int = FORMAT_VERSION
    mer_version: str = ""

    @property
    def samples_per_row(self) -> int:
        return len(self.targets) * self.variants

    @property
    def max_target_nodes(self) -> int:
        return max(json.loads(self.skeletons[t])["node_names"].__len__() for t in self.targets)

    @property
    def num_nodes(self) -> int:
        return len(json.loads(self.skeletons[self.robot])["node_names"])

    def shapes(self) -> dict[str, tuple[int, ...]]:
        return column_shapes(self.window, self.num_nodes, self.samples_per_row, self.max_target_nodes)

    def counts(self) -> dict[str, int]:
        ok = [s for s in self.sources if s.get("status") == "ok"]
        return {
            "clips": len(ok),
            "frames": int(sum(s.get("frames", 0) for s in ok)),
            "windows": self.num_rows,
            "samples": self.num_rows * self.samples_per_row,
            "short_clips": sum(s.get("status") == "short" for s in self.sources),
            "failed_clips": sum(s.get("status") == "failed" for s in self.sources),
        }

    # ---- (de)serialisation as flat string attributes ---------------------------------------
    def to_attrs(self) -> dict[str, str | int | float]:
        d = asdict(self)
        out: dict[str, str | int | float] = {}
        skeletons = d.pop("skeletons")
        for k, v in d.items():
            out[k] = json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v
        for name, text in skeletons.items():
            out[f"skeleton:{name}"] = text
        out["skeleton_names"] = json.dumps(sorted(skeletons))
        return out

    @classmethod
    def from_attrs(cls, attrs: dict[str, Any], path: str | Path) -> "ShardMeta":
        def get(k):
            v = attrs[k]
            if isinstance(v, np.generic):  # HDF5 attributes come back as numpy scalars
                v = v.item()
            return v.decode() if isinstance(v, bytes) else v

        try:
            fmt = get("format")
        except KeyError:
            raise ShardFormatError("not a mer shard (no 'format' metadata)", path=path) from None
        if fmt != FORMAT_NAME:
            raise ShardFormatError(f"not a mer shard (format {fmt!r})", path=path)
        version = int(get("format_version"))
        if version != FORMAT_VERSION:
            raise ShardFormatError(
                f"shard format version {version}; this mer reads version {FORMAT_VERSION}",
                path=path,
                fix="rebuild the shards with this mer: `mer shards build` (the old shard's "
                "configuration is shown by `mer shards inspect`)",
            )
        try:
            names = json.loads(get("skeleton_names"))
            kw: dict[str, Any] = {"skeletons": {n: get(f"skeleton:{n}") for n in names}}
            for f in cls.__dataclass_fields__:
                if f == "skeletons":
                    continue
                v = get(f)
                if f in ("targets", "config", "sources"):
                    v = json.loads(v)
                kw[f] = v
            meta = cls(**kw)
            meta.shard_index, meta.num_shards, meta.window = int(meta.shard_index), int(meta.num_shards), int(meta.window)
            meta.variants, meta.num_rows, meta.fps = int(meta.variants), int(meta.num_rows), float(meta.fps)
            meta.format_version = int(meta.format_version)
        except (KeyError, ValueError, TypeError) as exc:
            raise ShardFormatError(f"damaged shard metadata ({exc})", path=path) from None
        return meta


def detect_format(path: str | Path) -> str:
    """``"hdf5"`` or ``"mcap"`` from the file's magic bytes."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        raise ShardFormatError(f"cannot open the shard ({exc.strerror})", path=p) from None
    if head == HDF5_MAGIC:
        return "hdf5"
    if head == MCAP_MAGIC:
        return "mcap"
    raise ShardFormatError(
        "not a shard: neither HDF5 nor MCAP", path=p, fix="pass a .h5 or .mcap file written by `mer shards build`"
    )


def empty_rows(shapes: dict[str, tuple[int, ...]]) -> dict[str, np.ndarray]:
    """Zero-row arrays of every column."""
    return {k: np.zeros((0,) + shapes[k], dtype=object if COLUMNS[k] == "str" else COLUMNS[k]) for k in COLUMNS}
