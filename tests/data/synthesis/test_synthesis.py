"""Synthetic whole-body motion (mer_data.synthesis): determinism, limits, smoothness, ground, behaviours."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROBOTS

from mer_data.robots.registry import get_skeleton
from mer_data.synthesis import clip_seed, ground_heights, synthesize
from mer_data.synthesis.quat import qmatrix
from mer_data.synthesis.signals import soft_clamp

JERK_BOUND = 1.0  # rad/frame^3 at 30 Hz; LAFAN1 G1/H1 reach 2.2 / 1.7, the generator stays below 0.6


def _clips(robot: str, n: int, seconds: float = 20.0, seed: int = 0):
    skel = get_skeleton(robot)
    return skel, [synthesize(skel, seconds, 30.0, clip_seed(seed, robot, i)) for i in range(n)]


def test_soft_clamp_is_monotone_inside_and_identity_in_the_middle():
    x = np.linspace(-3, 3, 60001)
    y = soft_clamp(x, -1.0, 0.5, 0.1)
    assert y.min() == -1.0 and y.max() == 0.5  # reaches the limits exactly, never beyond
    assert np.all(np.diff(y) >= 0)
    mid = (x > -0.9) & (x < 0.4)
    assert np.array_equal(y[mid], x[mid])
    d = np.diff(y) / np.diff(x)
    assert np.abs(np.diff(d)).max() < 1e-3  # no kink anywhere (C1 and more)


def test_same_seed_same_bytes_other_seed_other_motion():
    skel = get_skeleton("g1")
    a, b = (synthesize(skel, 8.0, 30.0, clip_seed(7, "g1", 3)).motion for _ in range(2))
    for k in ("base_pos", "base_quat", "joints"):
        assert getattr(a, k).tobytes() == getattr(b, k).tobytes()
    c = synthesize(skel, 8.0, 30.0, clip_seed(8, "g1", 3)).motion
    assert not np.allclose(a.joints, c.joints)
    h1 = synthesize(get_skeleton("h1"), 8.0, 30.0, clip_seed(7, "h1", 3)).motion  # robots draw independently
    assert h1.joints.shape[1] == 19 and a.joints.shape[1] == 29


@pytest.mark.parametrize("robot", ROBOTS)
def test_every_builtin_robot_limits_smoothness_ground(robot):
    skel, clips = _clips(robot, 6, seconds=12.0)
    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    for c in clips:
        m = c.motion
        assert m.columns == skel.joint_names and m.num_frames == 361
        for a in (m.base_pos, m.base_quat, m.joints):
            assert np.all(np.isfinite(a))
        assert np.all(m.joints >= lo) and np.all(m.joints <= hi), "a joint left its limits"
        assert np.allclose(np.linalg.norm(m.base_quat, axis=1), 1.0, atol=1e-12)
        assert np.abs(np.diff(m.joints, 3, axis=0)).max() < JERK_BOUND
        assert np.abs(np.diff(m.joints, axis=0)).max() < 0.6  # rad/frame: no jumps (18 rad/s)
        lowest = ground_heights(skel, m).min(axis=1)
        grounded = c.flight == 0
        assert np.abs(lowest[grounded]).max() < 1e-9, "the lowest node must touch the ground"
        assert np.allclose(lowest[~grounded], c.flight[~grounded], atol=1e-9)  # jumps lift it by the flight height


def test_behaviours_appear_and_groups_are_independent():
    skel, clips = _clips("g1", 40)
    standing = -skel.rest_positions[:, 2].min()
    knee = [skel.joint_names.index(n) for n in ("left_knee_joint", "right_knee_joint")]
    left, right = (skel.joint_names.index(f"{s}_shoulder_pitch_joint") for s in ("left", "right"))
    kp = skel.keypoints
    found: dict[str, bool] = {}
    for c in clips:
        m = c.motion
        z = m.base_pos[:, 2] / standing
        up = qmatrix(m.base_quat)[:, 2, 2]  # cos of the base tilt
        heights = ground_heights(skel, m)
        lying = (z < 0.4) & (up < 0.35)
        standing_up = (z > 0.9) & (up > 0.94)
        found["lying"] = found.get("lying", False) or lying.any()
        found["getting up"] = found.get("getting up", False) or (lying.any() and standing_up[np.argmax(lying) :].any())
        found["crouch"] = found.get("crouch", False) or ((z < 0.75) & (up > 0.8) & (m.joints[:, knee].min(1) > 1.2)).any()
        kneeling = np.minimum(heights[:, kp["left_knee"]], heights[:, kp["right_knee"]]) < 0.03
        found["kneel"] = found.get("kneel", False) or (kneeling & (up > 0.8)).any()
        speed = np.linalg.norm(np.diff(m.base_pos[:, :2], axis=0), axis=1) * 30
        found["running"] = found.get("running", False) or speed.max() > 2.0
        yaw = np.unwrap(np.arctan2(qmatrix(m.base_quat)[:, 1, 0], qmatrix(m.base_quat)[:, 0, 0]))
        found["turning"] = found.get("turning", False) or np.ptp(yaw) > np.pi
        found["jump"] = found.get("jump", False) or heights.min(1).max() > 0.05
    assert all(found.values()), {k: v for k, v in found.items() if not v}
    q = np.concatenate([c.motion.joints for c in clips])
    assert abs(np.corrcoef(q[:, left], q[:, right])[0, 1]) < 0.5  # arms move independently
    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    reach = np.minimum((q.max(0) - lo) / (hi - lo), 1.0) - (q.min(0) - lo) / (hi - lo)
    assert reach.min() > 0.95, [skel.joint_names[j] for j in np.flatnonzero(reach <= 0.95)]  # whole ranges


def test_coverage_of_lafan1_g1(lafan1_dir):
    """The figures of docs/shards.md, on fewer synthetic clips: most of LAFAN1 lies inside the synthetic ranges."""
    import sys

    from conftest import REPO

    sys.path.insert(0, str(REPO / "tools"))
    from synthetic_coverage import report

    r = report("g1", lafan1_dir, clips=60, seconds=20.0, seed=0)
    s = r["summary"]
    assert s["joint_median"] >= 0.99 and s["joint_min"] >= 0.95
    assert s["keypoint_median"] >= 0.95
    for k in ("base_tilt", "base_height", "base_speed", "base_speed_xy"):  # issue 42: >= 95 % of LAFAN1's base states
        assert s[k] >= 0.95, (k, s[k])
    assert r["rows"]["base:tilt"]["synthetic"][1] >= 1.6 and r["rows"]["base:speed_xy"]["synthetic"][1] >= 5.0
