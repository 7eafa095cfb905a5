"""A registered robot's collision geometry per link, in link frames, for drawing it and writing its
model: the shapes each link has, the capsules mer fits where a body has none, and hull triangles.

Shared by the Foxglove messages (:mod:`mer_data.shards.foxglove`), the video and viewer meshes
(:mod:`mer_models.export.geometry`) and the MuJoCo model export (:mod:`mer_models.export.mjcf`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .articulation import Articulation
    from .registry import Robot
    from .shapes import Shape

__all__ = ["link_shapes", "fitted_hulls", "hull_triangles"]


def link_shapes(robot: "Robot") -> dict[str, tuple["Shape", ...]]:
    """Link → collision shapes in the link frame: the card's collision file, else the description's
    primitives (its meshes are not read here)."""
    from .mjcf import load_description
    from .shapes import read_collision, shapes_from_urdf

    if robot.card.collision:
        return dict(read_collision(robot.folder / robot.card.collision).links)
    return dict(shapes_from_urdf(load_description(robot.urdf_path, geometry=False), load_meshes=False)[0].links)


def fitted_hulls(robot: "Robot", art: "Articulation", shapes: dict[str, tuple["Shape", ...]]) -> dict[int, list[np.ndarray]]:
    """Body index → vertices (V, 3) in the body frame [m] of the capsules mer fits along a body
    that has no shape in ``shapes`` (only bodies of skeleton nodes get them; none where all have shapes)."""
    if all(any(shapes.get(link) for link in b.links) for b in art.bodies):
        return {}
    from .collision import collision_model

    cm = collision_model(robot)
    own = {b.name: i for i, b in enumerate(art.bodies)}
    out: dict[int, list[np.ndarray]] = {}
    for s in range(cm.num_shapes):
        if cm.source[s] != "fitted" or cm.link[s] not in own:
            continue
        b = own[cm.link[s]]
        t = art.bodies[b].in_node
        v = np.unique(cm.vertices[s], axis=0)
        out.setdefault(b, []).append((v - t[:3, 3]) @ t[:3, :3])  # node frame -> body frame
    return out


def hull_triangles(vertices: np.ndarray) -> np.ndarray:
    """(T, 3, 3) outward-facing (counter-clockwise seen from outside) triangles of the convex hull of
    ``vertices`` (V, 3)."""
    from scipy.spatial import ConvexHull

    v = np.asarray(vertices, np.float64)
    hull = ConvexHull(v)
    tri = v[hull.simplices]  # (T, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    tri[flip] = tri[flip][:, ::-1]
    return tri
