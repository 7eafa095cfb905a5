"""Orientation goals: which bodies the energy holds in orientation, and to what.

Orientation goals (:func:`orientation_goals`): the base, the feet (ankle bodies, where both robots
have toes) and the hands are
tracked in orientation relative to each robot's zero-pose frame; a hand's goal is turned by the
rotation that takes the target's zero-pose forearm onto the reference's, so robots whose arms rest
differently (Atlas' T-pose, G1's hanging arms) still mean the same hand pose. A hand without a
wrist, on either side, is not tracked: its orientation is its forearm's.
"""

from __future__ import annotations

import numpy as np

from mer_data.skeleton import Skeleton

__all__ = ["ORIENTED_KEYPOINTS", "orientation_calibration", "orientation_goals"]

#: Key points whose orientation the energy tracks (besides the base, which is always tracked).
ORIENTED_KEYPOINTS: tuple[str, ...] = ("left_ankle", "right_ankle", "left_hand", "right_hand")


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking direction ``a`` onto direction ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-9:  # opposite: half turn about any axis perpendicular to a
        p = np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0])
        p /= np.linalg.norm(p)
        return 2 * np.outer(p, p) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def orientation_calibration(ref: Skeleton, target: Skeleton) -> dict[str, np.ndarray]:
    """Key point (``"base"`` and :data:`ORIENTED_KEYPOINTS` both robots have) → (3, 3) ``C``.

    The target's goal orientation of that body is ``R_ref(t) @ C``: identity for the base and the
    feet (every robot's zero pose stands upright on flat feet); for a hand, the smallest rotation
    taking the target's zero-pose forearm (elbow → hand; shoulder → hand without an elbow) onto
    the reference's. A foot is tracked only where both robots have a toe: on a point foot the
    ankle key point sits on the shank, which must not be held flat like a sole. A target hand fixed
    to its forearm (no wrist joint, H1) is not tracked: the elbow and hand positions already set its
    orientation, and a goal would only fight them. Nor is a hand whose *reference* has no wrist: its
    orientation is the reference's forearm's, a goal that pulled wristed robots (Oli, TALOS,
    Valkyrie from H1) against their own arm positions.
    """
    out = {"base": np.eye(3)}
    rr, rt = ref.rest_positions, target.rest_positions
    for k in ORIENTED_KEYPOINTS:
        if ref.keypoints.get(k, -1) < 0 or target.keypoints.get(k, -1) < 0:
            continue
        c = np.eye(3)
        if k.endswith("ankle"):
            toe = k.replace("ankle", "toe")
            if ref.keypoints.get(toe, -1) < 0 or target.keypoints.get(toe, -1) < 0:
                continue  # a point foot (no toe: quadrupeds, Bolt): the "ankle" body is the shank
        if k.endswith("hand"):
            side = k.split("_")[0]
            elbow = target.keypoints.get(f"{side}_elbow", -1)
            if elbow >= 0 and target.rigidly_attached(elbow, target.keypoints[k]):
                continue  # no wrist (H1): the hand turns with the forearm, whose direction the positions set
            r_elbow = ref.keypoints.get(f"{side}_elbow", -1)
            if r_elbow >= 0 and ref.rigidly_attached(r_elbow, ref.keypoints[k]):
                continue  # a reference without a wrist (H1) says nothing about the hand beyond its forearm
            for start in (f"{side}_elbow", f"{side}_shoulder"):
                a_r, a_t = ref.keypoints.get(start, -1), target.keypoints.get(start, -1)
                if a_r >= 0 and a_t >= 0:
                    d_r = rr[ref.keypoints[k]] - rr[a_r]
                    d_t = rt[target.keypoints[k]] - rt[a_t]
                    if np.linalg.norm(d_r) > 1e-6 and np.linalg.norm(d_t) > 1e-6:
                        c = _min_rotation(d_t, d_r)
                    break
        out[k] = c
    return out


def orientation_goals(ref_rot: np.ndarray, ref: Skeleton, target: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Orientation goals of the reference's nodes for ``target``.

    Args:
        ref_rot: (..., J_ref, 3, 3) world rotations of the reference nodes (FK; each node frame is
            the root frame at the zero pose).

    Returns:
        goals (..., J_ref, 3, 3) (``R_ref @ C``, see :func:`orientation_calibration`; the identity
        where not tracked) and mask (J_ref,) bool: the nodes whose orientation is tracked.
    """
    ref_rot = np.asarray(ref_rot, np.float64)
    goals = np.broadcast_to(np.eye(3), ref_rot.shape).copy()
    mask = np.zeros(ref.num_nodes, bool)
    for k, c in orientation_calibration(ref, target).items():
        n = 0 if k == "base" else ref.keypoints[k]
        goals[..., n, :, :] = ref_rot[..., n, :, :] @ c
        mask[n] = True
    return goals, mask
