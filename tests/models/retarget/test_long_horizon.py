"""Long-horizon retargeting: clip coverage, in-painting, no seam at clip boundaries."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from model_helpers import MICRO

from mer_data.robots.registry import get_skeleton
from mer_models.config import SamplerConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.retarget.long_horizon import clip_starts, retarget_sequence
from mer_models.training.synthetic import _features, synthetic_motion


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 500), frames=st.integers(2, 80), data=st.data())
def test_clips_cover_every_frame_in_order(n, frames, data):
    overlap = data.draw(st.integers(0, frames - 1))
    starts = clip_starts(n, frames, overlap)
    covered = np.zeros(max(n, frames), bool)
    for s in starts:
        covered[s : s + frames] = True
    assert covered[:n].all()
    assert starts == sorted(starts) and starts[0] == 0
    for a, b in zip(starts, starts[1:]):
        assert b - a <= frames - overlap  # consecutive clips share at least `overlap` frames
    if n >= frames:
        assert starts[-1] + frames == n


class SmoothPrior:
    """The exact denoiser of zero-mean Gaussian-process data along time (RBF kernel, per channel):
    ``D(x, sigma) = K (K + sigma^2 I)^-1 x``. Each clip it samples is a smooth random curve, unrelated
    to the previous clip unless in-painting ties them together."""

    def __init__(self, T: int, length: float = 6.0, var: float = 0.25) -> None:
        t = torch.arange(T, dtype=torch.float64)
        self.K = var * torch.exp(-0.5 * ((t[:, None] - t[None]) / length) ** 2)

    def __call__(self, x, sigma, cond):
        s2 = float(sigma) ** 2
        M = self.K @ torch.linalg.inv(self.K + s2 * torch.eye(len(self.K), dtype=torch.float64))
        return torch.einsum("ts,bsjc->btjc", M.to(x.dtype), x)


def _boundary_jumps(q: np.ndarray, boundaries: list[int]) -> tuple[float, float]:
    step = np.abs(np.diff(q, axis=0)).max(axis=1)  # largest joint change per frame
    at = max(step[b - 1] for b in boundaries)
    inside = np.median(step)
    return at, inside


@pytest.mark.parametrize("inpaint", [True, False])
def test_no_jump_at_clip_boundaries_with_inpainting(inpaint, monkeypatch):
    torch.manual_seed(0)
    g1 = get_skeleton("g1")
    model = RetargetModel(MICRO).eval()
    monkeypatch.setattr(model, "denoise", SmoothPrior(60))
    ref = _features(g1, synthetic_motion(g1, 150, seed=3), 30.0)
    out = retarget_sequence(model, ref, g1, get_skeleton("h1"), SamplerConfig(steps=12, overlap=10), inpaint=inpaint, seed=1)
    assert out["q"].shape == (150, get_skeleton("h1").num_nodes)
    # clips start at 0, 50, 90: the first generated frames are 60 and 110
    at, inside = _boundary_jumps(out["q"], [60, 110])
    if inpaint:
        assert at < 4 * inside, (at, inside)
    else:
        assert at > 4 * inside, (at, inside)  # the test can fail: plain concatenation jumps


def test_short_motion_is_padded_and_trimmed():
    torch.manual_seed(0)
    g1 = get_skeleton("g1")
    model = RetargetModel(MICRO).eval()
    ref = _features(g1, synthetic_motion(g1, 25, seed=0), 30.0)
    out = retarget_sequence(model, ref, g1, get_skeleton("tron1"), SamplerConfig(steps=2))
    t1 = get_skeleton("tron1")
    assert out["q"].shape == (25, t1.num_nodes) and out["base_rot"].shape == (25, 3, 3)
    assert ((out["q"] >= t1.lower - 1e-6) & (out["q"] <= t1.upper + 1e-6)).all()


def test_an_oracle_denoiser_reproduces_the_source_motion(monkeypatch):
    """G1 -> G1 with a denoiser that returns the (canonical) reference: the long-horizon pipeline
    (origin shift, per-clip canonical frames, in-painting, decoding) must give back the source."""
    g1 = get_skeleton("g1")
    model = RetargetModel(MICRO).eval()
    monkeypatch.setattr(model, "denoise", lambda x, sigma, cond: cond.reference)
    motion = synthetic_motion(g1, 137, seed=5)
    ref = _features(g1, motion, 30.0)
    out = retarget_sequence(model, ref, g1, g1, SamplerConfig(steps=2, overlap=10))
    np.testing.assert_allclose(out["base_pos"], motion["base_pos"], atol=2e-5)
    np.testing.assert_allclose(out["q"], motion["q"], atol=2e-5)
    from mer_data.kinematics.rotations import quat_to_matrix

    np.testing.assert_allclose(out["base_rot"], quat_to_matrix(torch.from_numpy(motion["base_quat"])).numpy(), atol=2e-5)


def test_several_targets_in_one_pass_equal_one_target_calls():
    """``retarget_sequences``: the reference encoded once per window for every target, and each
    target's motion exactly what a one-target call gives (its own noise, in-painting across windows)."""
    from mer_models.retarget.long_horizon import retarget_sequences

    torch.manual_seed(0)
    g1 = get_skeleton("g1")
    model = RetargetModel(MICRO).eval()
    with torch.no_grad():
        for head in (model.net.base_head, model.net.joint_head):  # heads start at zero: make the network matter
            head.weight.normal_(0, 0.3)
            head.bias.normal_(0, 0.3)
    ref = _features(g1, synthetic_motion(g1, 130, seed=2), 30.0)
    targets = [get_skeleton(n) for n in ("h1", "tron1", "g1")]
    sampler = SamplerConfig(steps=3, overlap=10, init_noise=1.0)  # Heun from noise
    calls = []
    hook = model.net.encoder.register_forward_hook(lambda mod, args, out: calls.append(out.shape[0]))
    many = retarget_sequences(model, ref, g1, targets, sampler, seed=1)
    windows = len(clip_starts(130, MICRO.frames, 10))
    assert calls == [1] * windows  # once per window, not once per target
    hook.remove()
    for t, out in zip(targets, many):
        one = retarget_sequence(model, ref, g1, t, sampler, seed=1)
        assert out["q"].shape == one["q"].shape == (130, t.num_nodes)
        for k in ("q", "base_pos", "base_rot"):
            np.testing.assert_allclose(out[k], one[k], atol=1e-6, err_msg=f"{t.name} {k}")
    assert not np.allclose(many[0]["q"][:, :5], 0, atol=1e-3)  # the network's output, not a constant
