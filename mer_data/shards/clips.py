"""One clip -> one *piece*: read, check, resample, window, features, augmentation draws.

This is what the build's worker processes run. A piece is an HDF5 file with the shard layout holding
the windows of one clip; it is built in memory and written to a temporary name and renamed (a full
disk is a ``DiskFullError``, never a half-written piece), and it records the key of its inputs (build id, robot, clip, source sha256), so an interrupted build reuses the pieces it
finished. The builder then merges the pieces of a shard into the shard file.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from mer_data.base.errors import MerError
from mer_data.base.finite import require_finite
from mer_data.kinematics.fk import SkeletonTensors, skeleton_tensors
from mer_data.motion.lafan1 import Motion, decompress_motion, parse_lafan1, read_motion_file
from mer_data.motion.resample import resample
from mer_data.motion.sources import BVH_SOURCE, bvh_motion, read_human
from mer_data.motion.windows import make_windows, window_starts
from mer_data.robots.registry import Robot, load_robot
from mer_data.skeleton import KEYPOINTS, Skeleton

from .augment import LinkGroups, draw_dropped, draw_link_scales, link_groups
from .config import BuildConfig
from .hdf5_io import Hdf5Shard, Hdf5ShardWriter
from .humans import human_kind_of
from .schema import ShardMeta
from .sources import sha256_bytes, stable_words
from .synthetic_source import is_synthetic, synthetic_motion

log = logging.getLogger(__name__)

__all__ = ["BuildContext", "ClipTask", "ClipResult", "process_clip", "piece_key", "sample_rng"]


@dataclass
class BuildContext:
    """What every worker needs, sent once: the configuration, skeletons and shard metadata templates."""

    config: BuildConfig
    skeletons: dict[str, str]  # name -> Skeleton JSON
    metas: dict[str, ShardMeta]  # part name -> metadata template
    _skel: dict[str, Skeleton] = field(default_factory=dict, repr=False)
    _st: dict[str, SkeletonTensors] = field(default_factory=dict, repr=False)
    _groups: dict[str, LinkGroups] = field(default_factory=dict, repr=False)
    _robots: dict[str, Robot] = field(default_factory=dict, repr=False)

    def robot(self, name: str) -> Robot:
        """The registry entry (card: column layout), loaded once per process."""
        if name not in self._robots:
            self._robots[name] = load_robot(name)
        return self._robots[name]

    def skeleton(self, name: str) -> Skeleton:
        if name not in self._skel:
            self._skel[name] = Skeleton.from_json(self.skeletons[name])
        return self._skel[name]

    def tensors(self, name: str) -> SkeletonTensors:
        if name not in self._st:
            self._st[name] = skeleton_tensors(self.skeleton(name), torch.float32)
        return self._st[name]

    def groups(self, name: str) -> LinkGroups:
        if name not in self._groups:
            self._groups[name] = link_groups(self.skeleton(name))
        return self._groups[name]


@dataclass(frozen=True)
class ClipTask:
    robot: str
    clip: str
    path: str
    split: str
    part: str
    piece: str


@dataclass
class ClipResult:
    task: ClipTask
    record: dict  # the ShardMeta.sources entry
    piece: str | None  # None when the clip gave no windows (short or failed)
    reused: bool = False

    @property
    def status(self) -> str:
        return self.record["status"]


def piece_key(build_id: str, robot: str, clip: str, sha256: str) -> str:
    return hashlib.sha256(f"{build_id}/{robot}/{clip}/{sha256}".encode()).hexdigest()


def sample_rng(seed: int, robot: str, clip: str) -> np.random.Generator:
    """The augmentation generator of one clip: independent of the shard layout and of the workers."""
    return np.random.default_rng([seed, *stable_words(f"{robot}/{clip}")])


def _augmentation(ctx: BuildContext, task: ClipTask, n: int) -> dict[str, np.ndarray]:
    """Per-sample columns of ``n`` windows: targets, variants, link scales, dropped pairs."""
    meta = ctx.metas[task.part]
    V, targets = meta.variants, meta.targets
    K, Jm = len(targets) * V, meta.max_target_nodes
    out = {
        "sample_target": np.broadcast_to(np.repeat(np.arange(len(targets), dtype=np.int16), V), (n, K)).copy(),
        "sample_variant": np.broadcast_to(np.tile(np.arange(V, dtype=np.int16), len(targets)), (n, K)).copy(),
        "link_scales": np.ones((n, K, Jm), np.float32),
        "dropped": np.zeros((n, K, len(KEYPOINTS)), bool),
    }
    if V > 1 and n:
        rng = sample_rng(ctx.config.seed, task.robot, task.clip)
        aug = ctx.config.augmentation
        for t, name in enumerate(targets):
            skel = ctx.skeleton(name)
            scales = draw_link_scales(skel, rng, n * (V - 1), aug, ctx.groups(name)).reshape(n, V - 1, -1)
            dropped = draw_dropped(rng, n * (V - 1), aug).reshape(n, V - 1, -1)
            out["link_scales"][:, t * V + 1 : (t + 1) * V, : skel.num_nodes] = scales
            out["dropped"][:, t * V + 1 : (t + 1) * V] = dropped
    return out


def _reuse(piece: Path, key: str) -> ShardMeta | None:
    if piece.is_symlink() or not piece.is_file():
        return None  # a link is never read, and replaced (the name itself) when the piece is written
    try:
        meta = Hdf5Shard(piece).meta
    except MerError:
        return None
    return meta if meta.part_key == key else None


def _load(ctx: BuildContext, task: ClipTask, record: dict) -> tuple[Motion | None, ClipResult | None]:
    """The clip's motion (or the result of a failed read / a reused piece); fills ``record["sha256"]``."""
    cfg = ctx.config
    key = lambda: piece_key(ctx.metas[task.part].build_id, task.robot, task.clip, record["sha256"])  # noqa: E731
    piece = Path(task.piece)
    if is_synthetic(task.path):
        motion, record["sha256"] = synthetic_motion(cfg, ctx.skeleton(task.robot), task.path)
        old = _reuse(piece, key())
        return (None, ClipResult(task, old.sources[0], str(piece), reused=True)) if old is not None else (motion, None)
    path = Path(task.path)
    try:
        raw = read_motion_file(path)
    except MerError as exc:
        record["error"] = str(exc)
        return None, ClipResult(task, record, None)
    record["sha256"] = sha256_bytes(raw)
    old = _reuse(piece, key())
    if old is not None:
        return None, ClipResult(task, old.sources[0], str(piece), reused=True)
    try:
        kind = human_kind_of(task.robot)
        if kind is not None:  # a human, read as every retarget path reads it, as a motion of its body's skeleton
            if kind == BVH_SOURCE and cfg.up is None:
                from mer_data.motion.bvh import parse_bvh_bytes

                human = parse_bvh_bytes(raw, str(path))  # the bytes hashed above
            else:
                human = read_human(path, kind, cfg.human_options())
            motion = bvh_motion(human, ctx.skeleton(task.robot))
            record["fps_in"] = float(motion.fps)
        else:
            data = decompress_motion(raw, path)
            motion = parse_lafan1(data, ctx.robot(task.robot), path=path, fps=cfg.fps, quat_tolerance=cfg.quat_tolerance)
    except MerError as exc:
        record["error"] = str(exc)
        return None, ClipResult(task, record, None)
    return motion, None


def process_clip(ctx: BuildContext, task: ClipTask) -> ClipResult:
    """Turn one clip into a piece file (or a short/failed record). MerErrors become ``failed`` records."""
    cfg = ctx.config
    path = Path(task.path)
    name = task.path if is_synthetic(task.path) else path.name
    record: dict = {"clip": task.clip, "file": name, "sha256": "", "fps_in": cfg.fps, "status": "failed"}
    motion, done = _load(ctx, task, record)
    if done is not None:
        return done
    assert motion is not None
    key = piece_key(ctx.metas[task.part].build_id, task.robot, task.clip, record["sha256"])
    piece = Path(task.piece)
    record["frames_in"] = motion.num_frames
    if motion.warnings:
        record["warnings"] = list(motion.warnings)
    motion = resample(motion, cfg.out_fps, path=name)
    record["frames"] = motion.num_frames
    starts = window_starts(motion.num_frames, cfg.window, cfg.stride)
    record["windows"] = int(len(starts))
    if not len(starts):
        record["status"] = "short"
        record["error"] = f"{path}: {motion.num_frames} frames at {cfg.out_fps:g} Hz, shorter than a window of {cfg.window}"
        return ClipResult(task, record, None)
    record["status"] = "ok"
    wb = make_windows(motion, ctx.skeleton(task.robot), starts, cfg.window, st=ctx.tensors(task.robot))
    try:
        require_finite({"pos": wb.pos, "q": wb.q, "base_rotvec": wb.base_rotvec, "origin_xy": wb.origin_xy},
                       path=path, what="shard windows")  # fmt: skip
    except MerError as exc:
        record.update(status="failed", error=str(exc))
        return ClipResult(task, record, None)
    n = len(wb)
    rows = {
        "pos": wb.pos, "q": wb.q, "base_rotvec": wb.base_rotvec, "origin_xy": wb.origin_xy,
        "robot": np.array([task.robot] * n, object), "clip": np.array([task.clip] * n, object),
        "start_frame": wb.start_frame, "source_sha256": np.array([record["sha256"]] * n, object),
        **_augmentation(ctx, task, n),
    }  # fmt: skip
    meta = replace(ctx.metas[task.part], part_key=key, sources=[record])
    # built in memory, then one checked, atomic write below the build's folder (OUT/.partial/<file>/)
    writer = Hdf5ShardWriter(piece, meta, compression=cfg.compression, in_memory=True, below=piece.parents[2])
    try:
        writer.append(rows)
        writer.close(meta)
    except BaseException:
        writer.abort()
        raise
    return ClipResult(task, record, str(piece))
