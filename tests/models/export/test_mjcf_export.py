"""``mer robots export NAME --mjcf OUT.xml``: a MuJoCo model of any registered robot in which its
npz for mjlab replays. MuJoCo is the oracle: qpos from the npz (base pose from body 0, joint_pos
in the model's own joint order, as mjlab sets it), ``mj_kinematics``, and every body where the
npz's ``body_pos_w`` / ``body_quat_w`` say (1e-5 m; measured ~2e-7 m, float32 rounding).
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
import torch
from urdf_factory import humanoid

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.register import register_robot
from mer_data.robots.registry import Robot, load_robot
from mer_models.cli import main
from mer_models.export.mjcf import FREE_JOINT
from mer_models.export.writers import TargetMotion, write_npz
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is mer's MJCF reader (pip install -e .)")


def _export(robot: Robot, tmp_path, capsys) -> "mujoco.MjModel":
    out = tmp_path / f"{robot.name}.xml"
    assert main(["robots", "export", robot.name, "--mjcf", str(out)]) == 0
    assert "npz-for mjlab" in capsys.readouterr().out
    return mujoco.MjModel.from_xml_path(str(out))


def replay(model: "mujoco.MjModel", npz) -> tuple[float, float]:
    """Max body position [m] and orientation (~angle [rad]) errors of MuJoCo's FK of the npz's qpos."""
    z = np.load(npz)
    assert [model.body(i).name for i in range(1, model.nbody)] == list(z["body_names"])  # mjlab's order
    assert [model.joint(i).name for i in range(1, model.njnt)] == list(z["joint_names"])
    assert model.joint(0).name == FREE_JOINT and model.nq == 7 + z["joint_pos"].shape[1]
    data = mujoco.MjData(model)
    pos = rot = 0.0
    for f in range(z["joint_pos"].shape[0]):
        data.qpos[:3], data.qpos[3:7], data.qpos[7:] = z["body_pos_w"][f, 0], z["body_quat_w"][f, 0], z["joint_pos"][f]
        mujoco.mj_kinematics(model, data)
        pos = max(pos, float(np.abs(data.xpos[1:] - z["body_pos_w"][f]).max()))
        a, b = data.xquat[1:], z["body_quat_w"][f]
        rot = max(rot, 2 * float(np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1)).max()))
    return pos, rot


def _npz(robot: Robot, path, frames: int = 40, seed: int = 3):
    s = robot.skeleton
    m = synthetic_motion(s, frames, seed=seed)
    assert np.ptp(m["q"], axis=0).max() > 0.3  # the joints move
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    return write_npz(path, motion, tracker="mjlab")


def _stl(path, scale: float = 0.05) -> None:
    """A binary STL of a tetrahedron (a mesh file as a robot's description references it)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32) * scale
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    data = b"\0" * 80 + struct.pack("<I", len(faces))
    for f in faces:
        data += struct.pack("<12fH", 0, 0, 0, *v[f[0]], *v[f[1]], *v[f[2]], 0)
    path.write_bytes(data)


def test_a_robot_built_in_code_exports_and_its_npz_replays(tmp_path, capsys):
    """Fixed links with moving children, a locked joint, a mimic joint, a visual mesh whose file is there."""
    r = humanoid("toy", tilt=0.3)
    r.joint("head_tilt_joint", "revolute", "head_link", "eyes_link", xyz=(0.05, 0, 0.1), axis=(0, 1, 0),
            mimic=("neck_joint", 0.5, 0.1))  # fmt: skip
    text = r.xml().replace('<link name="left_forearm_link"/>', '<link name="left_forearm_link"><visual><geometry>'
                           '<mesh filename="package://toy/meshes/forearm.stl"/></geometry></visual></link>')  # fmt: skip
    (tmp_path / "toy.urdf").write_text(text)
    robot = register_robot("toy", tmp_path / "toy.urdf", locks={"right_wrist_joint": 0.4}).robot
    assert robot.skeleton.locked["right_wrist_joint"] == 0.4 and (robot.skeleton.mimic_source >= 0).sum() == 1
    (robot.folder / "meshes").mkdir()
    _stl(robot.folder / "meshes" / "forearm.stl")  # the user put the meshes beside the registered URDF
    model = _export(robot, tmp_path, capsys)
    pos, rot = replay(model, _npz(robot, tmp_path / "toy.npz"))
    assert pos < 1e-5 and rot < 1e-4, (pos, rot)
    z = np.load(tmp_path / "toy.npz")
    names = list(z["joint_names"])
    np.testing.assert_allclose(z["joint_pos"][:, names.index("right_wrist_joint")], 0.4, atol=1e-6)  # locked, held
    e, w = z["joint_pos"][:, names.index("neck_joint")], z["joint_pos"][:, names.index("head_tilt_joint")]
    np.testing.assert_allclose(w, 0.5 * e + 0.1, atol=1e-6)  # the mimic follows its master
    assert model.neq == 1 and model.eq_type[0] == mujoco.mjtEq.mjEQ_JOINT  # and the model keeps the relation
    visual = [g for g in range(model.ngeom) if model.geom_group[g] == 2]
    assert len(visual) == 1 and model.geom_contype[visual[0]] == 0 and model.geom_type[visual[0]] == mujoco.mjtGeom.mjGEOM_MESH
    assert model.body(model.geom_bodyid[visual[0]]).name == "left_forearm_link"
    collide = [g for g in range(model.ngeom) if model.geom_contype[g]]
    bare = {model.body("right_wrist_link").id}  # a locked joint's body without shapes: no capsule is fitted there
    assert {model.geom_bodyid[g] for g in collide} == set(range(1, model.nbody)) - bare  # every other body collides
    forearm = model.body("left_forearm_link").id  # collision shapes hidden (group 3) behind a visual mesh, else drawn
    assert {int(model.geom_group[g]) for g in collide if model.geom_bodyid[g] == forearm} == {3}
    assert {int(model.geom_group[g]) for g in collide if model.geom_bodyid[g] != forearm} == {0}
    jid = model.joint("left_knee_joint").id
    np.testing.assert_allclose(model.jnt_range[jid], [0.0, 2.4])
    assert model.nbody == 1 + 1 + len(robot.skeleton.joint_names) + 2  # world, pelvis, one per joint, the locked and the mimic


def test_a_builtin_robot_exports_with_its_masses(tmp_path, capsys):
    robot = load_robot("h1")
    model = _export(robot, tmp_path, capsys)
    pos, rot = replay(model, _npz(robot, tmp_path / "h1.npz"))
    assert pos < 1e-5 and rot < 1e-4
    assert abs(model.body_subtreemass[1] - 59.34) < 0.01  # the URDF's inertials (fixed links merged)


def test_a_wild_robot_with_locked_joints_exports(tmp_path, capsys, shared_wild_robots):
    """romeo: 24 of 55 revolute joints locked (fingers); no mesh files: fitted capsules where it has no shape."""
    robot = register_robot("romeo", shared_wild_robots / "romeo" / "romeo.urdf").robot
    model = _export(robot, tmp_path, capsys)
    assert model.njnt == 1 + 55 and len(robot.skeleton.locked) == 24
    pos, rot = replay(model, _npz(robot, tmp_path / "romeo.npz", frames=20))
    assert pos < 1e-5 and rot < 1e-4, (pos, rot)


@pytest.mark.parametrize("name, file", [("hi", "gmr_hightorque_hi/hi_25dof.xml"), ("g1m", "mjlab_unitree_g1/g1.xml")])
def test_an_mjcf_robot_exports_and_its_npz_replays_in_its_own_mjcf(tmp_path, capsys, shared_dir, name, file):
    """HighTorque Hi and mjlab's G1 registered from their MJCF: the npz lines up with our model and
    with the original file (meshes there), the model an mjlab user already has."""
    xml = shared_dir / "robots-mjcf" / file
    if not xml.is_file():
        pytest.skip(f"{xml} is absent")
    robot = register_robot(name, xml).robot
    model = _export(robot, tmp_path, capsys)
    npz = _npz(robot, tmp_path / f"{name}.npz")
    pos, rot = replay(model, npz)
    assert pos < 1e-5 and rot < 1e-4, (pos, rot)
    original = mujoco.MjModel.from_xml_path(str(xml))
    pos, rot = replay(original, npz)
    assert pos < 1e-5 and rot < 1e-4, (pos, rot)
