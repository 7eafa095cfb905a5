"""Foxglove 3D-panel messages for a skeleton motion (JSON encoding).

* ``foxglove.FrameTransforms`` per frame: one transform per node, ``world -> <robot>/<base>`` from
  the base pose, and ``<robot>/<parent> -> <robot>/<node>`` with the node's rest offset and its
  joint rotation ``Rot(axis, q)`` (node frames are root-aligned at the zero pose, so this is
  exactly the skeleton's forward kinematics, see :mod:`mer_data.kinematics.fk`).
* ``foxglove.SceneUpdate``: one frame-locked entity per node drawing the links to its children
  (a line list in the node's frame) and a sphere at the joint; key points are drawn larger.

Foxglove recognises the messages by their schema names and parses them with the schema text
embedded in the MCAP: that text is Foxglove's official JSON schema of each message, vendored
unchanged in ``foxglove_schemas/`` (MIT, from foxglove/foxglove-sdk; see its README). Every
message written here carries every field those schemas require.
"""

from __future__ import annotations

import json
from importlib.resources import files

import numpy as np

from mer_data.skeleton import Skeleton

__all__ = [
    "FRAME_TRANSFORMS_SCHEMA",
    "SCENE_UPDATE_SCHEMA",
    "frame_transforms",
    "scene_update",
    "sphere_scene",
    "rotvec_to_xyzw",
]


def _official_schema(name: str) -> bytes:
    """The vendored official JSON schema of ``foxglove.<name>`` (UTF-8 bytes, unchanged)."""
    return (files(__package__) / "foxglove_schemas" / f"{name}.json").read_bytes()


#: Foxglove's official JSON schema texts, embedded as the MCAP schema records.
FRAME_TRANSFORMS_SCHEMA = _official_schema("FrameTransforms")
SCENE_UPDATE_SCHEMA = _official_schema("SceneUpdate")


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


def frame_transforms(
    skel: Skeleton, prefix: str, base_pos: np.ndarray, base_rotvec: np.ndarray, q: np.ndarray, t0_ns: int, fps: float
) -> list[tuple[int, bytes]]:
    """(log_time_ns, JSON) per frame. ``base_pos`` (T, 3), ``base_rotvec`` (T, 3), ``q`` (T, J)."""
    names = [f"{prefix}/{n}" for n in skel.node_names]
    base_q = rotvec_to_xyzw(base_rotvec)
    joint_q = rotvec_to_xyzw(skel.axes[None, :, :] * np.asarray(q, np.float64)[:, :, None])  # (T, J, 4)
    offsets = [_vec(o) for o in skel.offsets]
    out = []
    for t in range(base_pos.shape[0]):
        ns = t0_ns + int(round(t * 1e9 / fps))
        stamp = _time(ns)
        tfs = [
            {"timestamp": stamp, "parent_frame_id": "world", "child_frame_id": names[0],
             "translation": _vec(base_pos[t]), "rotation": _quat(base_q[t])}
        ]  # fmt: skip
        for j in range(1, skel.num_nodes):
            tfs.append(
                {"timestamp": stamp, "parent_frame_id": names[skel.parents[j]], "child_frame_id": names[j],
                 "translation": offsets[j], "rotation": _quat(joint_q[t, j])}
            )  # fmt: skip
        out.append((ns, json.dumps({"transforms": tfs}, separators=(",", ":")).encode()))
    return out


def scene_update(skel: Skeleton, prefix: str, ns: int) -> bytes:
    """A SceneUpdate drawing ``skel`` in its node frames (valid until replaced)."""
    key_nodes = {v for v in skel.keypoints.values() if v >= 0}
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    ident = {"position": zero, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
    entities = []
    for j in range(skel.num_nodes):
        kids = skel.children(j)
        lines = []
        if kids:
            pts = []
            for c in kids:
                pts += [zero, _vec(skel.offsets[c])]
            lines.append(
                {"type": 2, "pose": ident, "thickness": 0.015, "scale_invariant": False, "points": pts,
                 "color": {"r": 0.2, "g": 0.6, "b": 1.0, "a": 1.0}, "colors": [], "indices": []}
            )  # fmt: skip
        size = 0.05 if j in key_nodes else 0.025
        color = {"r": 1.0, "g": 0.5, "b": 0.1, "a": 1.0} if j in key_nodes else {"r": 0.9, "g": 0.9, "b": 0.9, "a": 1.0}
        entities.append(
            {"timestamp": _time(ns), "frame_id": f"{prefix}/{skel.node_names[j]}", "id": f"{prefix}/{skel.node_names[j]}",
             "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": True, "metadata": [], "arrows": [], "cubes": [],
             "spheres": [{"pose": ident, "size": {"x": size, "y": size, "z": size}, "color": color}],
             "cylinders": [], "lines": lines, "triangles": [], "texts": [], "models": []}
        )  # fmt: skip
    return json.dumps({"deletions": [], "entities": entities}, separators=(",", ":")).encode()


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
