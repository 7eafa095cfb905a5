"""An mjlab-ready robot in one folder: ``mer robots export NAME --mjlab DIR``.

``DIR`` holds (and needs nothing outside it; moved elsewhere, it still loads)::

    pyproject.toml          # `pip install -e DIR` registers the tracking task with mjlab (entry point)
    mer_<name>/__init__.py  # the mjlab entity config and the task `Mjlab-Tracking-Flat-Mer-<Name>`
    mer_<name>/<name>.xml   # the MJCF: mer's model of the robot (:mod:`.mjcf`) plus what a tracker needs
    mer_<name>/meshes/      # one STL per body that has visual meshes, in its body frame
    mer_<name>/motions/     # the npz files given with --motion (checked against the robot by name)
    mer_<name>/LICENSE*     # the description's licence files; README.md: the numbers mer chose

The MJCF adds to :func:`~.mjcf.mjcf_tree`: a ``<position>`` actuator on every joint that is not a
mimic joint (gains, effort limit, armature: :mod:`.mjlab_drive`), joint armature / damping /
friction loss, contact spheres on the soles named ``<side>_foot<k>_collision`` (:mod:`.mjlab_body`;
the feet's own shapes stay as non-colliding geoms), every other collision geom named
``<body>_<k>_collision``, ``<contact><exclude>`` for each parent/child body pair and each pair
whose geometry touches at the initial pose (found by MuJoCo), the root body at the standing
height (qpos0 on the floor, not in it), an ``imu`` site on the root body with
the ``imu_ang_vel`` gyro and ``imu_lin_vel`` velocimeter that mjlab's tracking observations read.
"""

from __future__ import annotations

import logging
import re
import shutil
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lxml import etree

from mer_data.base.atomic import atomic_dir
from mer_data.base.errors import MerError
from mer_data.robots.articulation import articulation
from mer_data.robots.registry import Robot

from .geometry import robot_meshes
from .mjcf import _num, compile_text, mjcf_tree
from .mjlab_body import SOLE_RADIUS, Standing, standing
from .mjlab_drive import DAMPING_RATIO, NATURAL_FREQ, Drive, given_drives, joint_drives
from .mjlab_module import module_text, pyproject_text, readme_text
from .npz_read import read_npz

log = logging.getLogger(__name__)

__all__ = ["MjlabExport", "export_mjlab", "package_name", "task_id"]

_LICENCE = re.compile(r"^(LICEN[CS]E|COPYING|NOTICE)", re.IGNORECASE)
#: Friction of the sole spheres (mjlab's G1 feet).
FOOT_FRICTION = 0.6


def package_name(robot: str) -> str:
    """The Python package of ``robot``'s folder: ``mer_<name>``."""
    return "mer_" + re.sub(r"\W", "_", robot)


def task_id(robot: str) -> str:
    """The tracking task's id: ``Mjlab-Tracking-Flat-Mer-<Name>``."""
    return "Mjlab-Tracking-Flat-Mer-" + "-".join(p.capitalize() for p in re.split(r"[\W_]+", robot) if p)


@dataclass(frozen=True)
class MjlabExport:
    """What :func:`export_mjlab` wrote: ``folder``, ``package`` (its Python package folder), ``xml``,
    ``drives``, ``standing``, ``meshes`` (files), ``licences`` (files copied), ``motions``,
    ``excluded`` (body pairs), ``task`` (the task id)."""

    folder: Path
    package: Path
    xml: Path
    drives: tuple[Drive, ...]
    standing: Standing
    meshes: tuple[str, ...]
    licences: tuple[str, ...]
    motions: tuple[str, ...]
    excluded: tuple[tuple[str, str], ...]
    task: str


def _stl(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    """A binary STL of triangles ``v[f]`` (body frame) [m]."""
    tri = v[f].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    rec = np.zeros(len(f), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    rec["n"], rec["v"] = n, tri
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(f)) + rec.tobytes())


def _init_joints(robot: Robot) -> dict[str, float]:
    """Initial joint values: 0 inside the soft range (90 % of the limits, mjlab's G1), else its
    nearest end; locked joints at their value; mimic joints from their master."""
    art = articulation(robot)
    out: dict[str, float] = {}
    for j in art.joints:
        if j.held is not None:
            out[j.name] = float(j.held)
        elif j.lower is not None and j.upper is not None:
            c, h = (j.lower + j.upper) / 2, 0.45 * (j.upper - j.lower)
            out[j.name] = float(np.clip(0.0, c - h, c + h))
        else:
            out[j.name] = 0.0
    for j in art.joints:
        if j.mimic is not None:
            out[j.name] = j.mimic[1] * out[j.mimic[0]] + j.mimic[2]
    return out


def _dress(root: etree._Element, robot: Robot, st: Standing, drives: list[Drive]) -> None:
    """Add to mer's MJCF what a tracker needs (module docstring), in place."""
    art = articulation(robot)
    els = {el.get("name"): el for el in root.iter("body")}
    foot = {b for bodies in st.foot_bodies.values() for b in bodies}
    for b, body in enumerate(art.bodies):
        el = els[body.name]
        k = 0
        for g in el.findall("geom"):
            if g.get("contype") == "0":
                continue
            k += 1
            if b in foot:  # the foot's own shapes: drawn, not touching (the sole spheres do)
                g.set("name", f"{body.name}_{k}_shape")
                g.set("contype", "0")
                g.set("conaffinity", "0")
            else:
                g.set("name", f"{body.name}_{k}_collision")
    count = {"left": 0, "right": 0}
    for s in st.spheres:
        count[s.side] += 1
        etree.SubElement(els[art.bodies[s.body].name], "geom", name=f"{s.side}_foot{count[s.side]}_collision", type="sphere",
                         size=_num(SOLE_RADIUS), pos=_num(s.pos), group="3", condim="3", priority="1",
                         friction=_num([FOOT_FRICTION, 0.005, 0.0001]), rgba="0.9 0.3 0.2 0.6")  # fmt: skip
    by_name = {d.joint: d for d in drives}
    for je in root.iter("joint"):
        d = by_name.get(je.get("name"))
        if d is None:
            continue
        je.set("armature", _num(d.armature))
        if d.damping:
            je.set("damping", _num(d.damping))
        if d.frictionloss:
            je.set("frictionloss", _num(d.frictionloss))
    rootel = els[art.bodies[0].name]
    rootel.set("pos", _num([0.0, 0.0, st.height]))  # standing at qpos0 (mjlab builds its data there)
    etree.SubElement(rootel, "site", name="imu", pos="0 0 0", size="0.01", group="5")
    act = etree.SubElement(root, "actuator")
    for d in drives:
        etree.SubElement(act, "position", name=d.joint, joint=d.joint, kp=_num(d.kp), kv=_num(d.kd), ctrllimited="false",
                         forcelimited="true", forcerange=_num([-d.effort, d.effort]))  # fmt: skip
    sensor = etree.SubElement(root, "sensor")
    etree.SubElement(sensor, "gyro", name="imu_ang_vel", site="imu")
    etree.SubElement(sensor, "velocimeter", name="imu_lin_vel", site="imu")


def _touching(xml: Path, robot: Robot, st: Standing, init: dict[str, float]) -> list[tuple[str, str]]:
    """Body pairs (parent/child, and any whose geoms touch at the initial pose, by MuJoCo's collision
    detection) to exclude from contacts, each as (first, second) in body order."""
    import mujoco

    art = articulation(robot)
    pairs = {(art.bodies[b.parent].name, b.name) for b in art.bodies if b.parent >= 0}
    m = compile_text("", robot, xml)
    d = mujoco.MjData(m)
    d.qpos[:3] = [0.0, 0.0, st.height + 0.05]
    d.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    for name, v in init.items():
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = v
    mujoco.mj_forward(m, d)
    order = {b.name: i for i, b in enumerate(art.bodies)}
    for c in d.contact[: d.ncon]:
        a, b = (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) for g in (c.geom1, c.geom2))
        if a != b and a in order and b in order:
            pairs.add(tuple(sorted((a, b), key=order.__getitem__)))
    return sorted(pairs, key=lambda p: (order[p[0]], order[p[1]]))


def _licences(robot: Robot, mesh_dir: Path | None) -> list[Path]:
    dirs = [Path(robot.urdf_path).parent] + ([mesh_dir, mesh_dir.parent] if mesh_dir is not None else [])
    seen: dict[str, Path] = {}
    for d in dirs:
        for f in sorted(d.iterdir()) if d.is_dir() else ():
            if f.is_file() and _LICENCE.match(f.name) and f.name not in seen:
                seen[f.name] = f
    return list(seen.values())


def export_mjlab(robot: Robot, folder: str | Path, *, mesh_dir: str | Path | None = None, motions: list[str | Path] = (),
                 replace: bool = False) -> MjlabExport:  # fmt: skip
    """Write ``robot``'s mjlab folder (module docstring) to ``folder``, atomically.

    Args:
        mesh_dir: a folder with the description's mesh files, besides its own (as ``mer view --meshes``).
        motions: npz files for mjlab to copy in; each is read back and refused unless its names are
            this robot's in mjlab's order.
        replace: replace an existing ``folder`` (else it is refused).

    Raises:
        MerError: ``folder`` exists, a motion is another robot's, MuJoCo refuses the model.
    """
    folder = Path(folder)
    if folder.exists() and not replace:
        raise MerError(f"{folder} exists", path=folder, fix="give a new folder, or --force to replace it")
    for m in motions:  # checked before anything is written
        read_npz(m, robot, "mjlab")
    mesh_dir = Path(mesh_dir) if mesh_dir is not None else None
    art = articulation(robot)
    st = standing(robot, art)
    drives = joint_drives(art, given_drives(robot.urdf_path, art.source), st.world, st.soles)
    init = _init_joints(robot)
    pkg = package_name(robot.name)
    visual = [m for m in robot_meshes(robot, mesh_dir=mesh_dir, visual=True, max_faces=None).bodies if m.source == "mesh"]
    files = {m.body: f"meshes/{m.body:03d}_{re.sub(r'[^A-Za-z0-9_.-]', '_', art.bodies[m.body].name)}.stl" for m in visual}
    licences = _licences(robot, mesh_dir)
    if not licences:
        log.warning("%s: no licence file beside its description%s; add the description's licence (%s) to %s",
                    robot.name, "" if mesh_dir is None else f" or its meshes ({mesh_dir})", robot.card.license or "unknown",
                    folder)  # fmt: skip
    out: dict = {}

    def write(tmp: Path) -> None:
        p = tmp / pkg
        (p / "meshes").mkdir(parents=True)
        for m in visual:
            _stl(p / files[m.body], m.vertices, m.faces)
        root = mjcf_tree(robot, body_meshes=files)
        _dress(root, robot, st, drives)
        xml = p / f"{robot.name}.xml"
        xml.write_text(etree.tostring(root, pretty_print=True, encoding="unicode"))
        pairs = _touching(xml, robot, st, init)
        contact = etree.Element("contact")
        for a, b in pairs:
            etree.SubElement(contact, "exclude", body1=a, body2=b)
        root.insert(list(root).index(root.find("actuator")), contact)
        xml.write_text(etree.tostring(root, pretty_print=True, encoding="unicode"))
        compile_text("", robot, xml)
        for f in licences:
            shutil.copyfile(f, p / f.name)
        if motions:
            (p / "motions").mkdir()
            for m in motions:
                shutil.copyfile(m, p / "motions" / Path(m).name)
        (p / "__init__.py").write_text(module_text(robot, art, st, init, pkg, task_id(robot.name)))
        (p / "README.md").write_text(readme_text(robot, art, st, drives, pairs, NATURAL_FREQ, DAMPING_RATIO, SOLE_RADIUS,
                                                 [f.name for f in licences]))  # fmt: skip
        (tmp / "pyproject.toml").write_text(pyproject_text(pkg, robot.name))
        out["pairs"] = pairs

    atomic_dir(folder, write, replace=replace)
    pkg_dir = folder / pkg
    return MjlabExport(folder, pkg_dir, pkg_dir / f"{robot.name}.xml", tuple(drives), st, tuple(files.values()),
                       tuple(f.name for f in licences), tuple(Path(m).name for m in motions), tuple(out["pairs"]),
                       task_id(robot.name))  # fmt: skip
