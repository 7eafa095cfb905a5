"""Issue 42's two fixes of the diffusion model, behind ModelConfig flags: distinct frame and node
encodings (``split_encoding``) and the base orientation as ``R_goal Exp(delta)`` (``goal_frame_rotation``);
checkpoints written before them (the bundled ``mer-base``) give the same outputs as before."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from model_helpers import MICRO, micro_run, mixed_batch

from mer_data.kinematics.fk import skeleton_tensors
from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import axis_angle_to_matrix, axis_angle_to_quat, rotation_angle_between
from mer_data.motion.features import motion_features
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.registry import get_skeleton
from mer_models.config import from_dict, preset
from mer_models.diffusion.edm import denoising_loss
from mer_models.diffusion.model import RetargetModel
from mer_models.diffusion.network import GraphConditions, TokenEncoder, node_codes
from mer_models.diffusion.representation import denormalize
from mer_models.training.train import clean_samples

FIXED = dataclasses.replace(MICRO, goal_input=True, goal_prior=True, split_encoding=True, goal_frame_rotation=True)


# ---- distinct encodings ---------------------------------------------------------------------------
@pytest.mark.parametrize("split", [False, True])
def test_frame_t_node_j_and_frame_j_node_t_get_different_codes_only_with_split_encoding(split):
    torch.manual_seed(0)
    enc = TokenEncoder(24, split).eval()
    T, J = 60, 34
    with torch.no_grad():
        h = enc(torch.zeros(1, T, J, 9))[0]  # every joint token gets the same features: only the code differs
    t, j = torch.triu_indices(J, J, offset=1)
    keep = t >= 1  # node 0 (the base) has its own encoder
    t, j = t[keep], j[keep]
    diff = (h[t, j] - h[j, t]).abs().amax(-1)  # (pairs,)
    assert len(diff) == 33 * 32 // 2
    if split:
        assert float(diff.min()) > 1e-3  # every twin pair is told apart
    else:
        assert float(diff.max()) < 1e-5  # s(t) + s(j) = s(j) + s(t): the 1,122 ordered twins of a 34-node window


def test_split_node_code_fills_the_second_half_and_the_conditions_share_it():
    J, H = 34, 24
    code = node_codes(J, H, True)
    assert (code[:, : H // 2] == 0).all() and (code[:, H // 2 :].abs().sum(-1) > 0).all()
    torch.manual_seed(0)
    cond_split = GraphConditions(H, True)
    b = mixed_batch(("g1",))
    from mer_models.batch import graph_from_batch

    g = graph_from_batch(b, "tgt", torch.device("cpu"))
    with torch.no_grad():
        out = cond_split(g)[0]  # axes tokens
        plain = cond_split.axes(g.axes)
    torch.testing.assert_close(out - plain, code[None].expand_as(out))


# ---- R_goal Exp(delta) ----------------------------------------------------------------------------
def _tilted(angles: torch.Tensor, axis: torch.Tensor, T: int) -> torch.Tensor:
    """(B, T, 3, 3) rotations about unit ``axis`` (B, 3) by ``angles`` (B,) [rad] + a slow turn along the window."""
    a = angles[:, None] + 0.004 * torch.arange(T)[None]
    return axis_angle_to_matrix(a[..., None] * axis[:, None])


def _large_tilt_batch(goal_angles, teacher_angles):
    """A G1 → G1 batch whose base orientation goals and target/teacher base orientations are tilted by the given angles."""
    n = len(goal_angles)
    b = mixed_batch(("g1",) * n)
    T = b["target"].shape[1]
    torch.manual_seed(5)
    axis = torch.nn.functional.normalize(torch.randn(n, 3) * torch.tensor([1.0, 1.0, 0.2]), dim=-1)  # mostly tilt, a little yaw
    goal = _tilted(torch.tensor(goal_angles), axis, T)
    other = torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)
    teacher = _tilted(torch.tensor(teacher_angles), other, T)
    b["ref_goal_rot"] = b["ref_goal_rot"].clone()
    b["ref_goal_rot"][:, :, 0] = goal
    from mer_data.kinematics.rotations import matrix_to_axis_angle

    b["target"] = b["target"].clone()
    b["target"][:, :, 0, 0:3] = matrix_to_axis_angle(teacher)
    b["teacher"], b["has_teacher"] = b["target"].clone(), torch.ones(n, dtype=torch.bool)
    assert b["ref_rot_mask"][:, 0].all()  # the base has an orientation goal (else R_goal = I)
    return b, teacher


@pytest.mark.parametrize("fixed", [False, True])
def test_target_sample_decodes_to_the_teachers_rotation_at_any_tilt(fixed):
    """target_sample → decode gives the teacher's base rotation back, with tilts near pi/2 and beyond
    (lying, upside down); with the fix the sample's delta is the geodesic angle from the goal."""
    m = RetargetModel(dataclasses.replace(FIXED, split_encoding=fixed, goal_frame_rotation=fixed)).eval()
    goal_angles = [0.2, 1.5, 1.6, 2.4, 3.0, 3.1]
    teacher_angles = [1.57, 1.55, 2.0, 1.0, 3.13, 0.05]
    b, teacher = _large_tilt_batch(goal_angles, teacher_angles)
    cond = m.conditions(b)
    x = m.target_sample(b["target"], cond)
    out = m.decode(x, cond)
    torch.testing.assert_close(out["base_rot"], teacher, atol=2e-5, rtol=0)
    world = cond.rot.transpose(-1, -2)[:, None]
    if fixed:
        goal = cond.rot[:, None] @ b["ref_goal_rot"][:, :, 0]  # canonical frame
        torch.testing.assert_close(m.base_goal_rotation(cond), goal, atol=1e-6, rtol=0)
        angle = rotation_angle_between(goal, cond.rot[:, None] @ teacher)
        torch.testing.assert_close(x[:, 0, 0, 0:3].norm(dim=-1), angle[:, 0], atol=2e-5, rtol=0)
        # decoding the goal prior (delta = 0) is the goal itself
        prior = m.goal_prior(cond)
        assert (prior[:, :, 0, 0:3] == 0).all()
        torch.testing.assert_close(m.decode(prior, cond)["base_rot"], world @ goal, atol=2e-5, rtol=0)


def test_a_small_deviation_from_a_large_tilt_is_a_small_delta():
    """The conditioning the fix is for: a teacher 0.06 rad from a goal tilted by 3.16 rad (just past
    pi) has |delta| = 0.06 at every frame; the additive residual of the two rotation vectors (each
    unwrapped from its own first frame) is 6.2: the goal's rotation vector is the other representative."""
    m = RetargetModel(FIXED).eval()
    b = mixed_batch(("g1",))
    T = b["target"].shape[1]
    x_axis = torch.tensor([[1.0, 0.0, 0.0]])
    goal, teacher = _tilted(torch.tensor([3.16]), x_axis, T), _tilted(torch.tensor([3.10]), x_axis, T)
    from mer_data.kinematics.rotations import matrix_to_axis_angle

    b["ref_goal_rot"] = b["ref_goal_rot"].clone()
    b["ref_goal_rot"][:, :, 0] = goal
    b["target"] = b["target"].clone()
    b["target"][:, :, 0, 0:3] = matrix_to_axis_angle(teacher)
    cond = m.conditions(b)
    x = m.target_sample(b["target"], cond)
    torch.testing.assert_close(x[0, :, 0, 0:3].norm(dim=-1), torch.full((T,), 0.06), atol=2e-5, rtol=0)
    old = RetargetModel(dataclasses.replace(FIXED, goal_frame_rotation=False)).eval()
    additive = old.target_sample(b["target"], cond) - old.goal_prior(old.conditions(b))
    assert float(additive[0, 0, 0, 0:3].norm()) > 6.0


def test_training_targets_and_sampling_agree_on_the_base_rotation():
    """clean_samples (the teacher's files and the on-the-fly optimiser) → decode gives the same world
    motion with and without the fix: the training target is delta = Log(R_goal^T R_teacher)."""
    b, teacher = _large_tilt_batch([0.3, 1.6, 2.5], [1.5, 1.7, 0.4])
    run = micro_run()
    outs = {}
    for fixed in (False, True):
        m = RetargetModel(dataclasses.replace(FIXED, goal_frame_rotation=fixed)).eval()
        cond = m.conditions(b)
        has = b["has_teacher"].clone()
        has[1] = False  # the second sample is solved on the fly (the optimiser's fallback)
        x = clean_samples(m, {**b, "has_teacher": has}, cond, run.replace(model=m.cfg))
        outs[fixed] = (x, m.decode(x, cond))
    (x0, o0), (x1, o1) = outs[False], outs[True]
    for k in ("q", "base_pos", "base_rot"):
        torch.testing.assert_close(o1[k], o0[k], atol=3e-5, rtol=0)
    torch.testing.assert_close(o1["base_rot"][[0, 2]], teacher[[0, 2]], atol=2e-5, rtol=0)
    assert (x1[:, :, 0, 0:3] - x0[:, :, 0, 0:3]).abs().max() > 0.1  # a different coordinate, the same rotation
    torch.testing.assert_close(x1[..., 1:, :], x0[..., 1:, :])  # nothing else moves


def test_a_tiny_network_with_both_fixes_trains_forward_and_backward():
    """One forward/backward of the loss (EDM + energy) at large tilts: finite, and every parameter
    that the loss reaches gets a gradient; then two training steps through train() write a checkpoint
    whose configuration keeps the flags."""
    torch.manual_seed(0)
    m = RetargetModel(FIXED)
    b, _ = _large_tilt_batch([1.5, 3.1], [1.6, 3.0])
    cond = m.conditions(b)
    run = micro_run().replace(model=FIXED)
    x = clean_samples(m, b, cond, run)
    sigma = torch.tensor([0.3, 40.0])
    d = m.denoise(x + torch.randn(x.shape) * sigma.view(-1, 1, 1, 1), sigma, cond)
    loss = (denoising_loss(d, x, sigma, FIXED.sigma_data, cond.tgt_graph.mask) + m.energy(d, cond, run.energy)["total"]).mean()
    loss.backward()
    grads = [p.grad for p in m.parameters() if p.grad is not None]
    assert math.isfinite(float(loss.detach())) and grads and all(torch.isfinite(g).all() for g in grads)
    assert float(m.net.base_head.weight.grad.abs().sum()) > 0


def test_training_with_the_fixes_writes_them_into_the_checkpoint(tmp_path):
    from model_helpers import dataset

    from mer_models.training.train import train

    run = micro_run().replace(model=FIXED)
    run = run.replace(train=dataclasses.replace(run.train, start_frac=0.5, feedback_frac=0.25))
    res = train(run, dataset(size=8), tmp_path / "ckpt", steps=2)
    assert res.step == 2 and math.isfinite(res.last["loss"])
    saved = from_dict(json.loads((tmp_path / "ckpt" / "config.json").read_text())["run"])
    assert saved.model.split_encoding and saved.model.goal_frame_rotation


def test_presets_turn_the_fixes_on_and_old_configurations_load_with_them_off():
    for name in ("base", "paper"):
        assert preset(name).model.split_encoding and preset(name).model.goal_frame_rotation
    d = json.loads(json.dumps(preset("base").to_dict()))
    del d["model"]["split_encoding"], d["model"]["goal_frame_rotation"]  # written before the fields existed
    old = from_dict(d)
    assert (old.model.split_encoding, old.model.goal_frame_rotation) == (False, False)


def test_physical_refuses_to_guess_the_goal_frame():
    m = RetargetModel(FIXED)
    with pytest.raises(ValueError, match="goal_frame_rotation"):
        m.physical(torch.zeros(1, 60, 3, 9))


# ---- checkpoints written before the fixes ---------------------------------------------------------
def _closed_form_window(src, T: int = 60) -> np.ndarray:
    """(T, J, 9) float32 features of a closed-form G1 motion (no generator that may change)."""
    t = torch.arange(T, dtype=torch.float64)[:, None]
    lo, hi = torch.tensor(src.lower, dtype=torch.float64), torch.tensor(src.upper, dtype=torch.float64)
    j = torch.arange(src.num_nodes, dtype=torch.float64)[None]
    q = lo + (hi - lo) * (0.5 + 0.3 * torch.sin(0.15 * t + 0.7 * j))
    base_pos = torch.cat([0.04 * t, 0.01 * t, 0.75 + 0.02 * torch.sin(0.3 * t)], -1)
    rv = torch.cat([0.1 * torch.sin(0.2 * t), 0.15 + 0.05 * torch.cos(0.2 * t), 0.4 + 0.01 * t], -1)
    f = motion_features(skeleton_tensors(src, torch.float64), base_pos, axis_angle_to_quat(rv), q, 30.0)
    return f.float().numpy().astype(np.float32)


#: mer-base (bundled; its config.json predates the two fields) on the closed-form G1 window to H1,
#: Atlas and G1, computed with the code before the fixes (git HEAD before issue 42's change; the
#: working tree after it gave bit-identical tensors for every entry, 1 thread): (sum, sum of |.|).
PINNED = {
    "d_start": (15801.324740353259, 26125.603406805036),
    "start_q": (88.92584674060345, 2492.22162245214),
    "start_base_pos": (484.3561801579781, 484.6862145238556),
    "start_base_rot": (475.0226225364022, 754.8453875356354),
    "x_target": (5092.379186280261, 8961.596554253148),
    "d_mid": (15413.87868049054, 25340.856307220994),
    "physical": (18614.210258399136, 33550.1413294971),
    "project": (15107.884863185975, 24238.944624982898),
}
PINNED_ROWS = {
    "d_start[0,10,0]": [0.06587466597557068, 0.2453766167163849, 0.022077389061450958, 0.6054166555404663,
                        -0.060686998069286346, 1.0409055948257446, 0.8001879453659058, -0.11061204224824905,
                        -0.14516963064670563],
    "start_base_rot[0,59]": [0.5790657997131348, -0.8051398992538452, 0.12818919122219086, 0.78310227394104,
                             0.5930302143096924, 0.18725913763046265, -0.22678987681865692, -0.008050087839365005,
                             0.9739104509353638],
    "d_mid[1,40,0]": [0.1880609542131424, 0.08161072432994843, 0.4549097418785095, 2.193920135498047,
                      -0.39045006036758423, 0.924973726272583, 0.7698791027069092, -0.13113707304000854,
                      -0.10280600935220718],
    "x_target[2,20,0]": [-0.04984671622514725, 0.12840493023395538, 0.1954064965248108, 0.8140536546707153,
                         -0.13159285485744476, 0.7444117069244385, 0.6105402708053589, -0.09869462251663208,
                         0.0851249173283577],
}  # fmt: skip


def test_the_bundled_mer_base_gives_the_outputs_it_gave_before_the_fixes():
    from mer_models.zoo.checkpoint import resolve_model

    ckpt = resolve_model("mer-base")
    written = json.loads((ckpt.path / "config.json").read_text())["run"]["model"]
    assert "split_encoding" not in written and "goal_frame_rotation" not in written  # loaded through the legacy defaults
    m = ckpt.model.eval()
    assert not m.cfg.split_encoding and not m.cfg.goal_frame_rotation
    src = get_skeleton("g1")
    w = _closed_form_window(src)
    batch = collate([TrainingSample(w, src, get_skeleton(t), joint_map(get_skeleton(t), src), w.copy() if t == "g1" else None)
                     for t in ("h1", "atlas", "g1")])  # fmt: skip
    with torch.no_grad():
        cond = m.conditions(batch)
        d = m.denoise(m.goal_prior(cond), 80.0, cond)  # mer-base's sampler: one step from the goals
        out = {"d_start": d, **{f"start_{k}": v for k, v in m.decode(d, cond).items()}}
        out["x_target"] = m.target_sample(batch["target"], cond)
        g = torch.Generator().manual_seed(0)
        out["d_mid"] = m.denoise(m.goal_prior(cond) + 0.7 * torch.randn(d.shape, generator=g), 0.7, cond)
        out["physical"] = m.physical(out["d_mid"], cond)
        out["project"] = m.project(out["d_mid"], cond)
    assert torch.equal(out["physical"], denormalize(out["d_mid"], m.cfg))  # what the energy sees: unchanged
    for k, (total, absolute) in PINNED.items():
        v = out[k].double()
        assert float(v.sum()) == pytest.approx(total, rel=2e-6), k
        assert float(v.abs().sum()) == pytest.approx(absolute, rel=2e-6), k
    rows = {"d_start[0,10,0]": out["d_start"][0, 10, 0], "start_base_rot[0,59]": out["start_base_rot"][0, 59].flatten(),
            "d_mid[1,40,0]": out["d_mid"][1, 40, 0], "x_target[2,20,0]": out["x_target"][2, 20, 0]}  # fmt: skip
    for k, v in rows.items():
        torch.testing.assert_close(v, torch.tensor(PINNED_ROWS[k]), atol=2e-6, rtol=0, msg=k)
