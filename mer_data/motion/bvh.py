"""BVH (Biovision hierarchy) motion capture files: a strict reader and the file's own kinematics.

Format read::

    HIERARCHY
    ROOT Hips                      (one ROOT; names may contain spaces: "Bip01 L Thigh")
    {
      OFFSET x y z
      CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
      JOINT LeftUpLeg { OFFSET ... CHANNELS 3 Zrotation Xrotation Yrotation ... }
      End Site { OFFSET x y z }
    }
    MOTION
    Frames: N
    Frame Time: t                  (seconds per frame)
    N lines of one number per channel, in hierarchy order

Keywords are matched case-insensitively, joint names exactly. A joint has 0 to 6 distinct channels
in any order (any permutation of ``X/Y/Z position``, ``X/Y/Z rotation``; the root may have rotations
only). An End Site becomes a joint of its own named ``<parent>_End`` (``_End_2``... if taken).

Kinematics (:func:`fk`), per joint: ``local = Translation(t) @ R`` where ``t`` is the OFFSET, with
each component that has a position channel *replaced* by the channel's value (the common reading,
and the one real files need: Bandai's ``Hips`` offset says z = -452 cm, its channels z = -9 cm; its
``Spine`` channels repeat the 15.7 cm offset, which adding would double), and ``R`` the product of
the rotation channels in the order written (intrinsic: ``Zrotation Xrotation Yrotation`` is
``Rz @ Rx @ Ry``), angles in degrees. ``world_child = world_parent @ local``.

What :class:`BvhMotion` keeps: the channel values as written (file units, degrees, file axes); its
:meth:`~BvhMotion.positions` and :meth:`~BvhMotion.rotations` are in mer's convention: metres,
**z up, x forward** (``to_world`` = facing yaw @ up rotation, ``scale`` metres per file unit).

* **Up axis** (``up="y"|"z"`` overrides): a Y-up file is turned by the cyclic permutation
  ``(x, y, z)_mer = (z, x, y)_file`` (a proper rotation; BVH's customary forward +z becomes +x and
  its left +x becomes +y). Detected on the motion (the rest pose may be anything: Bandai's has every
  bone along +x): the axis among y and z along which the head/neck joints lie highest above the
  feet/toes/ankles (names, :func:`split_joint_name`), averaged over frames; with no such names,
  the axis along which the largest subtree of the hips (:func:`branch_joint`: the torso, with
  head and arms) lies above the other subtrees (the legs); failing that, the axis along which the
  figure is tallest (median over frames).
* **Units** (``units="m"|"cm"|"mm"|"in"`` overrides): from the figure's size ``H``, the 90th
  percentile over frames of the extent of all joints along the up axis (a standing adult: about
  0.9 of the stature, the head joint being below the top of the head). ``H < 10``: metres;
  ``10 <= H < 100``: inches; ``100 <= H < 500``: centimetres; ``H >= 500``: millimetres. The
  boundaries are the geometric means of the unit scales times 1.6 m, so the rule is right for any
  figure with H between 1.0 and 2.5 m whatever the unit (not for a child under about 1.1 m in
  centimetres, read as inches: give ``units=``). A size outside 0.5-3 m after conversion is logged.
* **Facing** (``facing="auto"``; ``"keep"`` leaves it): a constant yaw about z chosen so that at
  the first frame the figure's left (mean of left-named minus right-named mirror joints, the pairs
  nearest the root that are apart) points along +y, i.e. it faces +x. Without named sides the yaw
  is 0. A constant yaw is harmless for retargeting; it only makes the clip start facing +x.
* **Frame rate**: ``1 / Frame Time``, snapped to the nearest integer when within 0.01 % of it
  (files print 1/30 s as 0.0333333).

Strictness: every problem raises :class:`~mer_data.base.errors.BVHError` with the file, the
1-based line and a fix (not a BVH, unbalanced braces, missing or misplaced OFFSET/CHANNELS,
unknown or repeated channel names, duplicate joint names, several ROOTs, missing MOTION, bad
``Frames:``/``Frame Time:``, wrong number of values on a frame line, truncated or extra frame lines,
non-numeric or non-finite numbers, numbers beyond ``MAX_BVH_NUMBER``), and sizes are bounded by
``MER_MAX_BVH_BYTES``, ``MER_MAX_BVH_LINE_BYTES``, ``MER_MAX_BVH_JOINTS``, ``MER_MAX_BVH_FRAMES``
(:mod:`mer_data.base.limits`), and what it produces (the channel table, the kinematics of every
joint and End Site, a resampled motion) by ``MER_MAX_MOTION_VALUES``. The grammar is in :mod:`.bvh_parse`,
the detection of sides, up axis, units and facing in :mod:`.bvh_detect`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from mer_data.base.errors import BVHError
from mer_data.base.limits import check_motion_size
from mer_data.base.safe_io import decode_utf8, read_regular_file

from .bvh_detect import UNITS, branch_joint, detect_units, detect_up, detect_yaw, split_joint_name
from .bvh_parse import MAX_BVH_NUMBER, BvhJoint, parse_sections

log = logging.getLogger(__name__)

__all__ = [
    "BvhJoint",
    "BvhMotion",
    "read_bvh",
    "parse_bvh_bytes",
    "parse_bvh_text",
    "fk",
    "local_rotation",
    "local_translation",
    "axis_rotation",
    "branch_joint",
    "split_joint_name",
    "UNITS",
    "UP_ROTATIONS",
    "MAX_BVH_NUMBER",
]

#: File axes -> z-up axes.
UP_ROTATIONS: dict[str, np.ndarray] = {
    "z": np.eye(3),
    "y": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}
_FPS_SNAP = 1e-4
_MIN_FRAME_TIME = 1e-6
_SAMPLE_FRAMES = 256

Units = Literal["m", "cm", "mm", "in"]
Up = Literal["y", "z"]


@dataclass(frozen=True, eq=False)
class BvhMotion:
    """A parsed BVH file: the hierarchy, the channel values as written, and the conversion to mer.

    Attributes:
        path: the file (shown in errors).
        joints: (N,) joints and End Sites in file order.
        values: (F, C) float64 channel values as written (file units, degrees).
        frame_time: seconds per frame as written; fps: frame rate [Hz] (see module docstring).
        units: file unit (``UNITS`` key); up: the file's up axis, ``"y"`` or ``"z"``.
        yaw: facing correction about z [rad], applied after the up rotation.
        first_data_line: 1-based line of the first frame.
        notes: how units, up axis and facing were decided.
    """

    path: str
    joints: tuple[BvhJoint, ...]
    values: np.ndarray
    frame_time: float
    fps: float
    units: str
    up: str
    yaw: float
    first_data_line: int
    notes: tuple[str, ...] = ()

    @property
    def num_frames(self) -> int:
        return int(self.values.shape[0])

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def scale(self) -> float:
        """Metres per file unit."""
        return UNITS[self.units]

    @property
    def up_rotation(self) -> np.ndarray:
        """(3, 3) file axes -> z-up axes (no facing yaw)."""
        return UP_ROTATIONS[self.up].copy()

    @property
    def to_world(self) -> np.ndarray:
        """(3, 3) file axes -> mer world (z up, facing yaw applied)."""
        return _rot_z(self.yaw) @ UP_ROTATIONS[self.up]

    def index(self, name: str) -> int:
        """Index of the joint (or End Site) ``name``."""
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(f"{self.path} has no joint {name!r}")

    def children(self, i: int) -> list[int]:
        return [k for k, j in enumerate(self.joints) if j.parent == i]

    def fk_file(self, frames: np.ndarray | slice | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (F, N, 3) [file units] and frame rotations (F, N, 3, 3), in file axes."""
        vals = self.values if frames is None else self.values[frames]
        return fk(self.joints, vals)

    def positions(self, frames: np.ndarray | slice | None = None) -> np.ndarray:
        """(F, N, 3) joint and End Site positions [m] in mer's world (z up, x forward)."""
        pos, _ = self.fk_file(frames)
        return self.scale * pos @ self.to_world.T

    def rotations(self, frames: np.ndarray | slice | None = None) -> np.ndarray:
        """(F, N, 3, 3) each joint frame's orientation in mer's world (maps file-axis vectors of the frame)."""
        _, rot = self.fk_file(frames)
        return self.to_world @ rot


# ---- rotations and forward kinematics ---------------------------------------------------------


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """Rotations about the coordinate axis ``"x"|"y"|"z"`` by ``angle`` (...,) [rad] -> (..., 3, 3)."""
    angle = np.asarray(angle, np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i = "xyz".index(axis)
    a, b = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., a, a] = c
    out[..., b, b] = c
    out[..., a, b] = -s
    out[..., b, a] = s
    return out


def local_rotation(joint: BvhJoint, values: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotation of ``joint`` relative to its parent (its rotation channels, in order)."""
    R = np.broadcast_to(np.eye(3), (values.shape[0], 3, 3)).copy()
    for col, axis in joint.rotation_channels:
        R = R @ axis_rotation(axis, np.deg2rad(values[:, col]))
    return R


def local_translation(joint: BvhJoint, values: np.ndarray) -> np.ndarray:
    """(F, 3) translation of ``joint`` from its parent: the OFFSET, position channels replacing components."""
    t = np.tile(np.asarray(joint.offset, np.float64), (values.shape[0], 1))
    for col, comp in joint.position_channels:
        t[:, comp] = values[:, col]
    return t


def fk(joints: tuple[BvhJoint, ...] | list[BvhJoint], values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The file's own forward kinematics: (F, C) channel values -> positions (F, N, 3) [file units]
    and frame rotations (F, N, 3, 3), in file axes (see module docstring)."""
    F, N = values.shape[0], len(joints)
    check_motion_size(F, N * 12, what=f"the BVH's forward kinematics ({N} joints and End Sites, 12 numbers each)",
                      error=BVHError)  # fmt: skip
    pos = np.zeros((F, N, 3))
    rot = np.zeros((F, N, 3, 3))
    for k, j in enumerate(joints):
        t, R = local_translation(j, values), local_rotation(j, values)
        if j.parent < 0:
            pos[:, k], rot[:, k] = t, R
        else:
            Rp = rot[:, j.parent]
            pos[:, k] = pos[:, j.parent] + np.einsum("fij,fj->fi", Rp, t)
            rot[:, k] = Rp @ R
    return pos, rot


# ---- reading ----------------------------------------------------------------------------------


def read_bvh(
    path: str | Path, *, units: Units | None = None, up: Up | None = None, facing: Literal["auto", "keep"] = "auto"
) -> BvhMotion:
    """Read a ``.bvh`` file (a regular file of at most ``MER_MAX_BVH_BYTES``).

    Args:
        path: the file.
        units: ``"m"``, ``"cm"``, ``"mm"`` or ``"in"``; None detects them (module docstring).
        up: ``"y"`` or ``"z"``; None detects it.
        facing: ``"auto"`` turns the clip about z to start facing +x; ``"keep"`` does not.

    Raises:
        BVHError: with the file, the line and a fix (see the module docstring for the cases).
    """
    data = read_regular_file(path, BVHError, "MER_MAX_BVH_BYTES", fix="pass a regular .bvh file")
    return parse_bvh_bytes(data, path, units=units, up=up, facing=facing)


def parse_bvh_bytes(
    data: bytes,
    path: str | Path = "<bytes>",
    *,
    units: Units | None = None,
    up: Up | None = None,
    facing: Literal["auto", "keep"] = "auto",
) -> BvhMotion:
    """Parse the bytes of a BVH file (UTF-8 or ASCII; a byte-order mark is accepted)."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\0" in data[:256]:
        raise BVHError("the file is UTF-16 text or binary, not a BVH text file", path=path, line=1,
                       fix="save it as UTF-8 (or ASCII) text")  # fmt: skip
    return parse_bvh_text(decode_utf8(data, path, BVHError), path, units=units, up=up, facing=facing)


def parse_bvh_text(
    text: str,
    path: str | Path = "<text>",
    *,
    units: Units | None = None,
    up: Up | None = None,
    facing: Literal["auto", "keep"] = "auto",
) -> BvhMotion:
    """Parse BVH text into a :class:`BvhMotion` (arguments as :func:`read_bvh`)."""
    path = str(path)
    _check_options(units, up, facing, path)
    joints, values, frame_time, first = parse_sections(text, path)
    return _finish(path, tuple(joints), values, frame_time, first, units, up, facing)


def _check_options(units, up, facing, path: str) -> None:
    for what, value, allowed in (("units", units, (None, *UNITS)), ("up", up, (None, *UP_ROTATIONS)),
                                 ("facing", facing, ("auto", "keep"))):  # fmt: skip
        if value not in allowed:
            raise BVHError(f"{what}={value!r} is not one of {[a for a in allowed if a is not None]}", path=path,
                           fix=f"pass {what}= one of those (or leave it out to detect it)")  # fmt: skip


# ---- units, up axis, facing -------------------------------------------------------------------


def _finish(path: str, joints: tuple[BvhJoint, ...], values: np.ndarray, frame_time: float, first: int,
            units: str | None, up: str | None, facing: str) -> BvhMotion:  # fmt: skip
    if frame_time < _MIN_FRAME_TIME:
        raise BVHError(f"Frame Time {frame_time:g} s is under {_MIN_FRAME_TIME:g} s (over 1 MHz)", path=path,
                       line=first - 1, fix="write the seconds per frame, e.g. Frame Time: 0.0333333 for 30 Hz")  # fmt: skip
    fps = 1.0 / frame_time
    if round(fps) >= 1 and abs(fps - round(fps)) <= _FPS_SNAP * fps:
        fps = float(round(fps))
    F = values.shape[0]
    sample = np.unique(np.linspace(0, F - 1, min(F, _SAMPLE_FRAMES)).round().astype(np.int64))
    pos, _ = fk(joints, values[sample])
    notes = []
    if up is None:
        up, note = detect_up(joints, pos)
        notes.append(note)
    zpos = pos @ UP_ROTATIONS[up].T
    if units is None:
        units, note = detect_units(zpos)
        notes.append(note)
    H = float(np.percentile(np.ptp(zpos[..., 2], axis=1), 90)) * UNITS[units]
    if not 0.5 <= H <= 3.0:
        log.warning("%s: the figure is %.2f m tall in %s (expected 0.5-3 m for a human); pass units= if wrong",
                    path, H, units)  # fmt: skip
    yaw = 0.0
    if facing == "auto":
        yaw, note = detect_yaw(joints, zpos[0], H / UNITS[units])
        notes.append(note)
    for n in notes:
        log.debug("%s: %s", path, n)
    values.setflags(write=False)
    return BvhMotion(path, joints, values, frame_time, fps, units, up, yaw, first, tuple(notes))
