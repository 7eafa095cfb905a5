"""The three attention blocks of a layer (paper, Network Architecture), on tokens (B, T, J, H).

* :class:`SpatialAttention`: over the J nodes of one frame, with GRPE relation terms
  ``A_ij = q_i . E_q[psi_ij] + k_j . E_k[psi_ij]`` added to ``QK^T`` before the ``1/sqrt(D_h)``
  scaling (Park et al. 2022; as in AnyTop), padding nodes masked out as keys.
* :class:`TemporalAttention`: over the T frames of one node, frame i sees frames
  ``i - (T_w-1)/2 .. i + (T_w-1)/2`` (:func:`window_mask`).
* :class:`MultiConditionCrossAttention`: heads split evenly across the conditions, each head group
  with its own ``W_Q, W_K, W_V``; the concatenated heads go through one ``W_O``. Graph conditions
  (rotation axes, link vectors, joint limits: one token per node of a skeleton) carry the same GRPE
  relation terms, so a node finds its own and its neighbours' attributes. The reference-motion
  condition is masked by the joint map extended in time: target node i at frame t attends to
  reference node j at frame t iff ``eta_ij = 1``; a node without correspondence gets no reference
  message (its output from that head group is zero).

Each block returns ``LayerNorm(x + Dropout(block(x)))`` (post-norm, as the paper writes it).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "NUM_RELATIONS",
    "window_mask",
    "grpe_bias",
    "attend",
    "SpatialAttention",
    "TemporalAttention",
    "MultiConditionCrossAttention",
]

NUM_RELATIONS = 4  # psi: none, self, parent, child


def window_mask(T: int, window: int, device=None) -> torch.Tensor:
    """(T, T) bool, True where frame i may attend to frame j: ``|i - j| <= (window - 1) / 2``."""
    i = torch.arange(T, device=device)
    return (i[:, None] - i[None, :]).abs() <= (window - 1) // 2


def attend(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor, dropout: float = 0.0) -> torch.Tensor:
    """``softmax(q k^T / sqrt(d) + mask) v`` for (N, h, L, d) queries/keys/values; ``mask`` is an
    additive float mask or a bool mask (True = may attend), broadcastable to (N, h, L, S).

    PyTorch's fused ``scaled_dot_product_attention`` everywhere except for reduced precision on the
    CPU, where for these short sequences (L, S <= 60) the same arithmetic written out is 5-8x
    faster in training (forward + backward) and up to 2.4x at inference; in float32 on the CPU the
    fused kernel is the faster one (2 AMD EPYC cores, docs/model.md §CPU attention).
    """
    if q.device.type != "cpu" or q.dtype not in (torch.bfloat16, torch.float16):
        return F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=dropout)
    s = (q @ k.transpose(-1, -2)) * (1.0 / math.sqrt(q.shape[-1]))
    s = s.masked_fill(~mask, float("-inf")) if mask.dtype == torch.bool else s + mask.to(s.dtype)
    a = s.softmax(-1)
    if dropout > 0:
        a = F.dropout(a, dropout)
    return a @ v


def grpe_bias(q: torch.Tensor, k: torch.Tensor, psi: torch.Tensor, e_q: torch.Tensor, e_k: torch.Tensor) -> torch.Tensor:
    """GRPE relation terms ``A_ij = q_i . E_q[psi_ij] + k_j . E_k[psi_ij]`` (unscaled).

    Args:
        q: (..., h, I, d) queries; k: (..., h, J, d) keys (leading dims broadcast against q's).
        psi: (..., I, J) long relation codes, broadcastable to the leading dims (without h).
        e_q, e_k: (R, h, d) relation embeddings.

    Returns:
        (..., h, I, J).
    """
    qe = torch.einsum("...hid,rhd->...hir", q, e_q)  # (..., h, I, R)
    ke = torch.einsum("...hjd,rhd->...hjr", k, e_k)  # (..., h, J, R)
    # Selecting E[psi_ij] is a product with the one-hot codes: exact, and on the CPU faster than
    # gathering from an index expanded to (..., h, I, J).
    onehot = F.one_hot(psi, qe.shape[-1]).to(qe.dtype)  # (..., I, J, R)
    return torch.einsum("...hir,...ijr->...hij", qe, onehot) + torch.einsum("...hjr,...ijr->...hij", ke, onehot)


class _Residual(nn.Module):
    """A sub-layer's residual connection: post-norm ``LayerNorm(x + f(x))`` (the paper's) or, with
    ``norm_first``, pre-norm ``x + f(LayerNorm(x))``; ``f`` reads :meth:`inputs` ``(x)``."""

    def __init__(self, hidden: int, dropout: float, norm_first: bool = False) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(hidden)
        self.drop = nn.Dropout(dropout)
        self.norm_first = norm_first

    def inputs(self, x: torch.Tensor) -> torch.Tensor:
        return self.norm(x) if self.norm_first else x

    def forward(self, x: torch.Tensor, update: torch.Tensor) -> torch.Tensor:
        return x + self.drop(update) if self.norm_first else self.norm(x + self.drop(update))


class SpatialAttention(nn.Module):
    """Self-attention over the nodes of each frame with GRPE terms from ``psi``."""

    def __init__(self, hidden: int, heads: int, dropout: float = 0.0, norm_first: bool = False) -> None:
        super().__init__()
        self.h, self.d = heads, hidden // heads
        self.qkv = nn.Linear(hidden, 3 * hidden)
        self.out = nn.Linear(hidden, hidden)
        self.e_q = nn.Parameter(torch.randn(NUM_RELATIONS, heads, self.d) * 0.02)
        self.e_k = nn.Parameter(torch.randn(NUM_RELATIONS, heads, self.d) * 0.02)
        self.res = _Residual(hidden, dropout, norm_first)
        self.attn_drop = dropout

    def forward(self, x: torch.Tensor, psi: torch.Tensor, node_mask: torch.Tensor) -> torch.Tensor:
        """x (B, T, J, H); psi (B, J, J) long; node_mask (B, J) bool (True = real node)."""
        B, T, J, H = x.shape
        q, k, v = self.qkv(self.res.inputs(x)).view(B, T, J, 3, self.h, self.d).permute(3, 0, 1, 4, 2, 5)  # (B,T,h,J,d)
        bias = grpe_bias(q, k, psi[:, None], self.e_q, self.e_k) / math.sqrt(self.d)
        bias = bias.masked_fill(~node_mask[:, None, None, None, :], float("-inf"))
        o = attend(
            q.reshape(B * T, self.h, J, self.d),
            k.reshape(B * T, self.h, J, self.d),
            v.reshape(B * T, self.h, J, self.d),
            bias.reshape(B * T, self.h, J, J),
            self.attn_drop if self.training else 0.0,
        )
        o = o.view(B, T, self.h, J, self.d).permute(0, 1, 3, 2, 4).reshape(B, T, J, H)
        return self.res(x, self.out(o))


class TemporalAttention(nn.Module):
    """Self-attention over the frames of each node inside a window of ``T_w`` frames."""

    def __init__(self, hidden: int, heads: int, window: int, dropout: float = 0.0, norm_first: bool = False) -> None:
        super().__init__()
        self.h, self.d, self.window = heads, hidden // heads, window
        self.qkv = nn.Linear(hidden, 3 * hidden)
        self.out = nn.Linear(hidden, hidden)
        self.res = _Residual(hidden, dropout, norm_first)
        self.attn_drop = dropout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, T, J, H)."""
        B, T, J, H = x.shape
        qkv = self.qkv(self.res.inputs(x)).view(B, T, J, 3, self.h, self.d).permute(3, 0, 2, 4, 1, 5)  # (3,B,J,h,T,d)
        q, k, v = (t.reshape(B * J, self.h, T, self.d) for t in qkv)
        mask = window_mask(T, self.window, x.device)
        o = attend(q, k, v, mask, self.attn_drop if self.training else 0.0)
        o = o.view(B, J, self.h, T, self.d).permute(0, 3, 1, 2, 4).reshape(B, T, J, H)
        return self.res(x, self.out(o))


class _HeadGroup(nn.Module):
    """The heads of one condition: own W_Q, W_K, W_V (and GRPE embeddings for graph conditions)."""

    def __init__(self, hidden: int, heads: int, head_dim: int, relational: bool) -> None:
        super().__init__()
        self.h, self.d = heads, head_dim
        self.q = nn.Linear(hidden, heads * head_dim)
        self.kv = nn.Linear(hidden, 2 * heads * head_dim)
        if relational:
            self.e_q = nn.Parameter(torch.randn(NUM_RELATIONS, heads, head_dim) * 0.02)
            self.e_k = nn.Parameter(torch.randn(NUM_RELATIONS, heads, head_dim) * 0.02)


class MultiConditionCrossAttention(nn.Module):
    """Cross attention to several conditions, ``heads_per_condition`` heads each.

    Args:
        hidden: token width H.
        num_graph_conditions: per-node skeleton conditions (3: axes, link vectors, limits).
        with_reference: whether the last head group attends to reference-motion tokens.
        heads_per_condition, head_dim: size of each head group.
    """

    def __init__(
        self,
        hidden: int,
        num_graph_conditions: int,
        with_reference: bool,
        heads_per_condition: int,
        head_dim: int,
        dropout: float = 0.0,
        norm_first: bool = False,
    ) -> None:
        super().__init__()
        self.groups = nn.ModuleList(
            [_HeadGroup(hidden, heads_per_condition, head_dim, True) for _ in range(num_graph_conditions)]
        )
        self.ref_group = _HeadGroup(hidden, heads_per_condition, head_dim, False) if with_reference else None
        n = num_graph_conditions + int(with_reference)
        self.out = nn.Linear(n * heads_per_condition * head_dim, hidden)
        self.res = _Residual(hidden, dropout, norm_first)
        self.h, self.d = heads_per_condition, head_dim

    def _graph(self, g: _HeadGroup, x, cond, psi, cond_mask):
        B, T, J, _ = x.shape
        q = g.q(x).view(B, T, J, self.h, self.d).transpose(2, 3)  # (B,T,h,J,d)
        k, v = g.kv(cond).view(B, cond.shape[1], 2, self.h, self.d).permute(2, 0, 3, 1, 4)  # (B,h,Jc,d)
        scores = torch.einsum("bthid,bhjd->bthij", q, k) + grpe_bias(q, k[:, None], psi[:, None], g.e_q, g.e_k)
        scores = (scores / math.sqrt(self.d)).masked_fill(~cond_mask[:, None, None, None, :], float("-inf"))
        o = torch.einsum("bthij,bhjd->bthid", scores.softmax(-1), v)
        return o.transpose(2, 3).reshape(B, T, J, self.h * self.d)

    def _reference(self, x, ref, eta):
        g = self.ref_group
        B, T, J, _ = x.shape
        Jr = ref.shape[2]
        q = g.q(x).view(B, T, J, self.h, self.d).transpose(2, 3)  # (B,T,h,J,d)
        k, v = g.kv(ref).view(B, T, Jr, 2, self.h, self.d).permute(3, 0, 1, 4, 2, 5)  # (B,T,h,Jr,d)
        allowed = eta[:, None, None] > 0  # (B,1,1,J,Jr)
        scores = torch.einsum("bthid,bthjd->bthij", q, k) / math.sqrt(self.d)
        scores = scores.masked_fill(~allowed, float("-inf"))
        has = allowed.any(-1, keepdim=True)  # rows with a correspondence
        attn = torch.where(has, scores, torch.zeros_like(scores)).softmax(-1) * has
        o = torch.einsum("bthij,bthjd->bthid", attn, v)
        return o.transpose(2, 3).reshape(B, T, J, self.h * self.d)

    def forward(
        self,
        x: torch.Tensor,
        graph_conditions: list[torch.Tensor],
        psi: torch.Tensor,
        node_mask: torch.Tensor,
        reference: torch.Tensor | None = None,
        eta: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """x (B, T, J, H); graph_conditions: each (B, J, H) (same skeleton as x); psi (B, J, J);
        node_mask (B, J); reference (B, T, Jr, H) and eta (B, J, Jr) when ``with_reference``."""
        if len(graph_conditions) != len(self.groups):
            raise ValueError(f"expected {len(self.groups)} graph conditions, got {len(graph_conditions)}")
        h = self.res.inputs(x)
        parts = [self._graph(g, h, c, psi, node_mask) for g, c in zip(self.groups, graph_conditions)]
        if self.ref_group is not None:
            if reference is None or eta is None:
                raise ValueError("this block needs the reference tokens and the joint map")
            parts.append(self._reference(h, reference, eta))
        return self.res(x, self.out(torch.cat(parts, -1)))
