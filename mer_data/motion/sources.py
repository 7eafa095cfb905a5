"""A source motion from a file, whatever it is: a robot's LAFAN1-layout CSV or human motion capture (BVH).

Every retarget path (one file, a dataset, ``mer evaluate``, ``mer shards build``) reads its source
through :func:`read_source`, which gives the source skeleton and its motion at the model's 30 Hz:

* **CSV** (``.csv``, ``.csv.gz``): the registered source robot's skeleton, the file read by
  :func:`~mer_data.motion.lafan1.read_lafan1_csv` at ``fps``;
* **BVH** (``.bvh``, or ``source`` ``"bvh"``): the human in the file
  (:func:`~mer_data.motion.human.human_skeleton`), its zero pose the clip's most neutral standing
  frame (:func:`~mer_data.motion.human.standing_frame`; scaling reads standing heights and limb
  directions there), its angles unwrapped over time (Euler channels wrap at +-pi; forward kinematics
  does not care, interpolation does).

Either is resampled to 30 Hz by :func:`~mer_data.motion.resample.resample` (frames on the 30 Hz grid
are copied bit for bit, so 120 Hz capture of the same motion gives the same 30 Hz frames).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from mer_data.base.errors import MerError
from mer_data.skeleton import Skeleton

from .features import source_features
from .lafan1 import Motion, read_lafan1_csv
from .resample import resample

__all__ = ["BVH_SOURCE", "BvhOptions", "SourceMotion", "is_bvh", "is_bvh_source", "read_source", "load_bvh_keypoints",
           "bvh_files", "bvh_motion", "human_source_skeleton", "SOURCE_FPS"]

#: ``--source`` of human motion capture.
BVH_SOURCE = "bvh"
#: The rate every source is resampled to [Hz] (the model's).
SOURCE_FPS = 30.0


@dataclass(frozen=True)
class BvhOptions:
    """How to read a BVH: ``units`` (m, cm, mm, in; None: from the figure's size), ``up`` (y, z;
    None: detected), ``keypoints`` (key point -> joint name overrides, partial is fine)."""

    units: str | None = None
    up: str | None = None
    keypoints: Mapping[str, str] | None = None


@dataclass(frozen=True)
class SourceMotion:
    """A source motion at :data:`SOURCE_FPS`.

    Attributes:
        skeleton: the source's skeleton (a robot's, or the human's of this clip).
        motion: base pose and angles per revolute node, at 30 Hz.
        kind: ``csv`` or ``bvh``; notes: what reading decided (units, up axis, zero pose).
    """

    skeleton: Skeleton
    motion: Motion
    kind: str
    notes: tuple[str, ...] = field(default=())

    def features(self) -> np.ndarray:
        """(F, J, 9) float64 world-frame features (:func:`mer_data.motion.features.source_features`)."""
        m = self.motion
        return source_features(m.base_pos, m.base_quat, m.node_angles(self.skeleton), self.skeleton, SOURCE_FPS)


def load_bvh_keypoints(path: str | Path) -> dict[str, str]:
    """Key point -> BVH joint name overrides from a YAML or JSON file (the mapping itself, or under
    ``keypoints:``); partial is fine. Raises MerError naming the file and the entry at fault."""
    import yaml

    from mer_data.base.safe_io import decode_utf8, read_regular_file, safe_yaml_load, strict_json_loads
    from mer_data.skeleton import KEYPOINTS

    path = Path(path)
    fix = "write one line per key point, e.g. `left_ankle: LeftFoot` (key points: " + ", ".join(KEYPOINTS) + ")"
    text = decode_utf8(read_regular_file(path, MerError, "MER_MAX_CARD_BYTES", fix="check the path given to --bvh-keypoints"),
                       path, MerError)  # fmt: skip
    try:
        data = strict_json_loads(text) if path.suffix == ".json" else safe_yaml_load(text)
    except (ValueError, yaml.YAMLError, RecursionError) as exc:
        raise MerError(f"cannot parse the key point file: {str(exc)[:300]}", path=path, fix=fix) from None
    if isinstance(data, dict) and isinstance(data.get("keypoints"), dict):
        data = data["keypoints"]
    if not isinstance(data, dict):
        raise MerError("the key point file is not a mapping of key point -> joint name", path=path, fix=fix)
    out = {}
    for k, v in data.items():
        if k not in KEYPOINTS:
            raise MerError(f"unknown key point {k!r}", path=path, element=str(k), fix=fix)
        if not isinstance(v, str) or not v:
            raise MerError(f"key point {k!r} must name a BVH joint, got {v!r}", path=path, element=str(k), fix=fix)
        out[k] = v
    return out


def bvh_files(folder: str | Path) -> dict[str, Path]:
    """clip name → BVH file: ``DIR/bvh/*.bvh``, else ``DIR/*.bvh`` (regular files only; symlinks are
    not followed). Raises MerError where there are none."""
    root = Path(folder)
    if not root.is_dir():
        raise MerError("no such folder", path=root, fix="point --input at a folder of .bvh files (or holding bvh/*.bvh)")
    d = root / BVH_SOURCE if (root / BVH_SOURCE).is_dir() else root
    clips = {p.name[: -len(".bvh")]: p for p in sorted(d.iterdir())
             if p.name.lower().endswith(".bvh") and p.is_file() and not p.is_symlink()}  # fmt: skip
    if not clips:
        raise MerError("no BVH files in the input: neither bvh/*.bvh nor *.bvh", path=root,
                       fix="point --input at a folder holding <clip>.bvh files")  # fmt: skip
    return clips


def is_bvh(path: str | Path) -> bool:
    """Whether ``path`` names a BVH file (by its extension)."""
    return str(path).lower().endswith(".bvh")


def is_bvh_source(path: str | Path | None, source: Any) -> bool:
    """Whether a retarget's source is human motion capture: ``--source bvh`` or a ``.bvh`` input."""
    return (isinstance(source, str) and source.lower() == BVH_SOURCE) or (path is not None and is_bvh(path))


def read_source(path: str | Path, source: Any, *, fps: float = SOURCE_FPS, bvh: BvhOptions | None = None) -> SourceMotion:
    """Read one source motion file (module docstring).

    Args:
        path: the file; source: the source robot (a :class:`~mer_data.robots.registry.Robot`) for a
            CSV, or ``"bvh"`` / anything for a ``.bvh`` file.
        fps: the CSV's frame rate [Hz] (a BVH says its own).
        bvh: how to read a BVH.

    Raises:
        MotionFormatError / BVHError: the file's problem, with file and line; MerError: a CSV given
        ``--source bvh``.
    """
    if is_bvh(path):
        return _read_bvh(path, bvh or BvhOptions())
    if isinstance(source, str):
        raise MerError(f"{path} is not a BVH file, but the source is {source!r}",
                       path=path, fix="give a .bvh file for --source bvh, or the robot of the CSV as --source")  # fmt: skip
    motion = read_lafan1_csv(path, source, fps=fps)
    if motion.fps != SOURCE_FPS:
        motion = resample(motion, SOURCE_FPS, path=path)
    return SourceMotion(source.skeleton, motion, "csv")


def human_source_skeleton(clip: Any, keypoints: Mapping[str, str] | None = None) -> Skeleton:
    """The skeleton of the human in ``clip`` (a :class:`~mer_data.motion.bvh.BvhMotion`), named
    :data:`BVH_SOURCE`, its zero pose the clip's most neutral standing frame."""
    from .human import human_skeleton, standing_frame

    return human_skeleton(clip, keypoints=keypoints, name=BVH_SOURCE, rest_frame=standing_frame(clip, keypoints))


def bvh_motion(clip: Any, skel: Skeleton) -> Motion:
    """``clip`` as a :class:`~mer_data.motion.lafan1.Motion` of ``skel`` at the file's rate: a skeleton
    of this clip, or of another clip of the same hierarchy (a dataset's one human: the angles are
    measured from that skeleton's zero pose, the bones are that skeleton's). Angles are unwrapped."""
    from .human import human_motion

    base_pos, base_quat, q = human_motion(clip, skel)
    rev = np.flatnonzero(skel.revolute_mask)
    joints = np.unwrap(q[:, rev], axis=0) if len(q) > 1 else q[:, rev]
    return Motion(skel.name, float(clip.fps), np.asarray(base_pos, np.float64), np.asarray(base_quat, np.float64),
                  np.ascontiguousarray(joints, np.float64), tuple(skel.node_names[i] for i in rev))  # fmt: skip


def _read_bvh(path: str | Path, opts: BvhOptions) -> SourceMotion:
    from .bvh import read_bvh

    clip = read_bvh(path, units=opts.units, up=opts.up)
    skel = human_source_skeleton(clip, opts.keypoints)
    motion = bvh_motion(clip, skel)
    if motion.fps != SOURCE_FPS:
        motion = resample(motion, SOURCE_FPS, path=path)
    notes = (*clip.notes, "zero pose: the clip's most neutral standing frame")
    return SourceMotion(skel, motion, "bvh", notes)
