"""Robots from MJCF (MuJoCo's XML): the tree read through MuJoCo's compiler, checked against MuJoCo's
own kinematics, the built-in G1 URDF, a URDF/MJCF pair of the same robot, and registration.

The toy model written here always runs (default classes, an ``<include>``, a body with two hinges,
``ref`` angles in degrees, slide, ball and free joints, an equality mimic, every primitive, an STL
mesh and a missing one); the real files of ``../shared/robots-mjcf`` are used where present.
"""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from mer_data.base.errors import MalformedURDFError, URDFError
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.builder import build_skeleton, zero_pose_link_transforms
from mer_data.robots.card import RobotCard, load_card
from mer_data.robots.keypoints import propose_robot
from mer_data.robots.mjcf import compile_mjcf, description_format, expand_includes, load_description, load_mjcf
from mer_data.robots.register import register_robot
from mer_data.robots.registry import load_robot
from mer_data.robots.shapes import read_collision, shapes_from_urdf
from mer_data.robots.urdf import UrdfModel, load_urdf
from mer_data.skeleton import KEYPOINTS, Skeleton
from mer_models.cli import main

RNG = np.random.default_rng(39)


# ---- a toy MJCF written in code --------------------------------------------------------------------------
def _write_stl(path: Path, size=(0.1, 0.06, 0.2)) -> None:
    """A binary STL box centred at the origin (edge lengths ``size`` [m])."""
    h = np.asarray(size) / 2
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * h
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]  # fmt: skip
    out = bytearray(b"\0" * 80) + struct.pack("<I", len(faces))
    for f in faces:
        a, b, cc = c[list(f)]
        n = np.cross(b - a, cc - a)
        out += struct.pack("<12fH", *(n / np.linalg.norm(n)), *a, *b, *cc, 0)
    path.write_bytes(bytes(out))


TOY = """<mujoco model="toy">
  <compiler angle="degree" meshdir="meshes" autolimits="true"/>
  <include file="parts/defaults.xml"/>
  <asset>
    <mesh name="shin_mesh" file="shin.stl" scale="1 1 1.5"/>
    <mesh name="gone" file="missing.stl"/>
    <texture name="skin" type="2d" file="nowhere.png"/>
    <material name="painted" texture="skin"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="pelvis" pos="0 0 1" childclass="toy">
      <freejoint name="root"/>
      <geom class="col" type="box" size="0.1 0.15 0.05"/>
      <site name="imu" pos="0 0 0.05"/>
      <body name="left_thigh" pos="0 0.1 -0.05" euler="10 0 5">
        <joint name="left_hip_roll" class="hip" axis="1 0 0" pos="0 0 0.01"/>
        <joint name="left_hip_pitch" class="hip" axis="0 1 0" pos="0.01 0 0.02"/>
        <geom class="col" type="capsule" fromto="0 0 0 0 0 -0.4" size="0.04"/>
        <body name="left_shin" pos="0 0 -0.4">
          <joint name="left_knee_joint" axis="0 1 0" range="0 150" ref="20"/>
          <geom class="col" type="mesh" mesh="shin_mesh" pos="0 0 -0.2" euler="0 0 30"/>
          <geom class="vis" type="mesh" mesh="gone" material="painted"/>
          <body name="left_foot" pos="0 0 -0.4">
            <joint name="left_ankle" type="ball" range="0 45" pos="0 0 0.01"/>
            <geom class="col" type="mesh" mesh="gone"/>
            <site name="left_toe_tip" pos="0.1 0 -0.05"/>
          </body>
        </body>
      </body>
      <include file="parts/right_leg.xml"/>
      <body name="left_arm" pos="0 0.2 0.3">
        <joint name="left_slider" type="slide" axis="0 0 1" range="-0.1 0.1" ref="0.05"/>
        <joint name="left_shoulder_joint" type="hinge" axis="0 1 0" pos="0 0 0.03"/>
        <geom class="col" type="cylinder" size="0.03 0.1" pos="0 0 -0.1"/>
        <geom class="col" type="ellipsoid" size="0.03 0.04 0.05"/>
        <body name="left_forearm" pos="0 0 -0.25" quat="0.9 0.1 0 0">
          <joint name="left_elbow_joint" axis="0 1 0" range="-90 90"/>
          <body name="left_hand" pos="0 0 -0.2"/>
        </body>
      </body>
    </body>
    <body name="ball_prop" pos="2 0 0">
      <freejoint/>
      <geom size="0.1"/>
    </body>
  </worldbody>
  <equality>
    <joint joint1="right_knee_joint" joint2="left_knee_joint" polycoef="0.1 -1 0 0 0"/>
  </equality>
</mujoco>
"""

DEFAULTS = """<mujoco>
  <default>
    <default class="toy">
      <joint damping="1"/>
      <default class="hip"><joint range="-60 60"/></default>
      <default class="col"><geom contype="1" conaffinity="1" group="3"/></default>
      <default class="vis"><geom contype="0" conaffinity="0" group="2"/></default>
    </default>
  </default>
</mujoco>
"""

RIGHT_LEG = """<mujoco>
  <body name="right_thigh" pos="0 -0.1 -0.05">
    <joint name="right_hip_joint" axis="1 0 0" range="-60 60"/>
    <geom class="col" type="capsule" size="0.04 0.2" pos="0 0 -0.2"/>
    <body name="right_shin" pos="0 0 -0.4">
      <joint name="right_knee_joint" axis="0 1 0" range="-150 150" ref="-10"/>
      <geom class="col" type="sphere" size="0.05"/>
    </body>
  </body>
</mujoco>
"""


@pytest.fixture()
def toy(tmp_path: Path) -> Path:
    (tmp_path / "parts").mkdir()
    (tmp_path / "meshes").mkdir()
    (tmp_path / "parts" / "defaults.xml").write_text(DEFAULTS)
    (tmp_path / "parts" / "right_leg.xml").write_text(RIGHT_LEG)
    _write_stl(tmp_path / "meshes" / "shin.stl")
    path = tmp_path / "toy.xml"
    path.write_text(TOY)
    return path


def test_toy_tree_follows_the_conventions(toy):
    u = load_mjcf(toy)
    assert u.root == "pelvis" and u.name == "toy" and "ball_prop" not in u.links
    j = {x.name: x for x in u.joints}
    # two hinges in one body: a chain through an intermediate link named <body>__<joint>
    assert (j["left_hip_roll"].parent, j["left_hip_roll"].child) == ("pelvis", "left_thigh__left_hip_roll")
    assert (j["left_hip_pitch"].parent, j["left_hip_pitch"].child) == ("left_thigh__left_hip_roll", "left_thigh")
    np.testing.assert_allclose(j["left_hip_pitch"].origin[:3, 3], [0.01, 0, 0.01], atol=1e-12)  # anchor to anchor
    assert j["left_hip_roll"].type == "revolute" and j["left_hip_roll"].lower == pytest.approx(-np.pi / 3)  # class default, degrees
    assert j["left_knee_joint"].upper == pytest.approx(np.radians(150))
    assert j["left_shoulder_joint"].type == "continuous" and j["left_shoulder_joint"].lower is None  # no range: unlimited
    assert j["left_slider"].type == "prismatic" and j["left_slider"].lower == pytest.approx(-0.1)
    assert [j[f"left_ankle_{a}"].type for a in "xyz"] == ["revolute"] * 3 and j["left_ankle_x"].upper == pytest.approx(np.pi / 4)
    assert j["left_hand__fixed"].type == "fixed" and j["left_hand__fixed"].child == "left_hand"
    assert j["left_toe_tip__site"].type == "fixed" and "imu" in u.links  # sites are fixed frames
    assert all(x.velocity is None for x in u.joints)  # MJCF has no velocity limits
    # the equality joint with a linear polynomial is a mimic; refs folded in (qpos units)
    master, mult, off = j["right_knee_joint"].mimic
    assert master == "left_knee_joint" and mult == -1.0
    assert off == pytest.approx(np.radians(-10) + 0.1 + np.radians(20))
    assert j["left_knee_joint"].line == TOY.splitlines().index(next(x for x in TOY.splitlines() if "left_knee_joint" in x)) + 1
    text = " ".join(u.warnings)
    assert "ball_prop" in text and "left_ankle" in text and "missing.stl" in text
    assert "bodies that lost collision geometry" in text and "left_foot" in text  # the body named
    assert "visual geometry only" in text and "left_shin" in text


def test_toy_collision_shapes(toy):
    u = load_mjcf(toy)
    kinds = {link: [c["type"] for c in cs] for link, cs in u.collisions.items()}
    assert kinds["pelvis"] == ["box"] and kinds["left_thigh"] == ["capsule"] and kinds["right_shin"] == ["sphere"]
    assert kinds["left_arm"] == ["cylinder", "mesh"]  # an ellipsoid becomes points on its surface
    box = u.collisions["pelvis"][0]
    assert box["size"] == pytest.approx((0.2, 0.3, 0.1))  # MuJoCo's half sizes, doubled
    cap = u.collisions["left_thigh"][0]
    assert cap["radius"] == pytest.approx(0.04) and cap["length"] == pytest.approx(0.4)
    cf, _ = shapes_from_urdf(u)
    assert [s.type for s in cf.links["left_thigh"]] == ["capsule"]
    hull = cf.links["left_shin"][0]
    assert hull.type == "hull"
    # the STL box 0.1 x 0.06 x (0.2 * 1.5), turned 30 degrees about z at 0.2 m below the knee, in the link frame
    np.testing.assert_allclose(np.ptp(hull.vertices[:, 2]), 0.3, atol=1e-5)
    np.testing.assert_allclose(hull.vertices[:, 2].mean(), -0.2, atol=1e-5)
    assert "left_foot" in cf.missing and "left_foot" not in cf.links  # its only collision mesh is missing
    assert "pelvis" in u.collision_points and u.inertial_coms


def test_a_mesh_mujoco_cannot_read_is_dropped_and_named(toy):
    (toy.parent / "meshes" / "shin.stl").write_bytes(b"not an STL")
    u = load_mjcf(toy)
    text = " ".join(u.warnings)
    assert "refused by MuJoCo" in text and "shin.stl" in text and "left_shin" in text
    assert set(shapes_from_urdf(u)[0].missing) == {"left_shin", "left_foot"}


def _mujoco_state(m, skel: Skeleton, rng) -> tuple[np.ndarray, dict[str, float], np.ndarray, np.ndarray]:
    """Random angles within the limits: MuJoCo's qpos, mer's angles by joint name, and a base pose."""
    qpos = m.qpos0.copy()
    by_name: dict[str, float] = {}
    for i, n in enumerate(skel.urdf_joint_names):
        if skel.node_kinds[i] == "revolute" and skel.mimic_source[i] < 0:
            by_name[n] = float(rng.uniform(max(skel.lower[i], -2.5), min(skel.upper[i], 2.5)))
    for i, n in enumerate(skel.urdf_joint_names):  # mimics follow their masters, as MuJoCo's equality would
        if skel.node_kinds[i] == "revolute" and skel.mimic_source[i] >= 0:
            src = skel.urdf_joint_names[skel.mimic_source[i]]
            by_name[n] = skel.mimic_multiplier[i] * by_name[src] + skel.mimic_offset[i]
    for n, v in {**by_name, **skel.locked}.items():
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)
        if jid >= 0:
            qpos[m.jnt_qposadr[jid]] = v
    balls = {n[:-2] for n in by_name if n[-2:] in ("_x", "_y", "_z") and mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) < 0}
    for b in balls:  # a split ball joint: intrinsic x-y-z angles as MuJoCo's quaternion
        r = np.eye(3)
        for a, axis in zip("xyz", np.eye(3)):
            k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            t = by_name[f"{b}_{a}"]
            r = r @ (np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, r.reshape(-1))
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, b)
        qpos[m.jnt_qposadr[jid] : m.jnt_qposadr[jid] + 4] = quat
    base_pos = rng.normal(size=3)
    base_quat = rng.normal(size=4)
    base_quat /= np.linalg.norm(base_quat)
    return qpos, by_name, base_pos, base_quat


def _mer_fk(skel: Skeleton, by_name: dict[str, float], base_pos, base_quat) -> tuple[np.ndarray, np.ndarray]:
    """World positions (J, 3) and link orientations (J, 3, 3) of every node."""
    q = torch.zeros(skel.num_nodes, dtype=torch.float64)
    for i, n in enumerate(skel.urdf_joint_names):
        if skel.node_kinds[i] == "revolute" and n in by_name:
            q[i] = by_name[n]
    st = skeleton_tensors(skel, torch.float64)
    pos, rot = fk_skeleton(st, q, torch.tensor(base_pos), base_quat=torch.tensor(base_quat))
    return pos.numpy(), (rot @ st.rest_rotations).numpy()


def _body_card(u: UrdfModel, m, bodies: list[str], name: str = "t", locked=None) -> RobotCard:
    """A card whose key points sit at the origins of ``bodies`` (a body's link frame is its body frame
    moved to its last joint's anchor, so the body origin is at minus that anchor)."""
    kps = {}
    for key, b in zip(KEYPOINTS, bodies):
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b)
        n = int(m.body_jntnum[bid])
        anchor = m.jnt_pos[m.body_jntadr[bid] + n - 1] if n and m.jnt_type[m.body_jntadr[bid]] != mujoco.mjtJoint.mjJNT_FREE else np.zeros(3)
        kps[key] = {"link": b, "offset": tuple(float(-x) for x in anchor)}
    from mer_data.robots.card import KeypointSpec

    full = {k: (KeypointSpec(v["link"], v["offset"]) if (v := kps.get(k)) else None) for k in KEYPOINTS}
    return RobotCard(name=name, urdf=Path(u.path).name, keypoints=full, locked=dict(locked or {}))


def _check_against_mujoco(m, u: UrdfModel, skel: Skeleton, bodies: list[str], root: str, tries: int = 5) -> float:
    """mj_kinematics at random angles vs mer's FK: joint anchors, and key points at body origins
    (positions and orientations). Returns the largest position error [m]."""
    d = mujoco.MjData(m)
    root_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, root)
    free = [j for j in range(m.body_jntadr[root_id], m.body_jntadr[root_id] + m.body_jntnum[root_id])
            if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]  # fmt: skip
    worst = 0.0
    for _ in range(tries):
        qpos, by_name, bp, bq = _mujoco_state(m, skel, RNG)
        if free:
            a = m.jnt_qposadr[free[0]]
            qpos[a : a + 3], qpos[a + 3 : a + 7] = bp, bq
        elif u.root == "world":  # a fixed base hanging from an added 'world' link: the world frame
            bp, bq = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
        else:  # a fixed base: the root link is where MuJoCo puts it
            mujoco.mj_kinematics(m, d)
            bp, bq = d.xpos[root_id].copy(), d.xquat[root_id].copy()
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        pos, rot = _mer_fk(skel, by_name, bp, bq)
        for i, n in enumerate(skel.urdf_joint_names):
            if skel.node_kinds[i] != "revolute":
                continue
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) >= 0 else n[:-2])
            worst = max(worst, float(np.abs(pos[i] - d.xanchor[jid]).max()))
        for key, b in zip(KEYPOINTS, bodies):
            node = skel.keypoints[key]
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b)
            worst = max(worst, float(np.abs(pos[node] - d.xpos[bid]).max()))
            np.testing.assert_allclose(rot[node], d.xmat[bid].reshape(3, 3), atol=1e-6)
    return worst


def test_toy_fk_matches_mujoco(toy):
    c = compile_mjcf(toy)
    u = load_mjcf(toy)
    bodies = ["left_thigh", "left_shin", "left_foot", "right_thigh", "right_shin", "left_arm", "left_forearm", "left_hand"]
    skel = build_skeleton(u, _body_card(u, c.model, bodies, locked={"left_slider": 0.07}))
    assert skel.mimic_source[skel.node_index("right_knee_joint")] == skel.node_index("left_knee_joint")
    assert _check_against_mujoco(c.model, u, skel, bodies, "pelvis") < 1e-9
    # the mimic is MuJoCo's equality: at mer's mimic angle the constraint is satisfied
    d = mujoco.MjData(c.model)
    d.qpos[:] = _mujoco_state(c.model, skel, RNG)[0]
    mujoco.mj_forward(c.model, d)
    residual = d.efc_pos[d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY]
    assert len(residual) == 1 and abs(residual[0]) < 1e-12


def test_fixed_base_root_with_a_hinge_hangs_from_world(tmp_path):
    p = tmp_path / "arm.xml"
    p.write_text("""<mujoco><worldbody><body name="base" pos="0.1 0.2 0.3" euler="0 0 90">
      <joint name="yaw" axis="0 0 1" range="-3 3"/><geom size="0.05"/>
      <body name="link" pos="0.3 0 0"><joint name="pitch" axis="0 1 0" pos="0 0 0.01" range="-1 1"/><geom size="0.05"/>
      </body></body></worldbody></mujoco>""")
    u = load_mjcf(p)
    assert u.root == "world" and u.joint("yaw").parent == "world"
    m = compile_mjcf(p).model
    skel = build_skeleton(u, _body_card(u, m, ["base", "link"]))
    assert _check_against_mujoco(m, u, skel, ["base", "link"], "base") < 1e-9


@pytest.mark.parametrize(
    "body, match, error",
    [
        ('<body name="a"><freejoint/><geom size=".1"/><body name="b"><freejoint/><geom size=".1"/></body></body>',
         "free joint", URDFError),  # MuJoCo refuses it (mer's own check stands behind)
        ('<body name="a"><joint type="hinge" nosuch="1"/><geom size=".1"/></body>', "MuJoCo cannot parse", MalformedURDFError),
        ('<body name="a"><geom type="mesh" mesh="nope"/></body>', "MuJoCo", MalformedURDFError),
        ('<include file="absent.xml"/>', "absent.xml", MalformedURDFError),
        ('<include file="m.xml"/>', "includes itself", MalformedURDFError),
    ],
    ids=["nested-free", "bad-attribute", "unknown-mesh", "missing-include", "include-cycle"],
)
def test_refusals_name_the_file_and_the_problem(tmp_path, body, match, error):
    p = tmp_path / "m.xml"
    p.write_text(f"<mujoco><worldbody>{body}</worldbody></mujoco>")
    with pytest.raises(error, match=match) as e:
        load_mjcf(p)
    assert str(p) in str(e.value) and "fix:" in str(e.value)


def test_nested_includes_cannot_multiply_past_the_size_limit(tmp_path, monkeypatch):
    """Each level includes the next ten times: 10**6 copies of the leaf unless the bytes are counted."""
    monkeypatch.setenv("MER_MAX_URDF_BYTES", "100000")
    (tmp_path / "l6.xml").write_text('<mujoco><default class="c"/></mujoco>')
    for i in range(5, -1, -1):
        (tmp_path / f"l{i}.xml").write_text("<mujoco>" + f'<include file="l{i + 1}.xml"/>' * 10 + "</mujoco>")
    with pytest.raises(MalformedURDFError, match="MER_MAX_URDF_BYTES"):
        expand_includes(tmp_path / "l0.xml")


def test_format_is_read_from_the_content(tmp_path, toy):
    assert description_format(toy) == "mjcf"
    with pytest.raises(MalformedURDFError, match="MJCF") as e:
        load_urdf(toy)  # the URDF reader says what the file is, and what to do
    assert "--mjcf" in str(e.value)
    urdf = tmp_path / "r.urdf"
    urdf.write_text('<robot name="r"><link name="a"/></robot>')
    assert description_format(urdf) == "urdf" and load_description(urdf).root == "a"
    (tmp_path / "junk.xml").write_text("not xml at all")
    assert description_format(tmp_path / "junk.xml") == "urdf"  # the URDF reader then says what is wrong
    with pytest.raises(MalformedURDFError, match="not <mujoco>"):
        load_mjcf(urdf)


def test_expand_includes_is_one_self_contained_file(toy, tmp_path):
    text = expand_includes(toy)
    assert "<include" not in text and 'name="right_knee_joint"' in text and 'class="hip"' in text
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / "flat.xml").write_text(text)
    a, b = load_mjcf(toy, geometry=False), load_mjcf(other / "flat.xml", geometry=False)
    assert a.joint_names == b.joint_names and not b.warnings[:0]
    for ja, jb in zip(a.joints, b.joints):
        np.testing.assert_array_equal(ja.origin, jb.origin)


def test_register_toy_with_mjcf_flag_and_reload(toy, capsys):
    code = main(["robots", "register", "toybot", "--mjcf", str(toy), "--lock", "left_slider=0.02"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "registered 'toybot'" in out.out and "left_foot" in out.out  # the body that lost its mesh, named
    robot = load_robot("toybot")
    assert robot.urdf_path.name == "toybot.xml" and robot.card.urdf == "toybot.xml"
    assert "<include" not in robot.urdf_path.read_text()
    assert robot.skeleton.locked["left_slider"] == pytest.approx(0.02)
    card = load_card(robot.folder / "robot.yaml")
    assert "MJCF" in card.description and card.collision == "collision.json"
    cf = read_collision(robot.folder / "collision.json")
    assert {s.type for ss in cf.links.values() for s in ss} >= {"box", "capsule", "sphere", "cylinder", "hull"}
    assert cf.missing == ("left_foot",)
    # the stored file alone rebuilds the same skeleton
    u = load_mjcf(robot.urdf_path, geometry=False)
    assert build_skeleton(u, card).fingerprint == robot.skeleton.fingerprint


def test_urdf_flag_takes_an_mjcf_and_mjcf_flag_a_urdf(toy, tmp_path, capsys):
    code = main(["robots", "register", "toy2", "--urdf", str(toy), "--dry-run"])
    out = capsys.readouterr().out
    assert code == 0 and "is an MJCF model (<mujoco> root), given as --urdf: read as MJCF" in out
    urdf = tmp_path / "r.urdf"
    urdf.write_text("""<robot name="r"><link name="a"/><link name="b"/>
      <joint name="j" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 -0.3"/>
      <axis xyz="0 1 0"/><limit lower="-1" upper="1"/></joint></robot>""")
    rep = register_robot("r2", urdf, expect="mjcf")
    assert any("a URDF (not <mujoco>), given as --mjcf" in n for n in rep.notes)
    assert load_robot("r2").urdf_path.name == "r2.urdf"  # URDF robots are stored as before


def test_collision_model_of_an_mjcf_robot(toy):
    from mer_data.robots.collision import collision_model

    register_robot("toycol", toy, locks={"left_slider": 0.0})
    model = collision_model(load_robot("toycol"))
    assert model.counts()["mesh"] >= 1 and "left_foot" in model.missing


# ---- real MJCF files (../shared/robots-mjcf) -----------------------------------------------------------------
@pytest.fixture(scope="module")
def mjcf_dir() -> Path:
    from conftest import _shared

    d = _shared() / "robots-mjcf"
    if not (d / "README.md").is_file():
        pytest.skip(f"{d} is absent (the real MJCF files of mjlab, GMR)")
    return d


REAL = {
    "g1": "mjlab_unitree_g1/g1.xml",
    "hi": "gmr_hightorque_hi/hi_25dof.xml",
    "go1": "mjlab_unitree_go1/go1.xml",
    "n1": "gmr_fourier_n1/n1_mocap.xml",
}


@pytest.mark.parametrize("name", list(REAL))
def test_real_mjcf_fk_matches_mujoco(mjcf_dir, name):
    """MuJoCo as the oracle: joint anchors and key points (at body origins and as proposed) agree to 1e-6 m."""
    path = mjcf_dir / REAL[name]
    m = compile_mjcf(path, geometry=False).model
    u = load_mjcf(path, geometry=False)
    moving = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, m.nbody)
              if m.body_jntnum[b] and m.jnt_type[m.body_jntadr[b]] != mujoco.mjtJoint.mjJNT_FREE]  # fmt: skip
    bodies = moving[:: max(1, len(moving) // 14)][:14]
    skel = build_skeleton(u, _body_card(u, m, bodies))
    assert _check_against_mujoco(m, u, skel, bodies, u.root, tries=3) < 1e-6
    # the proposed key points, with their offsets, at the places MuJoCo puts those link points
    prop = propose_robot(u, {})
    card = RobotCard(name="p", urdf="x", keypoints={k: p.spec for k, p in prop.keypoints.items()}, locked=prop.locked)
    skel = build_skeleton(u, card)
    d = mujoco.MjData(m)
    qpos, by_name, bp, bq = _mujoco_state(m, skel, RNG)
    qpos[:3], qpos[3:7] = bp, bq
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    pos, _ = _mer_fk(skel, by_name, bp, bq)
    t0 = zero_pose_link_transforms(u)
    for key, spec in card.keypoints.items():
        if spec is None:
            continue
        link = spec.link  # a site link, or a body link: find the body it is fixed to
        while mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link) < 0:
            link = u.parent_joint_of(link).parent
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link)
        body_in_link = np.eye(4)
        n = int(m.body_jntnum[bid])
        if n and m.jnt_type[m.body_jntadr[bid]] != mujoco.mjtJoint.mjJNT_FREE:
            body_in_link[:3, 3] = -m.jnt_pos[m.body_jntadr[bid] + n - 1]
        local = np.linalg.inv(t0[link] @ body_in_link) @ t0[spec.link] @ np.append(spec.offset, 1.0)  # in the body frame
        want = d.xpos[bid] + d.xmat[bid].reshape(3, 3) @ local[:3]
        assert np.abs(pos[skel.keypoints[key]] - want).max() < 1e-6, key


def test_mjlab_g1_is_the_builtin_g1(mjcf_dir):
    """mjlab's G1 MJCF and mer's built-in G1 URDF: the same joints, and the same places for the joints and
    the built-in key points at random angles (to 1e-6 m: the MJCF's quaternions have 6 digits), the same limits."""
    g1 = load_robot("g1")
    urdf = load_urdf(g1.urdf_path)
    u = load_mjcf(mjcf_dir / REAL["g1"], geometry=False)
    assert {j.name for j in u.joints if j.type != "fixed"} == {j.name for j in urdf.joints if j.type != "fixed"}
    t_urdf = zero_pose_link_transforms(urdf)
    kps = {}
    for key, spec in g1.card.keypoints.items():  # a link the MJCF lacks (the rubber hand): its nearest ancestor
        if spec is None:
            kps[key] = None
            continue
        link = spec.link
        while link not in u.links:
            link = urdf.parent_joint_of(link).parent
        p = np.linalg.inv(t_urdf[link]) @ t_urdf[spec.link] @ np.append(spec.offset, 1.0)
        kps[key] = dataclasses.replace(spec, link=link, offset=tuple(float(x) for x in p[:3]))
    skel = build_skeleton(u, dataclasses.replace(g1.card, keypoints=kps, lafan1_columns=None))
    ref = g1.skeleton
    for n in ref.joint_names:
        assert skel.lower[skel.node_index(n)] == pytest.approx(ref.lower[ref.node_index(n)], abs=1e-5), n
        assert skel.upper[skel.node_index(n)] == pytest.approx(ref.upper[ref.node_index(n)], abs=1e-5), n
    for _ in range(5):
        angles = {n: float(RNG.uniform(lo, hi)) for n, lo, hi, k in zip(ref.urdf_joint_names, ref.lower, ref.upper, ref.node_kinds)
                  if k == "revolute"}  # fmt: skip
        bp, bq = RNG.normal(size=3), RNG.normal(size=4)
        bq /= np.linalg.norm(bq)
        a, _ = _mer_fk(ref, angles, bp, bq)
        b, _ = _mer_fk(skel, angles, bp, bq)
        for n in angles:
            assert np.abs(a[ref.node_index(n)] - b[skel.node_index(n)]).max() < 1e-6, n
        for key in KEYPOINTS:
            if ref.keypoints[key] >= 0:
                assert np.abs(a[ref.keypoints[key]] - b[skel.keypoints[key]]).max() < 1e-6, key


def test_hightorque_hi_urdf_and_mjcf_give_the_same_skeleton(mjcf_dir):
    """GMR's HighTorque Hi as URDF and as MJCF: same joints, limits, axes, offsets and FK (1e-6 m)."""
    d = mjcf_dir / "gmr_hightorque_hi"
    u_mj = load_mjcf(d / "hi_25dof.xml", geometry=False)
    u_ur = load_urdf(d / "hi_25dof.urdf")
    # the URDF hangs base_link from a 'world' link by a floating joint (mer adds the floating base itself)
    u_ur = dataclasses.replace(u_ur, links=tuple(x for x in u_ur.links if x != "world"), root="base_link",
                               joints=tuple(j for j in u_ur.joints if j.type != "floating"),
                               link_lines={k: v for k, v in u_ur.link_lines.items() if k != "world"})  # fmt: skip
    prop = propose_robot(u_mj, {})
    card = RobotCard(name="hi", urdf="x", keypoints={k: p.spec for k, p in prop.keypoints.items()})
    a, b = build_skeleton(u_ur, card), build_skeleton(u_mj, card)
    assert a.node_names == b.node_names and a.node_kinds == b.node_kinds and (a.parents == b.parents).all()
    for field in ("axes", "offsets", "lower", "upper", "rest_rotations"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=1e-9, err_msg=field)
    angles = {n: float(RNG.uniform(-1, 1)) for n, k in zip(a.urdf_joint_names, a.node_kinds) if k == "revolute"}
    pa, _ = _mer_fk(a, angles, np.zeros(3), np.array([1.0, 0, 0, 0]))
    pb, _ = _mer_fk(b, angles, np.zeros(3), np.array([1.0, 0, 0, 0]))
    assert np.abs(pa - pb).max() < 1e-6
    # collision meshes: MuJoCo's compiled vertices, placed by the MJCF, are the URDF's STL points placed by the URDF
    from scipy.spatial import cKDTree

    from mer_data.robots.shapes import _mesh_points, mesh_file

    u_geo = load_mjcf(d / "hi_25dof.xml")
    for link in ("l_ankle_roll_link", "r_elbow_link"):
        e, c = u_geo.collisions[link][0], u_ur.collisions[link][0]
        mj = e["vertices"] @ e["origin"][:3, :3].T + e["origin"][:3, 3]
        ur = _mesh_points(mesh_file(c["filename"], d)) * c["scale"] @ c["origin"][:3, :3].T + c["origin"][:3, 3]
        assert cKDTree(ur).query(mj)[0].max() < 1e-6 and cKDTree(mj).query(ur)[0].max() < 1e-6, link
    hull = shapes_from_urdf(dataclasses.replace(u_geo, collisions={"l_ankle_roll_link": u_geo.collisions["l_ankle_roll_link"]}))[0]
    assert hull.links["l_ankle_roll_link"][0].type == "hull" and len(hull.links["l_ankle_roll_link"][0].vertices) <= 48


def test_go1_registers_with_its_missing_mesh_named(mjcf_dir):
    rep = register_robot("go1_mjcf", mjcf_dir / REAL["go1"], expect="mjcf")
    assert any("trunk.stl" in w for w in rep.warnings) and any("trunk" in w and "visual" in w for w in rep.warnings)
    robot = load_robot("go1_mjcf")
    assert robot.skeleton.num_dof == 12 and robot.skeleton.keypoints["left_knee"] >= 0
    cf = read_collision(robot.folder / "collision.json")
    assert {s.type for s in cf.links["trunk"]} == {"box", "sphere"}


def test_fourier_n1_registers_from_kinematics(mjcf_dir):
    rep = register_robot("n1_mjcf", mjcf_dir / REAL["n1"], dry_run=True)
    text = "\n".join(rep.warnings)
    assert "29 mesh file(s) could not be read" in text and "left_foot_pitch_link" in text
    assert rep.skeleton.num_dof == 23 and sum(v >= 0 for v in rep.skeleton.keypoints.values()) >= 10
    assert json.loads(json.dumps(rep.card.description)).endswith("MJCF)")
