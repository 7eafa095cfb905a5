"""Safe, strict URDF loading: XML → validated kinematic tree (:class:`UrdfModel`).

The XML is parsed by us first, with entities and DTDs refused (no local file or network resource
is ever read), so that every structural problem can be reported with its file and line. The
validated document is then handed to yourdfpy (meshes off) for the element values.

Frames: every joint carries ``origin``, the 4x4 transform parent-link frame ← joint frame at zero
angle (= child-link frame at zero angle), exactly as in the URDF.
"""

from __future__ import annotations

import io
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

from mer_data.base.errors import MalformedURDFError
from mer_data.base.limits import MAX_LENGTH_M
from mer_data.base.safe_io import read_regular_file

from .urdf_checks import JOINT_TYPES, CheckedJoint, check_joints, check_links, check_tree, parse_xml

log = logging.getLogger(__name__)

__all__ = ["UrdfJoint", "UrdfModel", "load_urdf", "parse_urdf_bytes", "JOINT_TYPES"]


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>`` element, validated.

    Attributes:
        origin: (4, 4) parent-link frame ← joint frame at zero angle [m].
        axis: (3,) joint axis in the joint frame (unit length for movable joints).
        lower, upper: position limits [rad]; ``None`` where the URDF gives none.
        velocity: the ``<limit velocity>`` [rad/s]; ``None`` where absent, zero or not finite.
        mimic: ``(master_joint, multiplier, offset)`` or ``None``.
        line: 1-based line of the element in the file.
    """

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None
    upper: float | None
    mimic: tuple[str, float, float] | None
    line: int
    velocity: float | None = None


@dataclass(frozen=True)
class UrdfModel:
    """A URDF as a validated tree of links and joints.

    Attributes:
        path: where it was read from (for messages).
        name: the ``<robot name>``.
        links: link names in file order.
        link_lines: line of each link element.
        joints: joints in file order.
        root: the single link that is no joint's child.
        collision_points: link → (K, 3) extreme points of its box/sphere/cylinder collision
            shapes in the link frame [m] (meshes are not loaded); used to propose toe key points.
        inertial_coms: link → (3,) centre of mass in the link frame [m], where the URDF gives an
            ``<inertial>`` (used to tell which way a link extends).
        collisions: link → its ``<collision>`` elements as read, each ``{"type": box|sphere|cylinder|mesh,
            "origin": (4, 4), "size" | "radius", "length" | "filename", "scale"}`` (meshes not loaded).
        warnings: what was read but ignored (e.g. a ``<mimic>`` on a fixed joint), one sentence each.
    """

    path: str
    name: str
    links: tuple[str, ...]
    link_lines: dict[str, int]
    joints: tuple[UrdfJoint, ...]
    root: str
    collision_points: dict[str, np.ndarray]
    inertial_coms: dict[str, np.ndarray] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    collisions: dict[str, tuple[dict, ...]] = field(default_factory=dict)
    # lookups built once (linear in the file): name -> joint, link -> child joints / parent joint
    _by_name: dict[str, UrdfJoint] = field(init=False, repr=False, compare=False)
    _children: dict[str, tuple[UrdfJoint, ...]] = field(init=False, repr=False, compare=False)
    _parent: dict[str, UrdfJoint] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        children: dict[str, list[UrdfJoint]] = {}
        for j in self.joints:
            children.setdefault(j.parent, []).append(j)
        object.__setattr__(self, "_by_name", {j.name: j for j in self.joints})
        object.__setattr__(self, "_children", {k: tuple(v) for k, v in children.items()})
        object.__setattr__(self, "_parent", {j.child: j for j in self.joints})

    def joint(self, name: str) -> UrdfJoint:
        return self._by_name[name]

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def children_of(self, link: str) -> list[UrdfJoint]:
        """Joints whose parent is ``link``, in file order (a dictionary lookup, not a scan)."""
        return list(self._children.get(link, ()))

    def parent_joint_of(self, link: str) -> UrdfJoint | None:
        return self._parent.get(link)


def load_urdf(path: str | Path) -> UrdfModel:
    """Read and validate a URDF file.

    Raises:
        MalformedURDFError, UnsafeURDFError, BrokenReferenceError, KinematicTreeError,
        UnsupportedJointError: with the file, line and element at fault.
    """
    path = Path(path)
    data = read_regular_file(path, MalformedURDFError, "MER_MAX_URDF_BYTES", fix="check the path given to --urdf")
    return parse_urdf_bytes(data, str(path))


def parse_urdf_bytes(data: bytes, path: str = "<urdf>") -> UrdfModel:
    """Validate URDF text and build the :class:`UrdfModel` (see :func:`load_urdf`)."""
    root = parse_xml(data, path)
    link_lines = check_links(root, path)
    joints, _ = check_joints(root, path, link_lines)
    return UrdfModel(
        path=path,
        name=root.get("name") or Path(path).stem,
        links=tuple(link_lines),
        link_lines=link_lines,
        root=check_tree(link_lines, joints, path),
        **_read_values_with_yourdfpy(root, joints, path),
    )


def _read_values_with_yourdfpy(root, checked: list[CheckedJoint], path: str) -> dict:
    """Read origins, axes, limits, mimic tags and collision shapes with yourdfpy.

    Everything yourdfpy could choke on (numbers, references, limits) was validated above with
    line numbers; elements mer does not use (visuals, inertials, ...) are yourdfpy's to read, and
    anything it refuses there becomes a :class:`MalformedURDFError`. yourdfpy stays the one reader
    of element values.
    """
    import yourdfpy

    buf = io.BytesIO(etree.tostring(root))
    try:
        model = yourdfpy.URDF.load(buf, load_meshes=False, build_scene_graph=False, load_collision_meshes=False)
    except Exception as exc:  # noqa: BLE001 - a third-party parser's failure, reported as ours
        raise MalformedURDFError(
            f"an element mer does not check could not be read ({type(exc).__name__}: {exc})",
            path=path,
            fix="check the numbers and attributes of <visual>, <inertial>, <material> and other elements",
        ) from None
    theirs = {j.name: j for j in model.robot.joints}
    out, warnings = [], []
    for c in checked:
        j = theirs[c.name]
        lim = j.limit
        mimic = None if j.mimic is None else (j.mimic.joint, float(j.mimic.multiplier), float(j.mimic.offset))
        if mimic is not None and c.type == "fixed":
            # a fixed joint moves nothing: the tag has nothing to drive (common in gripper URDFs)
            warnings.append(
                f"{path}:{c.line}: joint '{c.name}' is fixed but carries <mimic joint=\"{mimic[0]}\">; "
                "a fixed joint moves nothing, so the tag is ignored"
            )
            log.warning("%s", warnings[-1])
            mimic = None
        out.append(
            UrdfJoint(
                name=c.name,
                type=c.type,
                parent=c.parent,
                child=c.child,
                origin=np.asarray(j.origin if j.origin is not None else np.eye(4), dtype=np.float64),
                axis=np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64),
                lower=None if lim is None or lim.lower is None else float(lim.lower),
                upper=None if lim is None or lim.upper is None else float(lim.upper),
                mimic=mimic,
                line=c.line,
                velocity=_velocity(lim),
            )
        )
    return {
        "joints": tuple(out),
        "collision_points": _collision_points(model),
        "inertial_coms": _inertial_coms(model),
        "warnings": tuple(warnings),
        "collisions": _collisions(model),
    }


def _velocity(lim) -> float | None:
    v = None if lim is None else getattr(lim, "velocity", None)
    try:
        v = None if v is None else float(v)
    except (TypeError, ValueError):
        return None
    return v if v is not None and math.isfinite(v) and v > 0 else None


def _inertial_coms(model) -> dict[str, np.ndarray]:
    """Centre of mass of every link with an ``<inertial>``, in the link frame."""
    out: dict[str, np.ndarray] = {}
    for link in model.robot.links:
        inertial = link.inertial
        if inertial is None:
            continue
        origin = inertial.origin if inertial.origin is not None else np.eye(4)
        com = np.asarray(origin, dtype=np.float64)[:3, 3]
        if np.isfinite(com).all() and np.abs(com).max() <= MAX_LENGTH_M:
            out[link.name] = com
    return out


def _collisions(model) -> dict[str, tuple[dict, ...]]:
    """Every link's ``<collision>`` elements (see :attr:`UrdfModel.collisions`); unreadable ones are skipped."""
    out: dict[str, tuple[dict, ...]] = {}
    for link in model.robot.links:
        items = []
        for col in link.collisions or ():
            g = col.geometry
            if g is None:
                continue
            t = np.asarray(col.origin if col.origin is not None else np.eye(4), dtype=np.float64)
            if g.box is not None:
                items.append({"type": "box", "origin": t, "size": tuple(float(x) for x in g.box.size)})
            elif g.sphere is not None:
                items.append({"type": "sphere", "origin": t, "radius": float(g.sphere.radius)})
            elif g.cylinder is not None:
                items.append({"type": "cylinder", "origin": t, "radius": float(g.cylinder.radius), "length": float(g.cylinder.length)})
            elif g.mesh is not None and g.mesh.filename:
                scale = g.mesh.scale
                sc = (1.0, 1.0, 1.0) if scale is None else tuple(float(x) for x in np.broadcast_to(np.asarray(scale, float), 3))
                items.append({"type": "mesh", "origin": t, "filename": str(g.mesh.filename), "scale": sc})
        if items:
            out[link.name] = tuple(items)
    return out


def _collision_points(model) -> dict[str, np.ndarray]:
    """Corner / extreme points of primitive collision shapes, per link, in the link frame."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    out: dict[str, np.ndarray] = {}
    for link in model.robot.links:
        pts = []
        for col in link.collisions or ():
            g = col.geometry
            if g is None:
                continue
            if g.box is not None:
                local = signs * (np.asarray(g.box.size, dtype=np.float64) / 2)
            elif g.sphere is not None:
                r = float(g.sphere.radius)
                local = np.concatenate([np.eye(3) * r, -np.eye(3) * r])
            elif g.cylinder is not None:
                r, h = float(g.cylinder.radius), float(g.cylinder.length)
                local = signs * np.array([r, r, h / 2])
            else:
                continue
            t = col.origin if col.origin is not None else np.eye(4)
            pts.append(local @ t[:3, :3].T + t[:3, 3])
        if pts:
            out[link.name] = np.concatenate(pts)
    return out


