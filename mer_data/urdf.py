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
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from .errors import (
    BrokenReferenceError,
    KinematicTreeError,
    MalformedURDFError,
    UnsafeURDFError,
    UnsupportedJointError,
)

log = logging.getLogger(__name__)

__all__ = ["UrdfJoint", "UrdfModel", "load_urdf", "parse_urdf_bytes", "JOINT_TYPES"]

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
_UNSAFE = re.compile(rb"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>`` element, validated.

    Attributes:
        origin: (4, 4) parent-link frame ← joint frame at zero angle [m].
        axis: (3,) joint axis in the joint frame (unit length for movable joints).
        lower, upper: position limits [rad]; ``None`` where the URDF gives none.
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


@dataclass(frozen=True)
class _Checked:
    """A joint whose structure has been validated; values are read later by yourdfpy."""

    name: str
    type: str
    parent: str
    child: str
    line: int


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
    """

    path: str
    name: str
    links: tuple[str, ...]
    link_lines: dict[str, int]
    joints: tuple[UrdfJoint, ...]
    root: str
    collision_points: dict[str, np.ndarray]

    def joint(self, name: str) -> UrdfJoint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def children_of(self, link: str) -> list[UrdfJoint]:
        """Joints whose parent is ``link``, in file order."""
        return [j for j in self.joints if j.parent == link]

    def parent_joint_of(self, link: str) -> UrdfJoint | None:
        for j in self.joints:
            if j.child == link:
                return j
        return None


def load_urdf(path: str | Path) -> UrdfModel:
    """Read and validate a URDF file.

    Raises:
        MalformedURDFError, UnsafeURDFError, BrokenReferenceError, KinematicTreeError,
        UnsupportedJointError: with the file, line and element at fault.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise MalformedURDFError(
            "file not found", path=path, fix="check the path given to --urdf"
        ) from None
    except OSError as exc:
        raise MalformedURDFError(f"cannot read the file: {exc}", path=path) from None
    return parse_urdf_bytes(data, str(path))


def _line_of(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


def _floats(text: str | None, n: int, *, what: str, path: str, line: int, element: str) -> np.ndarray:
    if text is None:
        raise MalformedURDFError(f"missing {what}", path=path, line=line, element=element)
    parts = text.split()
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise MalformedURDFError(
            f"{what}={text!r} is not {n} numbers",
            path=path,
            line=line,
            element=element,
            fix=f"write {what} as {n} space-separated numbers",
        ) from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise MalformedURDFError(
            f"{what}={text!r} must be {n} finite numbers",
            path=path,
            line=line,
            element=element,
            fix=f"write {what} as {n} space-separated finite numbers",
        )
    return np.asarray(vals, dtype=np.float64)


def _float(text: str | None, *, what: str, path: str, line: int, element: str) -> float | None:
    if text is None:
        return None
    return float(_floats(text, 1, what=what, path=path, line=line, element=element)[0])


def parse_urdf_bytes(data: bytes, path: str = "<urdf>") -> UrdfModel:
    """Validate URDF text and build the :class:`UrdfModel` (see :func:`load_urdf`)."""
    m = _UNSAFE.search(data)
    if m:
        raise UnsafeURDFError(
            f"the file declares <!{m.group(1).decode().upper()}>; mer never resolves DTDs or XML "
            "entities (they can read local files or the network)",
            path=path,
            line=_line_of(data, m.start()),
            fix="expand xacro/entities into plain XML (e.g. `xacro robot.urdf.xacro > robot.urdf`) "
            "and remove the DOCTYPE",
        )
    parser = etree.XMLParser(
        resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False, remove_comments=True
    )
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise MalformedURDFError(
            f"not well-formed XML: {exc.msg}",
            path=path,
            line=exc.lineno,
            fix="repair the XML (an unclosed tag or stray character is the usual cause)",
        ) from None
    if root.tag != "robot":
        raise MalformedURDFError(
            f"the root element is <{root.tag}>, not <robot>",
            path=path,
            line=root.sourceline,
            fix="a URDF's top element must be <robot name=...>",
        )
    robot_name = root.get("name") or Path(path).stem

    # ---- links -----------------------------------------------------------------------------
    links: list[str] = []
    link_lines: dict[str, int] = {}
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            raise MalformedURDFError(
                "<link> without a name", path=path, line=el.sourceline, fix="give every link a unique name"
            )
        if name in link_lines:
            raise MalformedURDFError(
                f"link '{name}' is defined twice (first at line {link_lines[name]})",
                path=path,
                line=el.sourceline,
                element=f"link '{name}'",
                fix="link names must be unique",
            )
        links.append(name)
        link_lines[name] = el.sourceline
    if not links:
        raise MalformedURDFError("the robot has no <link>", path=path, line=root.sourceline)

    # ---- joints: structure and values, validated with line numbers --------------------------
    joints: list[_Checked] = []
    seen: dict[str, int] = {}
    mimics: dict[str, tuple[str, int]] = {}
    child_of: dict[str, _Checked] = {}
    for el in root.findall("joint"):
        line = el.sourceline
        name = el.get("name")
        if not name:
            raise MalformedURDFError("<joint> without a name", path=path, line=line, fix="name every joint")
        element = f"joint '{name}'"
        if name in seen:
            raise MalformedURDFError(
                f"joint '{name}' is defined twice (first at line {seen[name]})",
                path=path,
                line=line,
                element=element,
                fix="joint names must be unique",
            )
        seen[name] = line
        jtype = el.get("type")
        if jtype not in JOINT_TYPES:
            raise MalformedURDFError(
                f"type={jtype!r} is not a URDF joint type",
                path=path,
                line=line,
                element=element,
                fix=f"use one of {', '.join(JOINT_TYPES)}",
            )
        ends = {}
        for tag in ("parent", "child"):
            sub = el.find(tag)
            if sub is None or not sub.get("link"):
                raise MalformedURDFError(
                    f"missing <{tag} link=...>",
                    path=path,
                    line=line,
                    element=element,
                    fix=f"every joint needs a <{tag} link=\"...\"/>",
                )
            ref = sub.get("link")
            if ref not in link_lines:
                raise BrokenReferenceError(
                    f"{tag} link '{ref}' does not exist",
                    path=path,
                    line=sub.sourceline,
                    element=element,
                    fix=_did_you_mean(ref, links, "define the link or correct the name"),
                )
            ends[tag] = ref
        if ends["parent"] == ends["child"]:
            raise KinematicTreeError(
                f"link '{ends['parent']}' is its own parent",
                path=path,
                line=line,
                element=element,
                fix="a joint must connect two different links",
            )
        org = el.find("origin")
        if org is not None:
            _floats(org.get("xyz", "0 0 0"), 3, what="origin xyz", path=path, line=org.sourceline, element=element)
            _floats(org.get("rpy", "0 0 0"), 3, what="origin rpy", path=path, line=org.sourceline, element=element)
        ax_el = el.find("axis")
        axis = np.array([1.0, 0.0, 0.0])
        if ax_el is not None:
            axis = _floats(ax_el.get("xyz", "1 0 0"), 3, what="axis xyz", path=path, line=ax_el.sourceline, element=element)
        lower = upper = None
        lim = el.find("limit")
        if lim is not None:
            lower = _float(lim.get("lower"), what="limit lower", path=path, line=lim.sourceline, element=element)
            upper = _float(lim.get("upper"), what="limit upper", path=path, line=lim.sourceline, element=element)
        mim = el.find("mimic")
        if mim is not None:
            master = mim.get("joint")
            if not master:
                raise MalformedURDFError(
                    "<mimic> without joint=...", path=path, line=mim.sourceline, element=element,
                    fix="name the joint this joint follows",
                )
            _float(mim.get("multiplier", "1"), what="mimic multiplier", path=path, line=mim.sourceline, element=element)
            _float(mim.get("offset", "0"), what="mimic offset", path=path, line=mim.sourceline, element=element)
            mimics[name] = (master, mim.sourceline)
        if jtype in ("revolute", "continuous", "prismatic"):
            norm = float(np.linalg.norm(axis))
            if norm < 1e-9:
                raise UnsupportedJointError(
                    "the joint axis is zero",
                    path=path,
                    line=(ax_el.sourceline if ax_el is not None else line),
                    element=element,
                    fix="give <axis xyz=...> a non-zero direction",
                )
        if jtype in ("revolute", "prismatic") and (lower is None or upper is None):
            raise UnsupportedJointError(
                f"a {jtype} joint needs <limit lower=... upper=...>",
                path=path,
                line=(lim.sourceline if lim is not None else line),
                element=element,
                fix="add the position limits, or make it type=\"continuous\" if it turns freely",
            )
        if lower is not None and upper is not None and lower > upper:
            raise MalformedURDFError(
                f"limit lower={lower} is above upper={upper}",
                path=path,
                line=lim.sourceline,
                element=element,
                fix="swap the two limits",
            )
        joint = _Checked(name, jtype, ends["parent"], ends["child"], line)
        if joint.child in child_of:
            other = child_of[joint.child]
            raise KinematicTreeError(
                f"link '{joint.child}' is the child of two joints ('{other.name}' at line {other.line} "
                f"and '{name}')",
                path=path,
                line=line,
                element=element,
                fix="a URDF must be a tree: every link has at most one parent joint (closed loops are "
                "not supported)",
            )
        child_of[joint.child] = joint
        joints.append(joint)

    # ---- one tree ----------------------------------------------------------------------------
    roots = [l for l in links if l not in child_of]
    if not roots:
        j = joints[0]
        raise KinematicTreeError(
            "every link is some joint's child: the joints form a cycle",
            path=path,
            line=j.line,
            fix="break the cycle so that exactly one link (the base) has no parent joint",
        )
    if len(roots) > 1:
        listed = ", ".join(f"'{r}' (line {link_lines[r]})" for r in roots[:6])
        raise KinematicTreeError(
            f"{len(roots)} links have no parent joint: {listed}; the robot must have a single root",
            path=path,
            line=link_lines[roots[1]],
            fix="connect the extra links with a joint, or remove the unused ones",
        )
    root_link = roots[0]
    reached = _reachable(root_link, joints)
    unreached = [l for l in links if l not in reached]
    if unreached:
        # a cycle detached from the root: every unreached link has a parent, so they loop
        j = child_of[unreached[0]]
        raise KinematicTreeError(
            f"links {', '.join(repr(u) for u in unreached[:6])} form a cycle not connected to the root "
            f"'{root_link}'",
            path=path,
            line=j.line,
            element=f"joint '{j.name}'",
            fix="remove the loop: a URDF must be a tree",
        )
    for jname, (master, line) in mimics.items():
        if master not in seen:
            raise BrokenReferenceError(
                f"mimics joint '{master}', which does not exist",
                path=path,
                line=line,
                element=f"joint '{jname}'",
                fix=_did_you_mean(master, list(seen), "correct the <mimic joint=...> name"),
            )
    return UrdfModel(
        path=path,
        name=robot_name,
        links=tuple(links),
        link_lines=link_lines,
        root=root_link,
        **_read_values_with_yourdfpy(root, joints),
    )


def _reachable(root: str, joints: list[_Checked]) -> set[str]:
    kids: dict[str, list[str]] = {}
    for j in joints:
        kids.setdefault(j.parent, []).append(j.child)
    out, stack = set(), [root]
    while stack:
        link = stack.pop()
        if link in out:
            continue
        out.add(link)
        stack.extend(kids.get(link, ()))
    return out


def _read_values_with_yourdfpy(root, checked: list[_Checked]) -> dict:
    """Read origins, axes, limits, mimic tags and collision shapes with yourdfpy.

    Everything yourdfpy could choke on (numbers, references, limits) was validated above with
    line numbers, so this cannot fail; yourdfpy stays the one reader of element values.
    """
    import yourdfpy

    buf = io.BytesIO(etree.tostring(root))
    model = yourdfpy.URDF.load(buf, load_meshes=False, build_scene_graph=False, load_collision_meshes=False)
    theirs = {j.name: j for j in model.robot.joints}
    out = []
    for c in checked:
        j = theirs[c.name]
        lim = j.limit
        mimic = None if j.mimic is None else (j.mimic.joint, float(j.mimic.multiplier), float(j.mimic.offset))
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
            )
        )
    return {"joints": tuple(out), "collision_points": _collision_points(model)}


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


def _did_you_mean(name: str, choices, otherwise: str) -> str:
    import difflib

    close = difflib.get_close_matches(name, list(choices), n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(repr(c) for c in close) + "?"
    return otherwise
