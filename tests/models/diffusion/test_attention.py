"""Attention blocks: window mask, GRPE terms, padding, joint-map masking, head groups."""

from __future__ import annotations

import math

import torch

from mer_models.diffusion.attention import (
    MultiConditionCrossAttention,
    SpatialAttention,
    TemporalAttention,
    attend,
    grpe_bias,
    window_mask,
)


def test_cpu_attention_equals_the_fused_kernel():
    """``attend`` has the values and gradients of ``scaled_dot_product_attention`` for bool and
    additive masks, -inf rows included."""
    g = torch.Generator().manual_seed(0)
    q, k, v = (torch.randn(3, 2, 7, 4, generator=g, dtype=torch.float64, requires_grad=True) for _ in range(3))
    bool_mask = window_mask(7, 3)
    add_mask = torch.randn(3, 2, 7, 7, generator=g, dtype=torch.float64)
    add_mask[..., 5:] = float("-inf")
    for mask in (bool_mask, add_mask):
        a = attend(q, k, v, mask)
        b = torch.nn.functional.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        torch.testing.assert_close(a, b)
        ga = torch.autograd.grad(a.sum(), (q, k, v))
        gb = torch.autograd.grad(b.sum(), (q, k, v))
        for x, y in zip(ga, gb):
            torch.testing.assert_close(x, y)


def test_cpu_bf16_attention_is_written_out_and_matches_float32():
    """In bfloat16 on the CPU ``attend`` takes the written-out path (the fused kernel is slower
    there): its output is the float32 fused kernel's to bf16 precision, masked keys get no weight."""
    g = torch.Generator().manual_seed(1)
    q, k, v = (torch.randn(4, 2, 60, 24, generator=g) for _ in range(3))
    mask = window_mask(60, 31)
    ref = torch.nn.functional.scaled_dot_product_attention(q, k, v, attn_mask=mask)
    out = attend(q.bfloat16(), k.bfloat16(), v.bfloat16(), mask)
    assert out.dtype == torch.bfloat16
    torch.testing.assert_close(out.float(), ref, atol=3e-2, rtol=3e-2)
    v_far = v.clone()
    v_far[:, :, 40:] += 100.0  # keys 40.. are outside frame 0's window: its output must not move
    out_far = attend(q.bfloat16(), k.bfloat16(), v_far.bfloat16(), mask)
    torch.testing.assert_close(out_far[:, :, 0], out[:, :, 0], atol=0, rtol=0)


def test_grpe_bias_broadcasts_over_frames():
    """A graph shared by every frame (psi without the time axis) gives the per-frame bias."""
    torch.manual_seed(2)
    B, T, h, J, d, R = 2, 3, 2, 5, 4, 6
    q, k = torch.randn(B, T, h, J, d), torch.randn(B, T, h, J, d)
    psi = torch.randint(0, R, (B, 1, J, J))
    e_q, e_k = torch.randn(R, h, d), torch.randn(R, h, d)
    a = grpe_bias(q, k, psi, e_q, e_k)
    assert a.shape == (B, T, h, J, J)
    for t in range(T):
        torch.testing.assert_close(a[:, t], grpe_bias(q[:, t], k[:, t], psi[:, 0], e_q, e_k))


def test_window_mask_sees_fifteen_frames_each_side():
    m = window_mask(60, 31)
    assert m[30, 15] and m[30, 45] and not m[30, 14] and not m[30, 46]
    assert m[0, :16].all() and not m[0, 16]
    assert m.sum(1).max() == 31
    assert torch.equal(m, m.T)


def test_grpe_bias_is_the_papers_formula():
    torch.manual_seed(0)
    h, J, d = 2, 5, 4
    q, k = torch.randn(h, J, d), torch.randn(h, J, d)
    psi = torch.randint(0, 4, (J, J))
    e_q, e_k = torch.randn(4, h, d), torch.randn(4, h, d)
    a = grpe_bias(q, k, psi, e_q, e_k)
    ref = torch.zeros(h, J, J)
    for n in range(h):
        for i in range(J):
            for j in range(J):
                r = psi[i, j]
                ref[n, i, j] = q[n, i] @ e_q[r, n] + k[n, j] @ e_k[r, n]
    torch.testing.assert_close(a, ref)


def _psi(J, parents):
    psi = torch.zeros(J, J, dtype=torch.long)
    psi[range(J), range(J)] = 1
    for c, p in enumerate(parents):
        if p >= 0:
            psi[c, p], psi[p, c] = 2, 3
    return psi


def test_spatial_attention_ignores_padding_nodes():
    torch.manual_seed(0)
    att = SpatialAttention(16, 2).eval()
    B, T, J = 1, 3, 6
    x = torch.randn(B, T, J, 16)
    psi = _psi(J, [-1, 0, 1, 0, 0, 0])[None]
    mask = torch.tensor([[True, True, True, True, False, False]])
    y1 = att(x, psi, mask)
    x2 = x.clone()
    x2[:, :, 4:] = 100 * torch.randn(B, T, 2, 16)
    y2 = att(x2, psi, mask)
    torch.testing.assert_close(y1[:, :, :4], y2[:, :, :4])


def test_spatial_attention_uses_psi():
    torch.manual_seed(0)
    att = SpatialAttention(16, 2).eval()
    with torch.no_grad():
        att.e_q.mul_(50)
    x = torch.randn(1, 2, 4, 16)
    mask = torch.ones(1, 4, dtype=torch.bool)
    a = att(x, _psi(4, [-1, 0, 1, 2])[None], mask)
    b = att(x, _psi(4, [-1, 0, 0, 0])[None], mask)
    assert (a - b).abs().max() > 1e-3


def test_temporal_attention_sees_only_its_window():
    torch.manual_seed(0)
    att = TemporalAttention(16, 2, window=31).eval()
    x = torch.randn(1, 60, 3, 16)
    y1 = att(x)
    x2 = x.clone()
    x2[:, 46:] += 10.0  # frames beyond 30 + 15
    y2 = att(x2)
    torch.testing.assert_close(y1[:, :31], y2[:, :31])
    assert (y1[:, 31:] - y2[:, 31:]).abs().max() > 1e-3


def test_reference_head_is_masked_by_the_time_extended_joint_map():
    torch.manual_seed(0)
    H, B, T, J, Jr = 16, 1, 4, 3, 5
    att = MultiConditionCrossAttention(H, 3, True, heads_per_condition=1, head_dim=8).eval()
    x = torch.randn(B, T, J, H)
    conds = [torch.randn(B, J, H) for _ in range(3)]
    psi = _psi(J, [-1, 0, 1])[None]
    mask = torch.ones(B, J, dtype=torch.bool)
    eta = torch.zeros(B, J, Jr)
    eta[0, 1, 3] = 1  # target node 1 <-> reference node 3; node 2 has no correspondence
    ref = torch.randn(B, T, Jr, H)
    y1 = att(x, conds, psi, mask, ref, eta)
    ref2 = ref.clone()
    ref2[:, :, [0, 1, 2, 4]] += 5.0  # unmapped reference nodes
    ref2[:, 1:, 3] += 5.0  # the mapped node at other frames
    y2 = att(x, conds, psi, mask, ref2, eta)
    torch.testing.assert_close(y1[:, 0], y2[:, 0])  # frame 0 only sees frame 0 of node 3
    ref3 = ref.clone()
    ref3[:, 0, 3] += 5.0
    y3 = att(x, conds, psi, mask, ref3, eta)
    assert (y3[:, 0, 1] - y1[:, 0, 1]).abs().max() > 1e-4
    torch.testing.assert_close(y3[:, 0, 2], y1[:, 0, 2])  # no correspondence: no reference message


def test_every_condition_has_its_own_projections():
    att = MultiConditionCrossAttention(24, 3, True, heads_per_condition=2, head_dim=6)
    groups = list(att.groups) + [att.ref_group]
    assert len(groups) == 4
    ids = {id(g.q.weight) for g in groups} | {id(g.kv.weight) for g in groups}
    assert len(ids) == 8
    assert att.out.in_features == 4 * 2 * 6 and att.out.out_features == 24
    assert math.isclose(sum(p.numel() for p in groups[0].parameters()) * 3 + sum(p.numel() for p in groups[3].parameters())
                        + sum(p.numel() for p in att.out.parameters()) + sum(p.numel() for p in att.res.parameters()),
                        sum(p.numel() for p in att.parameters()))  # fmt: skip
