"""A MuJoCo model (MJCF) of any registered robot, the one a motion tracker loads with mer's npz:
``mer robots export NAME --mjcf OUT.xml``.

The model is the robot's articulation (:mod:`mer_data.robots.articulation`), so its bodies and
joints are, in MuJoCo's order, exactly the npz's ``body_names`` / ``joint_names`` for mjlab:

- ``<worldbody>``: the root body with a free joint ``floating_base_joint``, then every body nested
  as in the description (fixed links merged into the body above), at its zero-pose offset;
- joints: a ``hinge`` (``slide`` for prismatic) per joint of the description, anchor and axis in
  the body frame, ``range`` where the description limits it (continuous joints unlimited); locked
  joints are joints too (the npz holds their locked values); a mimic joint follows its master by
  an ``<equality><joint>`` (``polycoef`` offset, multiplier);
- inertia: the description's, merged over fixed links (explicit ``<inertial>``; a massless body
  gets 1e-4 kg so MuJoCo compiles it);
- collision geometry: the robot's collision shapes (``collision.json``: primitives as MuJoCo
  primitives, mesh hulls as inline meshes), and where a body has none, the capsules mer fits
  along its links (a locked joint's body without shapes gets none); in ``group="3"`` (mjlab's and
  MuJoCo Menagerie's collision class, hidden in MuJoCo's viewer) on bodies with visual meshes, in
  group 0 (drawn) on the others;
- visual meshes (``group="2"``, no collisions, no mass): a URDF's ``<visual>`` mesh files found
  under the registered URDF's folder (STL and OBJ, MuJoCo's formats), referenced by absolute path.

The text is checked by compiling it with MuJoCo before it is written.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from lxml import etree

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import OutputError
from mer_data.robots.articulation import articulation, urdf_visual_meshes
from mer_data.robots.registry import Robot
from mer_data.robots.shapes import mesh_file

from .geometry import fitted_hulls, link_shapes

log = logging.getLogger(__name__)

__all__ = ["FREE_JOINT", "mjcf_tree", "compile_text", "mjcf_model", "write_mjcf"]

#: Name of the root body's free joint (mjlab's G1 calls it so).
FREE_JOINT = "floating_base_joint"
_MESH_SUFFIXES = (".stl", ".obj")
_MIN_MASS = 1e-4  # [kg] a massless body's mass: MuJoCo refuses moving bodies without one
_MIN_INERTIA = 1e-8  # [kg m^2]


def _num(a) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.ravel(a))


def _quat(r: np.ndarray) -> np.ndarray:
    """(3, 3) rotation → (4,) quaternion w, x, y, z (w >= 0)."""
    import torch

    from mer_data.kinematics.rotations import matrix_to_quat

    q = matrix_to_quat(torch.from_numpy(np.asarray(r, np.float64))).numpy()
    return -q if q[0] < 0 else q


def _pose(el: etree._Element, t: np.ndarray) -> None:
    """Set ``pos`` / ``quat`` of ``el`` from a (4, 4) transform (identity parts left out)."""
    if np.abs(t[:3, 3]).max() > 0:
        el.set("pos", _num(t[:3, 3]))
    if np.abs(t[:3, :3] - np.eye(3)).max() > 1e-12:
        el.set("quat", _num(_quat(t[:3, :3])))


def _inertial(body_el: etree._Element, mass: float, com: np.ndarray, inertia: np.ndarray) -> None:
    el = etree.SubElement(body_el, "inertial")
    if mass <= 0:
        el.set("pos", "0 0 0")
        el.set("mass", _num(_MIN_MASS))
        el.set("diaginertia", _num([_MIN_INERTIA] * 3))
        return
    w, v = np.linalg.eigh((inertia + inertia.T) / 2)
    if np.linalg.det(v) < 0:
        v[:, 2] = -v[:, 2]
    el.set("pos", _num(com))
    q = _quat(v)
    if np.abs(q - [1, 0, 0, 0]).max() > 1e-12:
        el.set("quat", _num(q))
    el.set("mass", _num(mass))
    el.set("diaginertia", _num(np.maximum(w, _MIN_INERTIA)))


def mjcf_tree(robot: Robot, *, body_meshes: dict[int, str] | None = None) -> etree._Element:
    """The ``<mujoco>`` element of ``robot`` (see the module docstring), not yet compiled.

    Args:
        body_meshes: body index -> a mesh file (path as written in ``file``) that draws the body, in
            its body frame; given, it replaces the URDF's visual meshes (the self-contained folder of
            :mod:`~mer_models.export.mjlab` writes one per body, referenced relatively).
    """
    art = articulation(robot)
    if "world" in art.body_names:
        raise OutputError(f"{robot.name!r} has a body named 'world', MuJoCo's name for the world body", element="mjcf",
                          fix="rename that link in the description and register the robot again")  # fmt: skip
    shapes = link_shapes(robot)
    fitted = fitted_hulls(robot, art, shapes)
    visuals = urdf_visual_meshes(robot.urdf_path) if art.source == "urdf" and body_meshes is None else {}
    folder = Path(robot.urdf_path).parent

    root = etree.Element("mujoco", model=robot.name)
    root.append(etree.Comment(f" {robot.name}: written by mer robots export from {Path(robot.urdf_path).name}; "
                              "bodies and joints in the order of its npz for mjlab "))  # fmt: skip
    etree.SubElement(root, "compiler", angle="radian", autolimits="true", balanceinertia="true", inertiafromgeom="false")
    asset = etree.SubElement(root, "asset")
    world = etree.SubElement(root, "worldbody")
    els: list[etree._Element] = []
    meshes = 0
    unused: list[str] = []  # visual mesh files not found (or not STL / OBJ)
    for b, body in enumerate(art.bodies):
        el = etree.SubElement(world if body.parent < 0 else els[body.parent], "body", name=body.name)
        _pose(el, body.origin)
        els.append(el)
        _inertial(el, body.mass, body.com, body.inertia)
        if body.parent < 0:
            etree.SubElement(el, "freejoint", name=FREE_JOINT)
        for j in body.joints:
            jt = art.joints[j]
            je = etree.SubElement(el, "joint", name=jt.name, type=jt.type, axis=_num(jt.axis))
            if np.abs(jt.pos).max() > 0:
                je.set("pos", _num(jt.pos))
            if jt.lower is not None and jt.upper is not None:
                je.set("range", _num([jt.lower, jt.upper]))
            else:
                je.set("limited", "false")
        collision: list[etree._Element] = []
        drawn = False
        for link, frame in zip(body.links, body.link_frames):
            for s in shapes.get(link, ()):
                t = frame @ s.origin
                g = etree.SubElement(el, "geom")
                collision.append(g)
                if s.type == "hull":
                    meshes += 1
                    name = f"collision_{meshes}"
                    v = np.asarray(s.vertices, np.float64) @ frame[:3, :3].T + frame[:3, 3]
                    etree.SubElement(asset, "mesh", name=name, vertex=_num(v))
                    g.set("type", "mesh")
                    g.set("mesh", name)
                else:
                    g.set("type", s.type)
                    size = np.asarray(s.size) / 2 if s.type == "box" else [s.radius] if s.type == "sphere" else [s.radius, s.length / 2]
                    g.set("size", _num(size))
                    _pose(g, t)
            for filename, t, scale in visuals.get(link, ()):
                f = mesh_file(filename, folder)
                if f is None or f.suffix.lower() not in _MESH_SUFFIXES:
                    unused.append(filename)
                    continue
                meshes += 1
                name = f"visual_{meshes}"
                m = etree.SubElement(asset, "mesh", name=name, file=str(f))
                if np.abs(scale - 1).max() > 0:
                    m.set("scale", _num(scale))
                g = etree.SubElement(el, "geom", type="mesh", mesh=name, group="2", contype="0", conaffinity="0")
                _pose(g, frame @ t)
                drawn = True
        if body_meshes is not None and b in body_meshes:
            meshes += 1
            etree.SubElement(asset, "mesh", name=f"visual_{meshes}", file=body_meshes[b])
            etree.SubElement(el, "geom", type="mesh", mesh=f"visual_{meshes}", group="2", contype="0", conaffinity="0")
            drawn = True
        if not collision:
            for v in fitted.get(b, []):
                meshes += 1
                name = f"collision_{meshes}"
                etree.SubElement(asset, "mesh", name=name, vertex=_num(v))
                collision.append(etree.SubElement(el, "geom", type="mesh", mesh=name))
        for g in collision:  # hidden behind the visual meshes where there are some, else drawn
            g.set("group", "3" if drawn else "0")
    mimics = [j for j in art.joints if j.mimic is not None]
    if mimics:
        eq = etree.SubElement(root, "equality")
        for j in mimics:
            master, mult, off = j.mimic
            etree.SubElement(eq, "joint", joint1=j.name, joint2=master, polycoef=_num([off, mult, 0, 0, 0]))
    if unused:
        log.warning("%s: %d visual mesh file(s) not found under %s or not STL/OBJ (%s%s); the model draws its collision "
                    "shapes there (put the meshes beside the registered URDF to use them)", robot.name, len(unused), folder,
                    ", ".join(Path(u).name for u in unused[:4]), ", ..." if len(unused) > 4 else "")  # fmt: skip
    if not len(asset):
        root.remove(asset)
    return root


def compile_text(text: str, robot: Robot, path: str | Path | None = None):
    """``text`` compiled by MuJoCo (its ``MjModel``; ``path``: the file it will be, whose folder
    relative mesh paths are read from).

    Raises:
        OutputError: MuJoCo refuses the model (its message).
    """
    import mujoco

    try:
        if path is None:
            return mujoco.MjModel.from_xml_string(text)
        return mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # noqa: BLE001 - MuJoCo's compiler error, reported as ours
        raise OutputError(f"MuJoCo refuses the model of {robot.name!r}: {exc}", element="mjcf", path=path,
                          fix="report it with the robot's description (the model is built from it)") from None  # fmt: skip


def mjcf_model(robot: Robot) -> str:
    """The MJCF text of ``robot`` (see the module docstring), compiled by MuJoCo once to check it.

    Raises:
        OutputError: MuJoCo refuses the model (its message).
    """
    text = etree.tostring(mjcf_tree(robot), pretty_print=True, encoding="unicode")
    compile_text(text, robot)
    return text


def write_mjcf(path: str | Path, robot: Robot) -> Path:
    """Write :func:`mjcf_model` of ``robot`` to ``path`` (atomically)."""
    text = mjcf_model(robot)
    out = atomic_write(path, text.encode())
    log.info("wrote the MuJoCo model of %s to %s", robot.name, out)
    return out
