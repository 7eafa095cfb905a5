"""The collision model of a robot: its shapes (:mod:`.shapes`) as convex polytopes attached to
skeleton nodes, which the artifact metrics (and the energy) compute with.

Every shape is attached to the skeleton node that carries its link (fixed links are merged, as in
the skeleton), expressed in that node's frame, and turned into a convex polytope: its vertices,
surface sample points (vertices and points along every edge) and face planes. A node none of whose
links has a shape gets **fitted capsules**, one along each segment to a child node (radius from
the segment's length), so every body collides. Curved primitives become polytopes that
circumscribe them (12 sides; 42-vertex spheres).

Self-penetration is checked between shapes of bodies that are neither the same body nor parent
and child (nodes that meet at one joint centre, a hip's yaw, roll and pitch, are one body), and
that do not already overlap at the zero pose (a robot's own rest contacts: hip
links nested in the pelvis, say), the way a collision matrix is usually built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np
import torch

from mer_data.base.errors import RobotCardError
from mer_data.kinematics.collision import pair_depths
from mer_data.skeleton import Skeleton

from .builder import zero_pose_link_transforms
from .mjcf import load_description
from .registry import Robot
from .shapes import Shape, read_collision, shapes_from_urdf

__all__ = ["CollisionModel", "shape_vertices", "polytope", "build_collision_model", "collision_model"]

_SIDES = 12  # polygon sides of cylinders and capsules
EDGE_SAMPLES = (0.25, 0.5, 0.75)  # points sampled along every hull edge (edge-edge contacts)
REST_TOLERANCE_M = 0.0  # a pair that interpenetrates at the zero pose by more than this is excluded


# ---- shapes as convex polytopes -------------------------------------------------------------------
@lru_cache(maxsize=1)
def _unit_sphere() -> np.ndarray:
    """42 unit vectors (an icosahedron subdivided once)."""
    t = (1 + 5**0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]  # fmt: skip
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]  # fmt: skip
    pts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for a, b, c in f:
        for i, j in ((a, b), (b, c), (c, a)):
            m = pts[i] + pts[j]
            pts.append(m / np.linalg.norm(m))
    u = np.unique(np.round(np.array(pts), 9), axis=0)
    return u


def shape_vertices(s: Shape) -> np.ndarray:
    """(V, 3) vertices of a polytope that contains the shape, in the link frame [m]."""
    if s.type == "hull":
        return np.asarray(s.vertices, np.float64)
    if s.type == "box":
        half = np.asarray(s.size) / 2
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    else:
        a = np.linspace(0, 2 * np.pi, _SIDES, endpoint=False)
        grow = 1 / math.cos(math.pi / _SIDES)  # circumscribe: the polygon's edges touch the circle
        if s.type == "cylinder":
            ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1) * s.radius * grow
            local = np.concatenate([ring + [0, 0, -s.length / 2], ring + [0, 0, s.length / 2]])
        else:
            sph = _unit_sphere() * s.radius * 1.08  # 42 vertices: 1.08 circumscribes the sphere
            if s.type == "sphere":
                local = sph
            else:  # capsule: two half spheres joined
                local = np.concatenate([sph + [0, 0, s.length / 2], sph - [0, 0, s.length / 2]])
    return local @ s.origin[:3, :3].T + s.origin[:3, 3]


def polytope(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The convex hull of ``vertices`` (V, 3): its vertices (H, 3), face planes (F, 4) ``[n, d]``
    with ``n . x + d <= 0`` inside (``n`` unit, outward) and surface sample points (P, 3): the
    vertices and points along every edge (:data:`EDGE_SAMPLES`)."""
    from scipy.spatial import ConvexHull  # qhull: the reference convex hull

    hull = ConvexHull(np.asarray(vertices, np.float64))
    verts = hull.points[hull.vertices]
    eq = np.unique(np.round(hull.equations, 10), axis=0)
    edges = set()
    for tri in hull.simplices:
        for i, j in ((0, 1), (1, 2), (2, 0)):
            a, b = sorted((int(tri[i]), int(tri[j])))
            edges.add((a, b))
    e = np.array(sorted(edges))
    pa, pb = hull.points[e[:, 0]], hull.points[e[:, 1]]
    along = [pa + (pb - pa) * f for f in EDGE_SAMPLES]
    return verts, eq, np.concatenate([verts, *along])


# ---- the model of one robot ------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CollisionModel:
    """The polytopes of a robot's bodies, attached to skeleton nodes (S shapes, padded arrays).

    Attributes:
        robot: robot name; skeleton_fingerprint: the skeleton the nodes index.
        node: (S,) the node each shape moves with.
        link, source: (S,) the URDF link and where the shape came from (``mesh``, ``primitive``, ``fitted``).
        vertices: (S, V, 3) polytope vertices in the node frame [m] (padded by repeating a vertex).
        points: (S, P, 3) surface sample points in the node frame (padded likewise).
        planes: (S, F, 4) face planes ``[n, d]`` in the node frame (padded by repeating a plane).
        center, radius: (S, 3), (S,) bounding sphere in the node frame [m].
        pairs: (K, 2) shape pairs checked for self-penetration (see the module docstring).
        foot: (S,) side of the foot a shape belongs to: 0 none, 1 left, 2 right.
        velocity_limit: (J,) the URDF velocity limit of each node's joint [rad/s] (inf where none).
    """

    robot: str
    skeleton_fingerprint: str
    node: np.ndarray
    link: tuple[str, ...]
    source: tuple[str, ...]
    vertices: np.ndarray
    points: np.ndarray
    planes: np.ndarray
    center: np.ndarray
    radius: np.ndarray
    pairs: np.ndarray
    foot: np.ndarray
    velocity_limit: np.ndarray
    missing: tuple[str, ...] = ()
    rest_excluded: int = 0

    @property
    def num_shapes(self) -> int:
        return int(len(self.node))

    def counts(self) -> dict[str, int]:
        """Shapes by source (``mesh``, ``primitive``, ``fitted``)."""
        out: dict[str, int] = {}
        for s in self.source:
            out[s] = out.get(s, 0) + 1
        return out


def _pad(arrays: list[np.ndarray]) -> np.ndarray:
    n = max(len(a) for a in arrays)
    return np.stack([np.concatenate([a, np.repeat(a[:1], n - len(a), 0)]) for a in arrays])


def _fitted(skel: Skeleton, j: int) -> list[tuple[int, Shape]]:
    """Capsules along node ``j``'s segments to its children (node frame), a sphere where it has none."""
    rest = skel.rest_positions
    kids = [c for c in range(len(skel.parents)) if skel.parents[c] == j]
    out = []
    for c in kids:
        d = rest[c] - rest[j]
        length = float(np.linalg.norm(d))
        if length < 1e-3:
            continue
        radius = float(np.clip(0.12 * length, 0.015, 0.05))
        z = d / length
        x = np.cross(z, [1.0, 0, 0]) if abs(z[0]) < 0.9 else np.cross(z, [0, 1.0, 0])
        x /= np.linalg.norm(x)
        t = np.eye(4)
        t[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
        t[:3, 3] = d / 2
        out.append((j, Shape("capsule", t, radius=radius, length=max(length - 2 * radius, 1e-3), source="fitted")))
    if not out and skel.node_kinds[j] != "site":
        out.append((j, Shape("sphere", np.eye(4), radius=0.03, source="fitted")))
    return out


def _feet(skel: Skeleton) -> dict[int, int]:
    """node → 1 (left foot) / 2 (right foot): the nodes at and below the ankle key point and the
    toe key point (the knee's, on a robot with neither)."""
    out: dict[int, int] = {}
    for side, code in (("left", 1), ("right", 2)):
        roots = [skel.keypoints.get(f"{side}_{k}", -1) for k in ("ankle", "toe")]
        roots = [n for n in roots if n >= 0] or [n for n in [skel.keypoints.get(f"{side}_knee", -1)] if n >= 0]
        for n in roots:
            for m in np.flatnonzero(skel.subtree(n)):
                out[int(m)] = code
    return out


JOINT_CENTRE_M = 0.01  # nodes closer than this to their parent share its joint centre


def _bodies(skel: Skeleton) -> np.ndarray:
    """(J,) the first node of each chain of nodes that meet at one point (a compound joint: a hip's
    yaw, roll and pitch axes crossing): such a chain moves as one ball joint, and its links are
    one body for the collision check."""
    out = np.arange(len(skel.parents))
    for j in range(1, len(skel.parents)):
        p = int(skel.parents[j])
        if p >= 0 and np.linalg.norm(skel.offsets[j]) < JOINT_CENTRE_M:
            out[j] = out[p]
    return out


def build_collision_model(
    skel: Skeleton,
    link_to_node: Mapping[str, int],
    link_in_node: Mapping[str, np.ndarray],
    shapes: Mapping[str, Sequence[Shape]],
    velocity_limit: Mapping[int, float] | None = None,
    missing: Sequence[str] = (),
) -> CollisionModel:
    """Attach ``shapes`` (link → shapes in the link frame) to ``skel``'s nodes and build the polytopes.

    Args:
        link_to_node: URDF link → the node that carries it.
        link_in_node: URDF link → (4, 4) node ← link transform at the zero pose.
        velocity_limit: node → URDF velocity limit [rad/s].
    """
    placed: list[tuple[int, str, Shape, np.ndarray]] = []  # node, link, shape, node <- link
    covered = set()
    for link, ss in shapes.items():
        if link not in link_to_node:
            continue  # a link the skeleton does not have (removed by the description's edits)
        n = link_to_node[link]
        for s in ss:
            placed.append((n, link, s, link_in_node[link]))
            covered.add(n)
    for j in range(len(skel.parents)):
        if j not in covered and skel.node_kinds[j] != "site":
            for n, s in _fitted(skel, j):
                placed.append((n, skel.link_names[n], s, np.eye(4)))
    verts, pts, planes, centers, radii, nodes, links, sources = [], [], [], [], [], [], [], []
    for n, link, s, t in placed:
        v = shape_vertices(s) @ t[:3, :3].T + t[:3, 3]
        hv, eq, sp = polytope(v)
        c = (hv.max(0) + hv.min(0)) / 2
        verts.append(hv)
        pts.append(sp)
        planes.append(eq)
        centers.append(c)
        radii.append(float(np.linalg.norm(hv - c, axis=1).max()))
        nodes.append(n)
        links.append(link)
        sources.append(s.source if s.type == "hull" or s.source == "fitted" else "primitive")
    node = np.array(nodes, np.int64)
    parents = skel.parents
    feet = _feet(skel)
    foot = np.array([feet.get(int(n), 0) for n in node], np.int64)
    body = _bodies(skel)  # nodes joined at one joint centre (a hip's yaw, roll and pitch) are one body
    bp = {int(b): int(body[parents[b]]) if parents[b] >= 0 else -1 for b in set(body.tolist())}
    cand = [(a, b) for a in range(len(node)) for b in range(a + 1, len(node))
            if body[node[a]] != body[node[b]] and bp[body[node[a]]] != body[node[b]] and bp[body[node[b]]] != body[node[a]]]  # fmt: skip
    model = CollisionModel(
        skel.name, skel.fingerprint, node, tuple(links), tuple(sources), _pad(verts), _pad(pts), _pad(planes),
        np.array(centers), np.array(radii), np.array(cand, np.int64).reshape(-1, 2), foot,
        np.array([float((velocity_limit or {}).get(j, np.inf)) for j in range(len(parents))]), tuple(missing),
    )  # fmt: skip
    if len(cand):  # the robot's own contacts at the zero pose are not self-penetration
        J = len(parents)
        pos = torch.from_numpy(skel.rest_positions)[None]
        rot = torch.eye(3, dtype=torch.float64).expand(1, J, 3, 3)
        d = pair_depths(model, pos, rot)[0].numpy()
        keep = d <= REST_TOLERANCE_M
        model = CollisionModel(**{**model.__dict__, "pairs": model.pairs[keep], "rest_excluded": int((~keep).sum())})
    return model


def _link_nodes(urdf, skel: Skeleton) -> dict[str, int]:
    """URDF link → the skeleton node that carries it (fixed and locked joints merged upwards)."""
    own = {skel.link_names[j]: j for j in range(len(skel.parents)) if skel.node_kinds[j] != "site"}
    out: dict[str, int] = {}
    for link in urdf.links:
        walk = link
        while walk not in own:
            pj = urdf.parent_joint_of(walk)
            if pj is None:
                break
            walk = pj.parent
        if walk in own:
            out[link] = own[walk]
    return out


_models: dict[tuple, CollisionModel] = {}


def collision_model(robot: Robot) -> CollisionModel:
    """The :class:`CollisionModel` of a registered robot: its card's ``collision`` file (fitted
    capsules where a body has no shape), cached per robot files and skeleton."""
    card_file = robot.card.collision
    path = robot.folder / card_file if card_file else None
    key = (str(robot.urdf_path), robot.skeleton.fingerprint, str(path),
           path.stat().st_mtime_ns if path is not None and path.is_file() else None)  # fmt: skip
    hit = _models.get(key)
    if hit is not None:
        return hit
    urdf = load_description(robot.urdf_path, geometry=False)
    if path is not None:
        cf = read_collision(path)
    else:  # no collision file: the URDF's primitives (its meshes are not read here)
        cf, _ = shapes_from_urdf(urdf, load_meshes=False)
    skel = robot.skeleton
    t_root = zero_pose_link_transforms(urdf, dict(skel.locked))
    nodes = _link_nodes(urdf, skel)
    rest = skel.rest_positions
    in_node = {}
    for link, n in nodes.items():
        t = t_root[link].copy()
        t[:3, 3] -= rest[n]  # node frames are the root frame's axes at the node's zero-pose position
        in_node[link] = t
    unknown = sorted(set(cf.links) - set(urdf.links))
    if unknown:
        raise RobotCardError(f"the collision file names links the URDF does not have: {unknown[:5]}",
                             path=path, element="links", fix="rebuild it for this URDF")  # fmt: skip
    vel = {}
    by_joint = {j.name: j for j in urdf.joints}
    for n, jn in enumerate(skel.urdf_joint_names):
        j = by_joint.get(jn) if jn else None
        if j is not None and j.velocity is not None:
            vel[n] = j.velocity
    model = build_collision_model(skel, nodes, in_node, cf.links, vel, cf.missing)
    _models[key] = model
    return model
