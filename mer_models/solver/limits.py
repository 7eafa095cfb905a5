"""The joint-limit parametrisation: ``q = lower + (upper - lower) * sigmoid(z)`` (paper, Implementation Details).

Every angle so produced is inside its URDF limits by construction; the optimiser works on ``z``,
and the model's preconditioned output leaves through the same clip (:mod:`mer_models.diffusion.edm`).
"""

from __future__ import annotations

import torch

__all__ = ["limit_clip", "limit_logit"]

_EPS = 1e-4  # clamp of the normalised angle before logit (|logit| <= 9.2)


def limit_clip(z: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """``lower + (upper - lower) * sigmoid(z)``: (..., J) logits → angles within [lower, upper]."""
    return lower + (upper - lower) * torch.sigmoid(z)


def limit_logit(q: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """The inverse of :func:`limit_clip`: (..., J) angles → logits (clamped into the open interval first)."""
    span = (upper - lower).clamp_min(1e-9)
    u = ((q - lower) / span).clamp(_EPS, 1 - _EPS)
    return torch.log(u) - torch.log1p(-u)
