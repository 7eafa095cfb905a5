"""The model as a denoiser: limits by construction, mixed batches, invariances, preconditioning."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from model_helpers import MICRO, mixed_batch

from mer_models.batch import rot_z
from mer_models.diffusion.edm import loss_weight, precondition, sample_sigma
from mer_models.diffusion.model import RetargetModel


@pytest.fixture(
    scope="module",
    params=[
        (False, False, False, False),
        (True, False, False, False),
        (True, True, False, False),
        (True, True, True, False),
        (True, True, False, True),
        (False, False, False, True),
    ],
    ids=["reference-only", "goal-input", "goal-prior", "pre-norm", "goal-prior-fixed", "reference-only-fixed"],
)
def model(request):
    """``fixed``: split frame/node encodings and the base rotation in the goal's frame (issue 42)."""
    torch.manual_seed(0)
    goal_input, goal_prior, norm_first, fixed = request.param
    cfg = dataclasses.replace(MICRO, goal_input=goal_input, goal_prior=goal_prior, norm_first=norm_first,
                              split_encoding=fixed, goal_frame_rotation=fixed)  # fmt: skip
    m = RetargetModel(cfg).eval()
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
    from mer_models.diffusion.representation import transform_features

    ref2 = transform_features(ref, R[None], -(shift @ R)[None])  # p -> R p + shift
    b2["reference"] = ref2
    b2["ref_scaled_pos"] = move(b["ref_scaled_pos"])
    b2["ref_goal_rot"] = R @ b["ref_goal_rot"]  # world orientation goals turn with the world
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
    torch.testing.assert_close(d, x, atol=3e-2, rtol=0)  # c_out(0.002) = 0.002 times |F| up to ~15 with these random heads


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


def test_goal_features_give_each_node_its_scaled_reference_goal():
    """goal_input: a mapped target node gets its goal (canonical frame, base-relative, velocity,
    orientation); unmapped and padding nodes get zeros; the network uses them."""
    from mer_models.diffusion.network import GOAL_DIM
    from mer_models.solver.energy import keypoint_goals, orientation_pairs

    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True)).eval()
    b = mixed_batch(("g1", "tron1"))
    cond = m.conditions(b)
    f = m.goal_features(cond)
    assert f.shape == cond.shape[:3] + (GOAL_DIM,)
    goals, has = keypoint_goals(cond.eta, cond.goal)
    has = has & cond.tgt_graph.mask
    assert has[:, 0].all() and not has.all()  # the base is mapped, some nodes are not
    torch.testing.assert_close(f[..., 0:3], goals * has[:, None, :, None])
    torch.testing.assert_close(f[..., 3:6], (goals - goals[:, :, :1]) * has[:, None, :, None])
    assert torch.equal(f[..., 9] > 0, has[:, None].expand_as(f[..., 9]))
    assert (f[:, :, ~cond.tgt_graph.mask[1]][1] == 0).all()  # tron1's padding
    grot, has_rot = orientation_pairs(cond.eta, cond.goal_rot, cond.rot_mask)
    assert has_rot[:, 0].all()  # the base's orientation is always tracked
    torch.testing.assert_close(f[:, :, 0, 10:13], grot[:, :, 0, :, 0])
    torch.testing.assert_close(f[:, :, 0, 13:16], grot[:, :, 0, :, 1])
    # in the base goal's frame: the goal relative to the base's, and the segment from the nearest mapped ancestor
    from mer_data.robots.registry import get_skeleton

    g1 = get_skeleton("g1")
    R = grot[0, :, 0]  # (T, 3, 3) the base's orientation goal
    local = torch.einsum("tji,tnj->tni", R, goals[0] - goals[0, :, :1])
    torch.testing.assert_close(f[0, :, :, 17:20], local * has[0, None, :, None], atol=1e-5, rtol=0)
    knee, hip = g1.keypoints["left_knee"], g1.keypoints["left_hip"]
    torch.testing.assert_close(f[0, :, knee, 20:23], local[:, knee] - local[:, hip], atol=1e-5, rtol=0)
    joint = int(g1.parents[knee])  # a joint between hip and knee with no goal of its own: towards the goals below it
    assert not has[0, joint]
    below = [k for k in range(g1.num_nodes) if has[0, k] and joint in g1.path_to_root(k)]
    want = local[:, below].mean(1) - local[:, hip]
    torch.testing.assert_close(f[0, :, joint, 20:23], want, atol=1e-5, rtol=0)
    assert (f[:, :, 0, 20:23] == 0).all()
    # the goals reach the output: moving one node's goal changes the denoised sample
    with torch.no_grad():
        m.net.joint_head.weight.normal_(0, 0.5)
        x = torch.randn(cond.shape)
        d1 = m.denoise(x, 80.0, cond)
        cond.goal_feats = f.clone()
        cond.goal_feats[..., 0:3] += 0.3 * has[:, None, :, None]
        d2 = m.denoise(x, 80.0, cond)
    assert (d1 - d2).abs().max() > 1e-3


def test_goal_prior_starts_at_the_goals_and_keeps_the_sample_at_low_noise():
    """goal_prior: the untrained denoiser (F = 0) at high noise returns the base's goal pose and
    every node's goal position (its nearest mapped ancestor's where it has none); at low noise D -> x."""
    from mer_models.solver.energy import keypoint_goals, orientation_pairs

    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    b = mixed_batch(("g1", "tron1"))
    cond = m.conditions(b)
    goals, has = keypoint_goals(cond.eta, cond.goal)
    torch.manual_seed(3)
    x = torch.randn(cond.shape) * 80
    with torch.no_grad():
        d = m.denoise(x, 80.0, cond)
        out = m.decode(d, cond)
    world = m.decode(cond.prior, cond)  # the prior decoded: the goals in world coordinates
    assert (out["base_pos"] - world["base_pos"]).abs().max() < 0.02
    grot, _ = orientation_pairs(cond.eta, cond.goal_rot, cond.rot_mask)
    from mer_data.kinematics.rotations import axis_angle_to_matrix

    torch.testing.assert_close(axis_angle_to_matrix(cond.prior[:, :, 0, 0:3]), grot[:, :, 0], atol=1e-4, rtol=0)
    pos = torch.cat([d[:, :, :1, 3:6], d[:, :, 1:, 1:4]], 2)  # position features (diffusion space, pos_scale 1)
    mapped = has & cond.tgt_graph.mask
    err = (pos - goals).norm(dim=-1)[:, :, mapped[1]][1]
    assert err.max() < 0.02  # mapped nodes of the second sample sit at their goals
    unmapped = (~has[1]) & cond.tgt_graph.mask[1]
    assert unmapped.any()
    j = int(torch.nonzero(unmapped)[0])
    p = j
    while not has[1, p]:
        p = int(cond.tgt_graph.parents[1, p])
    assert (pos[1, :, j] - goals[1, :, p]).norm(dim=-1).max() < 0.02
    with torch.no_grad():
        x = m.target_sample(b["target"], cond)
        d = m.denoise(x, 0.002, cond)
    live = d.clone()
    live[:, :, 1:, 0] = x[:, :, 1:, 0]  # angles pass the limit clip; compare the linear channels
    torch.testing.assert_close(live * cond.tgt_graph.mask[:, None, :, None], x * cond.tgt_graph.mask[:, None, :, None], atol=1e-3, rtol=0)


@pytest.mark.parametrize("init_noise", [0.0, 0.5])
def test_start_frac_trains_where_the_sampler_starts(init_noise):
    """TrainConfig.start_frac: the first k samples get sigma_max and the sampler's initial state (the
    goals plus init_noise * sigma_max noise); the rest keep their noisy input and sigma."""
    from mer_models.config import RunConfig, SamplerConfig
    from mer_models.training.train import _at_sampler_start

    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    b = mixed_batch(("g1", "tron1", "h1"))
    cond = m.conditions(b)
    run = RunConfig(model=m.cfg, sampler=SamplerConfig(init_noise=init_noise, sigma_max=60.0))
    torch.manual_seed(0)
    x = torch.randn(cond.shape)
    sigma = torch.tensor([0.5, 2.0, 7.0])
    unit = torch.randn(cond.shape)
    noise = unit * sigma.view(-1, 1, 1, 1)
    x_in, s = _at_sampler_start(m, cond, run, x + noise, sigma, unit, 2)
    torch.testing.assert_close(s, torch.tensor([60.0, 60.0, 7.0]))
    prior = m.goal_prior(cond)
    want = prior[:2] + init_noise * 60.0 * unit[:2]
    torch.testing.assert_close(x_in[:2], want)
    torch.testing.assert_close(x_in[2], (x + noise)[2])


def test_project_recomputes_positions_and_velocities_from_the_angles():
    """RetargetModel.project: a sample whose features came from FK is returned unchanged; scrambled
    position and velocity features are replaced by FK of its angles and base pose."""
    from mer_data.kinematics.rotations import axis_angle_to_matrix
    from mer_models.batch import batch_features
    from mer_models.diffusion.representation import normalize

    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    b = mixed_batch(("g1", "tron1", "talos"), augment_first=True)
    cond = m.conditions(b)
    g = cond.tgt_graph
    mask = g.mask[:, None, :, None]
    torch.manual_seed(0)
    B, T, J, _ = cond.shape
    t = torch.linspace(0, 2, T)[None, :, None]
    q = g.lower[:, None] + (g.upper - g.lower)[:, None] * (0.5 + 0.4 * torch.sin(3 * t + torch.rand(B, 1, J) * 6))
    base_pos = torch.cat([t.expand(B, T, 2) * torch.rand(B, 1, 2), 0.8 + 0.05 * torch.sin(4 * t[..., :1].expand(B, T, 1))], -1)
    base_rot = axis_angle_to_matrix(torch.cat([0.1 * torch.sin(2 * t).expand(B, T, 2), 0.5 * t.expand(B, T, 1)], -1))
    x = normalize(batch_features(g, q * g.revolute[:, None], base_pos, base_rot, cond.fps), m.cfg) * mask
    torch.testing.assert_close(m.project(x, cond), x, atol=2e-5, rtol=1e-4)
    bad = x.clone()
    bad[:, :, 1:, 1:7] += torch.randn_like(bad[:, :, 1:, 1:7]) * 0.3  # positions and velocities of every joint node
    bad[:, :, 0, 6:9] += 1.0  # the base's velocity
    torch.testing.assert_close(m.project(bad * mask, cond), x, atol=2e-5, rtol=1e-4)


def test_feedback_frac_trains_on_the_networks_own_projected_estimate():
    """TrainConfig.feedback_frac: samples k..k+kf get the network's own estimate from the sampler's
    start, made consistent (project), at sigma = feedback_sigma; the others are unchanged, and the
    cached reference encoding of that gradient-free evaluation is dropped."""
    from mer_models.config import RunConfig, SamplerConfig, TrainConfig
    from mer_models.training.train import _at_feedback

    torch.manual_seed(0)
    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    with torch.no_grad():
        for head in (m.net.base_head, m.net.joint_head):
            head.weight.normal_(0, 0.5)
    b = mixed_batch(("g1", "tron1", "h1"))
    cond = m.conditions(b)
    run = RunConfig(model=m.cfg, sampler=SamplerConfig(init_noise=0.0, sigma_max=60.0, feedback_sigma=0.4),
                    train=TrainConfig(start_frac=1 / 3, feedback_frac=1 / 3))
    x_in, sigma, unit = torch.randn(cond.shape), torch.tensor([60.0, 2.0, 7.0]), torch.randn(cond.shape)
    got, s = _at_feedback(m, cond, run, x_in, sigma, unit, 1, 1, False)
    assert cond.ref_tokens is None
    torch.testing.assert_close(s, torch.tensor([60.0, 0.4, 7.0]))
    with torch.no_grad():
        want = m.project(m.denoise(m.goal_prior(cond), 60.0, cond), cond)
    torch.testing.assert_close(got[1], want[1])
    assert torch.equal(got[0], x_in[0]) and torch.equal(got[2], x_in[2])
    assert not torch.allclose(got[1], x_in[1])


def test_pre_norm_is_a_different_network_with_one_more_norm_per_decoder():
    torch.manual_seed(0)
    post = RetargetModel(MICRO)
    torch.manual_seed(0)
    pre = RetargetModel(dataclasses.replace(MICRO, norm_first=True))
    extra = set(pre.state_dict()) - set(post.state_dict())
    assert extra == {f"net.{d}.final_norm.{p}" for d in ("encoder", "denoiser") for p in ("weight", "bias")}
    assert post.net.encoder.final_norm is None  # post-norm checkpoints keep their state-dict keys
    b = mixed_batch(("h1",))
    with torch.no_grad():
        tok_post = post.net.encode_reference(post.conditions(b).reference, post.conditions(b).ref_graph)
        tok_pre = pre.net.encode_reference(pre.conditions(b).reference, pre.conditions(b).ref_graph)
    assert not torch.allclose(tok_post, tok_pre, atol=1e-3)  # same weights, other arithmetic
