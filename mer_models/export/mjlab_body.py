"""What the mjlab export reads off the robot standing at its zero pose: where its bodies are, its
feet and their soles, the bodies a tracking task follows.

- **zero pose**: every joint at 0 (locked joints at their value), the root body at the origin, then
  lifted so the lowest collision point touches the floor (the initial state's height).
- **feet**: per side, the bodies below the ``<side>_ankle`` key point's body (toes included). The
  **sole** is the collision geometry (:func:`~mer_models.export.geometry.robot_meshes` with
  ``visual=False``: the shapes ``mer robots show`` lists, fitted capsules where a body has none)
  within :data:`SOLE_BAND` of the foot's lowest point; per foot body that reaches it, a sphere of
  radius :data:`SOLE_RADIUS` at each corner of the sole's rectangle (principal axes of the sole
  points in the floor plane), its bottom on the sole; one sphere where the sole is smaller than a
  sphere each way.
- **tracked bodies**: the root and the bodies of the 14 key points (hips, knees, ankles, toes,
  shoulders, elbows, hands; each once), as mjlab's G1 task tracks pelvis, hips, knees, ankles,
  torso, shoulders, elbows and wrists; the **anchor** is the lowest common ancestor of the two
  shoulders' bodies (G1: ``torso_link``), the root where a shoulder is missing.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from mer_data.base.errors import OutputError
from mer_data.robots.articulation import Articulation
from mer_data.robots.registry import Robot

from .geometry import robot_meshes

log = logging.getLogger(__name__)

__all__ = ["SOLE_BAND", "SOLE_RADIUS", "FootSphere", "Standing", "standing", "body_of_keypoint"]

#: How far above a foot's lowest point collision geometry counts as sole [m].
SOLE_BAND = 0.005
#: Radius of the sole's contact spheres [m] (mjlab's G1 foot capsules: 0.01).
SOLE_RADIUS = 0.01


@dataclass(frozen=True)
class FootSphere:
    """One contact sphere: ``side`` (left/right), ``body`` index, ``pos`` (3,) in the body frame [m]."""

    side: str
    body: int
    pos: np.ndarray


@dataclass(frozen=True)
class Standing:
    """The robot at its zero pose.

    Attributes:
        world: (B, 4, 4) world <- body, root at the origin [m].
        height: the root body's height that puts the lowest collision point on the floor [m].
        spheres: the feet's contact spheres; soles: foot body -> (3,) sole centre in ``world`` [m].
        foot_bodies: side -> the bodies of that foot.
        tracked: tracked body names (root first, the articulation's order); anchor: the anchor body's name.
    """

    world: np.ndarray
    height: float
    spheres: tuple[FootSphere, ...]
    soles: dict[int, np.ndarray]
    foot_bodies: dict[str, tuple[int, ...]]
    tracked: tuple[str, ...]
    anchor: str


def _world(art: Articulation) -> np.ndarray:
    out = np.empty((len(art.bodies), 4, 4))
    for b, body in enumerate(art.bodies):
        out[b] = body.origin if body.parent < 0 else out[body.parent] @ body.origin
    return out


def body_of_keypoint(robot: Robot, art: Articulation, key: str) -> int | None:
    """The index of the body that carries key point ``key``'s link (None: the robot has no such key point)."""
    node = robot.skeleton.keypoints.get(key, -1)
    if node is None or node < 0:
        return None
    link = robot.skeleton.link_names[node]
    return next((b for b, body in enumerate(art.bodies) if link in body.links), None)


def _subtree(art: Articulation, b: int) -> list[int]:
    out = [b]
    for i in range(b + 1, len(art.bodies)):
        if art.bodies[i].parent in out:
            out.append(i)
    return out


def _ancestors(art: Articulation, b: int) -> list[int]:
    out = [b]
    while art.bodies[out[-1]].parent >= 0:
        out.append(art.bodies[out[-1]].parent)
    return out


def _corners(points: np.ndarray, r: float) -> np.ndarray:
    """(K, 2) sphere centres in the floor plane: the corners of the points' rectangle (its axes the
    points' principal axes), or its centre where it is smaller than a sphere each way."""
    c = points.mean(0)
    d = points - c
    vt = np.linalg.svd(d, full_matrices=False)[2] if len(points) > 1 else np.eye(2)
    u = d @ vt.T
    lo, hi = u.min(0), u.max(0)
    if np.all(hi - lo < r):  # smaller than a sphere: one at its centre
        return (c + ((lo + hi) / 2) @ vt)[None]
    return np.array([c + np.array([x, y]) @ vt for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])


def standing(robot: Robot, art: Articulation) -> Standing:
    """:class:`Standing` of ``robot`` (module docstring)."""
    world = _world(art)
    meshes = robot_meshes(robot, visual=False, max_faces=None)
    verts: dict[int, np.ndarray] = {}
    for m in meshes.bodies:
        t = world[m.body]
        verts[m.body] = m.vertices @ t[:3, :3].T + t[:3, 3]
    if not verts:
        raise OutputError(f"{robot.name!r} has no collision geometry to stand on", element="mjlab",
                          fix="give the description collision shapes (`mer robots show` lists them) and register it again")  # fmt: skip
    floor = min(float(v[:, 2].min()) for v in verts.values())
    spheres: list[FootSphere] = []
    soles: dict[int, np.ndarray] = {}
    feet: dict[str, tuple[int, ...]] = {}
    for side in ("left", "right"):
        ankle = body_of_keypoint(robot, art, f"{side}_ankle")
        if ankle is None:
            continue
        bodies = [b for b in _subtree(art, ankle) if b in verts]
        if not bodies:
            continue
        feet[side] = tuple(bodies)
        low = min(float(verts[b][:, 2].min()) for b in bodies)
        for b in bodies:
            sole = verts[b][verts[b][:, 2] <= low + SOLE_BAND]
            if not len(sole):
                continue
            soles[b] = np.array([*sole[:, :2].mean(0), low])
            inv = np.linalg.inv(world[b])
            for xy in _corners(sole[:, :2], SOLE_RADIUS):
                p = np.array([xy[0], xy[1], low + SOLE_RADIUS, 1.0])
                spheres.append(FootSphere(side, b, (inv @ p)[:3]))
    if not spheres:
        log.warning(
            "%s: no foot found below its ankle key points: the model has no sole contact spheres (edit "
            "the key points, or add geoms named <side>_foot<k>_collision)",
            robot.name,
        )
    keys = [body_of_keypoint(robot, art, k) for k in robot.skeleton.keypoints]
    tracked = sorted({0, *(b for b in keys if b is not None)})
    ls, rs = body_of_keypoint(robot, art, "left_shoulder"), body_of_keypoint(robot, art, "right_shoulder")
    anchor = 0
    if ls is not None and rs is not None:
        right = set(_ancestors(art, rs))
        anchor = next(b for b in _ancestors(art, ls) if b in right)
    if anchor not in tracked:
        tracked = sorted({*tracked, anchor})
    return Standing(
        world, -floor, tuple(spheres), soles, feet, tuple(art.bodies[b].name for b in tracked), art.bodies[anchor].name
    )
