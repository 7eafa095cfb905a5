"""Scaling a reference motion to a target skeleton: the goals the energy tracks.

Two methods (``method=``):

``segments`` (default): **directions from the reference, lengths from the target**, so that the
scaled reference is a pose the target can actually reach.

* The *pelvis centre* ``c`` (mid-point of the hips) is the body that carries locomotion. Its
  trajectory is scaled by ``alpha_root`` about the window origin (heights about the ground z = 0);
  ``alpha_root`` puts the scaled standing zero pose's feet at the target's own standing heights.
* The *base* goal is where the target's own root link sits for that pelvis centre and the
  reference's base orientation ``R_b``: ``p'_0 = c' + (p_0 - c) - R_b (c_T - c_R)`` (``c_T``,
  ``c_R``: the zero-pose pelvis centres in each root frame). So the base key point means the same
  body on every robot (Talos' root link sits 0.27 m above its hips, G1's 0.13 m).
* *Hips* sit about ``c'`` and *shoulders* about the shoulder centre ``s'`` at the target's widths,
  in the reference's directions. A hip key point is a different body on different robots (G1: the
  roll link, which the hip-pitch joint swings on a 3 cm arm; H1: the pitch link, which hip roll
  swings on an 11.5 cm arm; TALOS: the point all three hip axes meet, which nothing moves), so how
  it moves against the pelvis is transferred only between robots whose hip key points are moved by
  the same sequence of joint axes (:func:`hip_signature`: G1 and Oli; a robot and its augmented
  copies). Otherwise the pelvis is rigid: ``c`` is the reference's zero-pose pelvis centre carried by
  its base, and the hips are the target's zero-pose hips carried by the reference's base. The
  shoulder centre is the target's own zero-pose trunk vector ``s_T - c_T`` turned by the
  reference trunk's rotation from its zero pose (a frame from the pelvis-to-shoulder vector and
  the shoulder line) and stretched as the reference's trunk is.
* *Limbs* (hip → knee → ankle → toe, shoulder → elbow → hand): every segment is scaled by its own
  ratio ``|b_T - a_T| / |b_R - a_R|`` of zero-pose lengths, keeping the reference's direction.
  A foot segment that is rigid in the reference (no joint between ankle and toe) is the target's
  own zero-pose vector turned by the reference body's rotation instead, so a flat foot stays flat
  on a robot whose toe sits lower under the ankle. Only the foot: every robot's zero pose stands
  on flat feet, but arms rest differently (G1's hang, Atlas' spread), so a hand fixed to its
  forearm (H1) keeps the reference's direction like any other segment (turning the target's rest
  vector sent Valkyrie's hands 0.2 m off when H1 was the reference).
* Nodes that are not key points follow their nearest key-point (or base) ancestor with that
  segment's ratio. A segment the target lacks (no knee, say) falls back to the body part's
  ``alpha_k``.

Used with the target's own motion as reference it is the identity; at the zero pose every scaled
segment has the target's length.

``parts``: the paper's per-body-part factor (Implementation Details)::

    alpha_k = argmin_a  sum_j || a * l_j^ref - l_j^target ||^2  =  sum_j l_j^ref l_j^tgt / sum_j (l_j^ref)^2

with ``l_j`` the cumulative bone length from the part's start to key point ``j`` at the zero pose.
One factor per chain stretches whole chains by one number, so single segments come out wrong (H1's
upper arm 0.279 m against its 0.333 m): kept for comparison (docs/decisions.md).

Orientation goals are :mod:`mer_data.kinematics.orientation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from mer_data.skeleton import Skeleton

__all__ = [
    "SCALING_METHODS",
    "ScalingMethod",
    "cumulative_lengths",
    "body_part_scales",
    "segment_ratios",
    "scale_reference_positions",
    "ROOT_PART",
    "SCALING_VERSION",
    "hip_signature",
]

ROOT_PART = "root"
#: Version of the ``segments`` goals: teacher files record it (``mer shards solve`` re-solves on a
#: change). 2: rigid pelvis between robots whose hips move differently (:func:`hip_signature`).
SCALING_VERSION = 2
ScalingMethod = Literal["segments", "parts"]
SCALING_METHODS: tuple[str, ...] = ("segments", "parts")
_FEET = ("left_ankle", "right_ankle", "left_toe", "right_toe")
_CHAINS = (
    ("left_hip", ("left_knee", "left_ankle", "left_toe")),
    ("right_hip", ("right_knee", "right_ankle", "right_toe")),
    ("left_shoulder", ("left_elbow", "left_hand")),
    ("right_shoulder", ("right_elbow", "right_hand")),
)


# ---- the paper's body-part factors ---------------------------------------------------------------
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


def _feet_root_scale(ref: Skeleton, target: Skeleton, apply, centre_height: float, default: float) -> float:
    """``alpha_root`` that puts the scaled standing zero pose's feet at the target's standing heights.

    ``apply(positions, root)`` scales (J_ref, 3) positions; their feet's z is affine in ``root`` with
    slope ``centre_height`` (the height of the point the root factor scales).
    """
    feet = [k for k in _FEET if ref.keypoints.get(k, -1) >= 0 and target.keypoints.get(k, -1) >= 0]
    ref_stand, tgt_stand = _standing(ref), _standing(target)
    root = math.nan
    if feet and centre_height > 1e-6:
        z1 = apply(ref_stand, 1.0)[..., 2]
        got = np.array([z1[ref.keypoints[k]] for k in feet])
        want = np.array([tgt_stand[target.keypoints[k], 2] for k in feet])
        root = 1.0 + float(np.mean(want - got)) / centre_height
    if not (math.isfinite(root) and root > 0):
        root = default
    return root


def body_part_scales(ref: Skeleton, target: Skeleton) -> dict[str, float]:
    """The paper's ``alpha_k`` per body part of the reference, plus ``"root"``; NaN-free (fallbacks applied)."""
    tparts = {b.name: b for b in target.body_parts}
    parts: dict[str, float] = {}
    for part in ref.body_parts:
        tpart = tparts.get(part.name, part)
        parts[part.name] = _fit(
            cumulative_lengths(ref, part.start, part.keypoints),
            cumulative_lengths(target, tpart.start, tpart.keypoints),
        )
    base_h, tgt_h = _standing(ref)[0, 2], _standing(target)[0, 2]
    default = tgt_h / base_h if base_h > 1e-6 and tgt_h > 1e-6 else 1.0
    trial = {k: (1.0 if math.isnan(v) else v) for k, v in parts.items()}
    root = _feet_root_scale(
        ref, target, lambda p, a: _scale_parts(p, ref, {**trial, ROOT_PART: a}, None), base_h, default
    )
    out = {ROOT_PART: root}
    out.update({k: (root if math.isnan(v) else v) for k, v in parts.items()})
    return out


def _scale_parts(positions: np.ndarray, ref: Skeleton, scales: dict[str, float], origin_xy) -> np.ndarray:
    root = scales[ROOT_PART]
    part_of: dict[int, tuple[int, float]] = {}
    for part in ref.body_parts:
        s = 0 if part.start == "base" else ref.keypoints.get(part.start, -1)
        if s < 0:
            continue
        for k in part.keypoints:
            j = ref.keypoints.get(k, -1)
            if j >= 0 and j not in part_of:
                part_of[j] = (s, scales.get(part.name, root))
    anchor_scale = {0: scales.get(ref.body_parts[0].name, root) if ref.body_parts else root}
    for part in ref.body_parts:
        s = 0 if part.start == "base" else ref.keypoints.get(part.start, -1)
        if s > 0 and s not in anchor_scale:
            anchor_scale[s] = scales.get(part.name, root)
    out = np.empty_like(positions)
    out[..., 0, :] = _scale_about_origin(positions[..., 0, :], root, origin_xy)
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


def _scale_about_origin(p: np.ndarray, root: float, origin_xy) -> np.ndarray:
    """(..., 3) points scaled by ``root`` about ``(origin_xy, 0)`` (heights about the ground)."""
    o = np.zeros(p.shape[:-1] + (2,)) if origin_xy is None else np.asarray(origin_xy, np.float64)
    out = np.empty_like(p)
    out[..., :2] = o + root * (p[..., :2] - o)
    out[..., 2] = root * p[..., 2]
    return out


# ---- segments ----------------------------------------------------------------------------------
def hip_signature(skel: Skeleton, node: int, tol: float = 1e-3) -> tuple[int, ...]:
    """The joints that move key node ``node`` against the base, base first: each joint's dominant
    root-frame axis (0: x, 1: y, 2: z) at the zero pose.

    A joint counts when ``node`` lies more than ``tol`` [m] off its axis (a joint whose axis passes
    through the node only turns it). G1's hip (roll link) gives ``(1,)``, H1's (pitch link, after
    yaw and roll) ``(2, 0)``, TALOS' (where its three hip axes meet) ``()``.
    """
    rest = skel.rest_positions
    out = []
    a = int(skel.parents[node])
    while a > 0:
        if skel.node_kinds[a] == "revolute":
            axis = skel.axes[a] / max(float(np.linalg.norm(skel.axes[a])), 1e-12)
            d = rest[node] - rest[a]
            if float(np.linalg.norm(d - (d @ axis) * axis)) > tol:
                out.append(int(np.argmax(np.abs(axis))))
        a = int(skel.parents[a])
    return tuple(reversed(out))


@dataclass(frozen=True)
class _SegmentPlan:
    """What :func:`scale_reference_positions` needs for one (reference, target) pair (zero-pose geometry)."""

    root: float
    hips: tuple[int, int] | None  # reference nodes of the two hips
    centre_ref: np.ndarray  # (3,) zero-pose pelvis centre, reference root frame
    centre_tgt: np.ndarray  # (3,) the same for the target
    shoulders: tuple[int, int] | None
    trunk_ref: np.ndarray  # (3, 3) zero-pose trunk frame of the reference (columns)
    trunk_len_ref: float
    trunk_tgt: np.ndarray  # (3,) target's zero-pose pelvis-centre → shoulder-centre vector
    width: dict[int, float]  # hip / shoulder node → ratio of its distance from its centre
    segments: tuple[tuple[int, int, float], ...]  # (parent key node, key node, ratio) in chain order
    rigid: dict[int, np.ndarray]  # key node → target's zero-pose vector from its chain parent
    others: tuple[tuple[int, int, float], ...]  # (anchor node, node, ratio) for the non-key nodes
    rigid_pelvis: bool = False  # the hips' motion against the pelvis does not transfer (hip_signature)
    hip_offsets: np.ndarray | None = None  # (2, 3) pelvis centre → zero-pose hip at the target's width (root frame)


def _frame(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) orthonormal frame, columns (u, v ⟂ u, u × v) from (..., 3) vectors."""
    e1 = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    v = v - (v * e1).sum(-1, keepdims=True) * e1
    e2 = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def _ratio(a: float, b: float, fallback: float) -> float:
    return a / b if b > 1e-6 and a > 1e-6 else fallback


def segment_ratios(ref: Skeleton, target: Skeleton) -> dict[str, float]:
    """Per key point of the reference, the factor its segment (from its chain parent) is scaled by,
    plus ``"root"``; see the module docstring."""
    plan = _plan(ref, target)
    names = {v: k for k, v in ref.keypoints.items() if v >= 0}
    out = {ROOT_PART: plan.root}
    out.update({names[n]: r for n, r in plan.width.items()})
    out.update({names[n]: r for _, n, r in plan.segments})
    return out


def _segment_plan(ref: Skeleton, target: Skeleton, root: float | None = None) -> _SegmentPlan:
    kr, kt = ref.keypoints, target.keypoints
    rr, rt = ref.rest_positions, target.rest_positions
    parts = body_part_scales(ref, target) if root is None else {}
    part_of = {k: p.name for p in ref.body_parts for k in p.keypoints}

    def both(names):
        return all(kr.get(k, -1) >= 0 for k in names)

    def tgt_both(names):
        return all(kt.get(k, -1) >= 0 for k in names)

    hipn = ("left_hip", "right_hip")
    hips = (kr[hipn[0]], kr[hipn[1]]) if both(hipn) else None
    centre_ref = rr[list(hips)].mean(0) if hips else np.zeros(3)
    centre_tgt = rt[[kt[k] for k in hipn]].mean(0) if hips and tgt_both(hipn) else np.zeros(3)
    width: dict[int, float] = {}
    if hips:
        for k, n in zip(hipn, hips):
            t = kt.get(k, -1)
            width[n] = _ratio(np.linalg.norm(rt[t] - centre_tgt), np.linalg.norm(rr[n] - centre_ref), 1.0) if t >= 0 else 1.0
    shn = ("left_shoulder", "right_shoulder")
    shoulders = (kr[shn[0]], kr[shn[1]]) if both(shn) else None
    trunk_ref, trunk_len, trunk_tgt = np.eye(3), 1.0, np.zeros(3)
    if shoulders:
        s_r = rr[list(shoulders)].mean(0)
        trunk_ref = _frame(s_r - centre_ref, rr[shoulders[0]] - rr[shoulders[1]])
        trunk_len = max(float(np.linalg.norm(s_r - centre_ref)), 1e-6)
        s_t = rt[[kt[k] for k in shn]].mean(0) if tgt_both(shn) else s_r - centre_ref + centre_tgt
        trunk_tgt = s_t - centre_tgt
        for k, n in zip(shn, shoulders):
            t = kt.get(k, -1)
            width[n] = _ratio(np.linalg.norm(rt[t] - s_t), np.linalg.norm(rr[n] - s_r), 1.0) if t >= 0 else 1.0
    segments, rigid = [], {}
    for start, chain in _CHAINS:
        prev = kr.get(start, -1)
        prev_name = start
        if prev < 0:
            continue
        for k in chain:
            n = kr.get(k, -1)
            if n < 0:
                continue
            a, b = kt.get(prev_name, -1), kt.get(k, -1)
            fallback = parts.get(part_of.get(k, ""), parts.get(ROOT_PART, 1.0)) if parts else 1.0
            r = _ratio(np.linalg.norm(rt[b] - rt[a]), np.linalg.norm(rr[n] - rr[prev]), fallback) if a >= 0 and b >= 0 else fallback
            segments.append((prev, n, r))
            if a >= 0 and b >= 0 and k.endswith("_toe") and ref.rigidly_attached(prev, n):
                rigid[n] = rt[b] - rt[a]
            prev, prev_name = n, k
    keyed = {0, *width, *(n for _, n, _ in segments)}
    ratio_at = {0: 1.0, **width, **{n: r for _, n, r in segments}}
    others = []
    for n in range(1, ref.num_nodes):
        if n in keyed:
            continue
        a = int(ref.parents[n])
        while a not in keyed:
            a = int(ref.parents[a])
        others.append((a, n, ratio_at[a]))
    rigid_pelvis = bool(hips) and tgt_both(hipn) and any(
        hip_signature(ref, kr[k]) != hip_signature(target, kt[k]) for k in hipn
    )
    plan = _SegmentPlan(1.0, hips, centre_ref, centre_tgt, shoulders, trunk_ref, trunk_len, trunk_tgt, width,
                        tuple(segments), rigid, tuple(others), rigid_pelvis,
                        np.stack([width[n] * (rr[n] - centre_ref) for n in hips]) if hips else None)  # fmt: skip
    if root is None:
        ref_stand = _standing(ref)
        centre_h = float(ref_stand[list(hips), 2].mean()) if hips else float(ref_stand[0, 2])
        tgt_stand = _standing(target)
        tgt_h = float(tgt_stand[[kt[k] for k in hipn], 2].mean()) if hips and tgt_both(hipn) else float(tgt_stand[0, 2])
        default = tgt_h / centre_h if centre_h > 1e-6 and tgt_h > 1e-6 else 1.0
        eye = np.broadcast_to(np.eye(3), (ref.num_nodes, 3, 3))
        root = _feet_root_scale(
            ref, target, lambda p, a: _apply_segments(p, eye, _replace_root(plan, a), None), centre_h, default
        )
    return _replace_root(plan, root)


@lru_cache(maxsize=512)
def _plan(ref: Skeleton, target: Skeleton) -> _SegmentPlan:
    """:func:`_segment_plan`, once per pair of skeleton objects (immutable, hashed by identity):
    collate asks for it for every sample, and most samples share their pair."""
    return _segment_plan(ref, target)


def _replace_root(plan: _SegmentPlan, root: float) -> _SegmentPlan:
    from dataclasses import replace

    return replace(plan, root=float(root))


def _apply_segments(positions: np.ndarray, rotations: np.ndarray, plan: _SegmentPlan, origin_xy) -> np.ndarray:
    P = positions
    base_rot = rotations[..., 0, :, :]
    out = np.empty_like(P)
    if plan.rigid_pelvis:  # the reference's zero-pose pelvis carried by its base
        c = P[..., 0, :] + np.einsum("...ij,j->...i", base_rot, plan.centre_ref)
    else:
        c = P[..., list(plan.hips), :].mean(-2) if plan.hips else P[..., 0, :]
    c_s = _scale_about_origin(c, plan.root, origin_xy)
    shift = np.einsum("...ij,j->...i", base_rot, plan.centre_tgt - plan.centre_ref)
    out[..., 0, :] = c_s + (P[..., 0, :] - c) - shift
    if plan.hips:
        for i, n in enumerate(plan.hips):
            if plan.rigid_pelvis:
                out[..., n, :] = c_s + np.einsum("...ij,j->...i", base_rot, plan.hip_offsets[i])
            else:
                out[..., n, :] = c_s + plan.width[n] * (P[..., n, :] - c)
    if plan.shoulders:
        l, r = plan.shoulders
        s = 0.5 * (P[..., l, :] + P[..., r, :])
        u = s - c
        frame = _frame(u, P[..., l, :] - P[..., r, :])
        turn = frame @ plan.trunk_ref.T
        stretch = np.linalg.norm(u, axis=-1, keepdims=True) / plan.trunk_len_ref
        s_s = c_s + stretch * np.einsum("...ij,j->...i", turn, plan.trunk_tgt)
        for n in plan.shoulders:
            out[..., n, :] = s_s + plan.width[n] * (P[..., n, :] - s)
    for a, n, r in plan.segments:
        if n in plan.rigid:
            out[..., n, :] = out[..., a, :] + np.einsum("...ij,j->...i", rotations[..., a, :, :], plan.rigid[n])
        else:
            out[..., n, :] = out[..., a, :] + r * (P[..., n, :] - P[..., a, :])
    for a, n, r in plan.others:  # nodes hanging off the base (waist, torso) scale with the root
        out[..., n, :] = out[..., a, :] + (plan.root if a == 0 else r) * (P[..., n, :] - P[..., a, :])
    return out


# ---- public entry points ------------------------------------------------------------------------
def scale_reference_positions(
    positions: np.ndarray,
    ref: Skeleton,
    target: Skeleton,
    *,
    rotations: np.ndarray | None = None,
    origin_xy: np.ndarray | None = None,
    method: ScalingMethod = "segments",
    scales: dict[str, float] | None = None,
) -> np.ndarray:
    """Scale reference node positions to the target's size (see the module docstring).

    Args:
        positions: (..., J_ref, 3) world positions of the reference nodes [m].
        rotations: (..., J_ref, 3, 3) world rotations of the reference nodes (FK); ``segments``
            places the target's base by the reference base's and turns rigid segments by their
            body's (identity when omitted: right for the zero pose standing upright).
        origin_xy: (..., 2) point the pelvis trajectory is scaled about (default: the origin, as in
            origin-normalized windows); heights are scaled about the ground z = 0.
        method: ``segments`` (default) or the paper's ``parts``.
        scales: ``parts`` only: precomputed :func:`body_part_scales`.

    Returns:
        (..., J_ref, 3) scaled positions [m].
    """
    positions = np.asarray(positions, dtype=np.float64)
    if method == "parts":
        return _scale_parts(positions, ref, scales or body_part_scales(ref, target), origin_xy)
    if method != "segments":
        raise ValueError(f"unknown scaling method {method!r}; known: {', '.join(SCALING_METHODS)}")
    rot = np.broadcast_to(np.eye(3), positions.shape + (3,)) if rotations is None else np.asarray(rotations, np.float64)
    return _apply_segments(positions, rot, _plan(ref, target), origin_xy)
