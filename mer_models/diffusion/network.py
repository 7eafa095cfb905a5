"""The two transformer decoders (paper, Network Architecture, Fig. 2).

* Tokens: one per node per frame, ``T * J`` per motion. The base node and the other nodes have
  separate input encoders (their 9 features mean different things) and separate output heads.
* Positional encoding: fixed sinusoids of the frame index and of the node index (the skeleton's
  topological order) on every token (:func:`position_codes`): added into the same channels, or,
  with ``ModelConfig.split_encoding``, the frame's in the first half of the channels and the
  node's in the second, so that (frame t, node j) and (frame j, node t) differ; the graph itself
  enters through GRPE (``psi``) and the condition tokens.
* Reference encoder: a decoder over the reference motion whose cross attention sees the reference
  skeleton's three graph conditions (rotation axes, link vectors, joint limits).
* Denoiser: a decoder over the noisy target motion (plus the noise-level embedding) whose cross
  attention sees the target skeleton's three graph conditions and the encoded reference motion,
  masked by the joint map extended in time.

:class:`RetargetNet` is the raw network ``F_theta``; EDM preconditioning and the joint-limit clip
are in :mod:`mer_models.diffusion.edm` and :mod:`mer_models.diffusion.model`.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from mer_data.motion.features import FEATURE_DIM
from mer_models.batch import BatchGraph
from mer_models.config import ModelConfig

from .attention import MultiConditionCrossAttention, SpatialAttention, TemporalAttention

__all__ = ["RetargetNet", "sinusoids", "node_codes", "position_codes", "JOINT_OUT", "GOAL_DIM"]

JOINT_OUT = 7  # a joint node's live features: angle, position (3), velocity (3)
#: Channels of a target token's goal input (``ModelConfig.goal_input``; :meth:`RetargetModel.goal_features`):
#: position (3), position relative to the base goal (3), velocity (3), flag (1), orientation as its
#: first two columns (6), flag (1), then in the base goal's frame: position relative to the base
#: goal (3) and the segment from the nearest mapped ancestor's goal (3).
GOAL_DIM = 23


def sinusoids(n: int, dim: int, device=None) -> torch.Tensor:
    """(n, dim) fixed sinusoidal encodings of positions 0..n-1 (Vaswani et al.)."""
    pos = torch.arange(n, device=device, dtype=torch.float32)[:, None]
    half = dim // 2
    freq = torch.exp(-math.log(10000.0) * torch.arange(half, device=device, dtype=torch.float32) / max(half, 1))
    out = torch.zeros(n, dim, device=device)
    out[:, 0 : 2 * half : 2] = torch.sin(pos * freq)
    out[:, 1 : 2 * half : 2] = torch.cos(pos * freq)
    return out


def node_codes(J: int, dim: int, split: bool, device=None) -> torch.Tensor:
    """(J, dim) the node-index code: sinusoids over all channels, or (``split``) over the second half
    ``dim - dim // 2`` channels, zero in the first (the frame code's)."""
    if not split:
        return sinusoids(J, dim, device)
    return torch.cat([torch.zeros(J, dim // 2, device=device), sinusoids(J, dim - dim // 2, device)], -1)


def position_codes(T: int, J: int, dim: int, split: bool, device=None) -> torch.Tensor:
    """(T, J, dim) the code added to the token of (frame t, node j).

    Not ``split``: ``s(t) + s(j)`` with the same sinusoids ``s`` over all channels (symmetric: (t, j)
    and (j, t) get the same code). ``split``: ``[s_{dim//2}(t), s_{dim-dim//2}(j)]``, the frame in the
    first half of the channels and the node in the second (equal only if the frame and the node are).
    """
    if not split:
        return sinusoids(T, dim, device)[:, None] + sinusoids(J, dim, device)[None]
    frame = torch.cat([sinusoids(T, dim // 2, device), torch.zeros(T, dim - dim // 2, device=device)], -1)
    return frame[:, None] + node_codes(J, dim, True, device)[None]


def _mlp(i: int, h: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, h), nn.SiLU(), nn.Linear(h, o))


class TokenEncoder(nn.Module):
    """Separate input encoders for the base node and the other nodes, plus the position code
    (:func:`position_codes`): (B, T, J, 9) → (B, T, J, H)."""

    def __init__(self, hidden: int, split: bool = False) -> None:
        super().__init__()
        self.base = _mlp(FEATURE_DIM, hidden, hidden)
        self.joint = _mlp(FEATURE_DIM, hidden, hidden)
        self.split = split

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, T, J, _ = x.shape
        tokens = torch.cat([self.base(x[:, :, :1]), self.joint(x[:, :, 1:])], dim=2)
        H = tokens.shape[-1]
        if self.split:
            return tokens + position_codes(T, J, H, True, x.device)[None]
        return tokens + sinusoids(T, H, x.device)[None, :, None] + sinusoids(J, H, x.device)[None, None]  # summed, as trained


class GraphConditions(nn.Module):
    """The three per-node skeleton conditions as tokens: rotation axes, link vectors, joint limits."""

    def __init__(self, hidden: int, split: bool = False) -> None:
        super().__init__()
        self.axes = _mlp(3, hidden, hidden)
        self.links = _mlp(4, hidden, hidden)
        self.limits = _mlp(4, hidden, hidden)
        self.split = split

    def forward(self, g: BatchGraph) -> list[torch.Tensor]:
        J = g.parents.shape[1]
        node_pe = node_codes(J, self.axes[-1].out_features, self.split, g.parents.device)[None]
        length = g.offsets.norm(dim=-1, keepdim=True)
        lim = torch.stack([g.lower, g.upper, g.upper - g.lower, g.revolute.to(g.lower.dtype)], -1)
        return [
            self.axes(g.axes) + node_pe,
            self.links(torch.cat([g.offsets, length], -1)) + node_pe,
            self.limits(lim) + node_pe,
        ]


class DecoderLayer(nn.Module):
    """Spatial attention → temporal attention → multi-conditional cross attention → feed-forward."""

    def __init__(self, cfg: ModelConfig, with_reference: bool) -> None:
        super().__init__()
        H, pre = cfg.hidden, cfg.norm_first
        self.spatial = SpatialAttention(H, cfg.heads, cfg.dropout, pre)
        self.temporal = TemporalAttention(H, cfg.heads, cfg.window, cfg.dropout, pre)
        self.cross = MultiConditionCrossAttention(
            H, 3, with_reference, cfg.cross_heads_per_condition, cfg.head_dim, cfg.dropout, pre
        )
        self.ffn = nn.Sequential(nn.Linear(H, cfg.ffn), nn.GELU(), nn.Dropout(cfg.dropout), nn.Linear(cfg.ffn, H))
        self.norm = nn.LayerNorm(H)
        self.drop = nn.Dropout(cfg.dropout)
        self.norm_first = pre

    def forward(self, x, g: BatchGraph, conds, reference=None, eta=None):
        x = self.spatial(x, g.psi, g.mask)
        x = self.temporal(x)
        x = self.cross(x, conds, g.psi, g.mask, reference, eta)
        if self.norm_first:
            return x + self.drop(self.ffn(self.norm(x)))
        return self.norm(x + self.drop(self.ffn(x)))


class Decoder(nn.Module):
    def __init__(self, cfg: ModelConfig, with_reference: bool) -> None:
        super().__init__()
        self.tokens = TokenEncoder(cfg.hidden, cfg.split_encoding)
        self.conditions = GraphConditions(cfg.hidden, cfg.split_encoding)
        self.layers = nn.ModuleList([DecoderLayer(cfg, with_reference) for _ in range(cfg.layers)])
        self.final_norm = nn.LayerNorm(cfg.hidden) if cfg.norm_first else None  # pre-norm: the stream is not normalised

    def forward(self, x, g: BatchGraph, extra: torch.Tensor | None = None, reference=None, eta=None):
        h = self.tokens(x)
        if extra is not None:
            h = h + extra
        conds = self.conditions(g)
        for layer in self.layers:
            h = layer(h, g, conds, reference, eta)
        return h if self.final_norm is None else self.final_norm(h)


class NoiseEmbedding(nn.Module):
    """``c_noise`` (B,) → (B, H): fixed Fourier features, then an MLP."""

    def __init__(self, hidden: int, num_freqs: int = 16) -> None:
        super().__init__()
        self.register_buffer("freqs", torch.exp(torch.linspace(0.0, math.log(1000.0), num_freqs)), persistent=False)
        self.mlp = _mlp(2 * num_freqs, hidden, hidden)

    def forward(self, c_noise: torch.Tensor) -> torch.Tensor:
        a = c_noise[:, None] * self.freqs[None]
        return self.mlp(torch.cat([a.sin(), a.cos()], -1))


class RetargetNet(nn.Module):
    """``F_theta``: reference encoder + denoiser (raw outputs, before preconditioning)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = Decoder(cfg, with_reference=False)
        self.denoiser = Decoder(cfg, with_reference=True)
        self.noise = NoiseEmbedding(cfg.hidden)
        self.goal = _mlp(GOAL_DIM, cfg.hidden, cfg.hidden) if cfg.goal_input else None
        self.base_head = nn.Linear(cfg.hidden, FEATURE_DIM)
        self.joint_head = nn.Linear(cfg.hidden, JOINT_OUT)
        for head in (self.base_head, self.joint_head):  # start as the identity denoiser (F = 0)
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def encode_reference(self, reference: torch.Tensor, ref_graph: BatchGraph) -> torch.Tensor:
        """(B, T, Jr, 9) normalized reference features → (B, T, Jr, H) tokens (noise-independent)."""
        return self.encoder(reference, ref_graph)

    def forward(
        self,
        x_in: torch.Tensor,
        c_noise: torch.Tensor,
        ref_tokens: torch.Tensor,
        tgt_graph: BatchGraph,
        eta: torch.Tensor,
        goal: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """x_in (B, T, Jt, 9) (already scaled by ``c_in``), c_noise (B,), ref_tokens (B, T, Jr, H),
        eta (B, Jt, Jr), goal (B, T, Jt, GOAL_DIM) (``goal_input`` networks only) → F (B, T, Jt, 9)
        (joint nodes' last two channels are zero)."""
        extra = self.noise(c_noise)[:, None, None, :]
        if self.goal is not None:
            if goal is None:
                raise ValueError("this network was configured with goal_input and needs the goal features")
            extra = extra + self.goal(goal.to(extra.dtype))
        h = self.denoiser(x_in, tgt_graph, extra, ref_tokens, eta)
        base = self.base_head(h[:, :, :1])
        joints = self.joint_head(h[:, :, 1:])
        joints = torch.cat([joints, joints.new_zeros(joints.shape[:-1] + (FEATURE_DIM - JOINT_OUT,))], -1)
        return torch.cat([base, joints], dim=2)
