"""Joint maps eta and body-part scaling alpha_k."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROBOTS
from hypothesis import given, settings
from hypothesis import strategies as st

from mer_data.kinematics.jointmap import joint_map, keypoint_pairs
from mer_data.kinematics.scaling import body_part_scales, scale_reference_positions
from mer_data.robots.registry import get_skeleton


@pytest.mark.parametrize("target", ROBOTS)
def test_joint_map_pairs_key_points(target):
    g1, t = get_skeleton("g1"), get_skeleton(target)
    eta = joint_map(t, g1)
    assert eta.shape == (t.num_nodes, g1.num_nodes) and eta.dtype == np.uint8
    assert eta.sum(0).max() <= 1 and eta.sum(1).max() <= 1  # one-to-one
    shared = [k for k in t.keypoints if t.keypoints[k] >= 0 and g1.keypoints[k] >= 0]
    assert eta.sum() == len(shared) + 1 and eta[0, 0] == 1
    for k in shared:
        assert eta[t.keypoints[k], g1.keypoints[k]] == 1
    assert joint_map(t, g1, include_base=False).sum() == len(shared)


def test_missing_keypoints_drop_the_pair():
    pairs = {k for k, _, _ in keypoint_pairs(get_skeleton("tron1"), get_skeleton("h1"))}
    assert "left_hand" not in pairs and "left_ankle" in pairs and "base" in pairs


def test_scales_are_one_for_the_same_robot_and_reciprocal():
    g1, h1 = get_skeleton("g1"), get_skeleton("h1")
    assert all(abs(v - 1) < 1e-12 for v in body_part_scales(g1, g1).values())
    ab, ba = body_part_scales(g1, h1), body_part_scales(h1, g1)
    # least squares is not exactly symmetric, but for proportional chains it is: check the legs
    assert ab["left_leg"] * ba["left_leg"] == pytest.approx(1.0, rel=0.02)


@settings(max_examples=20, deadline=None)
@given(k=st.floats(0.5, 2.0))
def test_uniformly_scaled_robot_scales_by_k(k):
    g1 = get_skeleton("g1")
    big = g1.with_link_scales(np.full(g1.num_nodes, k))
    scales = body_part_scales(g1, big)
    for v in scales.values():
        assert v == pytest.approx(k, rel=1e-9)
    rest = g1.rest_positions + np.array([0.3, -0.2, 0.8])
    out = scale_reference_positions(rest[None], g1, big)[0]
    np.testing.assert_allclose(out, k * rest, atol=1e-12)


@pytest.mark.parametrize("target", ROBOTS)
def test_scaled_standing_pose_keeps_feet_on_the_ground(target):
    """G1's zero pose, standing and scaled to a target, puts feet and knees at the target's heights."""
    g1, t = get_skeleton("g1"), get_skeleton(target)
    p = g1.rest_positions + np.array([0, 0, -g1.rest_positions[:, 2].min()])
    out = scale_reference_positions(p, g1, t)
    t_stand = t.rest_positions[:, 2] - t.rest_positions[:, 2].min()
    for k, tol in (("left_ankle", 0.04), ("right_toe", 0.04), ("left_knee", 0.06)):
        if t.keypoints[k] >= 0:
            assert abs(out[g1.keypoints[k], 2] - t_stand[t.keypoints[k]]) < tol, k
    assert out[:, 2].min() > -0.01  # nothing below the ground


def test_parts_missing_on_the_target_fall_back_to_the_root_scale():
    scales = body_part_scales(get_skeleton("g1"), get_skeleton("tron1"))
    assert scales["left_arm"] == scales["root"] and np.isfinite(list(scales.values())).all()
