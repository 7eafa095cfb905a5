"""The warm-start network: tokens (B, T, J, H), one per target node and frame.

Each layer: spatial attention over the nodes of one frame with a learned bias per head and
relation code (:func:`mer_models.warm.features.relations`: self, parent, child, ancestors and
descendants by hops), a depthwise convolution over ``kernel`` frames of each node (the only place
frames meet: the network sees a short window, not the whole motion), a feed-forward block; all
pre-norm residual. No reference encoder: each token already carries its goals and its mapped
reference joint's features (:func:`mer_models.warm.features.node_inputs`).

Outputs (zero-initialised heads, so an untrained network gives the nominal pose at the goals):
per node an angle logit offset (1), and from the base token the base orientation residual ``δ``
(3, rotation vector in the base goal's frame) and base position residual (3, heading frame) [m].
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mer_models.config import WarmConfig

from .features import INPUT_DIM, NUM_CODES

__all__ = ["WarmNet"]

_MASKED = -1e4  # the score of a padding key (finite: a row never turns into NaN)


class _Layer(nn.Module):
    def __init__(self, cfg: WarmConfig) -> None:
        super().__init__()
        H = cfg.hidden
        self.heads = cfg.heads
        self.norm1, self.norm2, self.norm3 = nn.LayerNorm(H), nn.LayerNorm(H), nn.LayerNorm(H)
        self.qkv = nn.Linear(H, 3 * H)
        self.out = nn.Linear(H, H)
        self.bias = nn.Parameter(torch.zeros(NUM_CODES, cfg.heads))
        self.half = cfg.kernel // 2
        self.taps = nn.Parameter(torch.randn(cfg.kernel, H) / cfg.kernel)  # a depthwise convolution over frames
        self.ffn = nn.Sequential(nn.Linear(H, cfg.ffn), nn.GELU(), nn.Linear(cfg.ffn, H))

    def forward(self, x: torch.Tensor, codes: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
        """x (B, T, J, H); codes (B, J, J) long; key_mask (B, J) bool (False: padding)."""
        B, T, J, H = x.shape
        h = self.heads
        d = H // h
        q, k, v = self.qkv(self.norm1(x)).view(B, T * J, 3, h, d).permute(2, 0, 3, 1, 4).unbind(0)  # (B, h, T*J, d)
        q, k, v = (t.reshape(B, h * T, J, d) for t in (q, k, v))
        bias = self.bias[codes].permute(0, 3, 1, 2)  # (B, h, J, J)
        bias = bias.masked_fill(~key_mask[:, None, None, :], _MASKED)[:, :, None].to(q.dtype)  # (B, h, 1, J, J)
        s = (q @ k.transpose(-1, -2)).view(B, h, T, J, J) * (d**-0.5) + bias
        a = (s.softmax(-1).view(B, h * T, J, J) @ v).view(B, h, T, J, d)
        x = x + self.out(a.permute(0, 2, 3, 1, 4).reshape(B, T, J, H))
        c = F.pad(self.norm2(x), (0, 0, 0, 0, self.half, self.half))  # (B, T + 2 half, J, H)
        w = self.taps  # (kernel, H)
        x = x + sum(c[:, i : i + T] * w[i] for i in range(w.shape[0]))
        return x + self.ffn(self.norm3(x))


class WarmNet(nn.Module):
    """``(B, T, J, INPUT_DIM)`` node inputs → angle logit offsets (B, T, J) and base residuals (B, T, 6)."""

    def __init__(self, cfg: WarmConfig) -> None:
        super().__init__()
        H = cfg.hidden
        self.inp = nn.Sequential(nn.Linear(INPUT_DIM, H), nn.SiLU(), nn.Linear(H, H))
        self.layers = nn.ModuleList([_Layer(cfg) for _ in range(cfg.layers)])
        self.norm = nn.LayerNorm(H)
        self.joint_head = nn.Linear(H, 1)
        self.base_head = nn.Linear(H, 6)
        for head in (self.joint_head, self.base_head):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def forward(self, x: torch.Tensor, codes: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.inp(x)
        for layer in self.layers:
            h = layer(h, codes, mask)
        h = self.norm(h)
        return self.joint_head(h)[..., 0], self.base_head(h[:, :, 0])
