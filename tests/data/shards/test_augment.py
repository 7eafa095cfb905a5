"""Target-skeleton augmentation: bounds, symmetry, key links, dropped pairs, reproducibility."""

from __future__ import annotations

import numpy as np
import pytest

from mer_data.kinematics.jointmap import END_EFFECTORS, joint_map
from mer_data.robots.registry import BUILTIN_ROBOTS, get_skeleton
from mer_data.shards.augment import (
    AugmentConfig,
    augmented_joint_map,
    draw_dropped,
    draw_link_scales,
    droppable_keypoints,
    leg_links,
    link_groups,
    mirror_nodes,
)
from mer_data.skeleton import KEYPOINTS

CFG = AugmentConfig()


@pytest.mark.parametrize("robot", BUILTIN_ROBOTS)
def test_scales_within_bounds_and_symmetric(robot):
    skel = get_skeleton(robot)
    scales = draw_link_scales(skel, np.random.default_rng(0), 500, CFG)
    legs = leg_links(skel)
    key = np.zeros(skel.num_nodes, bool)
    key[legs["thigh"] + legs["calf"]] = True
    assert legs["thigh"] and legs["calf"], "every built-in robot has thighs and calves"
    assert np.all(scales[:, 0] == 1.0)
    k, o = scales[:, key], scales[:, ~key][:, 1:]
    assert k.min() >= 0.5 and k.max() <= 2.0 and o.min() >= 0.67 and o.max() <= 1.5
    assert k.min() < 0.6 and k.max() > 1.8 and o.min() < 0.72 and o.max() > 1.4  # the full ranges are used
    mirror = mirror_nodes(skel)
    assert np.array_equal(scales, scales[:, mirror])  # left/right counterparts share a factor
    assert np.array_equal(mirror[mirror], np.arange(skel.num_nodes))


@pytest.mark.parametrize("robot", ["g1", "atlas", "valkyrie", "tron1"])
def test_thigh_and_calf_lengths_scale_by_their_factor(robot):
    skel = get_skeleton(robot)
    scales = draw_link_scales(skel, np.random.default_rng(3), 1, CFG)[0]
    aug = skel.with_link_scales(scales)
    kp = skel.keypoints
    for side in ("left", "right"):
        for top, bottom, seg in ((f"{side}_hip", f"{side}_knee", "thigh"), (f"{side}_knee", f"{side}_ankle", "calf")):
            a, b = kp[top], kp[bottom]
            before = np.linalg.norm(skel.rest_positions[b] - skel.rest_positions[a])
            after = np.linalg.norm(aug.rest_positions[b] - aug.rest_positions[a])
            factor = scales[leg_links(skel)[seg][0]]
            assert after == pytest.approx(factor * before, rel=1e-12)


def test_reproducible_with_a_seed():
    skel = get_skeleton("talos")
    a = draw_link_scales(skel, np.random.default_rng(42), 10, CFG)
    b = draw_link_scales(skel, np.random.default_rng(42), 10, CFG)
    c = draw_link_scales(skel, np.random.default_rng(43), 10, CFG)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    d1 = draw_dropped(np.random.default_rng(7), 50, AugmentConfig(drop_prob=0.3))
    d2 = draw_dropped(np.random.default_rng(7), 50, AugmentConfig(drop_prob=0.3))
    assert np.array_equal(d1, d2)


def test_end_effectors_and_base_are_never_dropped():
    dropped = draw_dropped(np.random.default_rng(0), 4000, AugmentConfig(drop_prob=0.5))
    ee = [KEYPOINTS.index(k) for k in END_EFFECTORS]
    assert not dropped[:, ee].any()
    rate = dropped[:, droppable_keypoints()].mean()
    assert 0.47 < rate < 0.53
    ref, tgt = get_skeleton("g1"), get_skeleton("h1")
    all_dropped = droppable_keypoints()
    eta = augmented_joint_map(tgt, ref, all_dropped)
    assert eta[0, 0] == 1  # the base pair stays
    for k in END_EFFECTORS:
        assert eta[tgt.keypoints[k], ref.keypoints[k]] == 1
    assert eta.sum() == 1 + len(END_EFFECTORS)
    assert np.array_equal(augmented_joint_map(tgt, ref, None), joint_map(tgt, ref))


def test_link_groups_pair_mirrored_names():
    skel = get_skeleton("atlas")
    g = link_groups(skel)
    i, j = skel.node_index("l_arm_shz"), skel.node_index("r_arm_shz")
    assert g.group[i] == g.group[j] and g.kinds[g.group[i]] == "other"
    assert g.kinds[g.group[skel.node_index("l_leg_kny")]] == "thigh"


def test_bad_ranges():
    with pytest.raises(ValueError):
        AugmentConfig(key_scale=(2.0, 0.5))
    with pytest.raises(ValueError):
        AugmentConfig(drop_prob=1.0)
