"""Resampling to 30 Hz: pass-through, exact grid, lerp/slerp values, last frame kept."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mer_data.kinematics.rotations import quat_conjugate, quat_multiply, quat_to_axis_angle
from mer_data.motion.lafan1 import Motion
from mer_data.motion.resample import output_times, resample
from mer_data.synthesis.walking import walking_motion


def _motion(fps: float, frames: int, seed: int = 0) -> Motion:
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    yaw = 0.8 * np.sin(t)
    quat = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)
    return Motion("g1", fps, rng.normal(size=(frames, 3)), quat, rng.normal(size=(frames, 4)), ("a", "b", "c", "d"))


def test_30hz_passes_through_untouched():
    m = walking_motion("g1", 1.0)
    out = resample(m, 30.0)
    assert out is m  # the same arrays, bit for bit


def test_60_to_30_takes_every_other_frame_exactly_and_keeps_the_last():
    m = _motion(60.0, 121)
    out = resample(m, 30.0)
    assert out.num_frames == 61 and out.fps == 30.0
    assert out.base_pos.tobytes() == m.base_pos[::2].tobytes()
    assert out.joints.tobytes() == m.joints[::2].tobytes()
    assert out.base_quat.tobytes() == m.base_quat[::2].tobytes()
    assert np.array_equal(out.joints[-1], m.joints[-1])


def test_50_to_30_interpolates_linearly_and_by_slerp():
    m = _motion(50.0, 101)  # 2 s: the last frame lies on the 30 Hz grid
    out = resample(m, 30.0)
    assert out.num_frames == 61
    assert np.array_equal(out.joints[-1], m.joints[-1]) and np.array_equal(out.base_quat[-1], m.base_quat[-1])
    k = 7  # t = 7/30 s = input frame 11.666...
    u = k * 50 / 30
    i, w = int(u), u - int(u)
    np.testing.assert_allclose(out.base_pos[k], (1 - w) * m.base_pos[i] + w * m.base_pos[i + 1], rtol=0, atol=1e-12)
    # slerp: the rotation from q_i is the fraction w of the rotation from q_i to q_{i+1}
    q0, q1, qk = (torch.from_numpy(m.base_quat[i]), torch.from_numpy(m.base_quat[i + 1]), torch.from_numpy(out.base_quat[k]))
    full = quat_to_axis_angle(quat_multiply(q1, quat_conjugate(q0)))
    part = quat_to_axis_angle(quat_multiply(qk, quat_conjugate(q0)))
    np.testing.assert_allclose(part.numpy(), w * full.numpy(), atol=1e-12)
    assert np.allclose(np.linalg.norm(out.base_quat, axis=1), 1.0)


def test_slerp_takes_the_short_arc_across_a_sign_flip():
    m = _motion(60.0, 3)
    m.base_quat[1] *= -1  # same rotation, opposite sign
    out = resample(m.with_arrays(base_quat=m.base_quat), 40.0)
    angles = [np.degrees(2 * np.arccos(min(1.0, abs(float(np.dot(out.base_quat[j], m.base_quat[0])))))) for j in range(out.num_frames)]
    assert max(angles) < 10


def test_trailing_remainder_shorter_than_a_frame_is_dropped():
    out = resample(_motion(120.0, 1000), 30.0)  # 8.325 s -> frames at 0 .. 8.3 s
    assert out.num_frames == 250


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 2000), st.sampled_from([24.0, 25.0, 30.0, 50.0, 60.0, 100.0, 120.0, 29.97]))
def test_output_grid_property(frames, fps_in):
    u = output_times(frames, fps_in, 30.0)
    duration = (frames - 1) / fps_in
    assert u[0] == 0 and u[-1] <= frames - 1
    assert duration - (len(u) - 1) / 30.0 < 1 / 30.0 + 1e-9  # nothing longer than a frame is lost
    np.testing.assert_allclose(np.diff(u), fps_in / 30.0, rtol=1e-9)


def test_bad_rate():
    with pytest.raises(ValueError):
        resample(_motion(60.0, 10), 0.0)
