"""Convex hulls of collision meshes, simplified to a bounded vertex count (inner approximations).

:func:`simplify_hull` keeps the extremes along ±x, ±y, ±z, then adds, one at a time, the vertex of
the full hull farthest from the hull of those chosen, until ``max_vertices`` (or ``tol``); its
error is the largest distance from a vertex of the full hull to the simplified one. Used by
registration (:func:`mer_data.robots.collision.shapes_from_urdf`) and by
``tools/build_collision.py`` for the built-in robots.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

__all__ = ["DECIMALS", "distance_to_hull", "simplify_hull"]

DECIMALS = 5  # vertices are rounded to 10 um


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distances (N, F) from points p (N, 3) to triangles (a, b, c) (F, 3) each (Ericson's regions)."""
    p = p[:, None, :]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        q = a + ab * v[..., None] + ac * w[..., None]  # inside the face
        # edges
        t_ab = np.clip(d1 / np.where(d1 - d3 != 0, d1 - d3, 1), 0, 1)
        t_ac = np.clip(d2 / np.where(d2 - d6 != 0, d2 - d6, 1), 0, 1)
        t_bc = np.clip((d4 - d3) / np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) + (d5 - d6), 1), 0, 1)
    q_ab = a + ab * t_ab[..., None]
    q_ac = a + ac * t_ac[..., None]
    q_bc = b + (c - b) * t_bc[..., None]
    region_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    region_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    region_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    q = np.where(region_bc[..., None], q_bc, q)
    q = np.where(region_ac[..., None], q_ac, q)
    q = np.where(region_ab[..., None], q_ab, q)
    q = np.where(((d6 >= 0) & (d5 <= d6))[..., None], c, q)
    q = np.where(((d3 >= 0) & (d4 <= d3))[..., None], b, q)
    q = np.where(((d1 <= 0) & (d2 <= 0))[..., None], a, q)
    return np.linalg.norm(p - q, axis=-1)


def distance_to_hull(points: np.ndarray, hull: ConvexHull) -> np.ndarray:
    """Euclidean distance (N,) from each point to the solid convex hull (0 inside)."""
    outside = (points @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1) > 1e-12
    d = np.zeros(len(points))
    if outside.any():
        tri = hull.points[hull.simplices]
        d[outside] = _closest_on_triangles(points[outside], tri[:, 0], tri[:, 1], tri[:, 2]).min(axis=1)
    return d


def simplify_hull(points: np.ndarray, max_vertices: int = 48, tol: float = 0.0) -> tuple[np.ndarray, float, int]:
    """An inner approximation of the convex hull of ``points`` with at most ``max_vertices`` vertices.

    Returns (vertices rounded to 10 um, error [m], number of vertices of the full hull): the error is the
    largest distance from a vertex of the full hull to the hull of the returned vertices.
    """
    full = ConvexHull(points)
    h = points[full.vertices]
    scale = np.ptp(h, axis=0).max()
    sel: list[int] = []
    for axis in range(3):
        for i in (int(np.argmin(h[:, axis])), int(np.argmax(h[:, axis]))):
            if i not in sel:
                sel.append(i)
    # make the seed span 3-D: add the vertex farthest from the affine span of those chosen
    while np.linalg.matrix_rank(h[sel] - h[sel[0]], tol=1e-9 * scale) < 3:
        base = h[sel] - h[sel[0]]
        _, _, vt = np.linalg.svd(base)
        rank = np.linalg.matrix_rank(base, tol=1e-9 * scale)
        rel = h - h[sel[0]]
        resid = rel - (rel @ vt[:rank].T) @ vt[:rank]
        sel.append(int(np.argmax(np.linalg.norm(resid, axis=1))))
    if len(h) > max_vertices:
        while len(sel) < max_vertices:
            d = distance_to_hull(h, ConvexHull(h[sel]))
            if d.max() <= tol:
                break
            sel.append(int(np.argmax(d)))
    else:
        sel = list(range(len(h)))
    rounded = np.round(h[sel], DECIMALS) + 0.0  # + 0.0: no "-0.0"
    simple = ConvexHull(rounded)
    verts = rounded[simple.vertices]
    err = float(distance_to_hull(h, ConvexHull(verts)).max())
    return verts, err, len(h)
