"""``mer robots export NAME --mjlab DIR`` without mjlab: MuJoCo is the oracle for the folder's MJCF
(it compiles from a moved copy, its actuators, sole spheres and exclusions are what docs/trackers.md
says); ``read_npz`` refuses another robot's npz by name. mjlab itself: test_mjlab_env.py.
"""

from __future__ import annotations

import ast
import math
import re
import shutil

import numpy as np
import pytest
import torch
from urdf_factory import humanoid

from mer_data.base.errors import MerError
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.articulation import articulation
from mer_data.robots.register import register_robot
from mer_data.robots.registry import load_robot
from mer_models.cli import main
from mer_models.export.mjlab_body import SOLE_RADIUS
from mer_models.export.mjlab_drive import ARMATURE_PER_SQRT_EFFORT, DAMPING_RATIO, NATURAL_FREQ
from mer_models.export.npz_read import read_npz
from mer_models.export.writers import TargetMotion, write_npz
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is mer's MJCF reader (pip install -e .)")


def npz_for(robot, path, tracker="mjlab", frames=30):
    s = robot.skeleton
    m = synthetic_motion(s, frames, seed=5)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    return write_npz(path, motion, tracker=tracker)


def _toy(tmp_path, effort="10"):
    r = humanoid("toy")
    r.joint("head_tilt_joint", "revolute", "head_link", "eyes_link", xyz=(0.05, 0, 0.1), axis=(0, 1, 0),
            mimic=("neck_joint", 0.5, 0.1))  # fmt: skip
    text = r.xml().replace('effort="10"', f'effort="{effort}"')
    text = text.replace('<joint name="left_knee_joint" type="revolute">',
                        '<joint name="left_knee_joint" type="revolute"><dynamics damping="0.5" friction="0.2"/>')  # fmt: skip
    text = text.replace('<link name="left_forearm_link"/>', '<link name="left_forearm_link"><inertial><origin xyz="0 0 -0.2"/><mass value="10"/>'
                        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial><visual><geometry>'
                        '<mesh filename="package://toy/meshes/forearm.stl"/></geometry></visual></link>')  # fmt: skip
    (tmp_path / "toy.urdf").write_text(text)
    robot = register_robot("toy", tmp_path / "toy.urdf", locks={"right_wrist_joint": 0.4}).robot
    (robot.folder / "meshes").mkdir()
    from test_mjcf_export import _stl

    _stl(robot.folder / "meshes" / "forearm.stl")
    (robot.folder / "LICENSE").write_text("toy licence\n")
    return robot


def test_the_folder_is_self_contained_and_its_model_is_what_the_docs_say(tmp_path, capsys):
    robot = _toy(tmp_path)
    out = tmp_path / "out"
    npz = npz_for(robot, tmp_path / "walk.npz")
    assert main(["robots", "export", "toy", "--mjlab", str(out), "--motion", str(npz)]) == 0
    said = capsys.readouterr().out
    assert "Mjlab-Tracking-Flat-Mer-Toy" in said and "pip install -e" in said
    moved = tmp_path / "elsewhere" / "toy_mjlab"
    moved.parent.mkdir()
    shutil.move(str(out), str(moved))  # relative paths only: it loads from where it is
    pkg = moved / "mer_toy"
    assert {p.name for p in pkg.iterdir()} >= {"__init__.py", "toy.xml", "meshes", "motions", "LICENSE", "README.md"}
    assert (moved / "pyproject.toml").is_file() and (pkg / "motions" / "walk.npz").is_file()
    text = (pkg / "toy.xml").read_text()
    assert str(tmp_path) not in text and 'file="meshes/' in text
    m = mujoco.MjModel.from_xml_path(str(pkg / "toy.xml"))
    art = articulation(robot)
    z = np.load(npz, allow_pickle=False)
    assert [m.joint(i).name for i in range(1, m.njnt)] == list(z["joint_names"])  # mjlab's Entity order
    assert [m.body(i).name for i in range(1, m.nbody)] == list(z["body_names"])
    # a position actuator on every joint but the mimic one, with the rule's gains and the URDF's effort
    acts = [m.actuator(a).name for a in range(m.nu)]
    assert acts == [j.name for j in art.joints if j.mimic is None] and "head_tilt_joint" not in acts
    a = m.actuator("left_knee_joint")
    arm = ARMATURE_PER_SQRT_EFFORT * math.sqrt(10.0)
    np.testing.assert_allclose(m.dof_armature[m.jnt_dofadr[m.joint("left_knee_joint").id]], arm, rtol=1e-6)
    np.testing.assert_allclose([a.gainprm[0], -a.biasprm[1], -a.biasprm[2]],
                               [arm * NATURAL_FREQ**2, arm * NATURAL_FREQ**2, 2 * DAMPING_RATIO * arm * NATURAL_FREQ], rtol=1e-6)  # fmt: skip
    np.testing.assert_allclose(a.forcerange, [-10, 10])
    knee = m.jnt_dofadr[m.joint("left_knee_joint").id]
    np.testing.assert_allclose([m.dof_damping[knee], m.dof_frictionloss[knee]], [0.5, 0.2])  # URDF <dynamics>
    assert not a.ctrllimited
    # standing at qpos0: the sole spheres on the floor, at the corners of the foot boxes, nothing lower
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    feet = [g for g in range(m.ngeom) if re.fullmatch(r"(left|right)_foot[0-9]+_collision", m.geom(g).name or "")]
    assert len(feet) == 8
    bottoms = d.geom_xpos[feet, 2] - SOLE_RADIUS
    np.testing.assert_allclose(bottoms, 0.0, atol=1e-6)
    left = sorted(g for g in feet if m.geom(g).name.startswith("left"))
    xy = d.geom_xpos[left, :2]
    np.testing.assert_allclose(np.ptp(xy, axis=0), [0.2, 0.08], atol=1e-6)  # the foot box's 0.2 x 0.08 m sole
    colliding = [g for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]]
    assert set(feet) <= set(colliding)
    assert all(m.geom(g).name.endswith("_collision") for g in colliding)
    assert d.ncon == 0  # no floor here, and no two bodies touch at the initial pose (excluded where they did)
    # exclusions: every parent/child pair
    pairs = {(m.body(m.exclude_signature[i] >> 16).name, m.body(m.exclude_signature[i] & 0xFFFF).name) for i in range(m.nexclude)}
    for b in art.bodies[1:]:
        assert (art.bodies[b.parent].name, b.name) in pairs or (b.name, art.bodies[b.parent].name) in pairs
    # the sensors mjlab's tracking observations read, and the module's names
    assert {m.sensor(i).name for i in range(m.nsensor)} >= {"imu_ang_vel", "imu_lin_vel"}
    src = (pkg / "__init__.py").read_text()
    tree = ast.parse(src)
    consts = {t.targets[0].id: t.value for t in tree.body if isinstance(t, ast.Assign) and isinstance(t.targets[0], ast.Name)}
    tracked = ast.literal_eval(consts["TRACKED_BODIES"])
    assert tracked[0] == "pelvis" and set(tracked) <= set(z["body_names"])
    # the shoulders' common body: the torso link, merged into waist_link (a fixed joint)
    assert ast.literal_eval(consts["ANCHOR_BODY"]) == "waist_link" and "waist_link" in tracked
    assert "left_foot" in (pkg / "README.md").read_text() and (pkg / "LICENSE").read_text() == "toy licence\n"


def test_rule_effort_where_the_description_gives_none(tmp_path, capsys):
    """No effort in the URDF: twice the static torque; the forearm's 10 kg load at the elbow is
    visible in the elbow's effort, the knee carries half the robot at the sole."""
    _toy(tmp_path, effort="0")
    out = tmp_path / "out"
    assert main(["robots", "export", "toy", "--mjlab", str(out)]) == 0
    m = mujoco.MjModel.from_xml_path(str(out / "mer_toy" / "toy.xml"))
    eff = {m.actuator(a).name: float(m.actuator(a).forcerange[1]) for a in range(m.nu)}
    assert eff["left_elbow_joint"] > eff["right_elbow_joint"] >= 5.0  # the left forearm has mass, the right none
    assert eff["left_knee_joint"] == pytest.approx(eff["right_knee_joint"], rel=1e-6) and eff["left_knee_joint"] >= 5.0
    readme = (out / "mer_toy" / "README.md").read_text()
    assert "(rule)" in readme and "(given)" not in readme


def test_an_npz_for_another_robot_is_refused_by_name(tmp_path, capsys):
    h1, g1 = load_robot("h1"), load_robot("g1")
    npz = npz_for(h1, tmp_path / "h1.npz")
    assert read_npz(npz, h1, "mjlab")["joint_pos"].shape[1] == 19
    with pytest.raises(MerError, match="another robot.*left_ankle_joint"):
        read_npz(npz, g1, "mjlab")
    bm = npz_for(h1, tmp_path / "h1-bm.npz", tracker="beyondmimic")
    with pytest.raises(MerError, match="beyondmimic's order"):
        read_npz(bm, h1, "mjlab")
    assert read_npz(bm, h1, "beyondmimic")["fps"].dtype == np.int64
    # the command refuses it before writing anything
    out = tmp_path / "g1dir"
    assert main(["robots", "export", "g1", "--mjlab", str(out), "--motion", str(npz)]) != 0
    assert "another robot" in capsys.readouterr().err and not out.exists()


def test_an_npz_without_names_is_checked_by_its_shapes(tmp_path, caplog):
    """A tracker's own converter writes no names: its shapes must still fit the robot."""
    h1, g1 = load_robot("h1"), load_robot("g1")
    z = dict(np.load(npz_for(h1, tmp_path / "h1.npz"), allow_pickle=False))
    del z["joint_names"], z["body_names"]
    np.savez(tmp_path / "bare.npz", **z)
    assert read_npz(tmp_path / "bare.npz", h1, "mjlab")["joint_pos"].shape[1] == 19
    assert "no joint_names" in caplog.text
    with pytest.raises(MerError, match=r"do not fit 'g1' \(29 joints"):
        read_npz(tmp_path / "bare.npz", g1, "mjlab")
    del z["body_quat_w"]
    np.savez(tmp_path / "short.npz", **z)
    with pytest.raises(MerError, match="no body_quat_w"):
        read_npz(tmp_path / "short.npz", h1, "mjlab")


def test_an_mjcf_s_own_drives_are_kept(tmp_path, capsys, shared_dir):
    """HighTorque Hi's MJCF gives every joint's actuatorfrcrange (21 N m); a <position> actuator and
    an armature added to one joint are taken as they are, the rest get the rule's gains."""
    xml = shared_dir / "robots-mjcf" / "gmr_hightorque_hi" / "hi_25dof.xml"
    if not xml.is_file():
        pytest.skip(f"{xml} is absent")
    text = xml.read_text().replace('<joint name="l_calf_joint" ', '<joint name="l_calf_joint" armature="0.02" ')
    text = text.replace("</mujoco>", '<actuator><position joint="l_calf_joint" kp="55" kv="3" forcelimited="true" '
                        'forcerange="-30 30"/></actuator></mujoco>')  # fmt: skip
    (tmp_path / "hi.xml").write_text(text)
    register_robot("hi", tmp_path / "hi.xml")
    out = tmp_path / "out"
    assert main(["robots", "export", "hi", "--mjlab", str(out)]) == 0
    m = mujoco.MjModel.from_xml_path(str(out / "mer_hi" / "hi.xml"))
    calf, waist = m.actuator("l_calf_joint"), m.actuator("waist_joint")
    np.testing.assert_allclose([calf.gainprm[0], -calf.biasprm[2], calf.forcerange[1]], [55, 3, 30])
    np.testing.assert_allclose(m.dof_armature[m.jnt_dofadr[m.joint("l_calf_joint").id]], 0.02)
    arm = ARMATURE_PER_SQRT_EFFORT * math.sqrt(21.0)
    np.testing.assert_allclose([waist.gainprm[0], waist.forcerange[1]], [arm * NATURAL_FREQ**2, 21], rtol=1e-6)
    assert m.nu == 25
