"""Forward kinematics against two independent implementations, and its mathematical properties."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import ROBOTS
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles import pk_chain, pk_config, yourdfpy_positions
from urdf_factory import humanoid

from mer_data.kinematics.fk import fk_skeleton, forward_kinematics, joint_rotations, skeleton_tensors
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.registry import load_robot
from mer_data.robots.urdf import parse_urdf_bytes


def random_config(skel, n, gen, dtype=torch.float64):
    lo = torch.tensor(skel.lower, dtype=dtype)
    hi = torch.tensor(skel.upper, dtype=dtype)
    q = lo + (hi - lo) * torch.rand(n, skel.num_nodes, generator=gen, dtype=dtype)
    return q * torch.tensor(skel.revolute_mask, dtype=dtype)


def random_base(n, gen, dtype=torch.float64):
    quat = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen, dtype=dtype), dim=-1)
    return torch.randn(n, 3, generator=gen, dtype=dtype), quat


@pytest.mark.parametrize("name", ROBOTS)
def test_fk_matches_yourdfpy_float64(name):
    robot = load_robot(name)
    skel = robot.skeleton
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(1)
    q = random_config(skel, 6, gen)
    pos, _ = fk_skeleton(st_, q, torch.zeros(6, 3, dtype=torch.float64), base_quat=torch.tensor([1.0, 0, 0, 0]).double())
    for i in range(q.shape[0]):
        ref = yourdfpy_positions(str(robot.urdf_path), skel, robot.card, q[i].numpy())
        np.testing.assert_allclose(pos[i].numpy(), ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("name", ROBOTS)
def test_fk_matches_pytorch_kinematics(name):
    """float32 within 1e-5 m; float64 within 1e-9 m (pk's float32 rpy parsing patched, see oracles)."""
    robot = load_robot(name)
    skel = robot.skeleton
    gen = torch.Generator().manual_seed(2)
    q64 = random_config(skel, 256, gen)
    bp, bq = random_base(256, gen)
    joints = [j for j, k in enumerate(skel.node_kinds) if k != "site"]
    for dtype, tol, exact in ((torch.float32, 1e-5, False), (torch.float64, 1e-9, True)):
        chain = pk_chain(str(robot.urdf_path), dtype, exact_origins=exact)
        q, base_pos, base_quat = q64.to(dtype), bp.to(dtype), bq.to(dtype)
        tf = chain.forward_kinematics(pk_config(chain, skel, q))
        pos, rot = fk_skeleton(skeleton_tensors(skel, dtype), q, base_pos, base_quat=base_quat)
        r0 = quat_to_matrix(base_quat)
        for j in joints:
            m = tf[skel.link_names[j]].get_matrix()
            expect = (r0 @ m[:, :3, 3:]).squeeze(-1) + base_pos
            torch.testing.assert_close(pos[:, j], expect, atol=tol, rtol=0)
            link_rot = rot[:, j] @ torch.tensor(skel.rest_rotations[j], dtype=dtype)
            torch.testing.assert_close(link_rot, r0 @ m[:, :3, :3], atol=10 * tol, rtol=0)


@pytest.mark.parametrize("name", ROBOTS)
def test_zero_pose_equals_rest_offsets(name):
    skel = load_robot(name).skeleton
    st_ = skeleton_tensors(skel, torch.float64)
    pos, rot = fk_skeleton(st_, torch.zeros(skel.num_nodes, dtype=torch.float64), torch.zeros(3).double(), base_rot=torch.eye(3).double())
    np.testing.assert_allclose(pos.numpy(), skel.rest_positions, atol=1e-12)
    np.testing.assert_allclose(rot.numpy(), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)


def test_fixed_joint_merging_preserves_positions(tmp_path):
    """A robot full of rotated fixed frames and tilted axes: every link position as yourdfpy has it."""
    from mer_data.robots.builder import build_skeleton
    from mer_data.robots.card import RobotCard
    from mer_data.robots.keypoints import propose_keypoints

    robot = humanoid(tilt=0.4)
    path = robot.write(tmp_path / "toy.urdf")
    model = parse_urdf_bytes(open(path, "rb").read(), path)
    kps = {k: p.spec for k, p in propose_keypoints(model).items()}
    card = RobotCard(name="toy", urdf="toy.urdf", keypoints=kps)
    skel = build_skeleton(model, card)
    assert "imu_joint" not in skel.node_names and "torso_fixed_joint" not in skel.node_names
    gen = torch.Generator().manual_seed(3)
    q = random_config(skel, 4, gen)
    pos, _ = fk_skeleton(skeleton_tensors(skel, torch.float64), q, torch.zeros(4, 3).double(), base_rot=torch.eye(3).double())
    for i in range(4):
        np.testing.assert_allclose(pos[i].numpy(), yourdfpy_positions(path, skel, card, q[i].numpy()), atol=1e-12)


def test_mixed_robot_batch_equals_individual_fk():
    from mer_data.kinematics.jointmap import joint_map
    from mer_data.motion.samples import TrainingSample, collate

    skels = [load_robot(n).skeleton for n in ("g1", "tron1", "h1", "g1")]
    T = 5
    gen = torch.Generator().manual_seed(4)
    samples = [
        TrainingSample(np.zeros((T, skels[0].num_nodes, 9), np.float32), skels[0], s, joint_map(s, skels[0])) for s in skels
    ]
    batch = collate(samples)
    J = batch["tgt_mask"].shape[1]
    q = torch.randn(len(skels), T, J, generator=gen)
    bp = torch.randn(len(skels), T, 3, generator=gen)
    br = quat_to_matrix(torch.nn.functional.normalize(torch.randn(len(skels), T, 4, generator=gen), dim=-1))
    pos, rot = forward_kinematics(q, bp, br, batch["tgt_offsets"][:, None], batch["tgt_axes"][:, None], batch["tgt_parents"])
    for b, s in enumerate(skels):
        st_ = skeleton_tensors(s)
        p1, r1 = forward_kinematics(q[b, :, : s.num_nodes], bp[b], br[b], st_.offsets, st_.axes, st_.parents)
        torch.testing.assert_close(pos[b, :, : s.num_nodes], p1)
        torch.testing.assert_close(rot[b, :, : s.num_nodes], r1)


def test_per_sample_offsets_match_scaled_skeletons():
    skel = load_robot("h1").skeleton
    rng = np.random.default_rng(5)
    scales = rng.uniform(0.5, 2.0, size=(3, skel.num_nodes))
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(5)
    q = random_config(skel, 3, gen)[:, None].expand(3, 7, -1)  # (B, T, J)
    offsets = st_.offsets * torch.as_tensor(scales)[..., None]  # (B, J, 3)
    pos, _ = forward_kinematics(q, torch.zeros(3, 7, 3).double(), torch.eye(3).double(), offsets[:, None], st_.axes, st_.parents)
    for b in range(3):
        sb = skeleton_tensors(skel.with_link_scales(scales[b]), torch.float64)
        pb, _ = fk_skeleton(sb, q[b], torch.zeros(7, 3).double(), base_rot=torch.eye(3).double())
        torch.testing.assert_close(pos[b], pb, atol=1e-12, rtol=0)


@settings(max_examples=25, deadline=None)
@given(node=st.integers(1, 33), factor=st.floats(0.3, 3.0), seed=st.integers(0, 2**16))
def test_scaling_a_link_moves_exactly_its_subtree(node, factor, seed):
    skel = load_robot("g1").skeleton
    node = node % skel.num_nodes or 1
    scales = np.ones(skel.num_nodes)
    scales[node] = factor
    scaled = skel.with_link_scales(scales)
    gen = torch.Generator().manual_seed(seed)
    q = random_config(skel, 1, gen)[0]
    st0, st1 = skeleton_tensors(skel, torch.float64), skeleton_tensors(scaled, torch.float64)
    p0, r0 = fk_skeleton(st0, q, torch.zeros(3).double(), base_rot=torch.eye(3).double())
    p1, _ = fk_skeleton(st1, q, torch.zeros(3).double(), base_rot=torch.eye(3).double())
    inside = torch.as_tensor(skel.subtree(node))
    torch.testing.assert_close(p1[~inside], p0[~inside], atol=1e-12, rtol=0)
    shift = (factor - 1) * r0[skel.parents[node]] @ st0.offsets[node]
    torch.testing.assert_close(p1[inside], p0[inside] + shift, atol=1e-12, rtol=0)


def test_fk_gradients_match_finite_differences():
    skel = load_robot("tron1").skeleton
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(6)
    q = random_config(skel, 2, gen).requires_grad_(True)
    bp = torch.randn(2, 3, generator=gen, dtype=torch.float64, requires_grad=True)
    off = st_.offsets.clone().requires_grad_(True)
    ax = st_.axes.clone().requires_grad_(True)
    br = torch.eye(3, dtype=torch.float64)

    def f(q, bp, off, ax):
        pos, rot = forward_kinematics(q, bp, br, off, ax, st_.parents)
        return pos.sum(-1), rot.flatten(-2)

    assert torch.autograd.gradcheck(f, (q, bp, off, ax))


def test_joint_rotation_is_identity_for_zero_axis_and_rodrigues_otherwise():
    axes = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    q = torch.tensor([1.3, 0.5], dtype=torch.float64)
    r = joint_rotations(axes, q)
    torch.testing.assert_close(r[0], torch.eye(3, dtype=torch.float64))
    c, s = np.cos(0.5), np.sin(0.5)
    torch.testing.assert_close(r[1], torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64))


def test_fk_broadcasts_leading_dimensions():
    skel = load_robot("g1").skeleton
    st_ = skeleton_tensors(skel)
    q = torch.zeros(2, 3, 4, skel.num_nodes)
    pos, rot = fk_skeleton(st_, q, torch.zeros(3), base_rot=torch.eye(3))
    assert pos.shape == (2, 3, 4, skel.num_nodes, 3) and rot.shape == (2, 3, 4, skel.num_nodes, 3, 3)


def test_fk_refuses_wrong_joint_count():
    skel = load_robot("g1").skeleton
    st_ = skeleton_tensors(skel)
    with pytest.raises(ValueError, match="nodes"):
        forward_kinematics(torch.zeros(5), torch.zeros(3), torch.eye(3), st_.offsets, st_.axes, st_.parents)


def test_per_sample_axes_match_individual_fk():
    skel = load_robot("oli").skeleton
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(7)
    B, T = 3, 4
    axes = torch.nn.functional.normalize(torch.randn(B, skel.num_nodes, 3, generator=gen, dtype=torch.float64), dim=-1)
    axes = axes * torch.tensor(skel.revolute_mask, dtype=torch.float64)[:, None]
    offsets = st_.offsets * torch.rand(B, skel.num_nodes, 1, generator=gen, dtype=torch.float64)
    q = random_config(skel, B * T, gen).reshape(B, T, -1)
    bp, bq = random_base(B * T, gen)
    br = quat_to_matrix(bq).reshape(B, T, 3, 3)
    for off in (offsets, st_.offsets):  # per-sample axes with per-sample and with shared offsets
        pos, rot = forward_kinematics(q, bp.reshape(B, T, 3), br, off[:, None] if off.dim() == 3 else off, axes[:, None], st_.parents)
        for b in range(B):
            ob = off[b] if off.dim() == 3 else off
            p1, r1 = forward_kinematics(q[b], bp.reshape(B, T, 3)[b], br[b], ob, axes[b], st_.parents)
            torch.testing.assert_close(pos[b], p1, atol=1e-12, rtol=0)
            torch.testing.assert_close(rot[b], r1, atol=1e-12, rtol=0)


def test_analytic_backward_matches_finite_differences():
    """q and base pose gradients go through the analytic Jacobian (geometry without grad)."""
    skel = load_robot("talos").skeleton  # mimic joints, sites, deep arms
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(8)
    q = random_config(skel, 3, gen).reshape(3, 1, -1).expand(3, 2, -1).clone().requires_grad_(True)
    bp = torch.randn(3, 1, 3, generator=gen, dtype=torch.float64, requires_grad=True)  # broadcast over T
    br = quat_to_matrix(torch.nn.functional.normalize(torch.randn(3, 2, 4, generator=gen, dtype=torch.float64), dim=-1))
    br.requires_grad_(True)

    def f(q, bp, br):
        pos, rot = forward_kinematics(apply_mimic_(q), bp, br, st_.offsets, st_.axes, st_.parents)
        return pos, rot

    def apply_mimic_(q):
        from mer_data.kinematics.fk import apply_mimic

        return apply_mimic(q, st_.mimic_source, st_.mimic_multiplier, st_.mimic_offset)

    assert torch.autograd.gradcheck(f, (q, bp, br), fast_mode=True)  # random projections u^T J v against finite differences


def test_analytic_and_autograd_backward_agree_on_a_real_robot():
    skel = load_robot("g1").skeleton
    st_ = skeleton_tensors(skel, torch.float64)
    gen = torch.Generator().manual_seed(9)
    q = random_config(skel, 64, gen)
    bp, bq = random_base(64, gen)
    br = quat_to_matrix(bq)
    gp = torch.randn(64, skel.num_nodes, 3, generator=gen, dtype=torch.float64)
    gr = torch.randn(64, skel.num_nodes, 3, 3, generator=gen, dtype=torch.float64)
    grads = []
    for geometry_grad in (False, True):  # True forces the autograd path
        qq, bb, rr = q.clone().requires_grad_(True), bp.clone().requires_grad_(True), br.clone().requires_grad_(True)
        off = st_.offsets.clone().requires_grad_(geometry_grad)
        pos, rot = forward_kinematics(qq, bb, rr, off, st_.axes, st_.parents)
        ((pos * gp).sum() + (rot * gr).sum()).backward()
        grads.append((qq.grad, bb.grad, rr.grad))
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, atol=1e-10, rtol=1e-10)
