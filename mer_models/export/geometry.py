"""A registered robot's geometry per body, for the files and views that draw or simulate it (the
MuJoCo model, the Foxglove MCAP, the video, the viewer).

- **collision shapes** per link (:func:`link_shapes`: ``collision.json``, else the description's
  primitives) and, for a body with none, the capsules mer fits along its links (:func:`fitted_hulls`);
  built in :mod:`mer_data.shards.foxglove` (the MCAP shards draw them too), named here.
- **what draws the robot** (:func:`robot_meshes`): triangle meshes per body of its articulation,
  in the body frame. A body's *visual meshes* where the description has some that can be read --
  a URDF's ``<visual>`` mesh files, an MJCF's mesh geoms that do not collide (group 1 or 2, or
  ``contype = conaffinity = 0``; all mesh geoms where none is visual) -- else its collision shapes as
  triangles (hulls as they are, primitives tessellated, fitted capsules as hulls). Mesh files are
  looked up beside the registered description (where ``mer robots register`` says to put them:
  the registry keeps no meshes) and, when given, under ``mesh_dir`` (a URDF's ``package://PKG/...``
  and ``meshes/x.stl`` paths tried as suffixes, then by file name; an MJCF's ``meshdir`` replaced);
  nothing outside those two folders is read. Meshes are thinned to a face budget by vertex
  clustering (:func:`decimate`) so a video frame or a browser draws them quickly.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from mer_data.robots.articulation import Articulation, articulation, urdf_visual_meshes
from mer_data.robots.link_geometry import fitted_hulls, hull_triangles, link_shapes
from mer_data.robots.registry import Robot
from mer_data.robots.shapes import Shape, mesh_file

log = logging.getLogger(__name__)

__all__ = ["link_shapes", "fitted_hulls", "hull_triangles", "BodyMesh", "RobotMeshes", "robot_meshes", "shape_mesh", "decimate",
           "bone_segments"]


def bone_segments(pos: np.ndarray, parents) -> np.ndarray:
    """(J, 3) node positions → (J-1, 2, 3) parent → child segments: the bones the video and the viewer
    draw for a skeleton, and between a robot's collision pieces."""
    child = np.arange(1, len(parents))
    return np.stack([pos[np.asarray(parents)[child]], pos[child]], axis=1)


@dataclass(frozen=True)
class BodyMesh:
    """The triangles of one body.

    Attributes:
        body: index of the body in the robot's articulation (:mod:`mer_data.robots.articulation`).
        vertices: (V, 3) float64 in the body frame [m]; faces: (T, 3) int vertex indices,
            counter-clockwise seen from outside.
        source: ``"mesh"`` (the description's visual meshes) or ``"collision"`` (its collision shapes).
    """

    body: int
    vertices: np.ndarray
    faces: np.ndarray
    source: Literal["mesh", "collision"]


@dataclass(frozen=True)
class RobotMeshes:
    """What draws a robot: one :class:`BodyMesh` per body that has geometry.

    Attributes:
        robot: its name; bodies: the meshes; body_names: (B,) the articulation's body names.
        missing: visual mesh files that could not be found or read (a URDF's, as written), or MuJoCo's
            sentences naming them (an MJCF's); their bodies draw their collision shapes.
    """

    robot: str
    bodies: tuple[BodyMesh, ...]
    body_names: tuple[str, ...]
    missing: tuple[str, ...] = ()

    @property
    def kind(self) -> Literal["mesh", "collision", "none"]:
        """``mesh`` where any body draws visual meshes, else ``collision`` (``none``: no geometry)."""
        if any(b.source == "mesh" for b in self.bodies):
            return "mesh"
        return "collision" if self.bodies else "none"

    @property
    def num_faces(self) -> int:
        return int(sum(len(b.faces) for b in self.bodies))


# ---- tessellation -----------------------------------------------------------------------------------
def _transform(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.asarray(v, np.float64) @ t[:3, :3].T + t[:3, 3]


def _hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tri = hull_triangles(points)  # (T, 3, 3) outward
    v, faces = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
    return v, faces.reshape(-1, 3)


def shape_mesh(s: Shape) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) vertices in the link frame [m] and (T, 3) outward faces of a collision shape (hulls as
    they are; boxes, spheres, cylinders and capsules tessellated coarsely: they are drawn small)."""
    import trimesh

    if s.type == "hull":
        return _hull_mesh(s.vertices)
    if s.type == "box":
        m = trimesh.creation.box(extents=s.size)
    elif s.type == "sphere":
        m = trimesh.creation.icosphere(subdivisions=1, radius=s.radius)
    elif s.type == "cylinder":
        m = trimesh.creation.cylinder(radius=s.radius, height=s.length, sections=12)
    else:  # capsule along z, its length between the sphere centres
        m = trimesh.creation.capsule(height=s.length, radius=s.radius, count=[8, 8])
    return _transform(m.vertices, s.origin), np.asarray(m.faces, np.int64)


def _weld(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices at the same place (to 1 µm) merged: STL files repeat each vertex per face."""
    _, first, idx = np.unique(np.round(v * 1e6).astype(np.int64), axis=0, return_index=True, return_inverse=True)
    return v[first], idx.ravel()[f]


def decimate(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_faces`` faces of a mesh by vertex clustering: vertices merged on a grid (each
    cell's mean), faces whose corners fall into fewer than three cells dropped, duplicates removed.
    The grid is the finest of a short bisection on the cell size that keeps the budget."""
    v, f = _weld(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    if len(f) <= max_faces:
        return v, f
    lo, span = v.min(0), float(np.ptp(v, axis=0).max()) or 1.0
    unit = (v - lo) / span  # in [0, 1]

    def cluster(cells: float) -> tuple[np.ndarray, np.ndarray]:
        n = int(cells) + 2
        k = np.floor(unit * cells).astype(np.int64)
        _, idx = np.unique((k[:, 0] * n + k[:, 1]) * n + k[:, 2], return_inverse=True)
        cf = idx[f]
        cf = cf[(cf[:, 0] != cf[:, 1]) & (cf[:, 1] != cf[:, 2]) & (cf[:, 0] != cf[:, 2])]
        s = np.sort(cf, axis=1)
        _, first = np.unique((s[:, 0] * (idx.max() + 1) + s[:, 1]) * (idx.max() + 1) + s[:, 2], return_index=True)
        cf = cf[np.sort(first)]
        counts = np.bincount(idx)
        centre = np.stack([np.bincount(idx, weights=v[:, i]) for i in range(3)], axis=1) / counts[:, None]
        used, cf = np.unique(cf, return_inverse=True)
        return centre[used], cf.reshape(-1, 3)

    a, b = 2.0, 1024.0  # cells along the longest side: few (coarse) .. many (fine)
    best = cluster(a)
    for _ in range(7):
        mid = (a * b) ** 0.5
        out = cluster(mid)
        if len(out[1]) <= max_faces:
            a, best = mid, out
        else:
            b = mid
    return best


# ---- visual meshes ----------------------------------------------------------------------------------
def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices and triangles of a mesh file (:func:`~mer_data.robots.mesh_io.read_mesh`), or None
    (logged); an archive is refused (MeshArchiveError), never unpacked."""
    from mer_data.robots.mesh_io import MeshArchiveError, read_mesh

    try:
        v, f = read_mesh(path)
    except MeshArchiveError:
        raise
    except Exception as exc:  # noqa: BLE001 - an unreadable mesh: the body draws its collision shapes
        log.warning("mesh %s could not be read (%s: %s)", path, type(exc).__name__, str(exc).splitlines()[0][:300])
        return None
    if len(f) == 0 or not np.isfinite(v).all():
        return None
    return v, f


def _find_mesh(filename: str, folder: Path, mesh_dir: Path | None) -> Path | None:
    """A URDF mesh reference under the description's folder, else under ``mesh_dir`` (suffixes of
    the path, then its file name)."""
    found = mesh_file(filename, folder)
    if found is None and mesh_dir is not None:
        found = mesh_file(filename if filename.startswith("package://") else f"package://x/{filename}", mesh_dir)
        if found is None:
            found = mesh_file(Path(filename).name, mesh_dir)
    return found


def _urdf_visuals(robot: Robot, art: Articulation, mesh_dir: Path | None) -> tuple[dict[int, list], list[str]]:
    """Body → [(vertices in the body frame, faces)] of a URDF's visual meshes; files not found."""
    folder = Path(robot.urdf_path).parent
    body_of = {link: (b, frame) for b, body in enumerate(art.bodies) for link, frame in zip(body.links, body.link_frames)}
    out: dict[int, list] = {}
    missing: list[str] = []
    for link, items in urdf_visual_meshes(robot.urdf_path).items():
        if link not in body_of:
            continue
        b, frame = body_of[link]
        for filename, t, scale in items:
            f = _find_mesh(filename, folder, mesh_dir)
            mesh = _read_mesh(f) if f is not None else None
            if mesh is None:
                missing.append(filename)
                continue
            v, faces = mesh
            if np.prod(scale) < 0:  # a mirroring scale (TALOS' right side: "1 -1 1") turns the faces inside out
                faces = faces[:, ::-1]
            out.setdefault(b, []).append((_transform(v * scale, frame @ t), faces))
    return out, missing


def _mjcf_visuals(robot: Robot, art: Articulation, mesh_dir: Path | None) -> tuple[dict[int, list], list[str]]:
    """Body → [(vertices in the body frame, faces)] of an MJCF's visual mesh geoms, as MuJoCo
    compiles them (its ``meshdir``, or ``mesh_dir``); mesh files that could not be read."""
    import mujoco
    from lxml import etree

    from mer_data.robots.mjcf import compile_mjcf

    path = Path(robot.urdf_path)
    with tempfile.TemporaryDirectory(prefix="mer-meshes-") as tmp:
        if mesh_dir is not None:  # the registered text with its meshdir pointing at mesh_dir
            root = etree.fromstring(path.read_bytes(), etree.XMLParser(resolve_entities=False, no_network=True))
            compiler = root.find("compiler")
            if compiler is None:
                compiler = etree.SubElement(root, "compiler")
            compiler.set("meshdir", str(Path(mesh_dir).resolve()) + os.sep)
            path = Path(tmp) / path.name
            path.write_bytes(etree.tostring(root))
        compiled = compile_mjcf(path, geometry=True, allowed=() if mesh_dir is None else (Path(mesh_dir),))
    missing = [w.replace(str(path), str(robot.urdf_path)) for w in compiled.warnings]
    m = compiled.model
    own = {name: b for b, name in enumerate(art.body_names)}
    mesh_geoms = [
        g for g in range(m.ngeom) if int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH) and int(m.geom_bodyid[g]) > 0
    ]
    visual = [
        g for g in mesh_geoms if int(m.geom_group[g]) in (1, 2) or not (int(m.geom_contype[g]) or int(m.geom_conaffinity[g]))
    ]
    out: dict[int, list] = {}
    for g in visual or mesh_geoms:
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g]))
        if body not in own:
            continue
        mid = int(m.geom_dataid[g])
        va, vn, fa, fn = (int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid]), int(m.mesh_faceadr[mid]), int(m.mesh_facenum[mid]))
        t = np.eye(4)
        w, x, y, z = m.geom_quat[g]
        t[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]  # fmt: skip
        t[:3, 3] = m.geom_pos[g]
        out.setdefault(own[body], []).append(
            (_transform(m.mesh_vert[va : va + vn], t), np.asarray(m.mesh_face[fa : fa + fn], np.int64))
        )
    return out, missing


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + n)
        n += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def robot_meshes(
    robot: Robot, *, mesh_dir: str | Path | None = None, visual: bool = True, max_faces: int | None = 20000
) -> RobotMeshes:
    """What draws ``robot`` (module docstring): per body its visual meshes, else its collision shapes.

    Args:
        mesh_dir: a folder to look for the description's mesh files in besides its own.
        visual: False draws the collision shapes only (no mesh file is read).
        max_faces: the face budget of the whole robot, shared by the bodies in proportion to their
            surface area (each keeps at least 60 faces); None keeps every face.
    """
    art = articulation(robot)
    mesh_dir = Path(mesh_dir) if mesh_dir is not None else None
    visuals, missing = ({}, [])
    if visual:
        visuals, missing = (_mjcf_visuals if art.source == "mjcf" else _urdf_visuals)(robot, art, mesh_dir)
    shapes = link_shapes(robot)
    fitted = fitted_hulls(robot, art, shapes)
    parts: list[tuple[int, np.ndarray, np.ndarray, str]] = []
    for b, body in enumerate(art.bodies):
        if b in visuals:
            v, f = _merge(visuals[b])
            parts.append((b, v, f, "mesh"))
            continue
        pieces = [(_transform(v, frame), f) for link, frame in zip(body.links, body.link_frames)
                  for v, f in map(shape_mesh, shapes.get(link, ()))]  # fmt: skip
        pieces += [_hull_mesh(v) for v in fitted.get(b, [])]
        if pieces:
            v, f = _merge(pieces)
            parts.append((b, v, f, "collision"))
    if max_faces is not None and sum(len(f) for _, _, f, _ in parts) > max_faces:  # shared by surface area
        area = np.array([0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
                         for _, v, f, _ in parts])  # fmt: skip
        share = area / max(area.sum(), 1e-12)
        parts = [(b, *decimate(v, f, max(60, int(max_faces * w))), s) for (b, v, f, s), w in zip(parts, share)]
    if missing:
        (log.warning if visuals else log.info)(
            "%s: visual meshes not found or not readable (%s); those bodies are drawn with their collision shapes (put the "
            "meshes beside the registered description%s)", robot.name, "; ".join(missing[:3]) + (", ..." if len(missing) > 3 else ""),
            "" if mesh_dir is None else f" or under {mesh_dir}")  # fmt: skip
    return RobotMeshes(robot.name, tuple(BodyMesh(b, v, f, s) for b, v, f, s in parts), art.body_names, tuple(missing))
