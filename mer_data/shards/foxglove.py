"""Foxglove 3D-panel messages (JSON encoding): a robot's motion as TF frames named after its links,
its URDF and collision shapes on those frames, mer's stick figure, and marker spheres. What the
retarget MCAP (:func:`mer_models.export.writers.write_mcap`) and the MCAP shards
(:mod:`.mcap_io`) both write.

* ``foxglove.FrameTransforms`` (:func:`tf_messages`, one message per frame): ``world → <root link>``
  (the base pose), then ``<parent link> → <link>`` for every link of the robot's articulation
  (:mod:`mer_data.robots.articulation`: links merged through fixed joints included, locked joints
  at their value). Frames are the description's own link frames, so anything drawn in a link's
  frame (a URDF's visuals, a mesh) moves with it; Foxglove's URDF layer attaches each link's
  visuals to the TF frame of the same name.
* ``/robot_description`` (:func:`description_message`, ``std_msgs/String`` as JSON, URDF robots):
  the registered URDF, which Foxglove's 3D panel loads from a topic of that name.
* ``foxglove.SceneUpdate``: the robot's collision shapes (:func:`robot_scene`: primitives, mesh
  hulls as triangle lists, mer's fitted capsules where a body has none), mer's skeleton as sticks
  and joint spheres (:func:`skeleton_scene`), both frame-locked to the link frames; spheres at
  points (:func:`sphere_scene`).

A skeleton that is not a registered robot's (an augmented one, a human from BVH) gets frames for
its nodes' links only (:func:`link_frames` with ``robot`` None), and no robot or description.

Foxglove recognises the messages by their schema names and parses them with the schema text
embedded in the MCAP: that text is Foxglove's official JSON schema of each message, vendored
unchanged in ``foxglove_schemas/`` (MIT, from foxglove/foxglove-sdk; see its README). Every
message written here carries every field those schemas require.
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from importlib.resources import files
from typing import TYPE_CHECKING

import numpy as np
import torch

from mer_data.kinematics.rotations import matrix_to_quat
from mer_data.robots.link_geometry import fitted_hulls, hull_triangles, link_shapes
from mer_data.skeleton import Skeleton

if TYPE_CHECKING:  # pragma: no cover
    from mer_data.robots.registry import Robot

__all__ = [
    "FRAME_TRANSFORMS_SCHEMA", "SCENE_UPDATE_SCHEMA", "DESCRIPTION_SCHEMA", "LinkFrames", "link_frames", "registered_robot",
    "motion_frames", "world_frame",
    "tf_messages", "robot_scene", "skeleton_scene", "description_message", "sphere_scene", "rotvec_to_xyzw",
]  # fmt: skip


def _official_schema(name: str) -> bytes:
    """The vendored official JSON schema of ``foxglove.<name>`` (UTF-8 bytes, unchanged)."""
    return (files(__package__) / "foxglove_schemas" / f"{name}.json").read_bytes()


#: Foxglove's official JSON schema texts, embedded as the MCAP schema records.
FRAME_TRANSFORMS_SCHEMA = _official_schema("FrameTransforms")
SCENE_UPDATE_SCHEMA = _official_schema("SceneUpdate")
#: JSON schema of ``std_msgs/String`` (the schema name Foxglove's URDF layer accepts for a URDF topic).
DESCRIPTION_SCHEMA = json.dumps({
    "title": "std_msgs/String", "description": "A string: here the robot's URDF (Foxglove's /robot_description)",
    "type": "object", "properties": {"data": {"type": "string", "description": "the URDF XML"}}, "required": ["data"],
}).encode()  # fmt: skip

_COLLISION_RGBA = {"r": 0.55, "g": 0.65, "b": 0.8, "a": 0.85}


def _time(ns: int) -> dict:
    """Foxglove ``time`` of ``ns`` [ns since the log start]."""
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def rotvec_to_xyzw(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 4) quaternions x, y, z, w (Foxglove's order)."""
    v = np.asarray(v, np.float64)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    scale = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-300), 0.5)
    return np.concatenate([v * scale, np.cos(half)], axis=-1)


def _vec(a) -> dict:
    return {"x": round(float(a[0]), 6), "y": round(float(a[1]), 6), "z": round(float(a[2]), 6)}


def _quat(a) -> dict:
    return {"x": round(float(a[0]), 7), "y": round(float(a[1]), 7), "z": round(float(a[2]), 7), "w": round(float(a[3]), 7)}


def _xyzw(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations → (..., 4) quaternions x, y, z, w."""
    q = matrix_to_quat(torch.from_numpy(np.asarray(r, np.float64))).numpy()  # w, x, y, z
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _pose(t: np.ndarray) -> dict:
    return {"position": _vec(t[:3, 3]), "orientation": _quat(_xyzw(t[:3, :3]))}


# ---- the link frames ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class LinkFrames:
    """World poses of a motion's link frames.

    Attributes:
        names: (L,) link names (the TF frame ids); parents: (L,) parent frame index, -1 for the root.
        poses: (F, L, 4, 4) world ← link [m].
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    poses: np.ndarray


def _rigid(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    t = np.zeros(pos.shape[:-1] + (4, 4))
    t[..., :3, :3] = rot
    t[..., :3, 3] = pos
    t[..., 3, 3] = 1.0
    return t


@dataclass(frozen=True)
class _LinkTree:
    """A robot's link frames as bodies carry them: per link its body, body ← link, parent link."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    body: tuple[int, ...]
    frame: np.ndarray  # (L, 4, 4) body <- link


_trees: dict[tuple, _LinkTree] = {}
_trees_lock = threading.Lock()


def _link_tree(robot: "Robot") -> _LinkTree:
    """The :class:`_LinkTree` of ``robot``'s articulation (cached per description file and skeleton)."""
    from mer_data.robots.articulation import articulation
    from mer_data.robots.mjcf import load_description

    key = (str(robot.urdf_path), robot.urdf_path.stat().st_mtime_ns, robot.skeleton.fingerprint)
    with _trees_lock:
        hit = _trees.get(key)
    if hit is not None:
        return hit
    art = articulation(robot)
    u = load_description(robot.urdf_path, geometry=False)
    names, body, frame = [], [], []
    for b, bd in enumerate(art.bodies):
        for link, f in zip(bd.links, bd.link_frames):
            names.append(link)
            body.append(b)
            frame.append(f)
    index = {n: i for i, n in enumerate(names)}
    parents = []
    for n in names:
        walk = u.parent_joint_of(n)
        while walk is not None and walk.parent not in index:  # an MJCF body's inner links have no frame
            walk = u.parent_joint_of(walk.parent)
        parents.append(-1 if walk is None else index[walk.parent])
    hit = _LinkTree(tuple(names), tuple(parents), tuple(body), np.stack(frame))
    with _trees_lock:
        _trees[key] = hit
    return hit


def link_frames(skel: Skeleton, node_pos: np.ndarray, node_rot: np.ndarray, robot: "Robot | None") -> LinkFrames:
    """The link frames of a motion from its node positions (F, J, 3) [m] and rotations (F, J, 3, 3):
    every link of ``robot``'s articulation, or (``robot`` None) the links of ``skel``'s nodes."""
    if robot is None:
        nodes = [j for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"]
        index = {j: i for i, j in enumerate(nodes)}
        poses = _rigid(node_pos[:, nodes], node_rot[:, nodes] @ skel.rest_rotations[nodes])
        parents = tuple(-1 if j == 0 else index[int(skel.parents[j])] for j in nodes)
        return LinkFrames(tuple(skel.link_names[j] for j in nodes), parents, poses)
    from mer_data.robots.articulation import articulation

    tree = _link_tree(robot)
    pos, rot = articulation(robot).body_poses(node_pos, node_rot)
    body = _rigid(pos, rot)  # (F, B, 4, 4)
    return LinkFrames(tree.names, tree.parents, body[:, list(tree.body)] @ tree.frame)


def registered_robot(skel: Skeleton, name: str | None = None) -> "Robot | None":
    """The registered robot named ``name`` (default: the skeleton's name) when ``skel`` is its
    skeleton; None for any other skeleton (scaled, augmented, a human from BVH, unregistered)."""
    from mer_data.base.errors import RegistryError
    from mer_data.robots.registry import load_robot

    try:
        robot = load_robot(name or skel.name)
    except RegistryError:  # unknown, or not a robot's name at all
        return None
    return robot if robot.skeleton.fingerprint == skel.fingerprint else None


def motion_frames(
    skel: Skeleton, robot: "Robot | None", base_pos: np.ndarray, base_rotvec: np.ndarray, q: np.ndarray
) -> LinkFrames:
    """:func:`link_frames` of a motion given as base positions (F, 3) [m], base rotation vectors
    (F, 3) [rad] and node angles (F, J) [rad] (the shards' columns), by the skeleton's forward kinematics."""
    from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
    from mer_data.kinematics.rotations import axis_angle_to_matrix

    rot = axis_angle_to_matrix(torch.as_tensor(np.asarray(base_rotvec, np.float64)))
    pos, nrot = fk_skeleton(skeleton_tensors(skel, torch.float64), torch.as_tensor(np.asarray(q, np.float64)),
                            torch.as_tensor(np.asarray(base_pos, np.float64)), base_rot=rot)  # fmt: skip
    return link_frames(skel, pos.numpy(), nrot.numpy(), robot)


def world_frame(frames: LinkFrames) -> str:
    """The fixed frame's name: ``world`` (``mer_world`` where a link is named ``world``)."""
    return "mer_world" if "world" in frames.names else "world"


def tf_messages(frames: LinkFrames, fps: float, t0_ns: int = 0) -> list[tuple[int, bytes]]:
    """(log_time_ns, ``foxglove.FrameTransforms`` JSON) per frame, from ``t0_ns`` at ``fps`` [Hz]:
    each link relative to its parent, the root relative to :func:`world_frame`."""
    F, L = frames.poses.shape[:2]
    par = np.array([max(p, 0) for p in frames.parents])
    rel = np.linalg.inv(frames.poses[:, par]) @ frames.poses  # (F, L, 4, 4) parent <- link
    roots = [i for i, p in enumerate(frames.parents) if p < 0]
    rel[:, roots] = frames.poses[:, roots]
    quat = _xyzw(rel[..., :3, :3])
    world = world_frame(frames)
    parent_names = [world if p < 0 else frames.names[p] for p in frames.parents]
    out = []
    for f in range(F):
        ns = t0_ns + int(round(f * 1e9 / fps))
        stamp = _time(ns)
        tfs = [{"timestamp": stamp, "parent_frame_id": parent_names[i], "child_frame_id": frames.names[i],
                "translation": _vec(rel[f, i, :3, 3]), "rotation": _quat(quat[f, i])} for i in range(L)]  # fmt: skip
        out.append((ns, json.dumps({"transforms": tfs}, separators=(",", ":")).encode()))
    return out


# ---- scenes ---------------------------------------------------------------------------------------------
def _entity(frame: str, ns: int, eid: str, **primitives) -> dict:
    e = {"timestamp": _time(ns), "frame_id": frame, "id": eid, "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": True,
         "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [], "triangles": [],
         "texts": [], "models": []}  # fmt: skip
    e.update(primitives)
    return e


def _triangles(tri: np.ndarray) -> dict:
    ident = {"position": _vec((0, 0, 0)), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
    return {"pose": ident, "points": [_vec(p) for p in tri.reshape(-1, 3)], "color": _COLLISION_RGBA, "colors": [], "indices": []}


def robot_scene(robot: "Robot", ns: int = 0) -> bytes:
    """A ``foxglove.SceneUpdate`` of ``robot``'s collision shapes, one frame-locked entity per link."""
    from mer_data.robots.articulation import articulation

    art = articulation(robot)
    shapes = link_shapes(robot)
    fitted = fitted_hulls(robot, art, shapes)
    entities = []
    for b, body in enumerate(art.bodies):
        for k, link in enumerate(body.links):
            prims: dict[str, list] = {"cubes": [], "spheres": [], "cylinders": [], "triangles": []}
            for s in shapes.get(link, ()):
                if s.type == "hull":
                    prims["triangles"].append(_triangles(hull_triangles(s.vertices)))
                elif s.type == "box":
                    prims["cubes"].append({"pose": _pose(s.origin), "size": _vec(s.size), "color": _COLLISION_RGBA})
                elif s.type == "sphere":
                    d = 2 * s.radius
                    prims["spheres"].append({"pose": _pose(s.origin), "size": _vec((d, d, d)), "color": _COLLISION_RGBA})
                else:  # cylinder, capsule: along the shape's z
                    d = 2 * s.radius
                    prims["cylinders"].append({"pose": _pose(s.origin), "size": _vec((d, d, s.length)), "bottom_scale": 1.0,
                                               "top_scale": 1.0, "color": _COLLISION_RGBA})  # fmt: skip
                    if s.type == "capsule":
                        for end in (-0.5, 0.5):
                            t = s.origin.copy()
                            t[:3, 3] = s.origin[:3, 3] + s.origin[:3, 2] * end * s.length
                            prims["spheres"].append({"pose": _pose(t), "size": _vec((d, d, d)), "color": _COLLISION_RGBA})
            if k == 0:
                to_link = np.linalg.inv(body.link_frames[0])  # body frame -> its own link's frame
                for v in fitted.get(b, []):
                    prims["triangles"].append(_triangles(hull_triangles(v @ to_link[:3, :3].T + to_link[:3, 3])))
            if any(prims.values()):
                entities.append(_entity(link, ns, f"{robot.name}/{link}", **prims))
    return json.dumps({"deletions": [], "entities": entities}, separators=(",", ":")).encode()


def skeleton_scene(skel: Skeleton, ns: int = 0) -> bytes:
    """mer's skeleton as a ``foxglove.SceneUpdate``: per node, lines to its children and a sphere at
    the joint (key points larger), drawn in the node's link frame (node offsets turned by the link's
    rest rotation: node frames are the root's axes at the zero pose)."""
    key_nodes = {v for v in skel.keypoints.values() if v >= 0}
    zero = _vec((0, 0, 0))
    ident = {"position": zero, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
    orange, grey = {"r": 1.0, "g": 0.5, "b": 0.1, "a": 1.0}, {"r": 0.9, "g": 0.9, "b": 0.9, "a": 1.0}
    entities = []
    for j in range(skel.num_nodes):
        if skel.node_kinds[j] == "site":
            continue
        r = skel.rest_rotations[j]
        size = 0.05 if j in key_nodes else 0.025
        spheres = [{"pose": ident, "size": _vec((size, size, size)), "color": orange if j in key_nodes else grey}]
        pts = []
        for c in skel.children(j):
            p = r.T @ skel.offsets[c]
            pts += [zero, _vec(p)]
            if skel.node_kinds[c] == "site":
                s = 0.05 if c in key_nodes else 0.025
                spheres.append({"pose": {"position": _vec(p), "orientation": ident["orientation"]}, "size": _vec((s, s, s)),
                                "color": orange if c in key_nodes else grey})  # fmt: skip
        lines = [{"type": 2, "pose": ident, "thickness": 0.015, "scale_invariant": False, "points": pts,
                  "color": {"r": 0.2, "g": 0.6, "b": 1.0, "a": 1.0}, "colors": [], "indices": []}] if pts else []  # fmt: skip
        entities.append(_entity(skel.link_names[j], ns, f"skeleton/{skel.node_names[j]}", spheres=spheres, lines=lines))
    return json.dumps({"deletions": [], "entities": entities}, separators=(",", ":")).encode()


def description_message(robot: "Robot") -> bytes | None:
    """``{"data": <URDF text>}`` of a URDF robot; None for an MJCF one (Foxglove reads URDFs only)."""
    from mer_data.robots.articulation import articulation

    if articulation(robot).source != "urdf":
        return None
    return json.dumps({"data": robot.urdf_path.read_text(encoding="utf-8")}).encode()


def sphere_scene(
    points: np.ndarray,
    ns: int,
    *,
    entity_id: str,
    frame_id: str = "world",
    size: float = 0.04,
    rgba: tuple[float, float, float, float] = (1.0, 0.1, 0.1, 0.8),
) -> bytes:
    """A SceneUpdate with one entity ``entity_id`` of spheres (diameter ``size`` [m]) at ``points`` (K, 3) [m]
    in ``frame_id``, stamped ``ns``; it replaces the previous message's entity of the same id."""
    ident = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    color = dict(zip("rgba", map(float, rgba)))
    spheres = [{"pose": {"position": _vec(p), "orientation": ident}, "size": {"x": size, "y": size, "z": size}, "color": color}
               for p in np.asarray(points, np.float64)]  # fmt: skip
    entity = {"timestamp": _time(ns), "frame_id": frame_id, "id": entity_id, "lifetime": {"sec": 0, "nsec": 0},
              "frame_locked": False, "metadata": [], "arrows": [], "cubes": [], "spheres": spheres, "cylinders": [],
              "lines": [], "triangles": [], "texts": [], "models": []}  # fmt: skip
    return json.dumps({"deletions": [], "entities": [entity]}, separators=(",", ":")).encode()
