"""A source motion from a file, whatever it is: a robot's LAFAN1-layout CSV, or a human: motion capture
(BVH), SMPL-family parameters (AMASS, video estimators) or joint positions (HumanML3D).

Every retarget path (one file, a dataset, ``mer evaluate``, ``mer shards build``) reads its source
through :func:`read_source`, which gives the source skeleton and its motion at the model's 30 Hz:

* **CSV** (``.csv``, ``.csv.gz``): the registered source robot's skeleton, the file read by
  :func:`~mer_data.motion.lafan1.read_lafan1_csv` at ``fps``;
* **BVH** (``.bvh``, or ``source`` ``"bvh"``): the human in the file
  (:func:`~mer_data.motion.human.human_skeleton`), its zero pose the clip's most neutral standing
  frame (:func:`~mer_data.motion.human.standing_frame`; scaling reads standing heights and limb
  directions there), its angles unwrapped over time (Euler channels wrap at +-pi; forward kinematics
  does not care, interpolation does).

* **SMPL** (``.npz`` with SMPL parameters, or ``source`` ``"smpl"``): the body model's joints for the
  motion's shape (:mod:`mer_data.motion.smpl`), then as a BVH;
* **joint positions** (``.npy``, ``.npz`` of T x 22|24 x 3, or ``source`` ``"joints"``): rotations
  derived from the positions (:mod:`mer_data.motion.joint_positions`), then as a BVH.

What a file is comes from its content (:mod:`mer_data.base.sniff`) as well as its name: a file of
another type (an image, a URDF, a pickle) is refused naming what it is, before any reader parses it.

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

__all__ = ["BVH_SOURCE", "HUMAN_SOURCES", "human_kind", "human_files", "BvhOptions", "HumanOptions", "SourceMotion", "is_bvh", "is_bvh_source", "read_source", "load_bvh_keypoints",
           "bvh_files", "bvh_motion", "human_source_skeleton", "SOURCE_FPS"]

#: ``--source`` of human motion capture.
BVH_SOURCE = "bvh"
#: ``--source`` of each human kind: BVH, SMPL-family parameters, joint-position arrays.
HUMAN_SOURCES = (BVH_SOURCE, "smpl", "joints")
#: The rate every source is resampled to [Hz] (the model's).
SOURCE_FPS = 30.0


@dataclass(frozen=True)
class BvhOptions:
    """How to read a human: ``units`` (BVH: m, cm, mm, in; None: from the figure's size), ``up``
    (BVH: y, z; SMPL and joints also x, -y...; None: detected or the layout's), ``keypoints`` (key
    point -> joint name overrides, partial is fine), ``body_model`` (SMPL: a model file or folder,
    :mod:`mer_data.motion.body_model`), ``fps`` (SMPL / joints files that say no rate [Hz])."""

    units: str | None = None
    up: str | None = None
    keypoints: Mapping[str, str] | None = None
    body_model: str | None = None
    fps: float | None = None


#: The options of any human source (the same as a BVH's).
HumanOptions = BvhOptions


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


_SUFFIXES = {BVH_SOURCE: (".bvh",), "smpl": (".npz",), "joints": (".npy", ".npz")}


def human_files(folder: str | Path, kind: str) -> dict[str, Path]:
    """clip name → file of a human ``kind`` (:data:`HUMAN_SOURCES`) in ``folder``: ``DIR/<kind>/*``
    else ``DIR/*`` with the kind's endings (regular files only). Raises MerError where there are none."""
    if kind == BVH_SOURCE:
        return bvh_files(folder)
    root, ends = Path(folder), _SUFFIXES[kind]
    if not root.is_dir():
        raise MerError("no such folder", path=root, fix=f"point --input at a folder of {'/'.join(ends)} files")
    d = root / kind if (root / kind).is_dir() else root
    clips = {p.name[: -len(p.suffix)]: p for p in sorted(d.iterdir())
             if p.suffix.lower() in ends and p.is_file() and not p.is_symlink()}  # fmt: skip
    if not clips:
        raise MerError(f"no {'/'.join(ends)} files in the input (source {kind})", path=root,
                       fix=f"point --input at a folder holding <clip>{ends[0]} files, or give the --source of its files")  # fmt: skip
    return clips


def human_kind(path: str | Path | None, source: Any) -> str | None:
    """The human kind of a retarget's source (:data:`HUMAN_SOURCES`), None for a robot's CSV: the
    ``source`` where it names one, else the file's content (:mod:`mer_data.base.sniff`): a BVH,
    an npz of SMPL parameters (else of joint positions), an npy. A file of no motion type (an image,
    a URDF, a pickle...) is refused here, naming what it is."""
    if isinstance(source, str) and source.lower() in HUMAN_SOURCES:
        return source.lower()
    if path is None or (source is not None and not isinstance(source, str)):
        return None if path is None else _robot_file(path)
    return _file_kind(path)


def _file_kind(path: str | Path) -> str | None:
    from mer_data.base.sniff import expect

    kind = expect(path, ("bvh", "npz", "npy", "text", "gzip", "binary", "empty"),
                  "a motion file (CSV, BVH, SMPL .npz, joint-position .npy)",
                  "give a motion: a robot's CSV with --source ROBOT, a .bvh, an SMPL .npz or a joint-position .npy")  # fmt: skip
    if kind in ("text", "gzip", "binary", "empty"):  # no type of its own: the name says (its reader names the problem)
        suffix = Path(path).suffix.lower()
        return BVH_SOURCE if suffix == ".bvh" else ("smpl" if suffix == ".npz" else "joints" if suffix == ".npy" else None)
    if kind == "bvh":
        return BVH_SOURCE
    if kind == "npz":
        import zipfile

        from .smpl import smpl_layout

        try:
            with zipfile.ZipFile(path) as zf:
                keys = [n[:-4] for n in zf.namelist() if n.endswith(".npy")]
        except (zipfile.BadZipFile, OSError):
            return "smpl"  # the reader names the problem
        return "smpl" if smpl_layout(keys) else "joints"
    if kind == "npy":
        return "joints"
    return None


def _robot_file(path: str | Path) -> None:
    """A robot's motion: refuse a file that is no CSV (a BVH, an npz, an image...) naming what it is."""
    kind = _file_kind(path)
    if kind is not None:
        raise MerError(f"is a human motion ({kind}), but the source given is a robot", path=path,
                       fix=f"drop --source (the file says what it is), or give --source {kind}")  # fmt: skip
    return None


def is_bvh(path: str | Path) -> bool:
    """Whether ``path`` names a BVH file (by its extension)."""
    return str(path).lower().endswith(".bvh")


def is_bvh_source(path: str | Path | None, source: Any) -> bool:
    """Whether a retarget's source is a human (:func:`human_kind`): ``--source bvh|smpl|joints`` or a
    human file."""
    return human_kind(path, source) is not None


def read_source(path: str | Path, source: Any, *, fps: float | None = SOURCE_FPS, bvh: BvhOptions | None = None) -> SourceMotion:
    """Read one source motion file (module docstring).

    Args:
        path: the file; source: the source robot (a :class:`~mer_data.robots.registry.Robot`) for a
            CSV, or ``"bvh"``, ``"smpl"``, ``"joints"`` (None or any string: from the file).
        fps: the CSV's frame rate [Hz] (None: 30; a BVH says its own; SMPL and joints: ``bvh.fps``).
        bvh: how to read a human (:class:`BvhOptions`).

    Raises:
        MotionFormatError / BVHError: the file's problem, with file and line; MerError: a file of
        another type, or one that is not of the kind ``source`` says.
    """
    opts = bvh or BvhOptions()
    if source is None or isinstance(source, str):
        found = _file_kind(path)
        kind = source.lower() if isinstance(source, str) and source.lower() in HUMAN_SOURCES else found
        if kind is None or found is None or (kind == BVH_SOURCE) != (found == BVH_SOURCE):
            want = {BVH_SOURCE: "a BVH file", "smpl": "an SMPL .npz", "joints": "a joint-position array"}.get(kind, "a human motion")
            what = {None: "a CSV or text", BVH_SOURCE: "a BVH"}.get(found, f"an array file ({found})")
            raise MerError(f"the source is {source!r}, but the file is not {want}: it is {what}", path=path,
                           fix="give a .bvh / SMPL .npz / joint-position .npy for a human source, or the robot of a "
                               "CSV as --source")  # fmt: skip
        return _read_human(path, kind, opts)
    _robot_file(path)
    motion = read_lafan1_csv(path, source, fps=SOURCE_FPS if fps is None else fps)
    if motion.fps != SOURCE_FPS:
        motion = resample(motion, SOURCE_FPS, path=path)
    return SourceMotion(source.skeleton, motion, "csv")


def human_source_skeleton(clip: Any, keypoints: Mapping[str, str] | None = None, name: str = BVH_SOURCE) -> Skeleton:
    """The skeleton of the human in ``clip`` (a :class:`~mer_data.motion.bvh.BvhMotion`), named
    ``name`` (its kind, :data:`HUMAN_SOURCES`), its zero pose the clip's most neutral standing frame."""
    from .human import human_skeleton, standing_frame

    return human_skeleton(clip, keypoints=keypoints, name=name, rest_frame=standing_frame(clip, keypoints))


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


def read_human(path: str | Path, kind: str, opts: BvhOptions | None = None) -> Any:
    """The human of a ``kind`` file as a :class:`~mer_data.motion.bvh.BvhMotion` (its file rate)."""
    opts = opts or BvhOptions()
    if kind == BVH_SOURCE:
        from .bvh import read_bvh

        return read_bvh(path, units=opts.units, up=opts.up)
    if opts.units is not None:
        raise MerError(f"--bvh-units applies to BVH files; {kind} files are in metres", path=path, fix="drop --bvh-units")
    if kind == "smpl":
        from .smpl import read_smpl

        return read_smpl(path, body_model=opts.body_model, fps=opts.fps, up=opts.up)
    from .joint_positions import read_joint_positions

    return read_joint_positions(path, fps=opts.fps, up=opts.up)


def _read_human(path: str | Path, kind: str, opts: BvhOptions) -> SourceMotion:
    clip = read_human(path, kind, opts)
    skel = human_source_skeleton(clip, opts.keypoints, name=kind)
    motion = bvh_motion(clip, skel)
    if motion.fps != SOURCE_FPS:
        motion = resample(motion, SOURCE_FPS, path=path)
    notes = (*clip.notes, "zero pose: the clip's most neutral standing frame")
    return SourceMotion(skel, motion, kind, notes)
