"""Synthetic clips as a shard source (``mer shards build --synthetic N``), beside motion files.

Clip ``i`` of robot ``R`` is named ``synthetic-R-0000i`` (the robot in the name: synthetic clips of
different robots are different motions, so no window is ever paired with another robot's window as
its retargeting) and addressed by the source string ``synthetic:R/i``. Its motion is generated on
demand by :func:`mer_data.synthesis.synthesize` (seeded by the build's ``synthetic_seed``, the
robot and ``i``) from the skeleton stored with the build, at the build's input ``fps``; its
"sha256" is that of the generated arrays, so resuming, piece reuse and provenance work as for files.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Sequence

import numpy as np

from mer_data.motion.lafan1 import Motion, read_motion_file
from mer_data.skeleton import Skeleton
from mer_data.synthesis import SYNTHESIS_VERSION, clip_seed, synthesize

from .config import BuildConfig
from .sources import sha256_bytes

__all__ = ["SYNTHETIC_PREFIX", "is_synthetic", "synthetic_clips", "synthetic_motion", "source_sha256", "source_size"]

SYNTHETIC_PREFIX = "synthetic:"


def is_synthetic(source: str | Path) -> bool:
    return str(source).startswith(SYNTHETIC_PREFIX)


def synthetic_clips(robots: Sequence[str], n: int) -> dict[str, dict[str, str]]:
    """robot -> clip name -> source string, ``n`` clips per robot."""
    return {r: {f"synthetic-{r}-{i:05d}": f"{SYNTHETIC_PREFIX}{r}/{i}" for i in range(n)} for r in robots}


def _index(source: str) -> tuple[str, int]:
    robot, _, i = source[len(SYNTHETIC_PREFIX) :].rpartition("/")
    return robot, int(i)


def motion_sha256(motion: Motion) -> str:
    """sha256 of a motion's arrays, frame rate, columns and the generator version."""
    h = hashlib.sha256(f"mer-synthesis/{SYNTHESIS_VERSION}/{motion.robot}/{motion.fps!r}/{','.join(motion.columns)}".encode())
    for a in (motion.base_pos, motion.base_quat, motion.joints):
        h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    return h.hexdigest()


def synthetic_motion(cfg: BuildConfig, skel: Skeleton, source: str) -> tuple[Motion, str]:
    """The motion of synthetic ``source`` and its sha256."""
    robot, i = _index(source)
    motion = synthesize(skel, cfg.synthetic_seconds, cfg.fps, clip_seed(cfg.synthetic_seed, robot, i)).motion
    return motion, motion_sha256(motion)


def source_sha256(cfg: BuildConfig, skel: Skeleton, source: str | Path) -> str:
    """sha256 of a clip's source: the file's bytes, or the generated arrays."""
    if is_synthetic(source):
        return synthetic_motion(cfg, skel, str(source))[1]
    return sha256_bytes(read_motion_file(source))


def source_size(source: str | Path) -> int:
    """Bytes of a source file (to schedule the largest first); 0 for synthetic clips (all alike)."""
    return 0 if is_synthetic(source) else Path(source).stat().st_size
