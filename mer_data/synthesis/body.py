"""What a synthetic motion needs to know about a robot, found from its skeleton alone.

Joint groups (left/right leg and arm, torso) come from the key points: a joint belongs to the limb
whose end (toe, ankle, hand...) is the only limb end below it; joints above several limb ends
(waist, spine) or above none but under the torso (neck, head) are the torso; joints past a limb end
(wrists after a hand key point) follow their parent. Pitch roles (hip, knee, ankle, shoulder,
elbow) are the joints of a limb whose axis at the zero pose is mostly the root's y axis (lateral):
their angle is set through ``r``, the rotation about the root's +y, as ``q = sign(axis_y) * r``.
With that convention ``r < 0`` at a hip or shoulder swings the limb forward, ``r > 0`` at a knee
moves the foot backward (flexion) and ``r > 0`` at an ankle points the toe down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mer_data.skeleton import Skeleton

__all__ = ["Body", "GROUPS", "SIDES", "body_of"]

SIDES = ("left", "right")
GROUPS = ("left_leg", "right_leg", "left_arm", "right_arm", "torso")
_ENDS = {
    "leg": ("toe", "ankle", "knee", "hip"),
    "arm": ("hand", "elbow", "shoulder"),
}
_PITCH = 0.7  # |axis_y| above this makes a joint a pitch joint


@dataclass(frozen=True)
class Body:
    """Roles of a skeleton's joints (node indices; -1 where the robot has no such joint).

    Attributes:
        dof: (D,) actuated joint nodes, in node order.
        group: (J,) index into :data:`GROUPS` per node (-1 for base, sites and mimic joints).
        hip, knee, ankle, shoulder, elbow: side -> pitch joint node or -1.
        sign: (J,) ``sign(axis_y)`` of every node (1 where it is 0).
        leg_length: hip-to-sole height at the zero pose [m] (at least 0.2).
        margin: (J,) soft-clamp margin per node [rad] (6 % of the range).
    """

    skel: Skeleton
    dof: np.ndarray
    group: np.ndarray
    hip: dict[str, int]
    knee: dict[str, int]
    ankle: dict[str, int]
    shoulder: dict[str, int]
    elbow: dict[str, int]
    sign: np.ndarray
    leg_length: float
    margin: np.ndarray

    def members(self, group: str) -> np.ndarray:
        return self.dof[self.group[self.dof] == GROUPS.index(group)]


def _limb_end(skel: Skeleton, side: str, limb: str) -> int:
    for name in _ENDS[limb]:
        node = skel.keypoints.get(f"{side}_{name}", -1)
        if node >= 0:
            return node
    return -1


def _groups(skel: Skeleton) -> np.ndarray:
    ends = {f"{s}_{l}": _limb_end(skel, s, l) for l in ("leg", "arm") for s in SIDES}
    group = np.full(skel.num_nodes, -1, np.int64)
    dof = skel.dof_mask
    for j in range(1, skel.num_nodes):
        if not dof[j]:
            continue
        below = skel.subtree(j)
        limbs = [g for g, e in ends.items() if e >= 0 and below[e]]
        if len(limbs) == 1:
            group[j] = GROUPS.index(limbs[0])
        elif len(limbs) == 0 and group[skel.parents[j]] >= 0:
            group[j] = group[skel.parents[j]]  # past a limb end (wrist after a hand key point)
        else:
            group[j] = GROUPS.index("torso")
    return group


def _pitch_on_path(skel: Skeleton, end: int, group: np.ndarray, want: int) -> list[int]:
    """Pitch joints of group ``want`` from the base down to ``end``: lateral axis, across the limb."""
    rest = skel.rest_positions
    out = []
    for j in skel.path_to_root(end)[::-1]:
        if not (skel.dof_mask[j] and group[j] == want and abs(skel.axes[j, 1]) >= _PITCH):
            continue
        along = rest[end] - rest[j]
        n = np.linalg.norm(along)
        if n > 1e-6 and abs(skel.axes[j] @ along) / n > 0.5:
            continue  # a twist about the limb, not a pitch
        out.append(j)
    return out


def body_of(skel: Skeleton) -> Body:
    """The :class:`Body` of ``skel``."""
    group = _groups(skel)
    roles: dict[str, dict[str, int]] = {k: {} for k in ("hip", "knee", "ankle", "shoulder", "elbow")}
    for side in SIDES:
        for limb, (upper, mid, lower) in (("leg", ("hip", "knee", "ankle")), ("arm", ("shoulder", "elbow", None))):
            g = GROUPS.index(f"{side}_{limb}")
            end = _limb_end(skel, side, limb)
            chain = _pitch_on_path(skel, end, group, g) if end >= 0 else []
            mid_kp = skel.keypoints.get(f"{side}_{mid}", -1)
            if mid_kp >= 0 and skel.subtree(mid_kp)[end]:
                above = [j for j in chain if j != mid_kp and skel.subtree(j)[mid_kp]]
                below = [j for j in chain if j != mid_kp and skel.subtree(mid_kp)[j]]
                roles[mid][side] = mid_kp if mid_kp in chain else -1
            else:
                above, below = chain[:1], chain[2:]
                roles[mid][side] = chain[1] if len(chain) > 1 else -1
            roles[upper][side] = above[0] if above else -1
            if lower:
                roles[lower][side] = below[0] if below else -1
    rest = skel.rest_positions
    hips = [skel.keypoints.get(f"{s}_hip", -1) for s in SIDES]
    feet = [n for s in SIDES for n in (_limb_end(skel, s, "leg"),) if n >= 0]
    top = np.mean([rest[h, 2] for h in hips if h >= 0]) if any(h >= 0 for h in hips) else 0.0
    sole = min((rest[f, 2] for f in feet), default=rest[:, 2].min())
    sign = np.where(skel.axes[:, 1] < 0, -1.0, 1.0)
    margin = 0.06 * np.maximum(skel.upper - skel.lower, 0.0)
    return Body(
        skel=skel, dof=np.flatnonzero(skel.dof_mask), group=group, sign=sign, margin=margin,
        leg_length=float(max(top - sole, 0.2)), **roles,
    )  # fmt: skip
