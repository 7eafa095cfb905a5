"""Body-part scaling of a reference motion to a target skeleton (paper, Implementation Details).

For each body part ``k`` (a start point and a chain of key points, from the reference's card)::

    alpha_k = argmin_a  sum_j || a * l_j^ref - l_j^target ||^2  =  sum_j l_j^ref l_j^tgt / sum_j (l_j^ref)^2

where ``l_j`` is the *cumulative link length* from the part's start to key point ``j``, summed along
the kinematic tree at the zero pose (so it does not depend on the rest pose: bent G1 elbows and a
straight Atlas arm measure the same way). The paper writes ``alpha * l_j ≈ l_j^o``; we scale the
reference *to* the target, which is the direction that makes the scaled reference a goal the
target can reach.

Scaled positions (every frame)::

    base:       p'_0 = o + alpha_root * (p_0 - o)          (o: the window origin, z about the ground)
    key point:  p'_j = p'_s + alpha_k * (p_j - p_s)        (s: the part's start, already scaled)
    other node: p'_n = p'_a + alpha_a * (p_n - p_a)        (a: nearest key-point/base ancestor)

``alpha_root`` is fitted on the legs (hip → knee, ankle, both sides): the base height and the
distance travelled scale with leg length. A part the target lacks falls back to ``alpha_root``, and
``alpha_root`` to 1 when either robot has no legs.
"""

from __future__ import annotations

import math

import numpy as np

from .skeleton import Skeleton

__all__ = ["cumulative_lengths", "body_part_scales", "scale_reference_positions", "ROOT_PART"]

ROOT_PART = "root"
_LEGS = (("left_hip", ("left_knee", "left_ankle")), ("right_hip", ("right_knee", "right_ankle")))


def _path_length(skel: Skeleton, start: int, node: int) -> float:
    """Sum of link lengths from ``node`` up to ``start`` (NaN if ``start`` is not an ancestor)."""
    total, n = 0.0, node
    lengths = skel.link_lengths
    while n != start:
        if n <= 0:
            return math.nan
        total += lengths[n]
        n = int(skel.parents[n])
    return total


def cumulative_lengths(skel: Skeleton, start: str, keypoints) -> dict[str, float]:
    """``l_j`` [m] for each key point the robot has (cumulative link length from ``start``)."""
    s = 0 if start == "base" else skel.keypoints.get(start, -1)
    out = {}
    if s < 0:
        return out
    for k in keypoints:
        j = skel.keypoints.get(k, -1)
        if j >= 0:
            length = _path_length(skel, s, j)
            if not math.isnan(length):
                out[k] = length
    return out


def _fit(ref: dict[str, float], tgt: dict[str, float]) -> float:
    common = [k for k in ref if k in tgt]
    den = sum(ref[k] ** 2 for k in common)
    if not common or den <= 1e-12:
        return math.nan
    return sum(ref[k] * tgt[k] for k in common) / den


def _leg_lengths(skel: Skeleton) -> dict[str, float]:
    """Cumulative hip → knee, ankle lengths of both legs (what ``alpha_root`` is fitted on)."""
    out = {}
    for hip, points in _LEGS:
        out.update({f"{hip}/{k}": v for k, v in cumulative_lengths(skel, hip, points).items()})
    return out


def body_part_scales(ref: Skeleton, target: Skeleton) -> dict[str, float]:
    """``alpha_k`` per body part of the reference, plus ``"root"``; NaN-free (fallbacks applied)."""
    root = _fit(_leg_lengths(ref), _leg_lengths(target))
    if math.isnan(root):
        root = 1.0
    out = {ROOT_PART: root}
    tparts = {b.name: b for b in target.body_parts}
    for part in ref.body_parts:
        tpart = tparts.get(part.name, part)
        a = _fit(
            cumulative_lengths(ref, part.start, part.keypoints),
            cumulative_lengths(target, tpart.start, tpart.keypoints),
        )
        out[part.name] = root if math.isnan(a) else a
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
    positions = np.asarray(positions, dtype=np.float64)
    scales = scales or body_part_scales(ref, target)
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
