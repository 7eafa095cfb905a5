"""Body-part scaling of a reference motion to a target skeleton (paper, Implementation Details).

For each body part ``k`` (a start point and a chain of key points, from the reference's card)::

    alpha_k = argmin_a  sum_j || a * l_j^ref - l_j^target ||^2  =  sum_j l_j^ref l_j^tgt / sum_j (l_j^ref)^2

where ``l_j`` is the cumulative *bone* length from the part's start to key point ``j``: the sum of
the straight distances between consecutive key points of the chain at the zero pose (hip → knee →
ankle → toe). Bone lengths do not depend on the rest pose (bent G1 elbows and a straight Atlas arm
measure the same), and unlike summed link offsets they ignore sideways zig-zags of a joint cluster
(H1's wide hip). The paper writes ``alpha * l_j ≈ l_j^o``; we scale the reference *to* the target,
the direction that makes the scaled reference a goal the target can reach.

Scaled positions (every frame)::

    base:       p'_0 = o + alpha_root * (p_0 - o)          (o: the window origin, z about the ground)
    key point:  p'_j = p'_s + alpha_k * (p_j - p_s)        (s: the part's start, already scaled)
    other node: p'_n = p'_a + alpha_a * (p_n - p_a)        (a: nearest key-point/base ancestor)

``alpha_root`` keeps the feet on the ground: it is the base scale for which the reference's zero
pose, standing on the ground and scaled, puts its ankles and toes at the target's own standing
heights (least squares). Where either robot has no feet it is the ratio of standing base heights.
A part the target lacks falls back to ``alpha_root``.
"""

from __future__ import annotations

import math

import numpy as np

from .skeleton import Skeleton

__all__ = ["cumulative_lengths", "body_part_scales", "scale_reference_positions", "ROOT_PART"]

ROOT_PART = "root"
_FEET = ("left_ankle", "right_ankle", "left_toe", "right_toe")


def cumulative_lengths(skel: Skeleton, start: str, keypoints) -> dict[str, float]:
    """``l_j`` [m]: bone length from ``start`` along the chain of ``keypoints`` (zero pose).

    Key points the robot lacks are skipped (the next bone spans the gap).
    """
    s = 0 if start == "base" else skel.keypoints.get(start, -1)
    if s < 0:
        return {}
    rest = skel.rest_positions
    out, total, prev = {}, 0.0, rest[s]
    for k in keypoints:
        j = skel.keypoints.get(k, -1)
        if j < 0:
            continue
        total += float(np.linalg.norm(rest[j] - prev))
        prev = rest[j]
        out[k] = total
    return out


def _fit(ref: dict[str, float], tgt: dict[str, float]) -> float:
    common = [k for k in ref if k in tgt]
    den = sum(ref[k] ** 2 for k in common)
    if not common or den <= 1e-12:
        return math.nan
    return sum(ref[k] * tgt[k] for k in common) / den


def _standing(skel: Skeleton) -> np.ndarray:
    """Zero-pose node positions with the lowest node on the ground (z = 0)."""
    rest = skel.rest_positions
    return rest - np.array([0.0, 0.0, rest[:, 2].min()])


def body_part_scales(ref: Skeleton, target: Skeleton) -> dict[str, float]:
    """``alpha_k`` per body part of the reference, plus ``"root"``; NaN-free (fallbacks applied)."""
    tparts = {b.name: b for b in target.body_parts}
    parts: dict[str, float] = {}
    for part in ref.body_parts:
        tpart = tparts.get(part.name, part)
        parts[part.name] = _fit(
            cumulative_lengths(ref, part.start, part.keypoints),
            cumulative_lengths(target, tpart.start, tpart.keypoints),
        )
    feet = [k for k in _FEET if ref.keypoints.get(k, -1) >= 0 and target.keypoints.get(k, -1) >= 0]
    ref_stand, tgt_stand = _standing(ref), _standing(target)
    base_h = ref_stand[0, 2]
    root = math.nan
    if feet and base_h > 1e-6:
        # z of the scaled feet is affine in alpha_root with slope base_h: solve for the target's heights
        trial = {**{k: (1.0 if math.isnan(v) else v) for k, v in parts.items()}, ROOT_PART: 1.0}
        z1 = _scale(ref_stand, ref, trial, None)[..., 2]
        got = np.array([z1[ref.keypoints[k]] for k in feet])
        want = np.array([tgt_stand[target.keypoints[k], 2] for k in feet])
        root = 1.0 + float(np.mean(want - got)) / base_h
    if not (math.isfinite(root) and root > 0):
        tgt_h = tgt_stand[0, 2]
        root = tgt_h / base_h if base_h > 1e-6 and tgt_h > 1e-6 else 1.0
    out = {ROOT_PART: root}
    out.update({k: (root if math.isnan(v) else v) for k, v in parts.items()})
    return out


def scale_reference_positions(
    positions: np.ndarray,
    ref: Skeleton,
    target: Skeleton,
    *,
    origin_xy: np.ndarray | None = None,
    scales: dict[str, float] | None = None,
) -> np.ndarray:
    """Scale reference node positions to the target's size (see module docstring).

    Args:
        positions: (..., J_ref, 3) world positions of the reference nodes [m].
        origin_xy: (..., 2) point the base trajectory is scaled about (default: the origin, as in
            origin-normalized windows); heights are scaled about the ground z = 0.
        scales: precomputed :func:`body_part_scales` (computed here if omitted).

    Returns:
        (..., J_ref, 3) scaled positions.
    """
    scales = scales or body_part_scales(ref, target)
    return _scale(np.asarray(positions, dtype=np.float64), ref, scales, origin_xy)


def _scale(positions: np.ndarray, ref: Skeleton, scales: dict[str, float], origin_xy) -> np.ndarray:
    root = scales[ROOT_PART]
    # which part each key point belongs to, and the part's start node
    part_of: dict[int, tuple[int, float]] = {}
    for part in ref.body_parts:
        s = 0 if part.start == "base" else ref.keypoints.get(part.start, -1)
        if s < 0:
            continue
        for k in part.keypoints:
            j = ref.keypoints.get(k, -1)
            if j >= 0 and j not in part_of:
                part_of[j] = (s, scales.get(part.name, root))
    # scale started by each anchor (for non-key nodes below it)
    anchor_scale = {0: scales.get(ref.body_parts[0].name, root) if ref.body_parts else root}
    for part in ref.body_parts:
        s = 0 if part.start == "base" else ref.keypoints.get(part.start, -1)
        if s > 0 and s not in anchor_scale:
            anchor_scale[s] = scales.get(part.name, root)

    out = np.empty_like(positions)
    o = np.zeros(positions.shape[:-2] + (2,)) if origin_xy is None else np.asarray(origin_xy, np.float64)
    out[..., 0, :2] = o + root * (positions[..., 0, :2] - o)
    out[..., 0, 2] = root * positions[..., 0, 2]
    anchors = {0, *part_of, *anchor_scale}
    for n in range(1, ref.num_nodes):
        if n in part_of and part_of[n][0] < n:
            s, alpha = part_of[n]
        else:  # nearest key-point/base ancestor, with the scale of the part it starts or belongs to
            s = int(ref.parents[n])
            while s not in anchors:
                s = int(ref.parents[s])
            alpha = anchor_scale.get(s, part_of.get(s, (0, root))[1])
        out[..., n, :] = out[..., s, :] + alpha * (positions[..., n, :] - positions[..., s, :])
    return out
