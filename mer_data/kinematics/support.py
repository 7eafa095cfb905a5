"""The support polygon: where the floor can push on the robot (docs/model.md §Balance).

Every vertex of the robot's collision polytopes (:mod:`mer_data.robots.collision`) within
:data:`CONTACT_HEIGHT` of the floor supports; the support polygon is the convex hull of their floor
projections. A frame is **flight** without any such vertex, **single support** where all of them belong to
one foot (the collision model's foot shapes), **double support** otherwise (both feet, or any other body
on the floor). Used by the balance metric (:mod:`mer_models.retarget.balance`) and the balance term
(:mod:`mer_models.solver.balance_term`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CONTACT_HEIGHT", "hull_indices", "polygon_distance", "support_kind", "support_polygons"]

CONTACT_HEIGHT = 0.02  # [m] collision geometry this close to the floor supports


def hull_indices(pts: np.ndarray) -> np.ndarray:
    """Indices of the 2-D convex hull of ``pts`` (N, 2), counter-clockwise (qhull; a monotone chain
    over the distinct points where they are collinear or fewer than three)."""
    from scipy.spatial import ConvexHull, QhullError

    if len(pts) >= 3:
        try:
            return ConvexHull(pts).vertices
        except QhullError:
            pass
    _, first = np.unique(np.round(pts, 9), axis=0, return_index=True)
    order = first[np.lexsort((pts[first, 1], pts[first, 0]))]
    if len(order) <= 2:
        return order

    def half(idx):
        out: list[int] = []
        for i in idx:
            while len(out) >= 2:
                a, b = pts[out[-2]], pts[out[-1]]
                if (b[0] - a[0]) * (pts[i][1] - a[1]) - (b[1] - a[1]) * (pts[i][0] - a[0]) <= 1e-12:
                    out.pop()
                else:
                    break
            out.append(int(i))
        return out

    lower, upper = half(order), half(order[::-1])
    return np.array(lower[:-1] + upper[:-1])


def polygon_distance(p: np.ndarray, pts: np.ndarray) -> float:
    """Distance [m] of the point ``p`` (2,) outside the convex hull of ``pts`` (N, 2); 0 inside."""
    h = pts[hull_indices(pts)]
    if len(h) == 1:
        return float(np.linalg.norm(p - h[0]))
    a, b = h, np.roll(h, -1, axis=0)
    if len(h) >= 3:
        cross = (b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[0] - a[:, 0])
        if np.all(cross >= -1e-12):
            return 0.0
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0, 1)
    return float(np.linalg.norm(a + t[:, None] * ab - p, axis=-1).min())


def support_kind(foot: np.ndarray, low: np.ndarray) -> np.ndarray:
    """(F,) 0 flight, 1 single, 2 double support from ``low`` (F, S, V) (vertices near the floor) and
    each shape's foot side ``foot`` (S,) (0 none, 1 left, 2 right)."""
    touch = low.any(-1)  # (F, S)
    out = np.zeros(len(low), np.int64)
    for f in np.flatnonzero(touch.any(-1)):
        sides = set(foot[touch[f]].tolist())
        out[f] = 1 if len(sides) == 1 and 0 not in sides else 2
    return out


def support_polygons(geometry: Any, verts: np.ndarray, max_corners: int = 12, floor: float = 0.0,
                     down: float | None = None) -> tuple[np.ndarray, list[np.ndarray | None], list[np.ndarray | None]]:  # fmt: skip
    """The support polygon of every contact frame, each corner with the node it moves with.

    Args:
        geometry: the collision model; verts: (F, S, V, 3) its vertices in the world [m].
        down: given, a foot's vertices count only where its lowest is within ``down`` [m] of the floor
            (a conservative polygon: a foot on its way up or down left out); None: the support polygon.

    Returns:
        kind: (F,) :func:`support_kind`; corner_nodes: per frame the skeleton node of each corner (K,)
        (None in flight, or where the contact points span no area); corners: per frame the hull's
        corners (K, 3) [m], counter-clockwise seen from above, at most ``max_corners`` (evenly picked:
        a polygon inside the hull), or None.
    """
    low = verts[..., 2] < floor + CONTACT_HEIGHT
    kind = support_kind(np.asarray(geometry.foot), low)
    nodes: list[np.ndarray | None] = [None] * len(verts)
    corners: list[np.ndarray | None] = [None] * len(verts)
    vert_node = np.broadcast_to(np.asarray(geometry.node)[:, None], low.shape[1:])
    foot = np.asarray(geometry.foot)
    for f in np.flatnonzero(kind > 0):
        near = low[f].copy()
        if down is not None:
            for side in (1, 2):
                if (foot == side).any() and verts[f][foot == side][..., 2].min() >= floor + down:
                    near[foot == side] = False
            if not near.any():
                continue
        pts = verts[f][near]
        h = hull_indices(pts[:, :2])
        if len(h) < 3:
            continue
        if len(h) > max_corners:
            h = h[np.round(np.linspace(0, len(h), max_corners, endpoint=False)).astype(int)]
        corners[f], nodes[f] = pts[h], vert_node[near][h]
    return kind, nodes, corners
