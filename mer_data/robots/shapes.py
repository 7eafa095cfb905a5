"""Collision shapes of a robot's links, and the file that carries them (``collision.json``).

**File** (beside the robot card, named by the card's ``collision`` field)::

    {"format": "mer-collision", "format_version": 1, "robot": "g1", "source": "...",
     "links": {"left_ankle_roll_link": [{"type": "hull", "vertices": [[x, y, z], ...]},
                                        {"type": "box", "size": [sx, sy, sz], "xyz": [...], "rpy": [...]}],
               ...},
     "missing": ["<link whose mesh could not be read>"]}

Shapes are in the link frame [m]: ``hull`` (a mesh as its convex hull, at most
:data:`MAX_HULL_VERTICES` vertices), ``box``, ``sphere``, ``cylinder`` and ``capsule`` (URDF / MJCF
primitives as they are, with their origin ``xyz`` / ``rpy``; cylinders and capsules along the
shape's z axis). :func:`shapes_from_urdf` reads them from a URDF: primitives as they are, meshes
(looked up under the URDF's own folder only) as simplified hulls (:mod:`.hulls`).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from mer_data.base.errors import RobotCardError
from mer_data.base.safe_io import decode_utf8, read_regular_file

from .hulls import simplify_hull

log = logging.getLogger(__name__)

__all__ = [
    "COLLISION_FILE",
    "COLLISION_FORMAT",
    "COLLISION_VERSION",
    "SHAPE_TYPES",
    "MAX_HULL_VERTICES",
    "Shape",
    "mesh_file",
    "CollisionFile",
    "parse_collision",
    "read_collision",
    "dump_collision",
    "shapes_from_urdf",
    "primitive_shape",
]

COLLISION_FILE = "collision.json"  # the name registration writes (the card may name another)
COLLISION_FORMAT = "mer-collision"
COLLISION_VERSION = 1
SHAPE_TYPES = ("hull", "box", "sphere", "cylinder", "capsule")
MAX_HULL_VERTICES = 64  # a file may hold up to this many per hull; the shipped ones hold at most 48
MAX_SHAPES = 4096  # per file


@dataclass(frozen=True)
class Shape:
    """One collision shape of a link.

    Attributes:
        type: one of :data:`SHAPE_TYPES`.
        origin: (4, 4) link ← shape transform (identity for hulls: their vertices are in the link frame).
        size: (3,) box edge lengths [m]; radius, length: sphere / cylinder / capsule [m].
        vertices: (V, 3) hull vertices in the link frame [m].
        source: ``mesh`` (a hull of the link's mesh), ``primitive`` (as in the description) or
            ``fitted`` (a capsule along the link, where the description has no geometry).
    """

    type: str
    origin: np.ndarray
    size: tuple[float, float, float] | None = None
    radius: float = 0.0
    length: float = 0.0
    vertices: np.ndarray | None = None
    source: str = "primitive"


@dataclass(frozen=True)
class CollisionFile:
    """A parsed ``collision.json``: link → shapes, where they came from, links that could not be read."""

    robot: str
    links: Mapping[str, tuple[Shape, ...]]
    source: str = ""
    missing: tuple[str, ...] = ()


def _rpy_matrix(rpy: Sequence[float]) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])  # fmt: skip


def _origin(xyz: Sequence[float], rpy: Sequence[float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _rpy_matrix(rpy)
    t[:3, 3] = xyz
    return t


def _numbers(v: Any, n: int | None, what: str, path: str, element: str, positive: bool = False) -> list[float]:
    ok = isinstance(v, list) and (n is None or len(v) == n) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and abs(x) <= 100 for x in v
    )
    if ok and positive:
        ok = all(x > 0 for x in v)
    if not ok:
        raise RobotCardError(
            f"{what} must be {n or 'a list of'} finite numbers{' > 0' if positive else ''} [m], got {str(v)[:60]}",
            path=path,
            element=element,
            fix="rebuild the file (tools/build_collision.py, or register the robot again)",
        )
    return [float(x) for x in v]


def _parse_shape(d: Any, path: str, element: str) -> Shape:
    if not isinstance(d, Mapping) or d.get("type") not in SHAPE_TYPES:
        raise RobotCardError(f"a shape must be an object with type one of {', '.join(SHAPE_TYPES)}", path=path, element=element)
    kind = d["type"]
    allowed = {"hull": {"type", "vertices"}, "box": {"type", "size", "xyz", "rpy"}, "sphere": {"type", "radius", "xyz"},
               "cylinder": {"type", "radius", "length", "xyz", "rpy"}, "capsule": {"type", "radius", "length", "xyz", "rpy"}}[kind]  # fmt: skip
    extra = sorted(set(d) - allowed)
    if extra:
        raise RobotCardError(f"unknown field(s) {extra} in a {kind}", path=path, element=element, fix=f"known: {sorted(allowed)}")
    xyz = _numbers(d.get("xyz", [0, 0, 0]), 3, "xyz", path, element)
    rpy = _numbers(d.get("rpy", [0, 0, 0]), 3, "rpy", path, element)
    origin = _origin(xyz, rpy)
    if kind == "hull":
        v = d.get("vertices")
        if not isinstance(v, list) or not 4 <= len(v) <= MAX_HULL_VERTICES:
            raise RobotCardError(f"a hull needs 4 to {MAX_HULL_VERTICES} vertices", path=path, element=element)
        verts = np.array([_numbers(p, 3, "a vertex", path, element) for p in v])
        if np.linalg.matrix_rank(verts - verts.mean(0), tol=1e-6) < 3:
            raise RobotCardError("a hull's vertices are flat (no volume)", path=path, element=element)
        return Shape("hull", np.eye(4), vertices=verts, source="mesh")
    if kind == "box":
        return Shape("box", origin, size=tuple(_numbers(d.get("size"), 3, "size", path, element, positive=True)))  # type: ignore[arg-type]
    radius = _numbers([d.get("radius")], 1, "radius", path, element, positive=True)[0]
    length = 0.0 if kind == "sphere" else _numbers([d.get("length")], 1, "length", path, element, positive=kind == "cylinder")[0]
    return Shape(kind, origin, radius=radius, length=length)


def parse_collision(text: str, path: str = "<collision>") -> CollisionFile:
    """Parse and validate the text of a ``collision.json`` (untrusted input: strict)."""
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise RobotCardError(f"not valid JSON: {str(exc)[:120]}", path=path) from None
    if not isinstance(data, dict) or data.get("format") != COLLISION_FORMAT:
        raise RobotCardError(f"not a {COLLISION_FORMAT} file", path=path, element="format")
    if data.get("format_version") != COLLISION_VERSION:
        raise RobotCardError(f"format_version {data.get('format_version')!r}, this mer reads {COLLISION_VERSION}",
                             path=path, element="format_version")  # fmt: skip
    links = data.get("links")
    if not isinstance(links, dict):
        raise RobotCardError("links must map a link name to a list of shapes", path=path, element="links")
    out: dict[str, tuple[Shape, ...]] = {}
    count = 0
    for name, shapes in links.items():
        if not isinstance(shapes, list):
            raise RobotCardError("the shapes of a link must be a list", path=path, element=f"links.{name}")
        count += len(shapes)
        if count > MAX_SHAPES:
            raise RobotCardError(f"more than {MAX_SHAPES} shapes", path=path, element="links")
        out[str(name)] = tuple(_parse_shape(s, path, f"links.{name}[{i}]") for i, s in enumerate(shapes))
    missing = data.get("missing", [])
    if not isinstance(missing, list) or not all(isinstance(m, str) for m in missing):
        raise RobotCardError("missing must be a list of link names", path=path, element="missing")
    return CollisionFile(str(data.get("robot", "")), out, str(data.get("source", "")), tuple(missing))


def read_collision(path: str | Path) -> CollisionFile:
    """Read a ``collision.json`` (a regular file, size-limited)."""
    raw = read_regular_file(path, RobotCardError, "MER_MAX_CARD_BYTES", fix="point the card's collision field at a collision.json")
    return parse_collision(decode_utf8(raw, path, RobotCardError), str(path))


def dump_collision(cf: CollisionFile) -> str:
    """The JSON text of ``cf`` (what :func:`parse_collision` reads back): one shape per line, 10 µm."""

    def r(x) -> list[float]:
        return [round(float(v), 5) for v in x]

    def shape(s: Shape) -> dict:
        if s.type == "hull":
            return {"type": "hull", "vertices": [r(v) for v in s.vertices]}  # type: ignore[union-attr]
        xyz = r(s.origin[:3, 3])
        rot = s.origin[:3, :3]
        rpy = r([math.atan2(rot[2, 1], rot[2, 2]), -math.asin(max(-1.0, min(1.0, rot[2, 0]))), math.atan2(rot[1, 0], rot[0, 0])])
        d: dict[str, Any] = {"type": s.type}
        if s.type == "box":
            d["size"] = r(s.size)  # type: ignore[arg-type]
        else:
            d["radius"] = round(s.radius, 5)
            if s.type != "sphere":
                d["length"] = round(s.length, 5)
        d["xyz"] = xyz
        if s.type != "sphere":
            d["rpy"] = rpy
        return d

    lines = [f'{{"format": "{COLLISION_FORMAT}", "format_version": {COLLISION_VERSION}, "robot": {json.dumps(cf.robot)},',
             f' "source": {json.dumps(cf.source)},', ' "links": {']  # fmt: skip
    items = list(cf.links.items())
    for i, (link, shapes) in enumerate(items):
        body = ",\n   ".join(json.dumps(shape(s), separators=(",", ":")) for s in shapes)
        lines.append(f"  {json.dumps(link)}: [\n   {body}]" + ("," if i < len(items) - 1 else ""))
    lines.append(" },")
    lines.append(f' "missing": {json.dumps(list(cf.missing))}}}')
    return "\n".join(lines) + "\n"


def mesh_file(filename: str, urdf_dir: Path) -> Path | None:
    """A mesh reference resolved under the URDF's own folder (``package://PKG/rest`` tried as
    ``rest`` under any ancestor-free prefix of that folder); None if it is not there."""
    name = filename
    if name.startswith("file://"):
        name = name[len("file://"):]
    cands = []
    if name.startswith("package://"):
        rest = name[len("package://"):].split("/", 1)
        tail = rest[1] if len(rest) == 2 else rest[0]
        parts = Path(tail).parts
        cands = [urdf_dir / Path(*parts[i:]) for i in range(len(parts))]
    else:
        cands = [urdf_dir / name]
    root = urdf_dir.resolve()
    for c in cands:
        try:
            r = c.resolve()
        except OSError:
            continue
        if r.is_file() and (r == root or root in r.parents):  # nothing outside the folder the user named
            return r
    return None


def primitive_shape(c: dict) -> Shape | None:
    """The :class:`Shape` of a description's collision element (:attr:`~.urdf.UrdfModel.collisions`)
    when it is a primitive (box, sphere, cylinder; MJCF's capsule along z, its length between the
    sphere centres); None for a mesh."""
    t = np.asarray(c["origin"], np.float64)
    if c["type"] == "box":
        return Shape("box", t, size=tuple(c["size"]))
    if c["type"] == "sphere":
        return Shape("sphere", t, radius=c["radius"])
    if c["type"] in ("cylinder", "capsule"):
        return Shape(c["type"], t, radius=c["radius"], length=c["length"])
    return None


def shapes_from_urdf(urdf: Any, *, load_meshes: bool = True, max_vertices: int = 48) -> tuple[CollisionFile, dict[str, float]]:
    """The collision shapes of a parsed URDF or MJCF (:class:`~mer_data.robots.urdf.UrdfModel`):
    primitives as they are, meshes as simplified convex hulls: a URDF's mesh files looked up under
    its folder only, an MJCF's vertices as MuJoCo compiled them (entries with ``vertices``).

    Returns:
        the :class:`CollisionFile` (links whose mesh could not be read are in ``missing``) and the
        hull simplification error per link [m].
    """
    urdf_dir = Path(urdf.path).parent
    links: dict[str, list[Shape]] = {}
    missing: list[str] = []
    errors: dict[str, float] = {}
    for link, items in urdf.collisions.items():
        out = []
        for c in items:
            t = np.asarray(c["origin"], np.float64)
            prim = primitive_shape(c)
            if prim is not None:
                out.append(prim)
            else:
                if "vertices" in c:  # MJCF: the compiled mesh's vertices (None: its file could not be read)
                    pts = None if c["vertices"] is None or not load_meshes else _solid(np.asarray(c["vertices"], np.float64))
                else:
                    f = mesh_file(c["filename"], urdf_dir) if load_meshes else None
                    pts = _mesh_points(f, f"<collision> mesh of link '{link}'") if f is not None else None
                if pts is None:
                    if link not in missing:
                        missing.append(link)
                    continue
                pts = pts * np.asarray(c["scale"]) @ t[:3, :3].T + t[:3, 3]
                v, err, _ = simplify_hull(pts, max_vertices)
                errors[link] = max(errors.get(link, 0.0), err)
                out.append(Shape("hull", np.eye(4), vertices=v, source="mesh"))
        if out:
            links[link] = out
    return CollisionFile(urdf.name, {k: tuple(v) for k, v in links.items()}, missing=tuple(missing)), errors


def _solid(v: np.ndarray) -> np.ndarray | None:
    """``v`` (V, 3) if it spans a volume (at least 4 finite points, not flat), else None."""
    if len(v) < 4 or not np.isfinite(v).all() or np.linalg.matrix_rank(v - v.mean(0), tol=1e-9) < 3:
        return None
    return v


def _mesh_points(path: Path, element: str | None = None) -> np.ndarray | None:
    """The vertices of a mesh file (:func:`~mer_data.robots.mesh_io.read_mesh`), or None (logged).

    Raises:
        MeshArchiveError: the file is a compressed archive (never unpacked).
    """
    from .mesh_io import MeshArchiveError, read_mesh

    try:
        v = read_mesh(path)[0]
    except MeshArchiveError as exc:
        raise MeshArchiveError(exc.message, path=exc.path, element=element, fix=exc.fix) from None
    except Exception as exc:  # noqa: BLE001 - an unreadable mesh falls back to fitted capsules
        log.warning("mesh %s could not be read (%s: %s)", path, type(exc).__name__, str(exc).splitlines()[0][:300])
        return None
    if len(v) < 4 or not np.isfinite(v).all() or np.linalg.matrix_rank(v - v.mean(0), tol=1e-9) < 3:
        log.warning("mesh %s has no volume: not used", path)
        return None
    return v
