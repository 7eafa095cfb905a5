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
(:mod:`mer_data.base.limits`).
"""

from __future__ import annotations

import itertools
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from mer_data.base.errors import BVHError
from mer_data.base.limits import limit, too_big
from mer_data.base.safe_io import decode_utf8, read_regular_file

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

#: Metres per file unit.
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: File axes -> z-up axes.
UP_ROTATIONS: dict[str, np.ndarray] = {
    "z": np.eye(3),
    "y": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}
#: Largest magnitude accepted for any number of the file (keeps every computed value finite).
MAX_BVH_NUMBER = 1e9
_UNIT_BOUNDS = ((10.0, "m"), (100.0, "in"), (500.0, "cm"), (math.inf, "mm"))
_FPS_SNAP = 1e-4
_MIN_FRAME_TIME = 1e-6
_SAMPLE_FRAMES = 256
_CHANNELS = {f"{a}{k}".upper(): f"{a}{k}" for k in ("position", "rotation") for a in "XYZ"}
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
_COUNT = re.compile(r"[0-9]{1,9}\Z")
_NOT_NUMERIC = re.compile(r"[^0-9eE+\-.\s]")
_FILE_FIX = "re-export the BVH from your motion capture tool"

Units = Literal["m", "cm", "mm", "in"]
Up = Literal["y", "z"]


@dataclass(frozen=True)
class BvhJoint:
    """One joint (or End Site) of the hierarchy, in file order (parents first).

    Attributes:
        name: the joint's name (End Sites: ``<parent>_End``).
        parent: index of the parent joint, -1 for the ROOT.
        offset: (3,) OFFSET in file units and axes.
        channels: channel names as written (``"Zrotation"``...), canonical capitalisation.
        column: column of the first channel in the frame table.
        line: 1-based line of the ROOT / JOINT / End Site keyword.
        end_site: True for End Sites.
    """

    name: str
    parent: int
    offset: tuple[float, float, float]
    channels: tuple[str, ...]
    column: int
    line: int
    end_site: bool = False

    @property
    def rotation_channels(self) -> tuple[tuple[int, str], ...]:
        """(column, axis ``"x"|"y"|"z"``) of each rotation channel, in the order written."""
        return tuple((self.column + i, c[0].lower()) for i, c in enumerate(self.channels) if c.endswith("rotation"))

    @property
    def position_channels(self) -> tuple[tuple[int, int], ...]:
        """(column, component 0-2) of each position channel."""
        return tuple((self.column + i, "XYZ".index(c[0])) for i, c in enumerate(self.channels) if c.endswith("position"))


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


# ---- joint names ------------------------------------------------------------------------------

_NAMESPACE = re.compile(r"^.*[:|]")
_PREFIX = re.compile(r"^(?:Bip0*1|Character\d*)[ _]", re.I)
_ASF = "femur|tibia|foot|toes|humerus|radius|wrist|hand|clavicle|hipjoint|fingers|thumb"
_SIDE_RULES = (
    re.compile(r"^(?P<side>(?i:left|right))(?P<core>[A-Z0-9].*|[_ .\-]+.+)$"),  # LeftUpLeg, leftArm, LEFT_ARM
    re.compile(r"^(?P<core>.+?)(?:[_ .\-]+(?P<side>(?i:left|right))|(?P<side2>Left|Right))$"),  # Arm_Left, ArmLeft
    re.compile(r"^(?P<side>[LR])[_ .\-]+(?P<core>.+)$", re.I),  # L_Hip, l.hand, "L Thigh"
    re.compile(r"^(?P<core>.+?)[_ .\-]+(?P<side>[LR])$", re.I),  # UpperLeg_L, hand.l
    re.compile(r"^(?P<side>[LR])(?P<core>[A-Z].*)$"),  # LHip, RUpperArm
    re.compile(rf"^(?P<side>[lr])(?P<core>{_ASF})$"),  # CMU ASF names: lfemur, rtibia
)


def split_joint_name(name: str) -> tuple[str | None, str]:
    """``(side, core)`` of a joint name: side ``"left"``, ``"right"`` or None; core lower case
    without namespace (``mixamorig:``), prefix (``Bip01 ``, ``Character1_``), side or separators.

    ``LeftUpLeg`` -> (left, upleg); ``UpperLeg_L`` -> (left, upperleg); ``mixamorig:RightForeArm``
    -> (right, forearm); ``L_Hip`` -> (left, hip); ``lfemur`` -> (left, femur); ``Hips`` -> (None, hips).
    """
    base = _PREFIX.sub("", _NAMESPACE.sub("", name.strip()))
    for rule in _SIDE_RULES:
        m = rule.match(base)
        if m:
            side = (m.groupdict().get("side") or m.groupdict().get("side2") or "").lower()
            side = {"l": "left", "r": "right"}.get(side, side)
            return side, _core(m["core"])
    return None, _core(base)


def _core(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


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
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    _check_line_lengths(lines, path)
    motion_at = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    last = len(lines)  # the last line that is not blank
    while last > 1 and not lines[last - 1].strip():
        last -= 1
    header = lines if motion_at is None else lines[:motion_at]
    joints = _Hierarchy(header, path, last if motion_at is None else motion_at + 1).parse(motion_at)
    if motion_at is None:
        raise BVHError("there is no MOTION section (the file ends after the hierarchy)", path=path, line=last,
                       fix="the file was cut short or is a hierarchy only: " + _FILE_FIX)  # fmt: skip
    C = sum(len(j.channels) for j in joints)
    if C == 0:
        raise BVHError("the hierarchy has no CHANNELS: there is no motion to read", path=path, line=joints[0].line,
                       fix="give the ROOT at least its CHANNELS (e.g. CHANNELS 6 Xposition ... Yrotation)")  # fmt: skip
    frames, frame_time, first = _motion_header(lines, motion_at, path)
    values = _parse_frames(lines, first, frames, joints, path, cut_short=not text.endswith(("\n", "\r")))
    return _finish(path, tuple(joints), values, frame_time, first + 2, units, up, facing)


def _check_options(units, up, facing, path: str) -> None:
    for what, value, allowed in (("units", units, (None, *UNITS)), ("up", up, (None, *UP_ROTATIONS)),
                                 ("facing", facing, ("auto", "keep"))):  # fmt: skip
        if value not in allowed:
            raise BVHError(f"{what}={value!r} is not one of {[a for a in allowed if a is not None]}", path=path,
                           fix=f"pass {what}= one of those (or leave it out to detect it)")  # fmt: skip


def _check_line_lengths(lines: list[str], path: str) -> None:
    """Every line within ``MER_MAX_BVH_LINE_BYTES`` (UTF-8 bytes; only lines that could be over are encoded)."""
    cap = limit("MER_MAX_BVH_LINE_BYTES")
    for i, line in enumerate(lines):
        if len(line) * 4 > cap and (n := len(line.encode("utf-8"))) > cap:
            msg, fix = too_big("MER_MAX_BVH_LINE_BYTES", n)
            raise BVHError(msg, path=path, line=i + 1, fix=fix)


class _Hierarchy:
    """Parser of the HIERARCHY section: tokens with their lines; ROOT/JOINT names are the rest of
    their line (they may contain spaces). Iterative (a deep hierarchy cannot exhaust the stack)."""

    def __init__(self, lines: list[str], path: str, end_line: int) -> None:
        self.path = path
        self.end_line = end_line  # the MOTION line, or the last line of the file
        self.toks: list[tuple[str, int]] = []  # (text, 1-based line)
        for i, raw in enumerate(lines, start=1):
            words = raw.split()
            if words and words[0].upper() in ("ROOT", "JOINT"):
                name = raw.strip()[len(words[0]) :].strip()
                brace = name.endswith("{")
                name = name[:-1].strip() if brace else name
                self.toks += [(words[0], i), (name, i)] + ([("{", i)] if brace else [])
            else:
                self.toks += [(w, i) for w in words]
        self.pos = 0
        self.joints: list[dict] = []
        self.lines_of: dict[str, int] = {}
        self.column = 0

    # -- token access --
    def _peek(self) -> tuple[str, int] | None:
        return self.toks[self.pos] if self.pos < len(self.toks) else None

    def _take(self, expected: str, where: str) -> tuple[str, int]:
        tok = self._peek()
        if tok is None:
            self._fail(f"the hierarchy ends where {expected} was expected ({where})", self.end_line,
                       "complete the hierarchy (every '{' needs its '}', and MOTION follows the ROOT's '}')")  # fmt: skip
        self.pos += 1
        return tok

    def _expect(self, word: str, where: str) -> int:
        tok = self._take(f"'{word}'", where)
        if tok[0].upper() != word.upper():
            self._fail(f"expected '{word}' ({where}), found {tok[0]!r}", tok[1], _FILE_FIX)
        return tok[1]

    def _fail(self, message: str, line: int, fix: str, element: str | None = None):
        raise BVHError(message, path=self.path, line=line, element=element, fix=fix)

    # -- grammar --
    def parse(self, motion_at: int | None) -> list[BvhJoint]:
        tok = self._peek()
        if tok is None or tok[0].upper() != "HIERARCHY":
            found = "an empty file" if tok is None else repr(tok[0][:40])
            self._fail(f"not a BVH file: it must start with HIERARCHY, found {found}", tok[1] if tok else 1,
                       "pass a BVH motion capture file (text starting with HIERARCHY)")  # fmt: skip
        self.pos += 1
        tok = self._take("ROOT", "after HIERARCHY")
        if tok[0].upper() != "ROOT":
            self._fail(f"expected ROOT after HIERARCHY, found {tok[0]!r}", tok[1], _FILE_FIX)
        stack = [self._joint_header(-1, tok[1])]  # open joints: (index, line of its '{')
        while stack:
            tok = self._peek()
            parent, opened = stack[-1]
            pname = self.joints[parent]["name"]
            if tok is None:
                where = "MOTION starts" if motion_at is not None else "the file ends"
                self._fail(f"unbalanced braces: {where} inside joint {pname!r}, whose '{{' on line {opened} is never "
                           "closed", self.end_line, "add the missing '}' (one per ROOT, JOINT and End Site)")  # fmt: skip
            self.pos += 1
            word = tok[0].upper()
            if word == "JOINT":
                stack.append(self._joint_header(parent, tok[1]))
            elif word == "END":
                self._end_site(parent, tok[1])
            elif word == "}":
                stack.pop()
            elif word == "ROOT":
                self._fail(f"ROOT inside joint {pname!r}: a ROOT's '}}' is missing, or the file has several ROOTs",
                           tok[1], "balance the braces; mer reads one skeleton (one ROOT) per file")  # fmt: skip
            elif word in ("OFFSET", "CHANNELS"):
                self._fail(f"{tok[0]} out of place in joint {pname!r}: OFFSET then CHANNELS come once, right after "
                           "the joint's '{'", tok[1], _FILE_FIX)  # fmt: skip
            else:
                self._fail(f"unexpected {tok[0][:40]!r} in joint {pname!r} (expected JOINT, End Site or '}}')", tok[1],
                           _FILE_FIX)  # fmt: skip
        tok = self._peek()
        if tok is not None:
            if tok[0] == "}":
                self._fail("unbalanced braces: a '}' closes nothing (the ROOT is already closed)", tok[1],
                           "remove the extra '}'")  # fmt: skip
            if tok[0].upper() == "ROOT":
                self._fail("a second ROOT: several skeletons in one file are not supported", tok[1],
                           "export one skeleton per file")  # fmt: skip
            self._fail(f"unexpected {tok[0][:40]!r} after the hierarchy (expected MOTION)", tok[1], _FILE_FIX)
        return self._joints()

    def _add(self, **kw) -> int:
        if len(self.joints) >= limit("MER_MAX_BVH_JOINTS"):
            msg, fix = too_big("MER_MAX_BVH_JOINTS", f"over {len(self.joints):,}")
            raise BVHError(msg, path=self.path, line=kw["line"], fix=fix)
        self.joints.append(kw)
        return len(self.joints) - 1

    def _joint_header(self, parent: int, line: int) -> tuple[int, int]:
        kind = "ROOT" if parent < 0 else "JOINT"
        name_tok = self._take("a joint name", f"after {kind}")
        name = name_tok[0]
        if not name or name in ("{", "}"):
            self._fail(f"{kind} without a name", line, f"give every joint a name: {kind} NAME")
        if name in self.lines_of:
            self._fail(f"duplicate joint name {name!r} (also on line {self.lines_of[name]})", line,
                       "give every joint a unique name", element=f"joint {name!r}")  # fmt: skip
        self.lines_of[name] = line
        opened = self._expect("{", f"after {kind} {name}")
        offset = self._offset(name)
        channels = self._channels(name) if (self._peek() or ("",))[0].upper() == "CHANNELS" else ()
        index = self._add(name=name, parent=parent, offset=offset, channels=channels, column=self.column, line=line)
        self.column += len(channels)
        return index, opened

    def _end_site(self, parent: int, line: int) -> None:
        self._expect("Site", "End Site")
        pname = self.joints[parent]["name"]
        self._expect("{", f"after End Site of {pname}")
        offset = self._offset(f"End Site of {pname}")
        tok = self._take("'}'", f"closing the End Site of {pname}")
        if tok[0] != "}":
            self._fail(f"an End Site holds only an OFFSET, found {tok[0][:40]!r} (End Site of {pname!r})", tok[1],
                       "close the End Site with '}' after its OFFSET; End Sites have no channels or children")  # fmt: skip
        self._add(name=None, parent=parent, offset=offset, channels=(), column=self.column, line=line)

    def _offset(self, owner: str) -> tuple[float, float, float]:
        line = self._expect("OFFSET", f"first in {owner}")
        vals = []
        for k in range(3):
            tok = self._take("a number", f"OFFSET of {owner}")
            if tok[1] != line:
                self._fail(f"OFFSET of {owner} has {k} numbers, expected 3", line, "write OFFSET x y z")
            vals.append(_number(tok[0], self.path, tok[1], f"OFFSET of {owner}"))
        nxt = self._peek()
        if nxt is not None and nxt[1] == line and _NUMBER.match(nxt[0]):
            self._fail(f"OFFSET of {owner} has more than 3 numbers ({nxt[0][:40]!r})", line, "write OFFSET x y z")
        return (vals[0], vals[1], vals[2])

    def _channels(self, owner: str) -> tuple[str, ...]:
        line = self._take("CHANNELS", owner)[1]
        tok = self._take("the channel count", f"CHANNELS of {owner}")
        if not _COUNT.match(tok[0]) or int(tok[0]) > 6:
            self._fail(f"CHANNELS of {owner}: the count {tok[0][:40]!r} is not a number from 0 to 6", line,
                       "write CHANNELS N NAME...: at most 3 position and 3 rotation channels")  # fmt: skip
        n, out = int(tok[0]), []
        for k in range(n):
            tok = self._peek()
            if tok is None or tok[1] != line:
                self._fail(f"CHANNELS of {owner} announces {n} channels but lists {k}", line,
                           "make the count match the channel names")  # fmt: skip
            self.pos += 1
            name = _CHANNELS.get(tok[0].upper())
            if name is None:
                self._fail(f"unknown channel {tok[0][:40]!r} in joint {owner!r}", line,
                           "channels are Xposition, Yposition, Zposition, Xrotation, Yrotation, Zrotation",
                           element=f"joint {owner!r}")  # fmt: skip
            if name in out:
                self._fail(f"channel {name} appears twice in joint {owner!r}", line, "list each channel once")
            out.append(name)
        nxt = self._peek()
        if nxt is not None and nxt[1] == line:
            self._fail(f"CHANNELS of {owner} announces {n} channels but lists more ({nxt[0][:40]!r})", line,
                       "make the count match the channel names")  # fmt: skip
        return tuple(out)

    def _joints(self) -> list[BvhJoint]:
        taken = set(self.lines_of)
        out = []
        for j in self.joints:
            name = j["name"]
            if name is None:  # an End Site: <parent>_End, made unique
                stem = f"{self.joints[j['parent']]['name']}_End"
                name, k = stem, 2
                while name in taken:
                    name, k = f"{stem}_{k}", k + 1
                taken.add(name)
            out.append(BvhJoint(name, j["parent"], j["offset"], j["channels"], j["column"], j["line"],
                                end_site=j["name"] is None))  # fmt: skip
        return out


def _number(text: str, path: str, line: int, what: str) -> float:
    if not _NUMBER.match(text):
        raise BVHError(f"{what}: {text[:40]!r} is not a number", path=path, line=line,
                       fix="numbers are decimal (1.5, -2, 3e-4); remove stray text")  # fmt: skip
    v = float(text)
    if not abs(v) <= MAX_BVH_NUMBER:
        raise BVHError(f"{what}: {text[:40]} is beyond +-{MAX_BVH_NUMBER:g}", path=path, line=line,
                       fix="check the export (units, a corrupt value)")  # fmt: skip
    return v


_FRAMES = re.compile(r"\s*frames\s*:\s*(\S+)\s*\Z", re.I)
_FRAME_TIME = re.compile(r"\s*frame\s+time\s*:\s*(\S+)\s*\Z", re.I)


def _motion_header(lines: list[str], motion_at: int, path: str) -> tuple[int, float, int]:
    """Frames, Frame Time and the 0-based index of the Frame Time line."""
    fix = "after MOTION write 'Frames: N' and 'Frame Time: SECONDS' on two lines"
    i = motion_at + 1
    m = _FRAMES.match(lines[i]) if i < len(lines) else None
    if m is None:
        found = repr(lines[i][:60]) if i < len(lines) else "the end of the file"
        raise BVHError(f"expected 'Frames: N' after MOTION, found {found}", path=path, line=i + 1, fix=fix)
    if not _COUNT.match(m[1]):
        raise BVHError(f"Frames: {m[1][:40]!r} is not a whole number", path=path, line=i + 1, fix=fix)
    frames = int(m[1])
    if frames == 0:
        raise BVHError("Frames: 0, the clip has no frames", path=path, line=i + 1, fix="export at least one frame")
    if frames > limit("MER_MAX_BVH_FRAMES"):
        msg, how = too_big("MER_MAX_BVH_FRAMES", frames)
        raise BVHError(msg, path=path, line=i + 1, fix=how)
    i += 1
    m = _FRAME_TIME.match(lines[i]) if i < len(lines) else None
    if m is None:
        found = repr(lines[i][:60]) if i < len(lines) else "the end of the file"
        raise BVHError(f"expected 'Frame Time: SECONDS', found {found}", path=path, line=i + 1, fix=fix)
    ft = _number(m[1], path, i + 1, "Frame Time")
    if not ft > 0:
        raise BVHError(f"Frame Time must be positive (seconds per frame), got {m[1]}", path=path, line=i + 1,
                       fix="write the seconds per frame, e.g. Frame Time: 0.0333333 for 30 Hz")  # fmt: skip
    return frames, ft, i


def _column_labels(joints: list[BvhJoint]) -> list[str]:
    return [f"{c} of {j.name!r}" for j in joints for c in j.channels]


def _parse_frames(lines: list[str], header: int, frames: int, joints: list[BvhJoint], path: str, *,
                  cut_short: bool) -> np.ndarray:  # fmt: skip
    """(F, C) values of the frame lines after the Frame Time line (0-based index ``header``)."""
    C = sum(len(j.channels) for j in joints)
    data = lines[header + 1 :]
    while data and not data[-1].strip():
        data.pop()
    first = header + 2  # 1-based line of the first frame
    rows = [line.split() for line in data[:frames]]
    for i, row in enumerate(rows):
        if len(row) != C:
            _wrong_count(row, i, C, len(data), first, path, cut_short)
    if len(data) < frames:
        raise BVHError(f"truncated: the file has {len(data)} of the {frames} frames that 'Frames:' announces",
                       path=path, line=first + len(data) - 1 if data else header + 1,
                       fix=f"the file was cut short (interrupted copy?): fetch it again, or set Frames: {len(data)}")  # fmt: skip
    if len(data) > frames:
        raise BVHError(f"{len(data)} frame lines, but 'Frames:' says {frames}", path=path, line=first + frames,
                       fix=f"set Frames: {len(data)}, or delete the lines after frame {frames}")  # fmt: skip
    values = None
    if not any(_NOT_NUMERIC.search(line) for line in data):  # no letters: float() reads exactly our syntax
        try:
            values = np.fromiter(map(float, itertools.chain.from_iterable(rows)), np.float64, frames * C)
        except ValueError:
            pass
    if values is None:
        _find_bad_number(rows, first, path, _column_labels(joints))
    values = values.reshape(frames, C)
    bad = ~(np.abs(values) <= MAX_BVH_NUMBER)
    if bad.any():
        i, c = (int(x[0]) for x in np.nonzero(bad))
        raise BVHError(f"value {rows[i][c][:40]} of {_column_labels(joints)[c]} is not finite or beyond "
                       f"+-{MAX_BVH_NUMBER:g}", path=path, line=first + i, element=f"frame {i + 1}",
                       fix="repair or drop the frames with NaN/inf (the capture has gaps)")  # fmt: skip
    return values


def _wrong_count(row: list[str], i: int, C: int, n: int, first: int, path: str, cut_short: bool):
    if not row:
        raise BVHError("blank line inside the frame data", path=path, line=first + i, fix="remove the blank line")
    if i == n - 1 and cut_short and len(row) < C:
        raise BVHError(f"truncated last frame: {len(row)} of {C} values; the file ends mid-line", path=path,
                       line=first + i, fix="the file was cut short: fetch it again, or delete the last line "
                       "and lower Frames: by one")  # fmt: skip
    raise BVHError(f"{len(row)} values on this frame line, expected {C} (one per channel of the hierarchy)",
                   path=path, line=first + i, element=f"frame {i + 1}",
                   fix="every frame line needs one number per channel, in hierarchy order")  # fmt: skip


def _find_bad_number(rows: list[list[str]], first: int, path: str, labels: list[str]):
    for i, row in enumerate(rows):
        for c, cell in enumerate(row):
            if not _NUMBER.match(cell):
                raise BVHError(f"{cell[:40]!r} is not a number ({labels[c]})", path=path, line=first + i,
                               element=f"frame {i + 1}",
                               fix="frame lines hold decimal numbers only (1.5, -2, 3e-4); no NaN, inf or text")  # fmt: skip
    raise AssertionError("unreachable: a frame value failed to parse but every cell looks numeric")


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
        up, note = _detect_up(joints, pos)
        notes.append(note)
    zpos = pos @ UP_ROTATIONS[up].T
    if units is None:
        units, note = _detect_units(zpos)
        notes.append(note)
    H = float(np.percentile(np.ptp(zpos[..., 2], axis=1), 90)) * UNITS[units]
    if not 0.5 <= H <= 3.0:
        log.warning("%s: the figure is %.2f m tall in %s (expected 0.5-3 m for a human); pass units= if wrong",
                    path, H, units)  # fmt: skip
    yaw = 0.0
    if facing == "auto":
        yaw, note = _detect_yaw(joints, zpos[0], H / UNITS[units])
        notes.append(note)
    for n in notes:
        log.debug("%s: %s", path, n)
    values.setflags(write=False)
    return BvhMotion(path, joints, values, frame_time, fps, units, up, yaw, first, tuple(notes))


def _named(joints: tuple[BvhJoint, ...], test) -> list[int]:
    return [k for k, j in enumerate(joints) if test(*split_joint_name(j.name))]


def _detect_up(joints: tuple[BvhJoint, ...], pos: np.ndarray) -> tuple[str, str]:
    """``"y"`` or ``"z"`` from FK positions (S, N, 3) in file axes (module docstring)."""
    top = _named(joints, lambda side, core: side is None and core.startswith(("head", "neck")))
    low = _named(joints, lambda side, core: side is not None and core.startswith(("foot", "toe", "ankle", "ball")))
    if top and low:
        d = (pos[:, top].mean(1) - pos[:, low].mean(1)).mean(0)
        up = "y" if d[1] >= d[2] else "z"
        i = "xyz".index(up)
        sure = d[i] > 0 and d[i] >= 0.7 * float(np.linalg.norm(d))
        note = f"up axis {up}: the head lies {'' if sure else 'only partly '}along +{up} from the feet"
        if not sure:
            log.warning("%s; pass up= if the result is wrong", note)
        return up, note
    base = branch_joint(joints)
    subtrees = [_subtree(joints, c) for c in range(len(joints)) if joints[c].parent == base and not joints[c].end_site]
    if len(subtrees) >= 2:  # the torso (the largest subtree of the hips) lies above the legs
        subtrees.sort(key=len, reverse=True)
        rest = [k for t in subtrees[1:] for k in t]
        d = (pos[:, subtrees[0]].mean(1) - pos[:, rest].mean(1)).mean(0)
        up = "y" if d[1] >= d[2] else "z"
        name = joints[base].name
        return up, f"up axis {up}: no head/foot names; the largest subtree of {name!r} lies along +{up} from the others"
    extent = np.median(np.ptp(pos, axis=1), axis=0)
    up = "y" if extent[1] >= extent[2] else "z"
    return up, f"up axis {up}: no head/foot names or branches, the figure is tallest along {up}"


def branch_joint(joints: tuple[BvhJoint, ...] | list[BvhJoint]) -> int:
    """The first joint from the ROOT that has other than one child joint (a human's hips)."""
    k = 0
    while True:
        kids = [c for c, j in enumerate(joints) if j.parent == k]
        if len(kids) != 1 or joints[kids[0]].end_site:
            return k
        k = kids[0]


def _subtree(joints: tuple[BvhJoint, ...], top: int) -> list[int]:
    inside = {top}
    for k in range(top + 1, len(joints)):
        if joints[k].parent in inside:
            inside.add(k)
    return sorted(inside)


def _detect_units(zpos: np.ndarray) -> tuple[str, str]:
    """Units from the figure size: FK positions (S, N, 3), z up, file units (module docstring)."""
    H = float(np.percentile(np.ptp(zpos[..., 2], axis=1), 90))
    units = next(u for bound, u in _UNIT_BOUNDS if H < bound)
    return units, f"units {units}: the figure is {H:.4g} file units tall ({H * UNITS[units]:.2f} m)"


def _detect_yaw(joints: tuple[BvhJoint, ...], zpos0: np.ndarray, height: float) -> tuple[float, str]:
    """Yaw [rad] that turns the figure's left (first frame, (N, 3) z-up positions) to +y."""
    sides = [split_joint_name(j.name) for j in joints]
    right = {core: k for k, (side, core) in enumerate(sides) if side == "right"}
    depth = [0] * len(joints)
    for k, j in enumerate(joints):
        depth[k] = depth[j.parent] + 1 if j.parent >= 0 else 0
    by_depth: dict[int, list[np.ndarray]] = {}
    for k, (side, core) in enumerate(sides):
        if side == "left" and core in right:
            d = max(depth[k], depth[right[core]])
            by_depth.setdefault(d, []).append(zpos0[k, :2] - zpos0[right[core], :2])
    for d in sorted(by_depth):
        v = np.sum(by_depth[d], axis=0)
        if np.linalg.norm(v) / len(by_depth[d]) > 0.02 * height:
            yaw = math.pi / 2 - math.atan2(v[1], v[0])
            yaw = math.atan2(math.sin(yaw), math.cos(yaw))
            return yaw, f"facing: turned {math.degrees(yaw):.1f} deg about z so that the left side is +y at frame 1"
    return 0.0, "facing: kept (no left/right joint pairs apart at frame 1)"
