"""A robot's own articulation: the joints and bodies a simulator builds from its description, and
the orders in which the motion trackers read them.

mer's skeleton keeps what retargeting moves (locked joints folded into their parents, fixed links
merged). A tracker's robot model keeps more: MuJoCo / mjlab and Isaac Lab load the description, so
every revolute, continuous and prismatic joint is a joint there (locked and mimic ones included),
and every link such a joint moves is a body. :class:`Articulation` is that model of a registered
robot; :func:`articulation` builds it.

- **bodies**: the root link and the child link of every moving joint; a link reached through fixed
  joints is merged into the body above it (MuJoCo's ``fusestatic`` for URDFs and Isaac Sim's URDF
  importer's ``merge_fixed_joints``, both on by default). A body's frame is its link's frame. A
  robot registered from an MJCF keeps its MJCF bodies (bodies without joints included, sites merged
  as frames) in their MJCF body frames (the link frame moved back from the last joint's anchor).
- **joints**: hinge (revolute, continuous) and slide (prismatic) joints, with axis and anchor in
  their body's frame at zero joint values; a body from an MJCF can carry several (MuJoCo applies
  them in order, about axes in the body frame).
- **values** (:meth:`Articulation.joint_values`): the skeleton's angles (mimic joints from their
  master), locked joints at their locked value.

Orders (:meth:`Articulation.order`), as each tracker's own loader expects them (docs/trackers.md):

- ``"mjlab"``: MuJoCo's order, which mjlab's ``Entity.joint_names`` / ``body_names`` follow: bodies
  depth-first in pre-order, children in the order the description declares them (a child reached
  through a fixed link takes that link's place); joints in the order of their bodies.
- ``"beyondmimic"``: Isaac Lab's, which BeyondMimic's ``MotionLoader`` indexes without reading
  names: PhysX lists an articulation's links breadth-first from the root, siblings in the order
  their joint prims are authored; Isaac Sim's URDF importer authors them depth-first with each
  link's child joints sorted by joint name (it keeps the URDF's joints in a name-keyed map), after
  merging fixed joints (whose children become their parent's children). Joints follow their bodies.
"""

from __future__ import annotations

import io
import logging
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from mer_data.base.errors import MalformedURDFError, OutputError

from .builder import zero_pose_link_transforms
from .mjcf import compile_mjcf, description_format, load_description
from .urdf import UrdfModel

if TYPE_CHECKING:  # pragma: no cover
    from .registry import Robot

log = logging.getLogger(__name__)

__all__ = [
    "TRACKERS", "Tracker", "ArticulatedJoint", "ArticulatedBody", "Articulation", "articulation", "build_articulation",
    "urdf_inertials", "urdf_visual_meshes", "urdf_joint_drives",
]  # fmt: skip

Tracker = Literal["mjlab", "beyondmimic"]
#: The trackers whose joint/body order an npz can be written in (:meth:`Articulation.order`).
TRACKERS: tuple[str, ...] = ("mjlab", "beyondmimic")


@dataclass(frozen=True, eq=False)
class ArticulatedJoint:
    """One joint of the articulation.

    Attributes:
        name: the description's joint name (a ball joint of an MJCF: ``<name>_x``, ``_y``, ``_z``).
        type: ``"hinge"`` (revolute, continuous) or ``"slide"`` (prismatic).
        body: index of the body it moves.
        axis: (3,) unit axis in the body frame at zero joint values.
        pos: (3,) anchor in the body frame [m].
        lower, upper: limits [rad] or [m]; ``None`` where unlimited (continuous joints).
        node: the skeleton node whose angle it takes (a mimic joint: its master's); -1 where it is held.
        held: the value of a locked joint [rad] or [m] (``None`` where it moves).
        mimic: ``(master joint, multiplier, offset)`` where it follows another joint that moves:
            its value is ``multiplier * q[node] + offset``.
    """

    name: str
    type: Literal["hinge", "slide"]
    body: int
    axis: np.ndarray
    pos: np.ndarray
    lower: float | None
    upper: float | None
    node: int
    held: float | None
    mimic: tuple[str, float, float] | None = None


@dataclass(frozen=True, eq=False)
class ArticulatedBody:
    """One body (rigid part) of the articulation.

    Attributes:
        name: the link (URDF) or body (MJCF) name.
        parent: index of the parent body, -1 for the root.
        joints: indices of the joints that move it against its parent (none: the root, a body
            without joints).
        key: the name of the description joint into it (the importer's sibling order).
        origin: (4, 4) parent body ← body at zero joint values [m].
        links: the description's links that move with it, its own first.
        link_frames: (4, 4) body ← link for each of ``links`` [m].
        node: the skeleton node it moves with.
        in_node: (4, 4) node frame ← body frame, constant (locked joints at their value) [m].
        mass: [kg] (0 where the description gives none); com: (3,) centre of mass in the body
            frame [m] (the origin where massless); inertia: (3, 3) about the centre of mass, body
            axes [kg m^2].
    """

    name: str
    parent: int
    joints: tuple[int, ...]
    key: str
    origin: np.ndarray
    links: tuple[str, ...]
    link_frames: tuple[np.ndarray, ...]
    node: int
    in_node: np.ndarray
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True, eq=False)
class Articulation:
    """The articulation of one registered robot (see the module docstring).

    Attributes:
        robot: its name; source: ``"urdf"`` or ``"mjcf"``; description: the registered file.
        bodies: in MuJoCo's (depth-first) order; joints: in MuJoCo's order (by body).
        skeleton_fingerprint: the skeleton whose node angles :meth:`joint_values` reads.
        ball_joints: MJCF ball joints written as three hinges (their MJCF names).
    """

    robot: str
    source: Literal["urdf", "mjcf"]
    description: Path
    bodies: tuple[ArticulatedBody, ...]
    joints: tuple[ArticulatedJoint, ...]
    skeleton_fingerprint: str
    ball_joints: tuple[str, ...] = ()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bodies)

    def order(self, tracker: str) -> tuple[list[int], list[int]]:
        """(joint indices, body indices) in ``tracker``'s order (one of :data:`TRACKERS`)."""
        if tracker == "mjlab":
            return list(range(len(self.joints))), list(range(len(self.bodies)))
        if tracker != "beyondmimic":
            raise ValueError(f"unknown tracker {tracker!r}; one of {', '.join(TRACKERS)}")
        kids: dict[int, list[int]] = {}
        for i, b in enumerate(self.bodies[1:], 1):
            kids.setdefault(b.parent, []).append(i)
        bodies = [0]
        for b in bodies:  # breadth-first; grows while it is walked
            bodies.extend(sorted(kids.get(b, []), key=lambda i: self.bodies[i].key))
        return [j for b in bodies for j in self.bodies[b].joints], bodies

    def joint_values(self, q: np.ndarray) -> np.ndarray:
        """(F, D) joint values [rad or m] in :attr:`joints` order from (F, J) skeleton node angles
        [rad] (mimic joints computed from their masters, locked joints at their values)."""
        q = np.asarray(q, np.float64)
        out = np.empty((q.shape[0], len(self.joints)))
        for i, j in enumerate(self.joints):
            if j.node < 0:
                out[:, i] = j.held
            elif j.mimic is not None:
                out[:, i] = j.mimic[1] * q[:, j.node] + j.mimic[2]
            else:
                out[:, i] = q[:, j.node]
        return out

    def body_poses(self, node_pos: np.ndarray, node_rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World positions (F, B, 3) [m] and rotations (F, B, 3, 3) of the body frames, from the
        skeleton's node positions (F, J, 3) and rotations (F, J, 3, 3) (its forward kinematics)."""
        nodes = [b.node for b in self.bodies]
        t = np.stack([b.in_node for b in self.bodies])  # (B, 4, 4)
        r = node_rot[:, nodes]
        rot = r @ t[:, :3, :3]
        pos = node_pos[:, nodes] + np.einsum("fbij,bj->fbi", r, t[:, :3, 3])
        return pos, rot


# ---- building it ---------------------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _inverse(t: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def _shift(v: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = v
    return t


def _yourdfpy_model(path: str | Path):
    """The registered URDF read by yourdfpy (as :func:`~mer_data.robots.urdf.load_urdf` reads the
    values it does not check itself), from the safely parsed XML."""
    import yourdfpy
    from lxml import etree

    from mer_data.base.safe_io import read_regular_file

    from .urdf_checks import parse_xml

    data = read_regular_file(path, MalformedURDFError, "MER_MAX_URDF_BYTES")
    root = parse_xml(data, str(path))
    return yourdfpy.URDF.load(io.BytesIO(etree.tostring(root)), load_meshes=False, build_scene_graph=False,
                              load_collision_meshes=False)  # fmt: skip


def urdf_inertials(path: str | Path) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """Link → (mass [kg], centre of mass (3,) in the link frame [m], inertia (3, 3) about it in
    the link axes [kg m^2]) of a URDF's ``<inertial>`` elements (links without mass left out)."""
    out = {}
    for link in _yourdfpy_model(path).robot.links:
        i = link.inertial
        if i is None or i.mass is None or not math.isfinite(float(i.mass)) or float(i.mass) <= 0:
            continue
        t = np.asarray(i.origin if i.origin is not None else np.eye(4), np.float64)
        inertia = np.asarray(i.inertia if i.inertia is not None else np.zeros((3, 3)), np.float64)
        out[link.name] = (float(i.mass), t[:3, 3].copy(), t[:3, :3] @ inertia @ t[:3, :3].T)
    return out


def urdf_joint_drives(path: str | Path) -> dict[str, dict[str, float]]:
    """Joint → what a URDF says of its drive: ``effort`` [N m or N] and ``velocity`` [rad/s or m/s]
    from ``<limit>``, ``damping`` and ``friction`` from ``<dynamics>`` (only the positive, finite ones)."""
    out: dict[str, dict[str, float]] = {}
    for j in _yourdfpy_model(path).robot.joints:
        vals = {}
        for key, obj, attr in (("effort", j.limit, "effort"), ("velocity", j.limit, "velocity"),
                               ("damping", j.dynamics, "damping"), ("friction", j.dynamics, "friction")):  # fmt: skip
            v = getattr(obj, attr, None) if obj is not None else None
            if v is not None and math.isfinite(float(v)) and float(v) > 0:
                vals[key] = float(v)
        out[j.name] = vals
    return out


def urdf_visual_meshes(path: str | Path) -> dict[str, list[tuple[str, np.ndarray, np.ndarray]]]:
    """Link → its ``<visual>`` meshes as (filename as written, (4, 4) link ← mesh, (3,) scale)."""
    out: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
    for link in _yourdfpy_model(path).robot.links:
        for v in link.visuals or ():
            mesh = v.geometry.mesh if v.geometry is not None else None
            if mesh is None or not mesh.filename:
                continue
            t = np.asarray(v.origin if v.origin is not None else np.eye(4), np.float64)
            scale = np.broadcast_to(np.asarray(mesh.scale if mesh.scale is not None else 1.0, np.float64), (3,)).copy()
            out.setdefault(link.name, []).append((mesh.filename, t, scale))
    return out


def _combine(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, centre of mass and inertia about it of rigidly joined parts (all in one frame)."""
    m = sum(p[0] for p in parts)
    if m <= 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    c = sum(p[0] * p[1] for p in parts) / m
    inertia = np.zeros((3, 3))
    for mi, ci, ii in parts:
        d = ci - c
        inertia += ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    return float(m), c, inertia


class _MjcfBodies:
    """What the compiled MJCF says that its converted tree (:func:`~.mjcf.mjcf_tree`) does not:
    which links are MJCF bodies, each body's joint anchor (its link frame's offset), its inertia."""

    def __init__(self, path: Path) -> None:
        import mujoco

        m = compile_mjcf(path, geometry=False).model
        free = int(mujoco.mjtJoint.mjJNT_FREE)
        self.anchor: dict[str, np.ndarray] = {}
        self.inertial: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        self.balls: list[str] = []
        for b in range(1, m.nbody):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}"
            js = [j for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])) if int(m.jnt_type[j]) != free]
            self.anchor[name] = np.asarray(m.jnt_pos[js[-1]], np.float64) if js else np.zeros(3)
            self.balls += [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in js
                           if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_BALL)]  # fmt: skip
            w, x, y, z = m.body_iquat[b]
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip
            self.inertial[name] = (float(m.body_mass[b]), np.asarray(m.body_ipos[b], np.float64), r @ np.diag(m.body_inertia[b]) @ r.T)


def build_articulation(robot: "Robot") -> Articulation:
    """The :class:`Articulation` of ``robot`` (uncached; :func:`articulation` caches it)."""
    skel = robot.skeleton
    fmt = description_format(robot.urdf_path)
    u: UrdfModel = load_description(robot.urdf_path, geometry=False)
    mj = _MjcfBodies(robot.urdf_path) if fmt == "mjcf" else None
    held = dict(skel.locked)
    t_zero = zero_pose_link_transforms(u, {})
    t_held = zero_pose_link_transforms(u, held)
    rest = skel.rest_positions
    own = {skel.link_names[j]: j for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"}
    node_of = {n: j for j, n in enumerate(skel.node_names) if skel.node_kinds[j] == "revolute"}
    mimic_of = {skel.node_names[j]: (skel.node_names[int(skel.mimic_source[j])], float(skel.mimic_multiplier[j]),
                                     float(skel.mimic_offset[j])) for j in np.flatnonzero(skel.mimic_source >= 0)}  # fmt: skip

    def carrier(link: str) -> int:
        walk = link
        while walk not in own:
            pj = u.parent_joint_of(walk)
            if pj is None:
                raise OutputError(f"link {link!r} of {robot.name!r} is not carried by any skeleton node",
                                  path=robot.urdf_path, fix="register the robot again")  # fmt: skip
            walk = pj.parent
        return own[walk]

    def body_frame(link: str, table: dict[str, np.ndarray]) -> np.ndarray:
        return table[link] @ _shift(-mj.anchor[link]) if mj is not None and link in mj.anchor else table[link]

    names: list[str] = []
    parents: list[int] = []
    keys: list[str] = []
    links: list[list[str]] = []
    body_joints: list[list[int]] = []
    joints: list[ArticulatedJoint] = []
    body_of: dict[str, int] = {}

    def new_body(link: str, parent: int, key: str) -> int:
        names.append(link)
        parents.append(parent)
        keys.append(key)
        links.append([link])
        body_joints.append([])
        body_of[link] = len(names) - 1
        return len(names) - 1

    def add_joint(j, b: int) -> None:
        t0 = body_frame(names[b], t_zero)
        tc = t_zero[j.child]
        axis_root = tc[:3, :3] @ _unit(j.axis)
        value = held.get(j.name)
        if j.name not in node_of and value is None:
            raise OutputError(f"joint {j.name!r} of {robot.name!r} neither moves in the skeleton nor is held",
                              path=robot.urdf_path, fix="register the robot again")  # fmt: skip
        joints.append(ArticulatedJoint(
            name=j.name, type="slide" if j.type == "prismatic" else "hinge", body=b, axis=t0[:3, :3].T @ axis_root,
            pos=t0[:3, :3].T @ (tc[:3, 3] - t0[:3, 3]), lower=j.lower, upper=j.upper,
            node=node_of[mimic_of[j.name][0]] if j.name in mimic_of else node_of.get(j.name, -1), held=value,
            mimic=mimic_of.get(j.name),
        ))  # fmt: skip
        body_joints[b].append(len(joints) - 1)

    if mj is not None and u.root not in mj.anchor:
        raise OutputError(f"the root body of {robot.name!r} turns or slides against the world (a fixed-base MJCF); a "
                          "tracker's robot has a floating base", path=robot.urdf_path,
                          fix="give the MJCF's root body a <freejoint/> (or no joint) and register it again")  # fmt: skip
    new_body(u.root, -1, "")
    stack = [(j, 0) for j in reversed(u.children_of(u.root))]
    while stack:
        j, b = stack.pop()
        if j.type == "fixed":
            if mj is not None and j.child in mj.anchor:  # an MJCF body without joints: a body of its own
                c = new_body(j.child, b, j.name)
            else:
                links[b].append(j.child)
                body_of[j.child] = b
                c = b
        else:
            chain = [j]
            while mj is not None and chain[-1].child not in mj.anchor:  # an MJCF body with several joints
                chain.append(next(k for k in u.children_of(chain[-1].child) if k.type != "fixed"))
            c = new_body(chain[-1].child, b, j.name)
            for k in chain:
                add_joint(k, c)
            j = chain[-1]
        stack.extend((k, c) for k in reversed(u.children_of(j.child)))

    inertials = mj.inertial if mj is not None else urdf_inertials(robot.urdf_path)
    bodies = []
    for b, name in enumerate(names):
        t0 = body_frame(name, t_zero)
        frames = tuple(_inverse(t0) @ t_zero[link] for link in links[b])
        parts = []
        for link, f in zip(links[b], frames):
            if mj is not None:  # the compiled body's own inertia, already in the body frame
                if link == name and name in mj.inertial and mj.inertial[name][0] > 0:
                    parts.append(mj.inertial[name])
            elif link in inertials:
                m, c, inertia = inertials[link]
                parts.append((m, f[:3, :3] @ c + f[:3, 3], f[:3, :3] @ inertia @ f[:3, :3].T))
        mass, com, inertia = _combine(parts)
        n = carrier(name)
        in_node = body_frame(name, t_held).copy()
        in_node[:3, 3] -= rest[n]
        origin = np.eye(4) if parents[b] < 0 else _inverse(body_frame(names[parents[b]], t_zero)) @ t0
        bodies.append(ArticulatedBody(name, parents[b], tuple(body_joints[b]), keys[b], origin, tuple(links[b]), frames, n,
                                      in_node, mass, com, inertia))  # fmt: skip
    return Articulation(robot.name, fmt, Path(robot.urdf_path), tuple(bodies), tuple(joints), skel.fingerprint,
                        tuple(mj.balls) if mj is not None else ())  # fmt: skip


_cache: dict[tuple, Articulation] = {}
_lock = threading.Lock()


def articulation(robot: "Robot") -> Articulation:
    """The :class:`Articulation` of a registered robot, cached per description file and skeleton."""
    p = Path(robot.urdf_path)
    key = (str(p), p.stat().st_mtime_ns, robot.skeleton.fingerprint)
    with _lock:
        hit = _cache.get(key)
    if hit is None:
        hit = build_articulation(robot)
        with _lock:
            _cache[key] = hit
    return hit
