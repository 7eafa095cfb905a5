"""MJCF (MuJoCo's XML, ``<mujoco>`` root) → the validated kinematic tree the URDF path produces.

MuJoCo's own compiler reads the model (``mujoco.MjSpec``: ``<include>``, default classes,
``childclass``, ``<frame>``, ``fromto``, Euler angles and degrees are all resolved by it), and the
tree is built from the **compiled** model (``body_pos``, ``body_quat``, ``jnt_pos``, ``jnt_axis``,
``jnt_range``, ``jnt_limited``, ``qpos0``), so the result is a :class:`~mer_data.robots.urdf.UrdfModel`
that the skeleton builder, key-point proposal, collision shapes and the registry use unchanged.
Before MuJoCo sees it, the XML is read by :mod:`.mjcf_xml` (every file confined to the model's
folder, the expansion of ``<replicate>``/``<flexcomp>`` counted) and compiled by :mod:`.mjcf_compile`.

Conventions (docs/robots.md §MJCF):

- **root**: the first body under ``<worldbody>`` with a free joint, else the first body. Other
  top-level bodies (props, a second robot) are ignored with a warning. The free joint is the
  floating base (mer adds its own); a free joint anywhere else is refused. A root body with other
  joints hangs from an added root link ``world``.
- **links**: one per body, named as the body, whose frame is the body frame moved to the anchor of
  the body's last joint (the URDF rule: a child link's origin lies on its joint's axis); a body
  with several joints becomes a chain, the links between named ``<body>__<joint>``. Every named
  ``<site>`` becomes a fixed child link (named as the site; ``<body>__<site>`` if that is taken):
  MJCF's hand, foot and IMU frames.
- **joints**: hinge → ``revolute`` (``continuous`` when unlimited), slide → ``prismatic`` (locked
  at registration, like a URDF's), ball → three revolute joints ``<joint>_x``, ``_y``, ``_z`` about
  the body's axes (intrinsic x-y-z; each within the ball's ``range`` when limited), a body
  without joints → a ``fixed`` joint ``<body>__fixed``. Angles are MuJoCo's ``qpos``: a joint's
  ``ref`` is folded into its origin, so mer's angle 0 is ``qpos = 0``.
- **mimic**: an active ``<equality><joint joint1 joint2 polycoef>`` with a linear polynomial makes
  ``joint1`` follow ``joint2``; a non-linear one, or one that pins a joint, is ignored with a warning.
- **velocity limits**: MJCF has none (``actuatorfrcrange`` and ``ctrlrange`` are forces or
  controls), so every ``velocity`` is ``None``.
- **collision geometry**: the geoms MuJoCo collides (``contype`` or ``conaffinity`` non-zero); a
  model where no robot geom does uses group 3 (mjlab's and Menagerie's collision class). Sizes are
  MuJoCo's (half extents, half lengths) turned into the URDF entries' (full box sizes, capsule
  and cylinder lengths); meshes carry MuJoCo's compiled vertices (``mesh_vert``, scale and mesh
  frame applied), ellipsoids points on their surface.
- **missing files**: mesh files that are not there (or not regular files, or over ``MER_MAX_MESH_BYTES``) are
  dropped with the geoms that use them, and the bodies that lost geometry are named in a warning
  (their collision falls back to fitted capsules). Textures and skins are never read.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mer_data.base.errors import KinematicTreeError, MalformedURDFError, UnsupportedJointError
from mer_data.base.limits import MAX_LENGTH_M, limit, too_big

from .mjcf_compile import CompiledMjcf, compile_mjcf
from .mjcf_xml import description_format, expand_includes, registry_copy
from .urdf import UrdfJoint, UrdfModel, load_urdf
from .urdf_checks import CheckedJoint, check_tree

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

log = logging.getLogger(__name__)

__all__ = [
    "CompiledMjcf",
    "compile_mjcf",
    "description_format",
    "expand_includes",
    "registry_copy",
    "load_description",
    "load_mjcf",
    "mjcf_tree",
]



# ---- the compiled model as a tree of links and joints -------------------------------------------------------
def _quat(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of a quaternion (w, x, y, z), normalised."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip


def _frame(pos: np.ndarray | None = None, rot: np.ndarray | None = None) -> np.ndarray:
    t = np.eye(4)
    if rot is not None:
        t[:3, :3] = rot
    if pos is not None:
        t[:3, 3] = pos
    return t


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _sphere_points(n: int = 64) -> np.ndarray:
    """(n, 3) unit vectors spread over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = math.pi * (3 - math.sqrt(5)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


class _Names:
    """Unique names: the first use keeps the name, later ones get ``_2``, ``_3``, ..."""

    def __init__(self) -> None:
        self.used: set[str] = set()

    def take(self, name: str) -> str:
        out, k = name, 2
        while out in self.used:
            out, k = f"{name}_{k}", k + 1
        self.used.add(out)
        return out


def mjcf_tree(c: CompiledMjcf) -> UrdfModel:
    """The compiled model as a :class:`UrdfModel` (see the module docstring for the conventions).

    Frames: every joint's ``origin`` is parent-link ← joint frame at ``qpos = 0`` [m]; a body's link
    frame is the body frame translated to its last joint's anchor (``jnt_pos``); collision entries,
    ``collision_points`` and ``inertial_coms`` are in the link frames.
    """
    import mujoco

    m, path = c.model, str(c.path)
    FREE, BALL, SLIDE, HINGE = (int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL),
                                int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE))  # fmt: skip
    jtype = [int(t) for t in m.jnt_type]  # plain ints: MuJoCo's enums do not compare with numpy integers in `in`
    warnings: list[str] = []

    def name(obj, i: int, fallback: str) -> str:
        return mujoco.mj_id2name(m, obj, i) or fallback

    def body_name(b: int) -> str:
        return "world" if b == 0 else name(mujoco.mjtObj.mjOBJ_BODY, b, f"body{b}")

    def joints_of(b: int) -> list[int]:
        return list(range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])))

    top = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0 and m.body_mocapid[b] < 0]
    if not top:
        raise KinematicTreeError("the MJCF has no body under <worldbody>", path=path, fix="put the robot's bodies under <worldbody>")
    free_top = [b for b in top if any(jtype[j] == FREE for j in joints_of(b))]
    root = free_top[0] if free_top else top[0]
    others = [b for b in top if b != root]
    if others:
        warnings.append(f"{path}: the robot is body '{body_name(root)}' and the bodies under it; "
                        f"{len(others)} other top-level bod{'y' if len(others) == 1 else 'ies'} "
                        f"({', '.join(repr(body_name(b)) for b in others[:6])}) ignored")  # fmt: skip
    bodies = [b for b in range(1, m.nbody) if m.body_rootid[b] == root]
    if len(bodies) > limit("MER_MAX_URDF_ELEMENTS"):
        msg, fix = too_big("MER_MAX_URDF_ELEMENTS", len(bodies))
        raise MalformedURDFError(msg, path=path, fix=fix)
    if np.abs(m.body_pos[bodies]).max(initial=0.0) > MAX_LENGTH_M or np.abs(m.jnt_pos).max(initial=0.0) > MAX_LENGTH_M:
        raise MalformedURDFError(f"a body or joint position is beyond +-{MAX_LENGTH_M:g} m", path=path,
                                 fix="write positions in metres")  # fmt: skip

    links = _Names()
    jnames = _Names()
    for b in bodies:  # body names first: they are the links the card and the collision file refer to
        links.take(body_name(b))
    link_of: dict[int, str] = {b: body_name(b) for b in bodies}
    anchor: dict[int, np.ndarray] = {}  # body -> its link frame's origin in the body frame
    link_order: list[str] = []
    link_lines: dict[str, int] = {}
    joints: list[UrdfJoint] = []
    joint_of: dict[int, str] = {}  # MuJoCo hinge/slide joint id -> our joint name

    def line(tag: str, n: str) -> int:
        return c.lines.get((tag, n), 0)

    def add_link(n: str, ln: int) -> None:
        link_order.append(n)
        link_lines[n] = ln

    def add_joint(n: str, kind: str, parent: str, child: str, origin: np.ndarray, axis=(1.0, 0.0, 0.0),
                  lower: float | None = None, upper: float | None = None, ln: int = 0) -> None:  # fmt: skip
        joints.append(UrdfJoint(n, kind, parent, child, origin, np.asarray(axis, np.float64), lower, upper, None, ln))

    root_joints = [j for j in joints_of(root) if jtype[j] != FREE]
    if any(jtype[j] == FREE for j in joints_of(root)) and root_joints:
        j = root_joints[0]
        n = name(mujoco.mjtObj.mjOBJ_JOINT, j, f"joint{j}")
        raise UnsupportedJointError("the root body has a free joint and other joints", path=path, line=line("joint", n),
                                    element=f"joint '{n}'", fix="keep the free joint alone in the root body")  # fmt: skip
    root_link = body_name(root)
    if root_joints:  # a fixed-base robot whose first body turns or slides against the world
        root_link = links.take("world")
        add_link(root_link, 0)
    for b in bodies:
        bname = body_name(b)
        own = [j for j in joints_of(b) if not (b == root and jtype[j] == FREE)]
        for j in own:
            if jtype[j] == FREE:
                n = name(mujoco.mjtObj.mjOBJ_JOINT, j, f"joint{j}")
                raise UnsupportedJointError(
                    "a free joint inside the robot (only the root body may float)", path=path, line=line("joint", n),
                    element=f"joint '{n}' of body '{bname}'",
                    fix="remove it (mer adds the floating base), or make the body a separate top-level body",
                )
        if b == root and not own:
            add_link(bname, line("body", bname))
            anchor[b] = np.zeros(3)
            continue
        if b == root:
            parent_link, t_cur = root_link, _frame(m.body_pos[b], _quat(m.body_quat[b]))
        else:
            p = int(m.body_parentid[b])
            parent_link = link_of[p]
            t_cur = _frame(-anchor[p]) @ _frame(m.body_pos[b], _quat(m.body_quat[b]))  # parent link <- body frame
        if not own:
            add_link(bname, line("body", bname))
            add_joint(jnames.take(f"{bname}__fixed"), "fixed", parent_link, bname, t_cur, ln=line("body", bname))
            anchor[b] = np.zeros(3)
            continue
        steps: list[tuple[str, str, np.ndarray, np.ndarray, float | None, float | None, int, int]] = []
        for j in own:  # (name, type, origin in the previous frame, axis, lower, upper, line, MuJoCo id)
            n = name(mujoco.mjtObj.mjOBJ_JOINT, j, f"{bname}__joint{j - own[0]}")
            ln = line("joint", n)
            pj, aj = np.asarray(m.jnt_pos[j], np.float64), np.asarray(m.jnt_axis[j], np.float64)
            limited = bool(m.jnt_limited[j])
            lo, hi = (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])) if limited else (None, None)
            ref = float(m.qpos0[m.jnt_qposadr[j]]) if jtype[j] in (HINGE, SLIDE) else 0.0
            if jtype[j] == HINGE:
                steps.append((n, "revolute" if limited else "continuous", t_cur @ _frame(pj, _axis_angle(aj, -ref)), aj, lo, hi, ln, j))
            elif jtype[j] == SLIDE:
                steps.append((n, "prismatic", t_cur @ _frame(pj - ref * aj / np.linalg.norm(aj)), aj, lo, hi, ln, j))
            elif jtype[j] == BALL:
                cone = (-hi, hi) if limited and hi else (None, None)
                for k, (suffix, ax) in enumerate(zip("xyz", np.eye(3))):
                    steps.append((f"{n}_{suffix}", "revolute" if cone[0] is not None else "continuous",
                                  t_cur @ _frame(pj) if k == 0 else np.eye(4), ax, cone[0], cone[1], ln, -1))  # fmt: skip
                warnings.append(f"{path}: ball joint '{n}' of body '{bname}' is split into three revolute joints "
                                f"{n}_x, {n}_y, {n}_z (intrinsic x-y-z about the body's axes); motions give its "
                                "quaternion as those three angles")  # fmt: skip
            t_cur = _frame(-pj)
        anchor[b] = np.asarray(m.jnt_pos[own[-1]], np.float64)
        prev = parent_link
        for i, (n, kind, origin, axis, lo, hi, ln, j) in enumerate(steps):
            jn = jnames.take(n)
            child = bname if i == len(steps) - 1 else links.take(f"{bname}__{n}")
            add_link(child, line("body", bname) if child == bname else ln)
            add_joint(jn, kind, prev, child, origin, axis, lo, hi, ln)
            if j >= 0:
                joint_of[j] = jn
            prev = child
    # sites: fixed child links (hand, foot, IMU frames)
    site_joints: list[UrdfJoint] = []
    for s in range(m.nsite):
        b = int(m.site_bodyid[s])
        sname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, s)
        if b not in link_of or not sname:
            continue
        child = links.take(sname if sname not in links.used else f"{link_of[b]}__{sname}")
        add_link(child, line("site", sname))
        origin = _frame(-anchor[b]) @ _frame(m.site_pos[s], _quat(m.site_quat[s]))
        site_joints.append(UrdfJoint(jnames.take(f"{child}__site"), "fixed", link_of[b], child, origin,
                                     np.array([1.0, 0.0, 0.0]), None, None, None, line("site", sname)))  # fmt: skip
    joints.extend(site_joints)
    joints = _with_mimics(m, joints, joint_of, warnings, path)

    collisions, points, unused = _collisions(m, c, bodies, link_of, anchor)
    if unused:
        warnings.append(f"{path}: {len(unused)} collision geom(s) of type plane/hfield/sdf not used ({', '.join(unused[:6])})")
    coms = {link_of[b]: np.asarray(m.body_ipos[b], np.float64) - anchor[b] for b in bodies if m.body_mass[b] > 1e-5}
    for w in warnings:
        log.warning("%s", w)
    checked = [CheckedJoint(j.name, j.type, j.parent, j.child, j.line) for j in joints]
    tree_root = check_tree(link_lines, checked, path)  # a tree by construction; checked all the same
    return UrdfModel(
        path=path,
        name=m.names[: m.names.index(b"\0")].decode() if m.names else Path(path).stem,
        links=tuple(link_order),
        link_lines=link_lines,
        joints=tuple(joints),
        root=tree_root,
        collision_points=points,
        inertial_coms=coms,
        warnings=tuple(c.warnings) + tuple(warnings),
        collisions=collisions,
    )


def _with_mimics(
    m: "mujoco.MjModel", joints: list[UrdfJoint], joint_of: dict[int, str], warnings: list[str], path: str
) -> list[UrdfJoint]:
    """Active ``<equality><joint>`` constraints with a linear polynomial as mimic relations.

    MuJoCo's ``joint1 - ref1 = sum_k c_k (joint2 - ref2)^k`` with only ``c_0``, ``c_1`` non-zero is
    ``joint1 = c_1 joint2 + (ref1 + c_0 - c_1 ref2)``: mer's ``(master, multiplier, offset)``.
    ``joint_of``: MuJoCo hinge/slide joint id → its name in the tree.
    """
    import dataclasses

    import mujoco

    mimic: dict[str, tuple[str, float, float]] = {}
    for e in range(m.neq):
        if int(m.eq_type[e]) != int(mujoco.mjtEq.mjEQ_JOINT):
            if m.eq_active0[e]:
                kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
                warnings.append(f"{path}: equality constraint {e} ({kind}) ignored: mer's skeletons are trees")
            continue
        if not m.eq_active0[e]:
            continue
        j1, j2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
        coef = np.asarray(m.eq_data[e, :5], np.float64)
        if j1 not in joint_of or (j2 >= 0 and j2 not in joint_of):
            continue  # a joint outside the robot, or a ball joint
        n1 = joint_of[j1]
        y0 = float(m.qpos0[m.jnt_qposadr[j1]])
        if j2 < 0:
            warnings.append(f"{path}: an equality constraint holds joint '{n1}' at {y0 + coef[0]:g}; ignored "
                            f"(hold it with --lock {n1}={y0 + coef[0]:g})")  # fmt: skip
            continue
        if np.abs(coef[2:]).max() > 1e-12:
            warnings.append(f"{path}: joint '{n1}' follows '{joint_of[j2]}' by a non-linear polynomial; ignored "
                            "(mer's mimic joints are linear)")  # fmt: skip
            continue
        if n1 in mimic:
            warnings.append(f"{path}: joint '{n1}' has a second equality constraint; ignored")
            continue
        x0 = float(m.qpos0[m.jnt_qposadr[j2]])
        mimic[n1] = (joint_of[j2], float(coef[1]), y0 + float(coef[0]) - float(coef[1]) * x0)
    return [dataclasses.replace(j, mimic=mimic[j.name]) if j.name in mimic else j for j in joints]


def _collisions(
    m: "mujoco.MjModel", c: CompiledMjcf, bodies: list[int], link_of: dict[int, str], anchor: dict[int, np.ndarray]
) -> tuple[dict[str, tuple[dict, ...]], dict[str, np.ndarray], list[str]]:
    """Collision entries (as :attr:`UrdfModel.collisions`), extreme points (K, 3) of primitives per
    link (link frame [m]), and the colliding geoms of types mer does not use (plane, hfield, sdf).

    ``anchor``: body → its link frame's origin in the body frame [m] (geoms are moved by minus it).
    """
    import mujoco

    G = mujoco.mjtGeom
    in_robot = set(bodies)
    geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in in_robot]
    group_mode = not any(m.geom_contype[g] or m.geom_conaffinity[g] for g in geoms)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    out: dict[str, list[dict]] = {}
    pts: dict[str, list[np.ndarray]] = {}
    unused: list[str] = []
    for g in geoms:
        if not (m.geom_group[g] == 3 if group_mode else (m.geom_contype[g] or m.geom_conaffinity[g])):
            continue
        b = int(m.geom_bodyid[g])
        link = link_of[b]
        t = _frame(-anchor[b]) @ _frame(m.geom_pos[g], _quat(m.geom_quat[g]))
        size = np.asarray(m.geom_size[g], np.float64)
        kind = int(m.geom_type[g])
        local = None
        if kind == int(G.mjGEOM_BOX):
            entry = {"type": "box", "origin": t, "size": tuple(float(x) for x in 2 * size)}
            local = signs * size
        elif kind == int(G.mjGEOM_SPHERE):
            entry = {"type": "sphere", "origin": t, "radius": float(size[0])}
            local = np.concatenate([np.eye(3), -np.eye(3)]) * size[0]
        elif kind == int(G.mjGEOM_CYLINDER):
            entry = {"type": "cylinder", "origin": t, "radius": float(size[0]), "length": float(2 * size[1])}
            local = signs * np.array([size[0], size[0], size[1]])
        elif kind == int(G.mjGEOM_CAPSULE):
            entry = {"type": "capsule", "origin": t, "radius": float(size[0]), "length": float(2 * size[1])}
            cap = np.concatenate([np.eye(3), -np.eye(3)]) * size[0]
            local = np.concatenate([cap + [0, 0, size[1]], cap - [0, 0, size[1]]])
        elif kind == int(G.mjGEOM_ELLIPSOID):
            entry = {"type": "mesh", "origin": t, "vertices": _sphere_points() * size, "scale": (1.0, 1.0, 1.0),
                     "filename": f"<ellipsoid {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or g}>"}  # fmt: skip
        elif kind == int(G.mjGEOM_MESH):
            mid = int(m.geom_dataid[g])
            adr, num = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
            entry = {"type": "mesh", "origin": t, "vertices": np.asarray(m.mesh_vert[adr : adr + num], np.float64),
                     "scale": (1.0, 1.0, 1.0), "filename": mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_MESH, mid) or f"mesh{mid}"}  # fmt: skip
        else:
            unused.append(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g} of body '{link}'")
            continue
        out.setdefault(link, []).append(entry)
        if local is not None:
            pts.setdefault(link, []).append(local @ t[:3, :3].T + t[:3, 3])
    names = {int(b): link_of[b] for b in bodies}
    by_name = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}": names[b] for b in bodies}
    for body, meshes in c.lost.items():  # dropped collision meshes: shapes_from_urdf lists the link as missing
        if body in by_name:
            for mesh in meshes:
                out.setdefault(by_name[body], []).append(
                    {"type": "mesh", "origin": np.eye(4), "vertices": None, "scale": (1.0, 1.0, 1.0), "filename": mesh})
    return ({k: tuple(v) for k, v in out.items()}, {k: np.concatenate(v) for k, v in pts.items()}, unused)


def load_mjcf(path: str | Path, *, geometry: bool = True) -> UrdfModel:
    """Read an MJCF with MuJoCo's compiler and return its kinematic tree (see the module docstring).

    Args:
        path: the main ``.xml``.
        geometry: False: kinematics only, meshes never read (the registry's reload).

    Raises:
        MalformedURDFError (unreadable, refused by MuJoCo), UnsupportedJointError (a free joint
        inside the robot), KinematicTreeError (no body): with the file and what to do.
    """
    return mjcf_tree(compile_mjcf(path, geometry=geometry))


def load_description(path: str | Path, *, geometry: bool = True) -> UrdfModel:
    """A robot description by its content: :func:`load_mjcf` for a ``<mujoco>`` file, else
    :func:`~mer_data.robots.urdf.load_urdf` (``geometry`` only concerns MJCF)."""
    if description_format(path) == "mjcf":
        return load_mjcf(path, geometry=geometry)
    return load_urdf(path)
