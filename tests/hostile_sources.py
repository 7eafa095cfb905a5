"""Hostile robots, meshes, motion capture and outputs (issue 51), generated in code for the tests
and ``tools/hostile_robots.py``: MJCF expansion bombs and files outside the model's folder, zip-bomb
meshes, BVH and CSV amplification, numbers Python accepts and the formats do not, duplicate keys.

Each writer puts its files under the folder given and returns the path to hand to mer. Sizes are
parameters, so the tests use small ones (a regression fails on a limit, it does not exhaust memory).
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

__all__ = ["mjcf", "replicate_bomb", "flexcomp_bomb", "jointed_replicate", "many_geoms", "outside_mjcf",
           "model_asset", "urdf", "zip_mesh", "bvh_text", "zero_channel_bvh", "slow_bvh", "big_bvh", "g1_csv",
           "odd_number_urdf", "duplicate_keys", "write_stl", "gzip_bytes"]  # fmt: skip

BODY = '<body name="torso"><freejoint/><geom size=".1"/>{}</body>'


def mjcf(folder: Path, inner: str, *, head: str = "", name: str = "robot.xml") -> Path:
    """An MJCF ``<mujoco>{head}<worldbody>{inner}</worldbody></mujoco>`` in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    p.write_text(f"<mujoco>{head}<worldbody>{inner}</worldbody></mujoco>\n")
    return p


def replicate_bomb(folder: Path, count: int = 1000, depth: int = 3) -> Path:
    """``depth`` nested ``<replicate count>`` around one geom (573 bytes ask for count**depth geoms)."""
    inner = '<geom size=".01"/>'
    for _ in range(depth):
        inner = f'<replicate count="{count}" offset="0.001 0 0">{inner}</replicate>'
    return mjcf(folder, BODY.format(inner))


def flexcomp_bomb(folder: Path, count: str = "1000 1000 100") -> Path:
    """A ``<flexcomp type="grid">`` of ``count`` points."""
    return mjcf(folder, BODY.format("") + f'<flexcomp name="f" type="grid" count="{count}" spacing=".01 .01 .01"/>')


def jointed_replicate(folder: Path, count: int = 300) -> Path:
    """Two nested replicates of a body with a hinge joint: ``count**2`` bodies and joints."""
    body = '<body><joint type="hinge"/><geom size=".01"/></body>'
    inner = f'<replicate count="{count}" offset=".01 0 0"><replicate count="{count}" offset="0 .01 0">{body}</replicate></replicate>'
    return mjcf(folder, BODY.format(inner))


def many_geoms(folder: Path, n: int = 10_000) -> Path:
    """One body with ``n`` geoms written out (no replicate): mer's own loops over them."""
    geoms = "".join(f'<geom size=".01" pos="{i * 1e-3:.3f} 0 0"/>' for i in range(n))
    return mjcf(folder, BODY.format(geoms))


def outside_mjcf(folder: Path, kind: str, outside: Path) -> Path:
    """An MJCF reading a file outside ``folder`` (``outside``: a folder beside it holding ``secret.xml``
    and ``secret.stl``): ``kind`` is include-abs, include-up, include-passwd, meshdir-abs, mesh-abs,
    mesh-up, or mesh-link (a link inside the folder to the outside mesh)."""
    outside.mkdir(parents=True, exist_ok=True)
    (outside / "secret.xml").write_text('<mujoco><worldbody><body name="SECRET"><joint type="hinge"/><geom size=".1"/>'
                                        "</body></worldbody></mujoco>\n")  # fmt: skip
    write_stl(outside / "secret.stl", scale=7.125)
    folder.mkdir(parents=True, exist_ok=True)
    mesh = '<geom type="mesh" mesh="m"/>'
    up = Path("..") / outside.name
    if kind == "include-abs":
        return mjcf(folder, BODY.format(""), head=f'<include file="{outside / "secret.xml"}"/>')
    if kind == "include-up":
        return mjcf(folder, BODY.format(""), head=f'<include file="{up / "secret.xml"}"/>')
    if kind == "include-passwd":
        return mjcf(folder, BODY.format(""), head='<include file="/etc/passwd"/>')
    if kind == "meshdir-abs":
        return mjcf(folder, BODY.format(mesh), head=f'<compiler meshdir="{outside}"/><asset><mesh name="m" file="secret.stl"/></asset>')
    if kind == "mesh-abs":
        return mjcf(folder, BODY.format(mesh), head=f'<asset><mesh name="m" file="{outside / "secret.stl"}"/></asset>')
    if kind == "mesh-up":
        return mjcf(folder, BODY.format(mesh), head=f'<asset><mesh name="m" file="{up / "secret.stl"}"/></asset>')
    if kind == "mesh-link":
        (folder / "m.stl").symlink_to(outside / "secret.stl")
        return mjcf(folder, BODY.format(mesh), head='<asset><mesh name="m" file="m.stl"/></asset>')
    raise ValueError(kind)


def write_stl(path: Path, scale: float = 1.0) -> Path:
    """An ASCII STL tetrahedron of size ``scale`` [m]."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    lines = ["solid t"]
    for f in faces:
        lines += ["facet normal 0 0 0", "outer loop", *(f"vertex {x:g} {y:g} {z:g}" for x, y, z in v[list(f)]), "endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid t"]) + "\n")
    return path


def model_asset(folder: Path, cwd: Path, *, outside: bool = False) -> Path:
    """An MJCF attaching ``<asset><model file="sub.xml">`` (joint ``own_joint``); ``cwd`` holds another
    ``sub.xml`` with the same body and joint ``CWD_JOINT`` (MuJoCo, given the text, reads the working
    directory's). ``outside``: the model file is ``../<cwd>/sub.xml``, outside the folder."""
    sub = '<mujoco><worldbody><body name="s"><joint name="{}" type="hinge"/><geom size=".1"/></body></worldbody></mujoco>\n'
    folder.mkdir(parents=True, exist_ok=True)
    cwd.mkdir(parents=True, exist_ok=True)
    (folder / "sub.xml").write_text(sub.format("own_joint"))
    (cwd / "sub.xml").write_text(sub.format("CWD_JOINT"))
    name = f"../{cwd.name}/sub.xml" if outside else "sub.xml"
    return mjcf(folder, BODY.format('<attach model="sub" body="s" prefix="p_"/>'), head=f'<asset><model name="sub" file="{name}"/></asset>')


def urdf(folder: Path, *, mesh: str | None = None, limit: str = "-1", origin: str = "0 0 0.1", name: str = "robot.urdf") -> Path:
    """A two-link URDF; ``mesh``: the collision mesh file of the first link; ``limit``/``origin``: texts as written."""
    folder.mkdir(parents=True, exist_ok=True)
    col = f'<collision><geometry><mesh filename="{mesh}"/></geometry></collision>' if mesh else ""
    p = folder / name
    p.write_text(f'<robot name="r"><link name="a">{col}</link><link name="b"/><joint name="j" type="revolute">'
                 f'<origin xyz="{origin}"/><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
                 f'<limit lower="{limit}" upper="1" effort="1" velocity="1"/></joint></robot>\n')  # fmt: skip
    return p


def zip_mesh(path: Path, inflated: int = 1 << 30) -> Path:
    """A zip holding one ``m.stl`` of ``inflated`` zero bytes (deflate: about 1 MB per GB), streamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z, z.open("m.stl", "w", force_zip64=True) as f:
        block = bytes(1 << 20)
        for _ in range(max(inflated >> 20, 1)):
            f.write(block)
    return path


def gzip_bytes(n: int) -> bytes:
    """``n`` zero bytes as one gzip member, streamed."""
    z = zlib.compressobj(9, zlib.DEFLATED, 31)
    block = bytes(1 << 20)
    return b"".join(z.compress(block) for _ in range(max(n >> 20, 1))) + z.flush()


def bvh_text(frames: int = 40, fps: float = 30.0, seed: int = 0) -> str:
    """A valid human BVH (tests/bvh_factory.py: LAFAN1 names, Y up, centimetres)."""
    from bvh_factory import human_definition, write_bvh

    return write_bvh(human_definition(np.random.default_rng(seed), frames), fps=fps)


def zero_channel_bvh(path: Path, extra: int = 960, frames: int = 50_000) -> Path:
    """A BVH whose root carries ``extra`` joints with ``CHANNELS 0`` (no column each, a joint of the
    kinematics each) and ``frames`` frames: a small file, a large forward kinematics."""
    text = bvh_text(2)
    head, motion = text.split("MOTION", 1)
    first = head.index("{", head.index("ROOT")) + 1
    at = head.index("\n", head.index("CHANNELS", first)) + 1
    joints = "".join(f"JOINT z{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\nEnd Site\n{{\nOFFSET 0 1 0\n}}\n}}\n" for i in range(extra // 2))
    lines = motion.strip().split("\n")
    row = lines[2]
    path.write_text(head[:at] + joints + head[at:] + f"MOTION\nFrames: {frames}\n{lines[1]}\n" + (row + "\n") * frames)
    return path


def slow_bvh(path: Path, frame_time: str = "10", frames: int = 130) -> Path:
    """A valid BVH with ``Frame Time: frame_time`` [s] (0.1 Hz: 300 output frames per frame at 30 Hz)."""
    text = bvh_text(frames)
    lines = text.split("\n")
    k = next(i for i, line in enumerate(lines) if line.lower().startswith("frame time"))
    lines[k] = f"Frame Time: {frame_time}"
    path.write_text("\n".join(lines))
    return path


def big_bvh(path: Path, mib: int = 30, bad_last: bool = True) -> Path:
    """A BVH of about ``mib`` MiB (its frames repeated); ``bad_last``: the last value is ``nan``, so
    the whole table is read before the file is refused (the memory of reading it is measured)."""
    text = bvh_text(4)
    head, motion = text.split("MOTION", 1)
    lines = motion.strip().split("\n")
    row = lines[2] + "\n"
    n = max((mib << 20) // len(row), 1)
    with open(path, "w") as f:
        f.write(head + f"MOTION\nFrames: {n}\n{lines[1]}\n")
        for _ in range(n - 1):
            f.write(row)
        f.write(row.rsplit(" ", 1)[0] + (" nan\n" if bad_last else " 0\n"))
    return path


def g1_csv(path: Path, frames: int = 60, cell: tuple[int, int, str] | None = None) -> Path:
    """A valid G1 motion CSV (LAFAN1 layout, synthetic motion); ``cell``: (row, column, text) replaced."""
    from mer_data.motion.lafan1 import write_lafan1_csv
    from mer_data.robots.registry import load_robot
    from mer_data.synthesis.motion import synthesize

    g1 = load_robot("g1")
    write_lafan1_csv(path, synthesize(g1.skeleton, frames / 30.0, seed=3).motion, robot=g1)
    if cell is not None:
        rows = path.read_text().split("\n")
        cells = rows[cell[0]].split(",")
        cells[cell[1]] = cell[2]
        rows[cell[0]] = ",".join(cells)
        path.write_text("\n".join(rows), encoding="utf-8")
    return path


def odd_number_urdf(folder: Path, text: str, where: str = "limit") -> Path:
    """A URDF with ``text`` (``-1_0``, full-width ``１``...) as a joint limit or origin coordinate."""
    return urdf(folder, limit=text) if where == "limit" else urdf(folder, origin=f"0 0 {text}")


def duplicate_keys(path: Path, kind: str = "json") -> Path:
    """A key-point file naming ``left_ankle`` twice (the second silently won before)."""
    if kind == "json":
        path.write_text('{"left_ankle": "LeftFoot", "left_ankle": "RightFoot"}\n')
    else:
        path.write_text("left_ankle: LeftFoot\nleft_ankle: RightFoot\n")
    return path
