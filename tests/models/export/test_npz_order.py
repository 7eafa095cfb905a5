"""The npz loads right in the tracker it is written for: ``--npz-for mjlab|beyondmimic``.

Neither tracker's ``MotionLoader`` reads ``joint_names`` / ``body_names``: both take ``joint_pos``
as the robot's joints in the robot's own order and pick tracked bodies by their index in the
robot's body list (BeyondMimic ``whole_body_tracking`` ``tasks/tracking/mdp/commands.py``, mjlab
``src/mjlab/tasks/tracking/mdp/commands.py`` @ 0eda4e7). :class:`ScratchMotionLoader` does what
they do, written from reading that code; a joint or body is *misplaced* when the slot the loader
reads holds another one.

The robots' orders come from outside mer: Isaac Lab's G1 order as public Isaac Lab G1 projects
read it from ``robot.joint_names`` / ``robot.body_names``; Isaac Lab's H1 joint order as Isaac
Sim's ``H1FlatTerrainPolicy`` example lists it; for a robot without a published order, the rule
of Isaac Sim's URDF importer re-implemented here from the raw URDF (joints in a name-keyed map,
fixed joints merged, links breadth-first); MuJoCo's order from MuJoCo itself (``MjSpec`` of the
exported model, what mjlab's ``Entity`` lists).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lxml import etree
from model_helpers import synthetic_csv

from mer_data.base.errors import MerError, OutputError
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.articulation import articulation
from mer_data.robots.registry import Robot, load_robot
from mer_data.robots.urdf import load_urdf
from mer_models.cli import main
from mer_models.export.mjcf import mjcf_model
from mer_models.export.writers import TargetMotion, write_npz
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is mer's MJCF reader (pip install -e .)")

ISAACLAB_G1_JOINTS = [
    "left_hip_pitch_joint", "right_hip_pitch_joint", "waist_yaw_joint",
    "left_hip_roll_joint", "right_hip_roll_joint", "waist_roll_joint",
    "left_hip_yaw_joint", "right_hip_yaw_joint", "waist_pitch_joint",
    "left_knee_joint", "right_knee_joint", "left_shoulder_pitch_joint", "right_shoulder_pitch_joint",
    "left_ankle_pitch_joint", "right_ankle_pitch_joint", "left_shoulder_roll_joint", "right_shoulder_roll_joint",
    "left_ankle_roll_joint", "right_ankle_roll_joint", "left_shoulder_yaw_joint", "right_shoulder_yaw_joint",
    "left_elbow_joint", "right_elbow_joint", "left_wrist_roll_joint", "right_wrist_roll_joint",
    "left_wrist_pitch_joint", "right_wrist_pitch_joint", "left_wrist_yaw_joint", "right_wrist_yaw_joint",
]  # fmt: skip
ISAACLAB_G1_BODIES = [
    "pelvis", "left_hip_pitch_link", "right_hip_pitch_link", "waist_yaw_link",
    "left_hip_roll_link", "right_hip_roll_link", "waist_roll_link", "left_hip_yaw_link", "right_hip_yaw_link", "torso_link",
    "left_knee_link", "right_knee_link", "left_shoulder_pitch_link", "right_shoulder_pitch_link",
    "left_ankle_pitch_link", "right_ankle_pitch_link", "left_shoulder_roll_link", "right_shoulder_roll_link",
    "left_ankle_roll_link", "right_ankle_roll_link", "left_shoulder_yaw_link", "right_shoulder_yaw_link",
    "left_elbow_link", "right_elbow_link", "left_wrist_roll_link", "right_wrist_roll_link",
    "left_wrist_pitch_link", "right_wrist_pitch_link", "left_wrist_yaw_link", "right_wrist_yaw_link",
]  # fmt: skip
#: Isaac Sim's H1 example (H1FlatTerrainPolicy): "H1 joint order", the order of its 19 gains.
ISAACSIM_H1_JOINTS = [
    "left_hip_yaw_joint", "right_hip_yaw_joint", "torso_joint", "left_hip_roll_joint", "right_hip_roll_joint",
    "left_shoulder_pitch_joint", "right_shoulder_pitch_joint", "left_hip_pitch_joint", "right_hip_pitch_joint",
    "left_shoulder_roll_joint", "right_shoulder_roll_joint", "left_knee_joint", "right_knee_joint",
    "left_shoulder_yaw_joint", "right_shoulder_yaw_joint", "left_ankle_joint", "right_ankle_joint",
    "left_elbow_joint", "right_elbow_joint",
]  # fmt: skip
#: The bodies both trackers' G1 configurations track (``commands.motion.body_names``).
G1_TRACKED = [
    "pelvis", "left_hip_roll_link", "left_knee_link", "left_ankle_roll_link", "right_hip_roll_link", "right_knee_link",
    "right_ankle_roll_link", "torso_link", "left_shoulder_roll_link", "left_elbow_link", "left_wrist_yaw_link",
    "right_shoulder_roll_link", "right_elbow_link", "right_wrist_yaw_link",
]  # fmt: skip


class ScratchMotionLoader:
    """What BeyondMimic's and mjlab's MotionLoader + MotionCommand do with an npz: every array as
    stored; ``joint_pos`` taken as the robot's joints in its order; tracked bodies picked by their
    index in the robot's body list (``find_bodies(names, preserve_order=True)``)."""

    def __init__(self, path, robot_joints: list[str], robot_bodies: list[str], tracked: list[str]) -> None:
        z = np.load(path)
        assert z["joint_pos"].shape[1] == len(robot_joints), "the loader would fail on the shape"
        self.body_indexes = [robot_bodies.index(n) for n in tracked]
        self.joint_pos = z["joint_pos"]  # column i is taken as robot_joints[i]
        self.body_pos_w = z["body_pos_w"][:, self.body_indexes]
        self.misplaced_joints = sum(a != b for a, b in zip(z["joint_names"], robot_joints))
        self.misplaced_bodies = sum(str(z["body_names"][i]) != n for i, n in zip(self.body_indexes, tracked))


def _motion(robot: Robot, frames: int = 30, seed: int = 2) -> TargetMotion:
    s = robot.skeleton
    m = synthetic_motion(s, frames, seed=seed)
    return TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())


def mjlab_names(text: str) -> tuple[list[str], list[str]]:
    """(joint names, body names) as mjlab's Entity lists them from the model's MjSpec (free joint and world left out)."""
    spec = mujoco.MjSpec.from_string(text)
    joints = [j.name for j in spec.joints if j.type != mujoco.mjtJoint.mjJNT_FREE]
    return joints, [b.name for b in spec.bodies[1:]]


def importer_order(urdf_path) -> tuple[list[str], list[str]]:
    """Isaac Sim's URDF importer + PhysX, re-implemented from the raw URDF: joints kept in a map
    keyed by name (so every link's child joints in name order), fixed joints merged into their
    parent link (their child joints re-parented), links breadth-first, a joint with its child link."""
    root = etree.parse(str(urdf_path)).getroot()
    joints = {j.get("name"): (j.get("type"), j.find("parent").get("link"), j.find("child").get("link"))
              for j in root.findall("joint")}  # fmt: skip
    children = {c for _, _, c in joints.values()}
    base = next(link.get("name") for link in root.findall("link") if link.get("name") not in children)
    merged_into = {}
    for name in sorted(joints):
        kind, p, c = joints[name]
        if kind == "fixed":
            merged_into[c] = p

    def body(link: str) -> str:
        while link in merged_into:
            link = merged_into[link]
        return link

    kids: dict[str, list[str]] = {}
    for name in sorted(joints):
        kind, p, c = joints[name]
        if kind != "fixed":
            kids.setdefault(body(p), []).append(name)
    order_j, order_b, queue = [], [base], [base]
    while queue:
        link = queue.pop(0)
        for name in kids.get(link, []):
            order_j.append(name)
            order_b.append(joints[name][2])
            queue.append(joints[name][2])
    return order_j, order_b


# ---- the orders against their published references --------------------------------------------------
def test_isaac_labs_order_is_derived_for_g1_and_h1_as_published():
    g1 = articulation(load_robot("g1"))
    j, b = g1.order("beyondmimic")
    assert [g1.joints[i].name for i in j] == ISAACLAB_G1_JOINTS and [g1.bodies[i].name for i in b] == ISAACLAB_G1_BODIES
    h1 = articulation(load_robot("h1"))
    j, _ = h1.order("beyondmimic")
    assert [h1.joints[i].name for i in j] == ISAACSIM_H1_JOINTS


def test_every_builtin_robots_orders_are_mujocos_and_the_importers():
    """mjlab: MuJoCo's own URDF compiler lists the same bodies and joints; beyondmimic: the importer rule."""
    for name in ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie"):
        r = load_robot(name)
        a = articulation(r)
        root = etree.parse(str(r.urdf_path)).getroot()
        for el in root.xpath("//visual|//collision|//inertial|//mujoco"):  # kinematics only
            el.getparent().remove(el)
        spec = mujoco.MjSpec.from_string(etree.tostring(root).decode())  # URDF: fixed links fused (fusestatic)
        spec.compiler.boundmass, spec.compiler.boundinertia = 1e-3, 1e-6
        spec.worldbody.first_body().add_freejoint()  # the floating base (else the root is fused into the world)
        m = spec.compile()
        assert list(a.body_names) == [m.body(i).name for i in range(1, m.nbody)], name
        assert list(a.joint_names) == [m.joint(i).name for i in range(1, m.njnt)], name
        j, b = a.order("beyondmimic")
        assert ([a.joints[i].name for i in j], [a.bodies[i].name for i in b]) == importer_order(r.urdf_path), name


# ---- both npz load right in their tracker --------------------------------------------------------------
def _both(tmp_path, robot: Robot, isaac: tuple[list[str], list[str]], tracked: list[str]) -> dict[str, tuple[int, int]]:
    """Misplaced (joints, bodies) of each npz in each tracker's scratch loader, and the mjlab npz's replay."""
    m = _motion(robot)
    text = mjcf_model(robot)
    mj = mjlab_names(text)
    out = {}
    for tracker in ("mjlab", "beyondmimic"):
        path = write_npz(tmp_path / f"{robot.name}-{tracker}.npz", m, tracker=tracker)
        for reader, (joints, bodies) in (("mjlab", mj), ("beyondmimic", isaac)):
            lo = ScratchMotionLoader(path, joints, bodies, tracked)
            out[f"{tracker} in {reader}"] = (lo.misplaced_joints, lo.misplaced_bodies)
    # and the values: the mjlab npz replays in the model, joints set in the model's own order (as mjlab does)
    z = np.load(tmp_path / f"{robot.name}-mjlab.npz")
    model = mujoco.MjModel.from_xml_string(text)
    data = mujoco.MjData(model)
    err = 0.0
    for f in range(z["joint_pos"].shape[0]):
        data.qpos[:3], data.qpos[3:7], data.qpos[7:] = z["body_pos_w"][f, 0], z["body_quat_w"][f, 0], z["joint_pos"][f]
        mujoco.mj_kinematics(model, data)
        err = max(err, float(np.abs(data.xpos[1:] - z["body_pos_w"][f]).max()))
    assert err < 1e-5, err
    return out


def test_g1_npz_loads_right_in_both_trackers_and_wrong_across(tmp_path):
    got = _both(tmp_path, load_robot("g1"), (ISAACLAB_G1_JOINTS, ISAACLAB_G1_BODIES), G1_TRACKED)
    assert got["mjlab in mjlab"] == (0, 0) and got["beyondmimic in beyondmimic"] == (0, 0)
    assert got["mjlab in beyondmimic"] == (27, 12)  # the silent failure: 27 of 29 joints, 12 of 14 bodies
    assert got["beyondmimic in mjlab"][0] > 20


def test_h1_npz_loads_right_in_both_trackers(tmp_path):
    r = load_robot("h1")
    u = {j.name: j.child for j in load_urdf(r.urdf_path).joints}
    bodies = ["pelvis"] + [u[j] for j in ISAACSIM_H1_JOINTS]  # PhysX: a joint comes with its child link
    got = _both(tmp_path, r, (ISAACSIM_H1_JOINTS, bodies), bodies)
    assert got["mjlab in mjlab"] == (0, 0) and got["beyondmimic in beyondmimic"] == (0, 0)
    assert got["mjlab in beyondmimic"][0] > 10


def test_a_robot_with_locked_joints_holds_its_whole_articulation(tmp_path, shared_wild_robots):
    """romeo (../shared): 55 revolute joints, 24 locked as fingers; the npz has all 55, locked ones at their value."""
    from mer_data.robots.register import register_robot

    r = register_robot("romeo", shared_wild_robots / "romeo" / "romeo.urdf").robot
    assert len(r.skeleton.locked) == 24 and r.skeleton.num_dof == 31
    got = _both(tmp_path, r, importer_order(r.urdf_path), list(articulation(r).body_names))
    assert got["mjlab in mjlab"] == (0, 0) and got["beyondmimic in beyondmimic"] == (0, 0)
    z = np.load(tmp_path / "romeo-beyondmimic.npz")
    names = list(z["joint_names"])
    assert len(names) == 55 and z["body_pos_w"].shape[1] == 56
    for joint, value in r.skeleton.locked.items():
        np.testing.assert_allclose(z["joint_pos"][:, names.index(joint)], value, atol=1e-6)


# ---- what is written: fps, velocities ------------------------------------------------------------------
def test_fps_is_written_as_the_converters_write_it(tmp_path):
    """mjlab's csv_to_npz logs ``[output_fps]`` of a float (float64), BeyondMimic's of an int (int64);
    the names are plain unicode arrays, read without pickle."""
    z = np.load(write_npz(tmp_path / "a.npz", _motion(load_robot("tron1")), tracker="mjlab"), allow_pickle=False)
    assert z["fps"].shape == (1,) and z["fps"].dtype == np.float64 and z["fps"][0] == 50.0
    assert z["joint_names"].dtype.kind == "U" and z["body_names"].dtype.kind == "U"
    z = np.load(write_npz(tmp_path / "c.npz", _motion(load_robot("tron1")), tracker="beyondmimic"), allow_pickle=False)
    assert z["fps"].shape == (1,) and z["fps"].dtype == np.int64 and int(z["fps"][0]) == 50
    assert z["joint_names"].dtype.kind == "U" and z["body_names"].dtype.kind == "U"
    with pytest.raises(OutputError, match="whole number"):
        write_npz(tmp_path / "b.npz", _motion(load_robot("tron1")), tracker="mjlab", fps=29.97)


def test_linear_velocity_is_the_com_for_beyondmimic_and_the_origin_for_mjlab(tmp_path):
    """A steady spin about z through the origin: every point moves at w x r. MuJoCo says where each
    body's centre of mass (xipos) and origin (xpos) are; Isaac Lab's body_lin_vel_w is the centre of
    mass's velocity, mjlab's body_link_lin_vel_w the origin's."""
    from mer_models.batch import rot_z

    r = load_robot("g1")
    s, F, rate = r.skeleton, 30, 1.5
    q = np.tile(s.nominal, (F, 1))
    m = TargetMotion(s, 30.0, q, np.zeros((F, 3)), rot_z(torch.arange(F, dtype=torch.float64) * rate / 30.0).numpy())
    model = mujoco.MjModel.from_xml_string(mjcf_model(r))
    data = mujoco.MjData(model)
    w = np.array([0.0, 0.0, rate])
    spread = 0.0
    for tracker, where in (("beyondmimic", "xipos"), ("mjlab", "xpos")):
        z = np.load(write_npz(tmp_path / f"{tracker}.npz", m, tracker=tracker))
        ids = [model.body(str(n)).id for n in z["body_names"]]
        qadr = [int(model.joint(str(n)).qposadr[0]) for n in z["joint_names"]]
        for f in range(2, z["joint_pos"].shape[0] - 2):  # central differences (the ends are one-sided)
            data.qpos[:3], data.qpos[3:7], data.qpos[qadr] = z["body_pos_w"][f, 0], z["body_quat_w"][f, 0], z["joint_pos"][f]
            mujoco.mj_kinematics(model, data)
            np.testing.assert_allclose(z["body_lin_vel_w"][f], np.cross(w, getattr(data, where)[ids]), atol=2e-4)
            spread = max(spread, float(np.abs(np.cross(w, data.xipos[1:] - data.xpos[1:])).max()))
    assert spread > 0.02  # the two conventions differ here by centimetres per second


# ---- no silent default ---------------------------------------------------------------------------------
def test_npz_without_a_tracker_is_refused_naming_both(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=20)
    argv = ["retarget", str(src), "--source", "g1", "--method", "optimize", "--target", "h1", "--no-physics"]
    assert main(argv + ["--npz", str(tmp_path / "h1.npz")]) == 1
    err = capsys.readouterr().err
    assert "--npz-for mjlab" in err and "--npz-for beyondmimic" in err and not (tmp_path / "h1.npz").exists()
    data = ["retarget", "--input", str(tmp_path), "--source", "g1", "--targets", "h1", "--out", str(tmp_path / "o"),
            "--formats", "npz", "--no-physics", "--quiet"]  # fmt: skip
    assert main(data) == 1
    err = capsys.readouterr().err
    assert "--npz-for mjlab" in err and "--npz-for beyondmimic" in err and not (tmp_path / "o" / "h1").exists()
    with pytest.raises(MerError, match='tracker="mjlab".*tracker="beyondmimic"'):
        write_npz(tmp_path / "x.npz", _motion(load_robot("h1")), tracker=None)
    assert main(argv + ["--npz", str(tmp_path / "h1.npz"), "--npz-for", "beyondmimic"]) == 0
    assert list(np.load(tmp_path / "h1.npz")["joint_names"]) == ISAACSIM_H1_JOINTS
    from mer_models.retarget.dataset import retarget_dataset  # what the dataset run does with --npz-for (short segments)

    retarget_dataset(str(tmp_path), "g1", ["h1"], tmp_path / "o", formats=("npz",), npz_for="beyondmimic", segment=24, context=2)
    assert list(np.load(tmp_path / "o" / "h1" / "walk.npz")["joint_names"]) == ISAACSIM_H1_JOINTS


def test_a_scaled_skeleton_is_refused(tmp_path):
    m = _motion(load_robot("h1"))
    scaled = m.skeleton.with_link_scales(np.full(m.skeleton.num_nodes, 1.1))
    with pytest.raises(OutputError, match="not a registered robot's"):
        write_npz(tmp_path / "s.npz", TargetMotion(scaled, m.fps, m.q, m.base_pos, m.base_rot), tracker="mjlab")
