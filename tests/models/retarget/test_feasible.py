"""The feasibility pass after a physics solve: joint speed and the floor, exactly."""

from __future__ import annotations

import numpy as np
import pytest

from mer_data.robots.collision import collision_model
from mer_data.robots.registry import load_robot
from mer_models.export.writers import TargetMotion
from mer_models.retarget.artifacts import motion_artifacts
from mer_models.retarget.feasible import clamp_speed, floor_lift, make_feasible


@pytest.mark.parametrize("seed", range(5))
def test_clamp_speed_is_a_feasible_symmetric_projection(seed):
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(0, 0.05, (200, 4)), 0)
    q[80:83, 1] += 1.5  # a spike
    q[120:, 2] += 2.0  # a step
    step = np.array([0.02, 0.03, 0.05, np.inf])
    out = clamp_speed(q, step)
    assert (np.abs(np.diff(out, axis=0)) <= step + 1e-12).all()
    np.testing.assert_array_equal(out[:, 3], q[:, 3])  # a free joint is untouched
    np.testing.assert_allclose(clamp_speed(q[::-1], step)[::-1], out, atol=1e-12)  # symmetric in time
    lo, hi = q.min(0), q.max(0)
    assert ((out >= lo - 1e-12) & (out <= hi + 1e-12)).all()  # between values the path had (limits kept)
    smooth = np.linspace(0, 1, 100)[:, None] * np.array([[0.5, 0.5, 0.5, 0.5]])
    np.testing.assert_array_equal(clamp_speed(smooth, step), smooth)  # a feasible path is unchanged


def test_floor_lift_covers_every_frame_and_eases():
    low = np.zeros(60) + 0.05
    low[20] = -0.10
    low[40:45] = -0.02
    lift = floor_lift(low, 3)
    assert (lift >= np.clip(-low, 0, None) - 1e-15).all()
    assert lift[:14].max() == 0 and lift[52:].max() == 0  # only near a penetration
    assert np.abs(np.diff(lift)).max() < 0.10 / 3  # eased in and out, not a step
    np.testing.assert_array_equal(floor_lift(np.full(10, 0.01), 3), 0)


def test_make_feasible_on_a_robot():
    """H1 swinging a hip faster than its URDF allows, sunk 5 cm: afterwards no joint over 95 % of its
    limit, nothing below the floor (MuJoCo-checked metrics), mimic-free angles otherwise kept."""
    robot = load_robot("h1")
    skel, geom = robot.skeleton, collision_model(robot)
    F = 90
    q = np.tile(skel.nominal, (F, 1)).astype(np.float64)
    j = skel.node_names.index(next(n for n in skel.node_names if "hip_pitch" in n))
    q[:, j] = np.clip(0.6 * np.sin(np.linspace(0, 6 * np.pi, F)), skel.lower[j], skel.upper[j])
    q[45:, j] = np.clip(q[45:, j] + 1.0, skel.lower[j], skel.upper[j])  # a jump far over any limit
    base = np.tile([0.0, 0.0, -skel.rest_positions[:, 2].min() - 0.05], (F, 1))  # the lowest joint centre 5 cm under the floor
    rot = np.tile(np.eye(3), (F, 1, 1))
    motion = TargetMotion(skel, 30.0, q, base, rot)
    before = motion_artifacts(q, base, rot, 30.0, skel, geom)
    assert before["body_floor_frames"] > 0.5
    out, rep = make_feasible(motion, geom)
    after = motion_artifacts(out.q, out.base_pos, out.base_rot, 30.0, skel, geom)
    assert before["speed_frames"] > 0 and after["speed_frames"] == 0
    assert after["speed_ratio_max"] <= 0.95 + 1e-9
    assert after["body_floor_frames"] == 0 and after["floor_depth_max"] < 1e-9
    assert rep.frames_clamped > 0 and rep.frames_lifted > 0
    others = [k for k in range(skel.num_nodes) if k != j]
    np.testing.assert_array_equal(out.q[:, others], q[:, others])
    lo, hi = skel.lower[j], skel.upper[j]
    assert (out.q[:, j] >= lo - 1e-12).all() and (out.q[:, j] <= hi + 1e-12).all()


def test_after_the_constraint_method_a_lift_raises_only_the_frames_in_the_floor():
    """``feasible_motion``: H1 standing on the floor with frame 10 sunk 3 cm. After the penalty method
    the lift is eased over the neighbours (frames 7-13 raised); after the constraint method only
    frame 10 is raised, so the neighbours' stance feet stay on the floor (no hovering made)."""
    from mer_models.retarget.feasible import feasible_motion
    from mer_models.solver.physics import PhysicsConfig

    robot = load_robot("h1")
    skel, geom = robot.skeleton, collision_model(robot)
    F = 21
    q = np.tile(skel.nominal, (F, 1)).astype(np.float64)
    rot = np.tile(np.eye(3), (F, 1, 1))
    base = np.zeros((F, 3))
    low = motion_artifacts(q[:1], base[:1], rot[:1], 30.0, skel, geom)["body_floor_depth_max"]
    base[:, 2] = low + 1e-4  # every frame just on the floor
    base[10, 2] -= 0.03
    motion = TargetMotion(skel, 30.0, q, base, rot)
    eased = feasible_motion(motion, geom, PhysicsConfig(method="penalty")).base_pos[:, 2] - base[:, 2]
    own = feasible_motion(motion, geom, PhysicsConfig(method="constraints")).base_pos[:, 2] - base[:, 2]
    assert abs(own[10] - 0.03) < 1e-3 and abs(eased[10] - 0.03) < 1e-3
    assert np.abs(np.delete(own, 10)).max() == 0.0
    assert eased[7:14].min() > 0.003  # the envelope: the neighbours raised too
