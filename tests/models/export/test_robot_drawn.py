"""The robot itself on screen (issue 39): what draws a robot (its visual meshes, else its collision
shapes) sits where MuJoCo puts the same meshes, and a ``--video`` frame shows the robot's meshes --
a check that fails when they are not drawn.

The robot with meshes is mjlab's G1 MJCF from ``../shared/robots-mjcf`` registered into the test's
own MER_HOME (skipped where the folder is absent); its meshes are put beside the registered
description, where ``mer robots register`` says to put them.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.articulation import articulation
from mer_data.robots.register import register_robot
from mer_data.robots.registry import load_robot
from mer_models.cli import main
from mer_models.export.geometry import decimate, robot_meshes
from mer_models.export.video import write_video
from mer_models.export.writers import TargetMotion
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo places the meshes (pip install -e .)")


@pytest.fixture
def g1_mjcf(shared_dir: Path) -> Path:
    d = shared_dir / "robots-mjcf" / "mjlab_unitree_g1"
    if not (d / "g1.xml").is_file() or not (d / "assets").is_dir():
        pytest.skip(f"mjlab's G1 MJCF with its meshes is absent from {d}")
    return d


@pytest.fixture
def g1m(g1_mjcf: Path):
    """mjlab's G1 registered as ``g1m``, its meshes copied beside the registered file."""
    robot = register_robot("g1m", g1_mjcf / "g1.xml").robot
    shutil.copytree(g1_mjcf / "assets", robot.folder / "assets")
    return load_robot("g1m")


def _motion(skel, frames: int, seed: int = 3) -> TargetMotion:
    m = synthetic_motion(skel, frames, seed=seed)
    return TargetMotion(skel, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())


def _quat_matrix(q) -> np.ndarray:
    return quat_to_matrix(torch.as_tensor(np.asarray(q, np.float64))).numpy()


def test_mjcf_meshes_sit_where_mujoco_puts_them(g1m, g1_mjcf):
    """Every body's mesh vertices, moved by mer's body poses, equal MuJoCo's geom poses applied to
    its compiled mesh vertices, at a pose of a synthetic motion (the original file, compiled as is)."""
    meshes = robot_meshes(g1m, max_faces=None)  # every face: the vertices are MuJoCo's own
    assert meshes.kind == "mesh" and not meshes.missing and meshes.num_faces == 393270
    art = articulation(g1m)
    motion = _motion(g1m.skeleton, 3)
    pos, rot = art.body_poses(*motion.forward_kinematics())
    model = mujoco.MjModel.from_xml_path(str(g1_mjcf / "g1.xml"))
    data = mujoco.MjData(model)
    f = 2
    data.qpos[:3] = pos[f, 0]
    w = torch.from_numpy(rot[f, 0])
    from mer_data.kinematics.rotations import matrix_to_quat

    data.qpos[3:7] = matrix_to_quat(w).numpy()
    values = art.joint_values(motion.q)[f]
    for j, joint in enumerate(art.joints):
        data.qpos[int(model.joint(joint.name).qposadr[0])] = values[j]
    mujoco.mj_kinematics(model, data)
    err, checked = 0.0, 0
    for bm in meshes.bodies:
        name = meshes.body_names[bm.body]
        ours = bm.vertices @ rot[f, bm.body].T + pos[f, bm.body]
        bid = model.body(name).id
        theirs = []
        for g in range(model.ngeom):
            if (
                int(model.geom_bodyid[g]) == bid
                and int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_MESH)
                and int(model.geom_group[g]) == 2
            ):
                mid = int(model.geom_dataid[g])
                v = model.mesh_vert[model.mesh_vertadr[mid] : model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
                theirs.append(v @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g])
        theirs = np.concatenate(theirs)
        assert ours.shape == theirs.shape, name
        err = max(err, float(np.abs(ours - theirs).max()))
        checked += 1
    assert checked == len(meshes.bodies) >= 25
    assert err < 1e-6, err


def test_without_meshes_a_robot_draws_its_collision_shapes(tmp_path, g1_mjcf):
    """Registered without its meshes: every body with shapes draws them (capsules, spheres); a URDF
    built-in without its shipped meshes finds the upstream ones in a folder given by name
    (``mesh_dir``), by file name."""
    bare = register_robot("g1bare", g1_mjcf / "g1.xml").robot
    m = robot_meshes(bare)
    assert m.kind == "collision" and m.missing and all(b.source == "collision" for b in m.bodies)
    assert len(m.bodies) >= 20
    found = robot_meshes(bare, mesh_dir=g1_mjcf / "assets", max_faces=4000)
    assert found.kind == "mesh" and not found.missing and found.num_faces <= 4000 + 60 * len(found.bodies)
    # the built-in G1's folder without its shipped meshes (visual/): its compact hulls, and the
    # upstream meshes given by folder are found by file name (the shipped STLs keep upstream's names)
    g1 = load_robot("g1")
    copy = tmp_path / "g1"
    shutil.copytree(g1.folder, copy, ignore=shutil.ignore_patterns("visual"))
    g1 = dataclasses.replace(g1, urdf_path=copy / g1.urdf_path.name)
    bare = robot_meshes(g1)
    assert bare.kind == "collision" and len(bare.missing) == 35
    g1_meshes = robot_meshes(g1, mesh_dir=g1_mjcf / "assets")
    assert g1_meshes.kind == "mesh" and not g1_meshes.missing


def test_decimate_keeps_the_budget_and_the_shape():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.1)  # 20480 faces
    v, f = decimate(sphere.vertices, sphere.faces, 500)
    assert 100 < len(f) <= 500
    r = np.linalg.norm(v, axis=1)
    assert np.abs(r - 0.1).max() < 0.01  # still a 10 cm sphere
    v2, f2 = decimate(sphere.vertices, sphere.faces, 10**6)  # within the budget: as it is
    assert len(f2) == len(sphere.faces)


# ---- the video ---------------------------------------------------------------------------------------
def _mesh_pixels(rgb: np.ndarray) -> int:
    """Pixels of the meshes' colour (a light blue: mer_models.export.video.MESH_RGB, shaded) in the
    right panel, where the robot stands."""
    a = rgb[:, rgb.shape[1] // 2 :].astype(int)
    return int(((a[..., 2] - a[..., 0] > 50) & (a[..., 2] - a[..., 1] > 20) & (a[..., 2] > 100)).sum())


def _shape_pixels(rgb: np.ndarray) -> int:
    """Pixels of the collision shapes' colour (amber: COLLISION_RGB, shaded) in the right panel."""
    a = rgb[:, rgb.shape[1] // 2 :].astype(int)
    return int(((a[..., 0] - a[..., 2] > 60) & (a[..., 1] - a[..., 2] > 20) & (a[..., 0] > 100)).sum())


def _frame(path: Path, i: int) -> np.ndarray:
    with Image.open(path) as im:
        im.seek(i)
        return np.asarray(im.convert("RGB"))


def test_a_video_frame_shows_the_robots_meshes_and_the_check_fails_without_them(tmp_path, g1m):
    motion = _motion(g1m.skeleton, 12)
    pos, _ = motion.forward_kinematics()
    key = [j for j in g1m.skeleton.keypoints.values() if j >= 0]
    ref = {"reference_points": pos[:, key], "reference_nodes": pos, "reference_skeleton": g1m.skeleton}
    drawn = write_video(tmp_path / "m.gif", motion, fps=30.0, **ref)  # meshes found beside the registered file
    frame = _frame(drawn, 6)
    assert _mesh_pixels(frame) > 3000, _mesh_pixels(frame)  # the robot's meshes, where it stands
    assert _mesh_pixels(frame[:, : frame.shape[1] // 2]) < 50  # the reference panel has none
    # the same motion with the meshes not drawn (collision shapes only): the check fails
    bare = write_video(tmp_path / "s.gif", motion, fps=30.0, meshes=robot_meshes(g1m, visual=False), **ref)
    frame = _frame(bare, 6)
    assert _mesh_pixels(frame) < 50 and _shape_pixels(frame) > 1000


def test_mer_retarget_video_draws_the_robot_with_a_floor_and_contacts(tmp_path, g1m, capsys):
    """End to end: ``mer retarget --video`` to the MJCF G1 draws its meshes; the feet of a walk are
    marked in contact (green on the floor) in some frames."""
    from shard_helpers import make_input

    src = make_input(tmp_path / "in", robots=("g1",), clips={"walk": (1.5, 0.0, 0.0)}) / "g1" / "walk.csv"  # mer's demo walk
    out = tmp_path / "g1m.gif"
    code = main(["retarget", str(src), "--source", "g1", "--target", "g1m", "--method", "optimize", "--video", str(out),
                 "--video-fps", "15", "--no-physics"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    with Image.open(out) as im:
        n = im.n_frames
    frames = [_frame(out, i) for i in range(n)]
    assert all(_mesh_pixels(f) > 2000 for f in frames)
    green = [int(((f[..., 1].astype(int) - f[..., 0] > 60) & (f[..., 1].astype(int) - f[..., 2] > 60)).sum()) for f in frames]
    assert max(green) > 30  # a contact mark under a foot


def test_a_scaled_skeleton_is_drawn_as_bones(tmp_path):
    """A skeleton no registered robot has (augmented): no meshes, its bones (no mesh colour)."""
    s = load_robot("h1").skeleton.with_link_scales(np.full(load_robot("h1").skeleton.num_nodes, 1.1))
    motion = _motion(s, 6)
    pos, _ = motion.forward_kinematics()
    out = write_video(tmp_path / "b.gif", motion, pos[:, :3], fps=30.0)
    right = _frame(out, 3)[:, 400:].astype(int)
    dark = (right.max(-1) < 110) & (right.max(-1) - right.min(-1) < 20)  # the bones' dark grey
    assert _mesh_pixels(_frame(out, 3)) < 50 and dark.sum() > 50


def test_a_builtin_video_frame_shows_its_shipped_meshes(tmp_path):
    """issue 52: `--video` of a built-in draws its real shape (its shipped visual meshes, light blue),
    not its collision shapes (amber), as it did before they were shipped."""
    h1 = load_robot("h1")
    motion = _motion(h1.skeleton, 6)
    pos, _ = motion.forward_kinematics()
    frame = _frame(write_video(tmp_path / "h1.gif", motion, pos[:, :3], fps=30.0), 3)
    assert _mesh_pixels(frame) > 2000 and _shape_pixels(frame) < 50, (_mesh_pixels(frame), _shape_pixels(frame))
