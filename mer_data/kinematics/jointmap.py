"""Joint maps ``eta`` between two skeletons, from their semantic key points (paper, Data Representation).

``eta[i, j] = 1`` where node ``i`` of the target and node ``j`` of the reference are the same key
point. A key point missing on either robot drops that pair. The floating bases always correspond
(every robot has one, and the base trajectory is what carries locomotion); ``include_base=False``
gives the paper's strict key-point-only map.
"""

from __future__ import annotations

import numpy as np

from mer_data.skeleton import KEYPOINTS, Skeleton

__all__ = ["keypoint_pairs", "joint_map", "END_EFFECTORS"]

#: Key points that are never dropped by correspondence augmentation.
END_EFFECTORS: tuple[str, ...] = ("left_toe", "right_toe", "left_hand", "right_hand")


def keypoint_pairs(target: Skeleton, ref: Skeleton, *, include_base: bool = True) -> list[tuple[str, int, int]]:
    """``(name, target node, reference node)`` for every key point both robots have.

    The base pair, when included, comes first and is named ``"base"``.
    """
    out = [("base", 0, 0)] if include_base else []
    for k in KEYPOINTS:
        i, j = target.keypoints.get(k, -1), ref.keypoints.get(k, -1)
        if i >= 0 and j >= 0:
            out.append((k, i, j))
    return out


def joint_map(target: Skeleton, ref: Skeleton, *, include_base: bool = True) -> np.ndarray:
    """(J_target, J_ref) uint8 joint map ``eta``."""
    eta = np.zeros((target.num_nodes, ref.num_nodes), np.uint8)
    for _, i, j in keypoint_pairs(target, ref, include_base=include_base):
        eta[i, j] = 1
    return eta
