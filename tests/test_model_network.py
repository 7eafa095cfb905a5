"""The model as a denoiser: limits by construction, mixed batches, invariances, preconditioning."""

from __future__ import annotations


import pytest
import torch

from mer_models.edm import loss_weight, precondition, sample_sigma
from mer_models.kinematics import rot_z
from mer_models.model import RetargetModel

from model_helpers import MICRO, mixed_batch


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    m = RetargetModel(MICRO).eval()
    with torch.no_grad():  # non-trivial output heads (they start at zero)
        for head in (m.net.base_head, m.net.joint_head):
            head.weight.normal_(0, 0.5)
            head.bias.normal_(0, 0.5)
    return m


def test_every_output_angle_is_inside_the_limits(model):
    b = mixed_batch(("g1", "h1", "tron1", "talos"), augment_first=True)
    cond = model.conditions(b)
    g = cond.tgt_graph
    for sigma in (0.002, 0.5, 80.0):
        x = torch.randn(cond.shape) * 50
        with torch.no_grad():
            d = model.denoise(x, sigma, cond)
        q = model.decode(d, cond)["q"]
        assert torch.isfinite(d).all()
        assert ((q >= g.lower[:, None] - 1e-6) & (q <= g.upper[:, None] + 1e-6)).all()
        assert (d * (~g.mask)[:, None, :, None] == 0).all()  # padding nodes are zero


def test_a_sample_does_not_depend_on_the_rest_of_the_batch(model):
    b = mixed_batch(("tron1", "g1", "atlas"))
    alone = mixed_batch(("tron1",))
    torch.manual_seed(1)
    x = torch.randn(3, 60, b["tgt_mask"].shape[1], 9)
    J0 = alone["tgt_mask"].shape[1]
    with torch.no_grad():
        d_mixed = model.denoise(x, 1.0, model.conditions(b))
        d_alone = model.denoise(x[:1, :, :J0], 1.0, model.conditions(alone))
    torch.testing.assert_close(d_mixed[:1, :, :J0], d_alone, atol=2e-5, rtol=1e-4)


def test_output_moves_with_the_input_heading_and_position(model):
    """Canonical frame: rotating/translating the reference about z rotates/translates the motion."""
    b = mixed_batch(("h1",))
    b2 = dict(b)
    yaw, shift = 1.1, torch.tensor([2.0, -1.0, 0.0])
    R = rot_z(torch.tensor(yaw, dtype=torch.float64)).float()

    def move(p):
        return p @ R.T + shift

    ref = b["reference"].clone()
    from mer_models.representation import transform_features

    ref2 = transform_features(ref, R[None], -(shift @ R)[None])  # p -> R p + shift
    b2["reference"] = ref2
    b2["ref_scaled_pos"] = move(b["ref_scaled_pos"])
    x = torch.randn(1, 60, b["tgt_mask"].shape[1], 9)
    with torch.no_grad():
        c1, c2 = model.conditions(b), model.conditions(b2)
        o1 = model.decode(model.denoise(x, 0.7, c1), c1)
        o2 = model.decode(model.denoise(x, 0.7, c2), c2)
    torch.testing.assert_close(o2["q"], o1["q"], atol=2e-4, rtol=1e-3)
    torch.testing.assert_close(o2["base_pos"], move(o1["base_pos"]), atol=2e-4, rtol=1e-3)
    torch.testing.assert_close(o2["base_rot"], R @ o1["base_rot"], atol=2e-4, rtol=1e-3)


def test_low_noise_keeps_the_sample(model):
    b = mixed_batch(("g1",))
    cond = model.conditions(b)
    x = model.target_sample(b["target"], cond)
    with torch.no_grad():
        d = model.denoise(x, 0.002, cond)
    torch.testing.assert_close(d, x, atol=2e-2, rtol=0)


def test_edm_preconditioning_formulas():
    s = torch.tensor([0.5, 2.0])
    c_skip, c_out, c_in, c_noise = precondition(s, 0.5)
    torch.testing.assert_close(c_skip, torch.tensor([0.5, 0.25 / 4.25]))
    torch.testing.assert_close(c_out, s * 0.5 / torch.sqrt(s**2 + 0.25))
    torch.testing.assert_close(c_in, 1 / torch.sqrt(s**2 + 0.25))
    torch.testing.assert_close(c_noise, s.log() / 4)
    torch.testing.assert_close(loss_weight(s, 0.5), (s**2 + 0.25) / (s * 0.5) ** 2)
    # unit effective weight: weight * c_out^2 == 1
    torch.testing.assert_close(loss_weight(s, 0.5) * c_out**2, torch.ones(2))


def test_training_noise_distribution():
    g = torch.Generator().manual_seed(0)
    ln = sample_sigma(20000, -1.2, 1.2, g).log()
    assert abs(float(ln.mean()) + 1.2) < 0.05 and abs(float(ln.std()) - 1.2) < 0.05


def test_paper_configuration_builds(tmp_path):
    from mer_models.config import preset

    m = RetargetModel(preset("paper").model)
    n = m.num_parameters()
    assert 5e6 < n < 2e7  # two 4-layer decoders at H = 240
