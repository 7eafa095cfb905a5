"""What a BVH file does not say: which joint is which side (names), the up axis, the units and the facing.

The rules are in :mod:`.bvh`'s docstring; each detector returns its choice and a note saying why.
"""

from __future__ import annotations

import logging
import math
import re

import numpy as np

from .bvh_parse import BvhJoint

log = logging.getLogger(__name__)

__all__ = ["split_joint_name", "branch_joint", "detect_up", "detect_units", "detect_yaw", "UNITS"]

#: Metres per file unit.
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
_UNIT_BOUNDS = ((10.0, "m"), (100.0, "in"), (500.0, "cm"), (math.inf, "mm"))


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


def _core(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


def _named(joints: tuple[BvhJoint, ...], test) -> list[int]:
    return [k for k, j in enumerate(joints) if test(*split_joint_name(j.name))]


def detect_up(joints: tuple[BvhJoint, ...], pos: np.ndarray) -> tuple[str, str]:
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


def detect_units(zpos: np.ndarray) -> tuple[str, str]:
    """Units from the figure size: FK positions (S, N, 3), z up, file units (module docstring)."""
    H = float(np.percentile(np.ptp(zpos[..., 2], axis=1), 90))
    units = next(u for bound, u in _UNIT_BOUNDS if H < bound)
    return units, f"units {units}: the figure is {H:.4g} file units tall ({H * UNITS[units]:.2f} m)"


def detect_yaw(joints: tuple[BvhJoint, ...], zpos0: np.ndarray, height: float) -> tuple[float, str]:
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
