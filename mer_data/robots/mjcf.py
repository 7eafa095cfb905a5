"""MJCF (MuJoCo's XML, ``<mujoco>`` root) → the validated kinematic tree the URDF path produces.

MuJoCo's own compiler reads the model (``mujoco.MjSpec``: ``<include>``, default classes,
``childclass``, ``<frame>``, ``fromto``, Euler angles and degrees are all resolved by it), and the
tree is built from the **compiled** model (``body_pos``, ``body_quat``, ``jnt_pos``, ``jnt_axis``,
``jnt_range``, ``jnt_limited``, ``qpos0``), so the result is a :class:`~mer_data.robots.urdf.UrdfModel`
that the skeleton builder, key-point proposal, collision shapes and the registry use unchanged.

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
- **missing files**: mesh files that are not there (or not regular files, or over 64 MB) are
  dropped with the geoms that use them, and the bodies that lost geometry are named in a warning
  (their collision falls back to fitted capsules). Textures and skins are never read.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from lxml import etree

from mer_data.base.errors import KinematicTreeError, MalformedURDFError, UnsupportedJointError
from mer_data.base.limits import MAX_LENGTH_M, limit, too_big
from mer_data.base.safe_io import read_regular_file

from .urdf import UrdfJoint, UrdfModel, load_urdf
from .urdf_checks import CheckedJoint, _check_depth, _check_unsafe, check_size, check_tree

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

log = logging.getLogger(__name__)

__all__ = [
    "CompiledMjcf",
    "compile_mjcf",
    "description_format",
    "expand_includes",
    "load_description",
    "load_mjcf",
    "mjcf_tree",
]

MAX_INCLUDE_DEPTH = 16
MAX_ASSET_BYTES = 64 * 2**20  # a mesh file larger than this is not read (as shapes.MAX_MESH_BYTES)
_FIX_MJCF = "check that MuJoCo loads it: python -c \"import mujoco; mujoco.MjModel.from_xml_path('FILE')\""
_OPEN_ERROR = re.compile(r"[Ee]rror opening file '([^']*)'")


# ---- reading the XML safely, with <include>s expanded ---------------------------------------------------
def _read_xml(path: Path, what: str, budget: list[int] | None = None) -> etree._Element:
    """A ``<mujoco>`` document: regular file, size and line limits, no DTD/entities, depth limit.

    ``budget``: bytes left for the main file and all its includes together (one file included many
    times counts each time, so nested includes cannot multiply past ``MER_MAX_URDF_BYTES``).
    """
    data = read_regular_file(path, MalformedURDFError, "MER_MAX_URDF_BYTES", fix=f"check the path of the {what}")
    check_size(data, str(path))
    if budget is not None:
        budget[0] -= len(data)
        if budget[0] < 0:
            msg, fix = too_big("MER_MAX_URDF_BYTES", limit("MER_MAX_URDF_BYTES") - budget[0])
            raise MalformedURDFError(f"{msg} (the model with its <include> files, each counted every time it is included)",
                                     path=path, fix=fix)  # fmt: skip
    _check_unsafe(data, str(path))
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise MalformedURDFError(f"not well-formed XML: {exc.msg}", path=path, line=exc.lineno,
                                 fix="repair the XML (an unclosed tag or stray character is the usual cause)") from None  # fmt: skip
    except ValueError as exc:
        raise MalformedURDFError(f"cannot parse the XML: {exc}", path=path, fix="save the model as UTF-8 XML") from None
    docinfo = root.getroottree().docinfo
    if docinfo.doctype or docinfo.internalDTD is not None or docinfo.externalDTD is not None:
        raise MalformedURDFError("the file declares a DOCTYPE; mer never resolves DTDs", path=path, line=1,
                                 fix="remove the DOCTYPE")  # fmt: skip
    if root.tag != "mujoco":
        hint = "this is a URDF: register it with --urdf" if root.tag == "robot" else "an MJCF's top element is <mujoco>"
        raise MalformedURDFError(f"the root element is <{root.tag}>, not <mujoco>", path=path, line=root.sourceline, fix=hint)
    _check_depth(root, str(path))
    return root


def _expand(root: etree._Element, path: Path, main_dir: Path, stack: tuple[Path, ...], budget: list[int]) -> None:
    """Replace every ``<include file>`` under ``root`` by the children of the included ``<mujoco>``
    (MuJoCo's rule: file names relative to the main model's folder), recursively, in place."""
    for inc in list(root.iter("include")):
        name = inc.get("file")
        if not name:
            raise MalformedURDFError("<include> without file=", path=path, line=inc.sourceline, fix="name the file to include")
        target = Path(name) if Path(name).is_absolute() else main_dir / name
        resolved = target.resolve()
        if resolved in stack:
            raise MalformedURDFError(f"<include file={name!r}> includes itself (through {len(stack)} file(s))",
                                     path=path, line=inc.sourceline, fix="remove the circular <include>")  # fmt: skip
        if len(stack) > MAX_INCLUDE_DEPTH:
            raise MalformedURDFError(f"<include> nested deeper than {MAX_INCLUDE_DEPTH} files", path=path,
                                     line=inc.sourceline, fix="flatten the includes")  # fmt: skip
        if not target.exists():
            raise MalformedURDFError(f"<include file={name!r}>: {target} does not exist", path=path, line=inc.sourceline,
                                     fix=f"include files are found relative to the main model's folder ({main_dir})")  # fmt: skip
        sub = _read_xml(target, f"<include file={name!r}> (relative to the main model's folder {main_dir})", budget)
        _expand(sub, target, main_dir, (*stack, resolved), budget)
        parent = inc.getparent()
        at = parent.index(inc)
        tail = inc.tail
        kids = [c for c in sub]
        parent[at : at + 1] = kids
        if kids:
            kids[-1].tail = (kids[-1].tail or "") + (tail or "")


def _source_lines(root: etree._Element) -> dict[tuple[str, str], int]:
    """(tag, name) → line in the main file, for named bodies, joints and sites."""
    out: dict[tuple[str, str], int] = {}
    for tag in ("body", "joint", "freejoint", "site"):
        for el in root.iter(tag):
            name = el.get("name")
            if name and (tag, name) not in out:
                out["joint" if tag == "freejoint" else tag, name] = el.sourceline or 0
    return out


def _expanded(path: Path) -> tuple[etree._Element, dict[tuple[str, str], int]]:
    """The main file's tree with its includes expanded, and the source lines of its own elements."""
    budget = [limit("MER_MAX_URDF_BYTES")]
    root = _read_xml(path, "MJCF given", budget)
    lines = _source_lines(root)
    _expand(root, path, path.parent, (path.resolve(),), budget)
    _check_depth(root, str(path))
    return root, lines


def expand_includes(path: str | Path) -> str:
    """The MJCF text of ``path`` with every ``<include>`` replaced by what it includes (numbers and
    comments verbatim): a single file, what registration stores. Raises :class:`MalformedURDFError`."""
    return etree.tostring(_expanded(Path(path))[0], encoding="unicode")


def description_format(path: str | Path) -> Literal["urdf", "mjcf"]:
    """``mjcf`` when the file's root element is ``<mujoco>``, else ``urdf`` (also for files that are
    not XML at all: the URDF reader then says what is wrong). Reads the file (a regular file only)."""
    data = read_regular_file(Path(path), MalformedURDFError, "MER_MAX_URDF_BYTES", fix="check the path of the robot description")
    try:
        for _, el in etree.iterparse(io.BytesIO(data), events=("start",), resolve_entities=False, no_network=True,
                                     load_dtd=False, huge_tree=False):  # fmt: skip
            return "mjcf" if el.tag == "mujoco" else "urdf"
    except (etree.XMLSyntaxError, ValueError):
        pass
    return "urdf"


# ---- compiling with MuJoCo --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CompiledMjcf:
    """A model compiled by MuJoCo, and what had to be left out.

    Attributes:
        model: the ``mujoco.MjModel`` (textures and skins removed; unreadable meshes and their geoms dropped).
        path: the main file.
        lines: (tag, name) → line in the main file, for messages.
        lost: body → the meshes of its colliding geoms that were dropped (its link is then listed as
            missing by :func:`~mer_data.robots.shapes.shapes_from_urdf`: fitted capsules).
        warnings: one sentence each (missing mesh files, the bodies concerned).
    """

    model: "mujoco.MjModel"
    path: Path
    lines: dict[tuple[str, str], int] = field(default_factory=dict)
    lost: dict[str, tuple[str, ...]] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()


def _asset_file(spec, name: str) -> Path:
    """Where MuJoCo looks for a mesh file: ``meshdir`` (relative to the model's folder) / file."""
    p = Path(Path(name).name if spec.strippath else name)
    if p.is_absolute():
        return p
    d = Path(spec.meshdir or "")
    return (d if d.is_absolute() else Path(spec.modelfiledir) / d) / p


def _asset_problem(p: Path) -> str | None:
    """Why a mesh file cannot be read (None if it can): absent, not a regular file, too large."""
    try:
        st = p.stat()
    except OSError:
        return "missing"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    if st.st_size > MAX_ASSET_BYTES:
        return f"larger than {MAX_ASSET_BYTES >> 20} MB"
    return None


def _some(names: list[str], n: int = 8) -> str:
    """At most ``n`` names, then how many more."""
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def _collides(g, group_mode: bool) -> bool:
    return int(g.group) == 3 if group_mode else bool(int(g.contype) or int(g.conaffinity))


def compile_mjcf(path: str | Path, *, geometry: bool = True) -> CompiledMjcf:
    """Compile an MJCF with MuJoCo, leaving out what cannot be read.

    Args:
        path: the main ``.xml`` (``<include>`` files are read relative to its folder).
        geometry: False drops every mesh (and mesh geom) unread: kinematics only, no warnings
            (the registry's reload; collision shapes are in the robot's ``collision.json``).

    Raises:
        MalformedURDFError: the file cannot be read or MuJoCo refuses it (its message, and the fix).
    """
    import mujoco

    path = Path(path)
    root, lines = _expanded(path)
    text = etree.tostring(root, encoding="unicode")
    try:
        spec = mujoco.MjSpec.from_string(text)
    except Exception as exc:  # noqa: BLE001 - MuJoCo's parser error, reported as ours
        raise MalformedURDFError(f"MuJoCo cannot parse the MJCF: {exc}", path=path, fix=_FIX_MJCF.replace("FILE", str(path))) from None
    spec.modelfiledir = str(path.parent) + os.sep
    spec.compiler.fusestatic = False  # keep bodies without joints: they are links (frames, sites)
    spec.compiler.alignfree = False  # keep the root body's frame where the file puts it
    spec.compiler.boundmass = max(float(spec.compiler.boundmass), 1e-6)  # bodies that lose all geoms still compile
    spec.compiler.boundinertia = max(float(spec.compiler.boundinertia), 1e-12)

    # never read: textures and skins (visual only), height fields (terrain, not a robot part)
    for t in list(spec.textures):
        spec.delete(t)
    for mat in spec.materials:
        mat.textures = [""] * len(mat.textures)
    for s in list(spec.skins):
        spec.delete(s)
    robot_geoms = [g for g in spec.geoms if g.parent is not None and g.parent.name != "world"]  # not the floor
    group_mode = not any(_collides(g, False) for g in robot_geoms)
    hfields = {h.name for h in spec.hfields}
    for g in list(spec.geoms):
        if g.type == mujoco.mjtGeom.mjGEOM_HFIELD or (g.hfieldname and g.hfieldname in hfields):
            spec.delete(g)
    for h in list(spec.hfields):
        spec.delete(h)

    drop: dict[str, tuple[str, str]] = {}  # mesh name -> (file, why it cannot be read)
    for mesh in spec.meshes:
        if not geometry:
            drop[mesh.name] = ("", "")
        elif mesh.file:
            why = _asset_problem(_asset_file(spec, mesh.file))
            if why:
                drop[mesh.name] = (mesh.file, why)
    lost: dict[str, list[str]] = {}
    visual: dict[str, list[str]] = {}
    warnings: list[str] = []

    def drop_meshes(names: dict[str, tuple[str, str]]) -> None:
        for g in list(spec.geoms):
            if g.type == mujoco.mjtGeom.mjGEOM_MESH and g.meshname in names:
                body = g.parent.name or f"body{g.parent.id}"
                (lost if _collides(g, group_mode) else visual).setdefault(body, []).append(g.meshname)
                spec.delete(g)
        for mesh in list(spec.meshes):
            if mesh.name in names:
                spec.delete(mesh)

    drop_meshes(drop)
    for _ in range(len(spec.meshes) + 1):
        try:
            model = spec.compile()
            break
        except Exception as exc:  # noqa: BLE001 - MuJoCo's compiler error, reported as ours
            msg = str(exc).replace("Error: ", "").strip()
            m = _OPEN_ERROR.search(msg)
            hit = {}
            if m:
                hit = {me.name: (me.file, "could not be opened") for me in spec.meshes if me.file and m.group(1).endswith(me.file)}
            else:  # a mesh MuJoCo could not read (corrupt, empty, no volume): name it by its name or file
                hit = {me.name: (me.file or me.name, f"refused by MuJoCo ({msg.splitlines()[0]})") for me in spec.meshes
                       if f"'{me.name}'" in msg or (me.file and me.file in msg)}  # fmt: skip
            if not hit or not geometry:
                raise MalformedURDFError(f"MuJoCo's compiler refused the model: {msg}", path=path,
                                         fix=_FIX_MJCF.replace("FILE", str(path))) from None  # fmt: skip
            drop.update(hit)
            drop_meshes(hit)
    else:  # pragma: no cover - every mesh dropped and it still fails: raised above
        raise MalformedURDFError("MuJoCo's compiler refused the model", path=path)
    if geometry and drop:
        why: dict[str, list[str]] = {}
        for file, reason in drop.values():
            why.setdefault(reason, []).append(file)
        listed = "; ".join(f"{reason}: {_some(sorted(files))}" for reason, files in why.items())
        warnings.append(f"{path}: {len(drop)} mesh file(s) could not be read ({listed}); put them where the model's "
                        f"meshdir points ({_asset_file(spec, 'x').parent}) to use them")  # fmt: skip
        if lost:
            warnings.append(f"{path}: bodies that lost collision geometry (they get capsules fitted along their links): "
                            f"{_some(sorted(lost))}")  # fmt: skip
        only_visual = sorted(set(visual) - set(lost))
        if only_visual:
            warnings.append(f"{path}: bodies that lost visual geometry only (their collision geometry is unaffected): "
                            f"{_some(only_visual)}")  # fmt: skip
        for w in warnings:
            log.warning("%s", w)
    return CompiledMjcf(model, path, lines, {k: tuple(v) for k, v in lost.items()}, tuple(warnings))


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
