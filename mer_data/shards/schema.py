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
        except (KeyError, ValueError, TypeError, AttributeError, RecursionError, OverflowError) as exc:
            raise ShardFormatError(f"damaged shard metadata ({type(exc).__name__}: {exc})", path=path) from None
        meta.check(path)
        return meta

    def check(self, path: str | Path | None = None) -> None:
        """Refuse metadata of the wrong types or out of range (a file from a stranger), naming the field."""
        from mer_data.base.limits import limit, too_big

        def bad(field: str, why: str, fix: str | None = None) -> ShardFormatError:
            return ShardFormatError(f"damaged shard metadata: {field} {why}", path=path, element=f"metadata {field!r}",
                                    fix=fix or "rebuild the shard with `mer shards build`")  # fmt: skip

        def is_int(v: Any) -> bool:
            return isinstance(v, int) and not isinstance(v, bool)

        for name in ("robot", "split", "build_id", "part_key", "mer_version"):
            if not isinstance(getattr(self, name), str):
                raise bad(name, f"is {type(getattr(self, name)).__name__}, expected a string")
        if not (isinstance(self.targets, list) and self.targets and all(isinstance(t, str) for t in self.targets)):
            raise bad("targets", "is not a non-empty list of names")
        if not (isinstance(self.skeletons, dict) and all(isinstance(k, str) and isinstance(v, str) for k, v in self.skeletons.items())):
            raise bad("skeletons", "are not strings")
        for n in {self.robot, *self.targets}:
            if n not in self.skeletons:
                raise bad("skeletons", f"lack {n!r}")
        for n, text in self.skeletons.items():
            try:
                obj = json.loads(text)
                names = obj["node_names"]
            except (ValueError, TypeError, KeyError, RecursionError) as exc:
                raise bad(f"skeleton:{n}", f"is not a skeleton ({type(exc).__name__})") from None
            if not (isinstance(names, list) and 0 < len(names) <= 10_000):
                raise bad(f"skeleton:{n}", "has no valid node_names")
        if not isinstance(self.config, dict):
            raise bad("config", "is not an object")
        if not (isinstance(self.sources, list) and all(isinstance(s, dict) for s in self.sources)):
            raise bad("sources", "is not a list of objects")
        if not (1 <= self.window <= 100_000):
            raise bad("window", f"is {self.window}, expected 1..100000")
        if not (1 <= self.variants <= 10_000) or len(self.targets) * self.variants > 100_000:
            raise bad("variants", f"is {self.variants} (x {len(self.targets)} targets), expected 1..10000 and at most 100000 samples per row")
        if not (np.isfinite(self.fps) and 0 < self.fps <= 10_000):
            raise bad("fps", f"is {self.fps}, expected a positive rate")
        if not (is_int(self.num_rows) and 0 <= self.num_rows):
            raise bad("num_rows", f"is {self.num_rows}")
        if self.num_rows > limit("MER_MAX_SHARD_ROWS"):
            msg, fix = too_big("MER_MAX_SHARD_ROWS", self.num_rows)
            raise bad("num_rows", msg, fix)
        if not (0 <= self.shard_index < max(self.num_shards, 1)):
            raise bad("shard_index", f"{self.shard_index} is not below num_shards {self.num_shards}")


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
