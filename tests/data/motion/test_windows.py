"""Windows: coverage, origin normalization, and features that agree with the foundation's FK."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.motion.features import finite_difference, motion_features
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.motion.windows import make_windows, window_features, window_starts
from mer_data.robots.registry import get_skeleton
from mer_data.shards import BuildConfig
from mer_data.synthesis.walking import walking_motion


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 3000), st.integers(3, 120), st.data())
def test_windows_cover_every_frame(frames, window, data):
    stride = data.draw(st.integers(1, window))  # BuildConfig refuses stride > window
    starts = window_starts(frames, window, stride)
    if frames < window:
        assert len(starts) == 0
        return
    covered = np.zeros(frames, bool)
    for s in starts:
        covered[s : s + window] = True
    assert covered.all()
    assert starts[0] == 0 and starts[-1] == frames - window
    assert np.all(np.diff(starts) > 0) and np.all(np.diff(starts) <= stride)


def test_stride_longer_than_the_window_is_refused():
    with pytest.raises(ValueError, match="stride"):
        BuildConfig(input="x", robots=("g1",), window=60, stride=61)


def test_default_stride_gives_non_overlapping_windows_plus_a_tail():
    assert window_starts(250, 60, 60).tolist() == [0, 60, 120, 180, 190]
    assert window_starts(240, 60, 60).tolist() == [0, 60, 120, 180]
    assert window_starts(59, 60, 60).tolist() == []


def _fk64(skel, m, sel):
    st = skeleton_tensors(skel, torch.float64)
    pos, _ = fk_skeleton(st, torch.from_numpy(m.node_angles(skel)[sel]), torch.from_numpy(m.base_pos[sel]),
                         base_quat=torch.from_numpy(m.base_quat[sel]))  # fmt: skip
    return pos.numpy()


def test_origin_normalization():
    m = walking_motion("h1", 6.0)
    skel = get_skeleton("h1")
    starts = window_starts(m.num_frames, 60, 45)
    wb = make_windows(m, skel, starts, 60)
    for i, s in enumerate(starts):
        sel = np.arange(s, s + 60)
        world = _fk64(skel, m, sel)
        assert np.allclose(wb.pos[i, 0, 0, :2], 0.0, atol=1e-7)  # first frame's base at the origin
        np.testing.assert_allclose(wb.origin_xy[i], m.base_pos[s, :2])
        shifted = world.copy()
        shifted[..., :2] -= m.base_pos[s, :2]
        np.testing.assert_allclose(wb.pos[i], shifted, atol=2e-6)  # every position shifted the same way
        np.testing.assert_allclose(wb.pos[i, :, 0, 2], m.base_pos[sel, 2], atol=1e-6)  # height kept


@pytest.mark.parametrize("robot,clip", [("g1", "fallAndGetUp1_subject1"), ("h1", "dance1_subject1")])
def test_features_agree_with_the_foundation_fk_on_real_clips(lafan1_dir, robot, clip):
    m = read_lafan1_csv(lafan1_dir / robot / f"{clip}.csv", robot)
    skel = get_skeleton(robot)
    starts = window_starts(m.num_frames, 60, 60)[::7]
    wb = make_windows(m, skel, starts, 60)
    feats = window_features(wb.pos, wb.q, wb.base_rotvec)
    assert feats.shape == (len(starts), 60, skel.num_nodes, 9) and feats.dtype == np.float32
    for i, s in enumerate(starts):
        sel = np.arange(s, s + 60)
        world = _fk64(skel, m, sel)
        world[..., :2] -= m.base_pos[s, :2]
        np.testing.assert_allclose(feats[i, :, 1:, 1:4], world[:, 1:], atol=2e-6)  # node positions [m]
        np.testing.assert_allclose(feats[i, :, 0, 3:6], world[:, 0], atol=2e-6)  # base position
        vel = finite_difference(torch.from_numpy(world), 30.0, dim=-3).numpy()
        np.testing.assert_allclose(feats[i, :, 1:, 4:7], vel[:, 1:], atol=1e-4)  # [m/s], float32 differences
        np.testing.assert_allclose(feats[i, :, 1:, 0], m.node_angles(skel)[sel][:, 1:], atol=1e-6)
        assert np.all(feats[i, :, 1:, 7:] == 0)
        sites = [j for j, k in enumerate(skel.node_kinds) if k == "site"]
        assert sites and np.all(feats[i, :, sites, 0] == 0)  # sites included, zero angle
    # bit-identical to motion_features of the same batch (what the build computes)
    idx = starts[:, None] + np.arange(60)
    base = m.base_pos[idx].copy()
    base[..., :2] -= m.base_pos[starts, None, :2]
    st32 = skeleton_tensors(skel, torch.float32)
    ref = motion_features(st32, torch.from_numpy(base.astype(np.float32)), torch.from_numpy(m.base_quat[idx].astype(np.float32)),
                          torch.from_numpy(m.node_angles(skel)[idx].astype(np.float32)))  # fmt: skip
    assert feats.tobytes() == ref.numpy().tobytes()


@pytest.mark.parametrize("frames", [1, 2, 3, 4, 61])
@pytest.mark.parametrize("dim", [-3, 0, 1])
def test_finite_difference_is_numpy_gradient(frames, dim):
    """Second order inside and at both ends (edge_order=2), as numpy.gradient (first order with 2 frames, zeros with 1)."""
    shape = [4, 5, 3]
    shape.insert(dim % 4, frames)  # time axis at ``dim`` of a 4-d array
    x = torch.from_numpy(np.random.default_rng(frames).normal(size=shape) * 3.0)
    got = finite_difference(x, 30.0, dim=dim)
    assert got.shape == x.shape
    if frames >= 3:
        ref = np.gradient(x.numpy(), 1 / 30.0, axis=dim, edge_order=2)
    elif frames == 2:
        ref = np.gradient(x.numpy(), 1 / 30.0, axis=dim, edge_order=1)
    else:
        ref = np.zeros(shape)
    np.testing.assert_allclose(got.numpy(), ref, rtol=1e-12, atol=1e-12)
    x32 = x.float().requires_grad_()
    v = finite_difference(x32, 30.0, dim=dim)  # float32 and autograd (the energy differentiates through it)
    np.testing.assert_allclose(v.detach().numpy(), ref, rtol=1e-5, atol=1e-4)
    if frames >= 2:
        v.square().sum().backward()
        assert x32.grad is not None and torch.isfinite(x32.grad).all()
