"""The Skeleton graph: node order, psi, sites, locked and mimic joints, immutability, serialisation."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import ROBOTS
from oracles import yourdfpy_positions
from urdf_factory import Robot, humanoid

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.builder import build_skeleton
from mer_data.robots.card import KeypointSpec, RobotCard
from mer_data.robots.registry import load_robot
from mer_data.robots.urdf import parse_urdf_bytes
from mer_data.skeleton import KEYPOINTS, PSI_CHILD, PSI_PARENT, PSI_SELF, Skeleton

EXPECTED_DOF = {"g1": 29, "h1": 19, "h1_2": 27, "atlas": 30, "oli": 31, "tron1": 8, "talos": 30, "valkyrie": 32}


@pytest.mark.parametrize("name", ROBOTS)
def test_builtin_skeletons_are_well_formed(name):
    skel = load_robot(name).skeleton
    assert skel.num_dof == EXPECTED_DOF[name]
    assert skel.node_kinds[0] == "base" and skel.parents[0] == -1
    assert all(0 <= p < j for j, p in enumerate(skel.parents) if j > 0)
    rev = skel.revolute_mask
    np.testing.assert_allclose(np.linalg.norm(skel.axes[rev], axis=1), 1.0, atol=1e-12)
    assert np.all(skel.axes[~rev] == 0) and np.all(skel.offsets[0] == 0)
    assert np.all(skel.lower[rev] <= skel.nominal[rev]) and np.all(skel.nominal[rev] <= skel.upper[rev])
    # joints first (depth-first order), then sites
    kinds = list(skel.node_kinds)
    assert kinds == sorted(kinds, key=lambda k: {"base": 0, "revolute": 1, "site": 2}[k])
    for j, n in enumerate(skel.urdf_joint_names):
        assert (n is None) == (skel.node_kinds[j] != "revolute")
    assert set(skel.keypoints) == set(KEYPOINTS)


def test_locked_and_mimic_joints_of_talos_and_valkyrie():
    talos = load_robot("talos").skeleton
    assert "gripper_left_joint" not in talos.node_names
    assert talos.locked["gripper_left_fingertip_1_joint"] == 0.0  # mimic of a locked joint is held too
    assert not any("gripper" in n for n in talos.node_names)
    valk = load_robot("valkyrie").skeleton
    assert not any("Finger" in n or "Thumb" in n or "Pinky" in n for n in valk.node_names)
    atlas = load_robot("atlas").skeleton
    assert "hokuyo_joint" not in atlas.node_names and atlas.locked == {"hokuyo_joint": 0.0}


def test_psi_relations():
    skel = load_robot("tron1").skeleton
    psi = skel.psi
    assert np.all(np.diag(psi) == PSI_SELF)
    for j in range(1, skel.num_nodes):
        p = skel.parents[j]
        assert psi[j, p] == PSI_PARENT and psi[p, j] == PSI_CHILD
    assert (psi == PSI_PARENT).sum() == skel.num_nodes - 1 == (psi == PSI_CHILD).sum()


def test_sites_are_added_only_off_joint():
    g1 = load_robot("g1").skeleton
    sites = [n for n, k in zip(g1.node_names, g1.node_kinds) if k == "site"]
    assert sites == ["left_toe", "right_toe", "left_hand", "right_hand"]
    assert g1.node_kinds[g1.keypoints["left_knee"]] == "revolute"
    assert g1.node_names[g1.keypoints["left_knee"]] == "left_knee_joint"


def test_node_order_is_stable_and_independent_of_file_order(tmp_path):
    """Shuffling the joint elements in the file does not change the tree, only sibling order."""
    r = humanoid()
    a = parse_urdf_bytes(r.xml().encode(), "a.urdf")
    r.joints = list(reversed(r.joints))
    b = parse_urdf_bytes(r.xml().encode(), "b.urdf")
    card = RobotCard(name="toy", urdf="x", keypoints={k: None for k in KEYPOINTS})
    sa, sb = build_skeleton(a, card), build_skeleton(b, card)
    assert sorted(sa.node_names) == sorted(sb.node_names)
    pos_a = dict(zip(sa.node_names, sa.rest_positions))
    pos_b = dict(zip(sb.node_names, sb.rest_positions))
    for n in pos_a:
        np.testing.assert_allclose(pos_a[n], pos_b[n], atol=1e-12)
    assert build_skeleton(a, card) == sa  # deterministic


def test_mimic_joint_follows_its_master(tmp_path):
    r = Robot("mimicbot")
    r.link("base")
    r.joint("a", "revolute", "base", "l1", xyz=(0, 0, 0.1), axis=(0, 1, 0))
    r.joint("b", "revolute", "l1", "l2", xyz=(0, 0, 0.2), axis=(0, 1, 0), mimic=("a", -0.5, 0.1))
    r.joint("tipj", "fixed", "l2", "tip", xyz=(0.1, 0, 0.1))
    path = r.write(tmp_path / "m.urdf")
    kps = {k: None for k in KEYPOINTS}
    kps["left_hand"] = KeypointSpec("tip")
    card = RobotCard(name="m", urdf="m.urdf", keypoints=kps)
    skel = build_skeleton(parse_urdf_bytes(open(path, "rb").read(), path), card)
    assert skel.num_dof == 1 and skel.mimic_source[skel.node_index("b")] == skel.node_index("a")
    q = np.zeros(skel.num_nodes)
    q[skel.node_index("a")] = 0.7
    q[skel.node_index("b")] = 123.0  # ignored: b follows a
    pos, _ = fk_skeleton(skeleton_tensors(skel, torch.float64), torch.tensor(q), torch.zeros(3).double(), base_rot=torch.eye(3).double())
    np.testing.assert_allclose(pos.numpy(), yourdfpy_positions(path, skel, card, q), atol=1e-12)


def test_skeleton_is_immutable_and_round_trips_bit_exactly():
    skel = load_robot("valkyrie").skeleton
    with pytest.raises(ValueError):
        skel.offsets[1, 0] = 1.0
    with pytest.raises(AttributeError):
        skel.name = "x"  # type: ignore[misc]
    again = Skeleton.from_json(skel.to_json())
    assert again == skel and again.fingerprint == skel.fingerprint
    for k in ("offsets", "axes", "rest_rotations", "lower", "upper"):
        assert np.array_equal(getattr(again, k), getattr(skel, k))
    d = json.loads(skel.to_json())
    d["format_version"] = 99
    with pytest.raises(ValueError, match="format version"):
        Skeleton.from_dict(d)


def test_with_link_scales_validates():
    skel = load_robot("h1").skeleton
    with pytest.raises(ValueError):
        skel.with_link_scales(np.zeros(skel.num_nodes))
    scaled = skel.with_link_scales(np.full(skel.num_nodes, 2.0))
    np.testing.assert_allclose(scaled.rest_positions, 2 * skel.rest_positions)
    assert scaled.fingerprint != skel.fingerprint
