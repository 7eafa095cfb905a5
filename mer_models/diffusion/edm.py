"""EDM preconditioning, training noise and loss weighting (Karras et al. 2022, Table 1), plus the
paper's joint-limit clip folded into the preconditioned output.

``D(x, sigma) = c_skip x + c_out F(c_in x, c_noise)`` with::

    c_skip = sd^2 / (sigma^2 + sd^2)       c_out = sigma sd / sqrt(sigma^2 + sd^2)
    c_in   = 1 / sqrt(sigma^2 + sd^2)      c_noise = ln(sigma) / 4
    ln sigma ~ N(P_mean, P_std^2)          weight(sigma) = (sigma^2 + sd^2) / (sigma sd)^2

**Limit clip.** A joint angle leaves through ``q = lower + (upper - lower) * sigmoid(z)`` (paper,
Implementation Details), so every output is inside the limits by construction. The skip
connection is kept in the sigmoid's argument: ``z = c_skip * logit((x_q - lower) / (upper -
lower)) + c_out * F_q`` (the noisy angle is clamped into the open interval first). At low noise
``D_q -> x_q`` exactly as EDM's skip intends; at high noise the network's output decides.
"""

from __future__ import annotations

import torch

from mer_models.solver.limits import limit_clip, limit_logit

__all__ = [
    "precondition",
    "sample_sigma",
    "loss_weight",
    "combine",
    "denoising_loss",
]

def precondition(sigma: torch.Tensor, sigma_data: float) -> tuple[torch.Tensor, ...]:
    """``(c_skip, c_out, c_in, c_noise)`` for sigma (B,), each (B,)."""
    s2 = sigma**2 + sigma_data**2
    return sigma_data**2 / s2, sigma * sigma_data / s2.sqrt(), 1 / s2.sqrt(), sigma.log() / 4


def sample_sigma(n: int, p_mean: float, p_std: float, generator: torch.Generator | None = None, device=None) -> torch.Tensor:
    """Training noise levels: ``ln sigma ~ N(p_mean, p_std^2)``, (n,)."""
    z = torch.randn(n, generator=generator, device=device)
    return (p_mean + p_std * z).exp()


def loss_weight(sigma: torch.Tensor, sigma_data: float) -> torch.Tensor:
    """EDM's ``lambda(sigma) = (sigma^2 + sd^2) / (sigma sd)^2``: unit effective weight at every noise level."""
    return (sigma**2 + sigma_data**2) / (sigma * sigma_data) ** 2


def combine(
    x: torch.Tensor,
    f: torch.Tensor,
    sigma: torch.Tensor,
    sigma_data: float,
    lower: torch.Tensor,
    upper: torch.Tensor,
    node_mask: torch.Tensor,
) -> torch.Tensor:
    """Preconditioned output ``D`` from the noisy sample and the raw network output.

    Args:
        x, f: (B, T, J, 9) noisy sample (diffusion space) and ``F_theta`` output.
        sigma: (B,).
        lower, upper: (B, J) joint limits [rad] (zero-width for base, sites and padding).
        node_mask: (B, J) bool.

    Returns:
        (B, T, J, 9); channel 0 of every node but the base is an angle inside [lower, upper];
        padding nodes and the joints' two padding channels are zero.
    """
    c_skip, c_out, _, _ = (c.view(-1, 1, 1, 1) for c in precondition(sigma, sigma_data))
    d = c_skip * x + c_out * f
    lo, hi = lower[:, None, 1:], upper[:, None, 1:]
    z = c_skip[..., 0] * limit_logit(x[:, :, 1:, 0], lo, hi) + c_out[..., 0] * f[:, :, 1:, 0]
    q = limit_clip(z, lo, hi)
    d = torch.cat([d[:, :, :1], torch.cat([q[..., None], d[:, :, 1:, 1:7], torch.zeros_like(d[:, :, 1:, 7:])], -1)], 2)
    return d * node_mask[:, None, :, None].to(d.dtype)


def denoising_loss(
    d: torch.Tensor, x: torch.Tensor, sigma: torch.Tensor, sigma_data: float, node_mask: torch.Tensor
) -> torch.Tensor:
    """Per-sample ``weight(sigma) * mean ||D - x||^2`` over real nodes and live channels, (B,)."""
    live = torch.ones(d.shape[-2:], dtype=d.dtype, device=d.device)
    live[1:, 7:] = 0
    m = node_mask[:, None, :, None].to(d.dtype) * live
    err = ((d - x) ** 2 * m).sum((1, 2, 3)) / (m.sum((1, 2, 3)) * d.shape[1]).clamp_min(1)
    return loss_weight(sigma, sigma_data) * err
