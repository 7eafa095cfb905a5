"""Key points: the built-in cards against the reference reading, proposals for unseen robots, mirrors."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from conftest import ROBOTS
from urdf_factory import biped, humanoid, quadruped

from mer_data.robots.builder import build_skeleton
from mer_data.robots.card import RobotCard
from mer_data.robots.keypoints import propose_keypoints, propose_robot
from mer_data.robots.registry import load_robot
from mer_data.robots.urdf import load_urdf, parse_urdf_bytes
from mer_data.skeleton import KEYPOINTS


def _swap(k: str) -> str:
    return k.replace("left", "\0").replace("right", "left").replace("\0", "right")


@pytest.mark.parametrize("name", ROBOTS)
def test_builtin_keypoints_agree_with_the_reference_reading(name, shared_robots):
    ref = json.loads((shared_robots / "keypoints.reference.json").read_text())[name]
    skel = load_robot(name).skeleton
    rest = skel.rest_positions
    for k in KEYPOINTS:
        if ref.get(k) is None:
            assert skel.keypoints[k] == -1
            continue
        node = skel.keypoints[k]
        assert node >= 0, k
        # the reading rounds to 0.1 mm
        np.testing.assert_allclose(rest[node], ref[k]["pos_zero_pose_in_root"], atol=1e-4, err_msg=k)


@pytest.mark.parametrize("name", ROBOTS)
def test_builtin_urdfs_are_the_shared_ones(name, shared_robots):
    """Byte for byte the shared URDF, but for the mesh file names: a built-in that ships its compact
    visual meshes (issue 52) names them ``visual/<the upstream file's stem>.stl`` (a COLLADA original
    converted; a stem two meshes share prefixed by its part, e.g. TALOS's ``gripper_base_link``), and
    they are there."""
    robot = load_robot(name)
    ours, theirs = robot.urdf_path.read_bytes(), (shared_robots / name / f"{name}.urdf").read_bytes()
    mesh = re.compile(rb'filename="([^"]*)"')
    assert mesh.sub(b"F", ours) == mesh.sub(b"F", theirs)
    for a, b in zip(mesh.findall(ours), mesh.findall(theirs), strict=True):
        if a != b:
            assert a.startswith(b"visual/") and (robot.folder / a.decode()).is_file(), a
            stem = b.rsplit(b"/", 1)[-1].rsplit(b".", 1)[0]
            assert a[len(b"visual/") :].rsplit(b".", 1)[0].endswith(stem), (a, b)
    assert (robot.folder / "LICENSE").read_bytes() == (shared_robots / name / "LICENSE").read_bytes()


@pytest.mark.parametrize("name", ROBOTS)
def test_proposals_on_real_robots_are_close_to_the_reading(name):
    """Where the proposer commits to a key point, it is within 6 cm of the curated one."""
    robot = load_robot(name)
    props = propose_keypoints(load_urdf(robot.urdf_path), dict(robot.card.locked))
    rest = robot.skeleton.rest_positions
    for k, p in props.items():
        node = robot.skeleton.keypoints[k]
        if p.spec is None:
            assert p.confidence == "absent" and p.reason
            continue
        assert node >= 0, f"proposed {k} that {name} does not have"
        assert np.linalg.norm(np.asarray(p.position) - rest[node]) < 0.06, (k, p)


def _proposed_skeleton(robot_factory_output):
    model = parse_urdf_bytes(robot_factory_output.xml().encode(), robot_factory_output.name)
    props = propose_keypoints(model)
    card = RobotCard(name="x", urdf="x.urdf", keypoints={k: p.spec for k, p in props.items()})
    return build_skeleton(model, card), props


def test_unseen_humanoid_gets_all_keypoints_right():
    skel, props = _proposed_skeleton(humanoid(tilt=0.3))
    expect = {
        "left_hip": "left_hip_pitch_joint", "left_knee": "left_knee_joint", "left_ankle": "left_ankle_roll_joint",
        "left_shoulder": "left_shoulder_roll_joint", "left_elbow": "left_elbow_joint",
    }  # fmt: skip
    for k, node_name in expect.items():
        assert skel.node_names[skel.keypoints[k]] == node_name, k
        assert skel.node_names[skel.keypoints[_swap(k)]] == _swap(node_name)
    assert skel.link_names[skel.keypoints["left_hand"]] == "left_hand_link"
    toe = skel.rest_positions[skel.keypoints["left_toe"]] - skel.rest_positions[skel.keypoints["left_ankle"]]
    np.testing.assert_allclose(toe, [0.14, 0.0, -0.04], atol=1e-9)  # front-bottom of the foot box
    assert all(p.confidence in ("high", "medium") for p in props.values())


def test_unseen_biped_without_arms():
    skel, props = _proposed_skeleton(biped())
    for k in ("left_shoulder", "right_elbow", "left_hand"):
        assert skel.keypoints[k] == -1 and props[k].confidence == "absent"
    for k in ("left_hip", "left_knee", "left_ankle", "left_toe", "right_toe"):
        assert skel.keypoints[k] >= 0
    assert skel.node_names[skel.keypoints["left_knee"]] == "knee_left_joint"


def test_unseen_quadruped_maps_rear_legs_to_legs_and_front_legs_to_arms():
    skel, props = _proposed_skeleton(quadruped())
    name = lambda k: skel.link_names[skel.keypoints[k]]  # noqa: E731
    assert name("left_knee") == "RL_calf" and name("right_knee") == "RR_calf"
    assert name("left_ankle") == "RL_foot"
    assert name("left_elbow") == "FL_calf" and name("right_hand") == "FR_foot"
    assert props["left_shoulder"].confidence == "medium" and "standing in for the arm" in props["left_shoulder"].reason
    assert skel.keypoints["left_toe"] == -1


def test_mirrored_robot_gives_mirrored_keypoints():
    robot = humanoid(asymmetric=True, tilt=0.2)
    skel, _ = _proposed_skeleton(robot)
    mskel, _ = _proposed_skeleton(robot.mirrored())
    flip = np.array([1.0, -1.0, 1.0])
    for k in KEYPOINTS:
        a, b = skel.keypoints[k], mskel.keypoints[_swap(k)]
        assert (a >= 0) == (b >= 0)
        if a >= 0:
            np.testing.assert_allclose(mskel.rest_positions[b], skel.rest_positions[a] * flip, atol=1e-12, err_msg=k)


@pytest.mark.parametrize("name", ["talos", "valkyrie"])
def test_proposed_finger_locks_are_the_curated_ones(name):
    """Without the card's locks, the proposer locks exactly the joints the curated card locks."""
    robot = load_robot(name)
    got = propose_robot(load_urdf(robot.urdf_path))
    assert got.locked == dict(robot.card.locked)
    rest = robot.skeleton.rest_positions
    for k, p in got.keypoints.items():
        if p.spec is not None:
            assert np.linalg.norm(np.asarray(p.position) - rest[robot.skeleton.keypoints[k]]) < 0.06, (k, p)
