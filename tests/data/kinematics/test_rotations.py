"""Rotation conversions: round trips and agreement with independent formulas (property tests)."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mer_data.kinematics import rotations as R

finite = st.floats(-1.0, 1.0, allow_nan=False)
quats = arrays(np.float64, (4,), elements=finite).filter(lambda q: np.linalg.norm(q) > 0.1)
vecs = arrays(np.float64, (3,), elements=st.floats(-3.0, 3.0))


def t(a):
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


@settings(max_examples=200, deadline=None)
@given(quats)
def test_quat_matrix_round_trip(q):
    q = t(q / np.linalg.norm(q))
    m = R.quat_to_matrix(q)
    torch.testing.assert_close(m @ m.T, torch.eye(3, dtype=torch.float64), atol=1e-12, rtol=0)
    assert torch.det(m) > 0
    back = R.matrix_to_quat(m)
    assert torch.allclose(back, q, atol=1e-9) or torch.allclose(back, -q, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(vecs)
def test_axis_angle_round_trips(v):
    v = t(v)
    m = R.axis_angle_to_matrix(v)
    torch.testing.assert_close(R.quat_to_matrix(R.axis_angle_to_quat(v)), m, atol=1e-12, rtol=0)
    back = R.matrix_to_axis_angle(m)
    torch.testing.assert_close(R.axis_angle_to_matrix(back), m, atol=1e-9, rtol=0)
    assert back.norm() <= np.pi + 1e-9


@settings(max_examples=100, deadline=None)
@given(quats, quats)
def test_quat_multiply_is_matrix_product(a, b):
    a, b = t(a / np.linalg.norm(a)), t(b / np.linalg.norm(b))
    torch.testing.assert_close(R.quat_to_matrix(R.quat_multiply(a, b)), R.quat_to_matrix(a) @ R.quat_to_matrix(b), atol=1e-12, rtol=0)


@settings(max_examples=100, deadline=None)
@given(quats, quats, st.floats(0.0, 1.0))
def test_slerp_endpoints_and_constant_speed(a, b, s):
    a, b = t(a / np.linalg.norm(a)), t(b / np.linalg.norm(b))
    for tt, want in ((0.0, a), (1.0, b)):
        got = R.quat_slerp(a, b, t(tt))
        assert torch.allclose(got, want, atol=1e-7) or torch.allclose(got, -want, atol=1e-7)
    mid = R.quat_slerp(a, b, t(s))
    total = R.rotation_angle_between(R.quat_to_matrix(a), R.quat_to_matrix(b))
    part = R.rotation_angle_between(R.quat_to_matrix(a), R.quat_to_matrix(mid))
    assert abs(part - s * total) < 1e-6


def test_xyzw_conversion_and_small_angles():
    q = t([0.1, 0.2, 0.3, 0.9])
    torch.testing.assert_close(R.wxyz_to_xyzw(R.xyzw_to_wxyz(q)), q)
    tiny = t([1e-9, -2e-9, 0.0])
    torch.testing.assert_close(R.axis_angle_to_matrix(tiny), torch.eye(3, dtype=torch.float64) + t([[0, 0, -2e-9], [0, 0, -1e-9], [2e-9, 1e-9, 0]]), atol=1e-15, rtol=0)
    torch.testing.assert_close(R.quat_to_axis_angle(R.axis_angle_to_quat(tiny)), tiny, atol=1e-15, rtol=0)
    angle = R.rotation_angle_between(torch.eye(3, dtype=torch.float64), R.axis_angle_to_matrix(t([0.0, 0.0, np.pi - 1e-7])))
    assert abs(angle - (np.pi - 1e-7)) < 1e-9
