"""Structural validation of URDF XML, with the file and line of every problem.

The checks that :func:`mer_data.robots.urdf.parse_urdf_bytes` runs before any value is read: safe parsing
(no DTD, no entities), names, references, numbers, limits, axes and the tree shape.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from lxml import etree

from mer_data.base.errors import (
    BrokenReferenceError,
    KinematicTreeError,
    MalformedURDFError,
    UnsafeURDFError,
    UnsupportedJointError,
)
from mer_data.base.limits import MAX_LENGTH_M, MAX_NUMBER, limit, too_big
from mer_data.base.numbers import parse_number

__all__ = [
    "JOINT_TYPES",
    "CheckedJoint",
    "parse_xml",
    "check_size",
    "check_links",
    "check_joints",
    "check_tree",
    "did_you_mean",
]

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
_UNSAFE = re.compile(rb"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)
_UNSAFE_TEXT = re.compile(r"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)


@dataclass(frozen=True)
class CheckedJoint:
    """A joint whose structure has been validated; values are read later by yourdfpy."""

    name: str
    type: str
    parent: str
    child: str
    line: int


def _line_of(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


def _floats(
    text: str | None, n: int, *, what: str, path: str, line: int, element: str, bound: float = MAX_NUMBER
) -> np.ndarray:
    if text is None:
        raise MalformedURDFError(f"missing {what}", path=path, line=line, element=element)
    parts = text.split()
    vals = [parse_number(p) for p in parts]
    if any(v is None for v in vals):
        raise MalformedURDFError(
            f"{what}={text!r} is not {n} numbers",
            path=path,
            line=line,
            element=element,
            fix=f"write {what} as {n} space-separated decimal numbers (no 1_0, no non-ASCII digits, no nan/inf)",
        )
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise MalformedURDFError(
            f"{what}={text!r} must be {n} finite numbers",
            path=path,
            line=line,
            element=element,
            fix=f"write {what} as {n} space-separated finite numbers",
        )
    if any(abs(v) > bound for v in vals):
        unit = " m" if bound == MAX_LENGTH_M else ""
        raise MalformedURDFError(
            f"{what}={text!r} is beyond +-{bound:g}{unit}: no robot is that large, and it would overflow the kinematics",
            path=path,
            line=line,
            element=element,
            fix=f"write {what} in SI units (metres, radians); a joint that turns freely is type=\"continuous\"",
        )
    return np.asarray(vals, dtype=np.float64)


def _float(text: str | None, *, what: str, path: str, line: int, element: str) -> float | None:
    if text is None:
        return None
    return float(_floats(text, 1, what=what, path=path, line=line, element=element)[0])


def _unsafe(kind: str, path: str, line: int | None) -> UnsafeURDFError:
    return UnsafeURDFError(
        f"the file declares <!{kind.upper()}>; mer never resolves DTDs or XML "
        "entities (they can read local files or the network)",
        path=path,
        line=line,
        fix="expand xacro/entities into plain XML (e.g. `xacro robot.urdf.xacro > robot.urdf`) "
        "and remove the DOCTYPE",
    )


def check_size(data: bytes, path: str) -> None:
    """File size and longest line within their limits (one linear pass over the bytes)."""
    if len(data) > limit("MER_MAX_URDF_BYTES"):
        msg, fix = too_big("MER_MAX_URDF_BYTES", len(data))
        raise MalformedURDFError(msg, path=path, fix=fix)
    ends = np.flatnonzero(np.frombuffer(data, np.uint8) == 10)
    bounds = np.concatenate([[-1], ends, [len(data)]])
    lengths = np.diff(bounds) - 1
    i = int(np.argmax(lengths))
    if lengths[i] > limit("MER_MAX_URDF_LINE_BYTES"):
        msg, fix = too_big("MER_MAX_URDF_LINE_BYTES", int(lengths[i]))
        raise MalformedURDFError(msg, path=path, line=i + 1, fix=fix)


def _wide_codec(head: bytes) -> str | None:
    """UTF-16/32 from a byte-order mark or the NUL bytes around the first ``<``; None for 8-bit text."""
    for prefix, codec in (
        (b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"), (b"\xff\xfe", "utf-16"),
        (b"\xfe\xff", "utf-16"), (b"<\x00\x00\x00", "utf-32-le"), (b"\x00\x00\x00<", "utf-32-be"),
        (b"<\x00", "utf-16-le"), (b"\x00<", "utf-16-be"),
    ):  # fmt: skip
        if head.startswith(prefix):
            return codec
    return None


def _check_unsafe(data: bytes, path: str) -> None:
    """Refuse DTDs and entities, whatever the encoding (UTF-8 bytes, or UTF-16/32 text)."""
    m = _UNSAFE.search(data)
    if m:
        raise _unsafe(m.group(1).decode(), path, _line_of(data, m.start()))
    codec = _wide_codec(data[:4])
    if codec is not None:
        text = data.decode(codec, errors="replace")
        t = _UNSAFE_TEXT.search(text)
        if t:
            raise _unsafe(t.group(1), path, text.count("\n", 0, t.start()) + 1)


def _check_depth(root, path: str) -> None:
    """Nesting depth of the elements within the limit (one walk over the tree)."""
    cap = limit("MER_MAX_XML_DEPTH")
    depth = 0
    for event, el in etree.iterwalk(root, events=("start", "end")):
        depth += 1 if event == "start" else -1
        if depth > cap:
            msg, fix = too_big("MER_MAX_XML_DEPTH", f"over {cap}")
            raise MalformedURDFError(msg, path=path, line=el.sourceline, element=f"<{el.tag}>", fix=fix)


#: Attributes of URDF elements that hold numbers (what yourdfpy reads with Python's ``float``).
_NUMERIC = {"origin": ("xyz", "rpy"), "axis": ("xyz",), "limit": ("lower", "upper", "effort", "velocity"),
            "mimic": ("multiplier", "offset"), "box": ("size",), "sphere": ("radius",), "cylinder": ("radius", "length"),
            "mesh": ("scale",), "mass": ("value",), "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
            "dynamics": ("damping", "friction"), "safety_controller": ("soft_lower_limit", "soft_upper_limit")}  # fmt: skip


def _check_numbers(root, path: str) -> None:
    """Every numeric attribute a strict decimal number (:mod:`mer_data.base.numbers`): Python's
    ``float`` would read ``1_0`` as 10 and full-width digits as digits."""
    for el in root.iter(*_NUMERIC):
        for attr in _NUMERIC[el.tag]:
            text = el.get(attr)
            if text is None:
                continue
            bad = next((p for p in text.split() if parse_number(p) is None), None if text.split() else text)
            if bad is not None:
                parent = el.getparent()
                raise MalformedURDFError(f"<{el.tag} {attr}={text[:60]!r}>: {bad[:40]!r} is not a decimal number", path=path,
                                         line=el.sourceline, element=f"<{parent.tag} name={parent.get('name')!r}>",
                                         fix="write plain decimal numbers (1.5, -2, 3e-4): no digit separators (1_0), "
                                             "no non-ASCII digits, no nan/inf")  # fmt: skip


def parse_xml(data: bytes, path: str):
    """Parse URDF bytes safely (DTDs and entities refused, size, line length, depth and element
    counts within :mod:`mer_data.base.limits`) → the ``<robot>`` element. Linear in the file."""
    check_size(data, path)
    _check_unsafe(data, path)
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
    except ValueError as exc:  # e.g. a str with an encoding declaration, or an unknown encoding
        raise MalformedURDFError(f"cannot parse the XML: {exc}", path=path, fix="save the URDF as UTF-8 XML") from None
    docinfo = root.getroottree().docinfo
    if docinfo.doctype or docinfo.internalDTD is not None or docinfo.externalDTD is not None:
        raise _unsafe("DOCTYPE", path, 1)
    if not isinstance(root.tag, str):
        raise MalformedURDFError("the document has no element", path=path, fix="a URDF's top element must be <robot name=...>")
    if root.tag == "mujoco":
        raise MalformedURDFError(
            "the root element is <mujoco>: this is an MJCF (MuJoCo) model, not a URDF",
            path=path,
            line=root.sourceline,
            fix="register it with `mer robots register NAME --mjcf FILE.xml` (or read it with mer_data.robots.mjcf.load_mjcf)",
        )
    if root.tag != "robot":
        raise MalformedURDFError(
            f"the root element is <{root.tag}>, not <robot>",
            path=path,
            line=root.sourceline,
            fix="a URDF's top element must be <robot name=...>",
        )
    _check_depth(root, path)
    _check_numbers(root, path)
    for tag in ("link", "joint"):
        n = sum(1 for _ in root.iterchildren(tag))
        if n > limit("MER_MAX_URDF_ELEMENTS"):
            msg, fix = too_big("MER_MAX_URDF_ELEMENTS", n)
            raise MalformedURDFError(msg, path=path, line=root.sourceline, element=f"<{tag}>", fix=fix)
    for el in root.iter():
        if not isinstance(el.tag, str):  # an entity reference or processing instruction
            if isinstance(el, etree._Entity):
                raise _unsafe("ENTITY", path, el.sourceline)
    return root


def check_links(root, path: str) -> dict[str, int]:
    """Link name → line, in file order; names present and unique."""
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
        link_lines[name] = el.sourceline
        _check_collisions(el, name, path)
    if not link_lines:
        raise MalformedURDFError("the robot has no <link>", path=path, line=root.sourceline)
    return link_lines


_SHAPES = {"box": (("size", 3),), "sphere": (("radius", 1),), "cylinder": (("radius", 1), ("length", 1))}


def _check_collisions(link, name: str, path: str) -> None:
    """The numbers of a link's collision origins and primitive shapes (read for key-point proposals)."""
    element = f"link '{name}'"
    for col in link.iterchildren("collision"):
        org = col.find("origin")
        if org is not None:
            _floats(org.get("xyz", "0 0 0"), 3, what="collision origin xyz", path=path, line=org.sourceline, element=element, bound=MAX_LENGTH_M)
            _floats(org.get("rpy", "0 0 0"), 3, what="collision origin rpy", path=path, line=org.sourceline, element=element)
        geo = col.find("geometry")
        if geo is None:
            continue
        for shape, attrs in _SHAPES.items():
            el = geo.find(shape)
            if el is None:
                continue
            for attr, n in attrs:
                _floats(el.get(attr), n, what=f"{shape} {attr}", path=path, line=el.sourceline, element=element, bound=MAX_LENGTH_M)


def check_joints(root, path: str, link_lines: dict[str, int]) -> tuple[list[CheckedJoint], dict[str, tuple[str, int]]]:
    """Every ``<joint>``: name, type, ends, numbers, axis, limits, mimic tag; one parent per link.

    Returns the joints in file order and ``joint → (mimicked joint, line)``.
    """
    links = list(link_lines)
    joints: list[CheckedJoint] = []
    seen: dict[str, int] = {}
    mimics: dict[str, tuple[str, int]] = {}
    child_of: dict[str, CheckedJoint] = {}
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
                    fix=did_you_mean(ref, links, "define the link or correct the name"),
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
            _floats(org.get("xyz", "0 0 0"), 3, what="origin xyz", path=path, line=org.sourceline, element=element, bound=MAX_LENGTH_M)
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
        joint = CheckedJoint(name, jtype, ends["parent"], ends["child"], line)
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

    for jname, (master, line) in mimics.items():
        if master not in seen:
            raise BrokenReferenceError(
                f"mimics joint '{master}', which does not exist",
                path=path,
                line=line,
                element=f"joint '{jname}'",
                fix=did_you_mean(master, list(seen), "correct the <mimic joint=...> name"),
            )
    return joints, mimics


def check_tree(link_lines: dict[str, int], joints: list[CheckedJoint], path: str) -> str:
    """The links and joints form one tree; returns its root link."""
    links = list(link_lines)
    child_of = {j.child: j for j in joints}
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
    return root_link


def _reachable(root: str, joints: list[CheckedJoint]) -> set[str]:
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


def did_you_mean(name: str, choices, otherwise: str) -> str:
    import difflib

    close = difflib.get_close_matches(name, list(choices), n=3, cutoff=0.6)
    if close:
        return "did you mean " + " or ".join(repr(c) for c in close) + "?"
    return otherwise
