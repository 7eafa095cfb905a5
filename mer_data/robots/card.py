"""Robot cards: the small YAML file beside each URDF that says what the URDF cannot.

Example (``g1``)::

    name: g1
    urdf: g1.urdf
    collision: collision.json        # optional: the links' collision shapes (mer_data.robots.shapes)
    description: Unitree G1, 29 DoF, rev 1.0
    license: BSD-3-Clause
    source: unitreerobotics/unitree_ros robots/g1_description/g1_29dof_rev_1_0.urdf @ d6f13aad
    keypoints:                       # the 14 key points: a link, an optional offset, or null
      left_hip: {link: left_hip_roll_link}
      left_toe: {link: left_ankle_roll_link, offset: [0.125, 0.0, -0.035]}   # [m], link frame
      left_hand: null                # absent
    locked: {hokuyo_joint: 0.0}      # joints held at a value [rad]
    nominal: {left_elbow_joint: 0.3} # optional nominal angles [rad] (default 0, clipped to limits)
    body_parts:                      # chains scaled together; default DEFAULT_BODY_PARTS
      left_leg: {start: left_hip, keypoints: [left_knee, left_ankle, left_toe]}
    lafan1_columns: [left_hip_pitch_joint, ...]   # joint order after root xyz + quat xyzw

Unknown fields are refused (with the list of known ones), never ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from mer_data.base.errors import RobotCardError
from mer_data.base.limits import MAX_LENGTH_M
from mer_data.base.safe_io import decode_utf8, read_regular_file, safe_yaml_load
from mer_data.skeleton import KEYPOINTS, BodyPart

__all__ = ["RobotCard", "KeypointSpec", "DEFAULT_BODY_PARTS", "load_card", "parse_card", "dump_card"]

#: The standard humanoid body plan used for reference scaling (paper: body-part scaling).
DEFAULT_BODY_PARTS: tuple[BodyPart, ...] = (
    BodyPart("pelvis", "base", ("left_hip", "right_hip")),
    BodyPart("chest", "base", ("left_shoulder", "right_shoulder")),
    BodyPart("left_leg", "left_hip", ("left_knee", "left_ankle", "left_toe")),
    BodyPart("right_leg", "right_hip", ("right_knee", "right_ankle", "right_toe")),
    BodyPart("left_arm", "left_shoulder", ("left_elbow", "left_hand")),
    BodyPart("right_arm", "right_shoulder", ("right_elbow", "right_hand")),
)

_CARD_FIELDS = (
    "name", "urdf", "description", "license", "source", "keypoints", "locked", "nominal",
    "body_parts", "lafan1_columns", "collision", "notes",
)  # fmt: skip
_KP_FIELDS = ("link", "offset", "note")


@dataclass(frozen=True)
class KeypointSpec:
    """A key point: the origin of ``link`` plus ``offset`` (link frame) [m]."""

    link: str
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    note: str | None = None


@dataclass(frozen=True)
class RobotCard:
    """Parsed robot card. ``keypoints`` holds all 14 names (``None`` = absent)."""

    name: str
    urdf: str
    keypoints: Mapping[str, KeypointSpec | None]
    locked: Mapping[str, float] = field(default_factory=dict)
    nominal: Mapping[str, float] = field(default_factory=dict)
    body_parts: tuple[BodyPart, ...] = DEFAULT_BODY_PARTS
    lafan1_columns: tuple[str, ...] | None = None
    collision: str | None = None
    description: str = ""
    license: str = ""
    source: str = ""
    notes: str = ""
    path: str | None = None

    def with_locked(self, extra: Mapping[str, float]) -> "RobotCard":
        from dataclasses import replace

        return replace(self, locked={**self.locked, **extra})


def load_card(path: str | Path) -> RobotCard:
    """Read a robot card YAML file (see module docstring)."""
    path = Path(path)
    data = read_regular_file(path, RobotCardError, "MER_MAX_CARD_BYTES", fix="check the robot's folder")
    return parse_card(decode_utf8(data, path, RobotCardError), str(path))


def _load_yaml(text: str, path: str) -> Any:
    try:
        return safe_yaml_load(text)
    except RecursionError:
        raise RobotCardError("the YAML is nested too deeply", path=path, fix="repair the YAML structure") from None
    except yaml.YAMLError as exc:
        line = getattr(getattr(exc, "problem_mark", None), "line", None)
        raise RobotCardError(
            f"not valid YAML: {getattr(exc, 'problem', exc)}",
            path=path,
            line=None if line is None else line + 1,
            fix="repair the YAML syntax",
        ) from None


def parse_keypoints(data: Any, path: str, *, require_all: bool = True) -> dict[str, KeypointSpec | None]:
    """Validate a ``keypoints`` mapping (from a card or a ``--keypoints`` file)."""
    if not isinstance(data, Mapping):
        raise RobotCardError(
            "keypoints must be a mapping of key point name to {link, offset} or null",
            path=path,
            element="keypoints",
        )
    unknown = [k for k in data if k not in KEYPOINTS]
    if unknown:
        raise RobotCardError(
            f"unknown key point(s) {', '.join(map(repr, unknown))}",
            path=path,
            element="keypoints",
            fix=f"use the names {', '.join(KEYPOINTS)}",
        )
    missing = [k for k in KEYPOINTS if k not in data]
    if missing and require_all:
        raise RobotCardError(
            f"key point(s) {', '.join(missing)} are not given",
            path=path,
            element="keypoints",
            fix="list all 14 key points; write `name: null` for the ones the robot does not have",
        )
    out: dict[str, KeypointSpec | None] = {}
    for k in KEYPOINTS:
        v = data.get(k)
        if v is None:
            out[k] = None
            continue
        if isinstance(v, str):
            v = {"link": v}
        if not isinstance(v, Mapping) or "link" not in v:
            raise RobotCardError(
                f"key point {k!r} must be {{link: NAME, offset: [x, y, z]}} or null",
                path=path,
                element=f"keypoints.{k}",
            )
        bad = [f for f in v if f not in _KP_FIELDS]
        if bad:
            raise RobotCardError(
                f"key point {k!r} has unknown field(s) {', '.join(map(repr, bad))}",
                path=path,
                element=f"keypoints.{k}",
                fix=f"allowed fields: {', '.join(_KP_FIELDS)}",
            )
        off = v.get("offset", (0.0, 0.0, 0.0))
        if (
            not isinstance(off, (list, tuple))
            or len(off) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in off)
        ):
            raise RobotCardError(
                f"offset of key point {k!r} must be three finite numbers [m]",
                path=path,
                element=f"keypoints.{k}.offset",
            )
        if any(abs(x) > MAX_LENGTH_M for x in off):
            raise RobotCardError(
                f"offset {list(off)} of key point {k!r} is beyond +-{MAX_LENGTH_M:g} m from its link",
                path=path,
                element=f"keypoints.{k}.offset",
                fix="give the offset in metres, in the link's frame",
            )
        out[k] = KeypointSpec(str(v["link"]), tuple(float(x) for x in off), v.get("note"))
    return out


def _float_map(data: Any, path: str, element: str) -> dict[str, float]:
    if data is None:
        return {}
    if not isinstance(data, Mapping) or not all(
        isinstance(v, (int, float)) and math.isfinite(v) for v in data.values()
    ):
        raise RobotCardError(
            f"{element} must map joint names to finite numbers [rad]", path=path, element=element
        )
    return {str(k): float(v) for k, v in data.items()}


def parse_card(text: str, path: str = "<card>") -> RobotCard:
    data = _load_yaml(text, path)
    if not isinstance(data, Mapping):
        raise RobotCardError("a robot card must be a YAML mapping", path=path)
    unknown = [k for k in data if k not in _CARD_FIELDS]
    if unknown:
        raise RobotCardError(
            f"unknown field(s) {', '.join(map(repr, unknown))}",
            path=path,
            fix=f"known fields: {', '.join(_CARD_FIELDS)}",
        )
    for req in ("name", "urdf", "keypoints"):
        if req not in data:
            raise RobotCardError(f"missing required field {req!r}", path=path)
    parts = DEFAULT_BODY_PARTS
    if data.get("body_parts") is not None:
        bp = data["body_parts"]
        if not isinstance(bp, Mapping):
            raise RobotCardError("body_parts must be a mapping", path=path, element="body_parts")
        parts_l = []
        for name, spec in bp.items():
            if (
                not isinstance(spec, Mapping)
                or set(spec) != {"start", "keypoints"}
                or not isinstance(spec["keypoints"], list)
            ):
                raise RobotCardError(
                    f"body part {name!r} must be {{start: base|KEYPOINT, keypoints: [KEYPOINT, ...]}}",
                    path=path,
                    element=f"body_parts.{name}",
                )
            for k in [spec["start"], *spec["keypoints"]]:
                if k != "base" and k not in KEYPOINTS:
                    raise RobotCardError(
                        f"body part {name!r} names {k!r}, which is not a key point",
                        path=path,
                        element=f"body_parts.{name}",
                        fix=f"use 'base' or one of {', '.join(KEYPOINTS)}",
                    )
            parts_l.append(BodyPart(str(name), str(spec["start"]), tuple(spec["keypoints"])))
        parts = tuple(parts_l)
    cols = data.get("lafan1_columns")
    if cols is not None and (not isinstance(cols, list) or not all(isinstance(c, str) for c in cols)):
        raise RobotCardError("lafan1_columns must be a list of joint names", path=path, element="lafan1_columns")
    coll = data.get("collision")
    if coll is not None and (not isinstance(coll, str) or not coll or Path(coll).name != coll or coll.startswith(".")):
        raise RobotCardError(
            f"collision must be the name of a file beside the card, got {coll!r}",
            path=path,
            element="collision",
            fix="e.g. collision: collision.json",
        )
    return RobotCard(
        name=str(data["name"]),
        urdf=str(data["urdf"]),
        keypoints=parse_keypoints(data["keypoints"], path),
        locked=_float_map(data.get("locked"), path, "locked"),
        nominal=_float_map(data.get("nominal"), path, "nominal"),
        body_parts=parts,
        lafan1_columns=None if cols is None else tuple(cols),
        collision=coll,
        description=str(data.get("description", "")),
        license=str(data.get("license", "")),
        source=str(data.get("source", "")),
        notes=str(data.get("notes", "")),
        path=path,
    )


def dump_card(card: RobotCard) -> str:
    """YAML text of a card (what :func:`parse_card` reads back)."""
    kp = {}
    for k in KEYPOINTS:
        spec = card.keypoints.get(k)
        if spec is None:
            kp[k] = None
        else:
            d: dict[str, Any] = {"link": spec.link}
            if any(spec.offset):
                d["offset"] = list(spec.offset)
            if spec.note:
                d["note"] = spec.note
            kp[k] = d
    data: dict[str, Any] = {"name": card.name, "urdf": card.urdf}
    for f in ("description", "license", "source"):
        if getattr(card, f):
            data[f] = getattr(card, f)
    data["keypoints"] = kp
    if card.locked:
        data["locked"] = dict(card.locked)
    if card.nominal:
        data["nominal"] = dict(card.nominal)
    data["body_parts"] = {b.name: {"start": b.start, "keypoints": list(b.keypoints)} for b in card.body_parts}
    if card.lafan1_columns:
        data["lafan1_columns"] = list(card.lafan1_columns)
    if card.collision:
        data["collision"] = card.collision
    if card.notes:
        data["notes"] = card.notes
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
