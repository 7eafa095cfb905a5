"""Compiling an MJCF with MuJoCo, leaving out what cannot be read (textures, skins, height fields,
unreadable meshes and the geoms that use them): :func:`compile_mjcf` → :class:`CompiledMjcf`.

The XML is read, confined and counted by :mod:`.mjcf_xml` first: MuJoCo sees only files inside the
model's folder and a model whose expansion fits ``MER_MAX_MJCF_ELEMENTS``. The conventions of the
tree built from the compiled model are in :mod:`.mjcf`.
"""

from __future__ import annotations

import logging
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from lxml import etree

from mer_data.base.errors import MalformedURDFError
from mer_data.base.limits import limit

from .mjcf_xml import expand_mjcf

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

log = logging.getLogger(__name__)

__all__ = ["CompiledMjcf", "compile_mjcf", "FIX_MJCF"]

FIX_MJCF = "check that MuJoCo loads it: python -c \"import mujoco; mujoco.MjModel.from_xml_path('FILE')\""
_OPEN_ERROR = re.compile(r"[Ee]rror opening file '([^']*)'")


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
    if st.st_size > limit("MER_MAX_MESH_BYTES"):
        return f"larger than MER_MAX_MESH_BYTES ({limit('MER_MAX_MESH_BYTES') >> 20} MiB)"
    return None


def _some(names: list[str], n: int = 8) -> str:
    """At most ``n`` names, then how many more."""
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def _collides(g, group_mode: bool) -> bool:
    return int(g.group) == 3 if group_mode else bool(int(g.contype) or int(g.conaffinity))


def compile_mjcf(path: str | Path, *, geometry: bool = True, allowed: tuple[Path, ...] = ()) -> CompiledMjcf:
    """Compile an MJCF with MuJoCo, leaving out what cannot be read.

    Args:
        path: the main ``.xml`` (``<include>`` files are read relative to its folder).
        geometry: False drops every mesh (and mesh geom) unread: kinematics only, no warnings
            (the registry's reload; collision shapes are in the robot's ``collision.json``).
        allowed: folders besides the model's own where its files may lie (``mer view --mesh-dir``);
            any file elsewhere is refused (:mod:`~mer_data.robots.mjcf_xml`).

    Raises:
        MalformedURDFError: the file cannot be read or MuJoCo refuses it (its message, and the fix).
    """
    import mujoco

    path = Path(path)
    expanded = expand_mjcf(path, allowed=allowed, assets=geometry)  # files confined, expansion counted before MuJoCo runs
    lines = expanded.lines
    text = etree.tostring(expanded.root, encoding="unicode")
    try:
        spec = mujoco.MjSpec.from_string(text)
    except Exception as exc:  # noqa: BLE001 - MuJoCo's parser error, reported as ours
        raise MalformedURDFError(f"MuJoCo cannot parse the MJCF: {exc}", path=path, fix=FIX_MJCF.replace("FILE", str(path))) from None
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
    # spec.geoms walks the whole tree on every access (quadratic over a loop): read once, kept current
    geoms = list(spec.geoms)
    robot_geoms = [g for g in geoms if g.parent is not None and g.parent.name != "world"]  # not the floor
    group_mode = not any(_collides(g, False) for g in robot_geoms)
    hfields = {h.name for h in spec.hfields}
    terrain = [g for g in geoms if g.type == mujoco.mjtGeom.mjGEOM_HFIELD or (g.hfieldname and g.hfieldname in hfields)]
    for g in terrain:
        spec.delete(g)
    for h in list(spec.hfields):
        spec.delete(h)
    mesh_geoms = [g for g in geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH]  # (height-field geoms are not mesh geoms)

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
        if not names:
            return
        keep = []
        for g in mesh_geoms:
            if g.meshname in names:
                body = g.parent.name or f"body{g.parent.id}"
                (lost if _collides(g, group_mode) else visual).setdefault(body, []).append(g.meshname)
                spec.delete(g)
            else:
                keep.append(g)
        mesh_geoms[:] = keep
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
                                         fix=FIX_MJCF.replace("FILE", str(path))) from None  # fmt: skip
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
