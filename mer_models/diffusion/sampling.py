"""Samplers: stateless loops over a noise schedule (k-diffusion style).

Every sampler is a pure function of ``(denoiser, x, sigmas, cond)`` where
``denoiser(x, sigma, cond) -> D`` is the x0-prediction (``RetargetModel.denoise``), ``x`` starts as
``sigmas[0] * N(0, I)`` and ``sigmas`` ends with 0. Options:

* ``guidance(d, sigma, cond) -> d``: applied to the denoised estimate of every step (test-time
  energy guidance, :class:`EnergyGuidance`; in-painting is a denoiser wrapper, see
  :mod:`mer_models.retarget.long_horizon`). Heun's corrector evaluation is left unguided: its slope divides
  by the next, smaller sigma, which would multiply the guidance's displacement (unstable near
  sigma_min); the last step returns the guided estimate itself;
* ``callback(dict)``: called after every step with ``i, sigma, x, denoised``;
* ``disable``: hide the progress bar.

Schedules: :func:`karras_sigmas` (EDM, Eq. 5: ``rho = 7``). Samplers: :func:`sample_heun` (EDM
Alg. 1, deterministic, ``2 N - 1`` network evaluations for N steps; the last step, to sigma 0,
returns the denoised estimate itself, so joint limits hold exactly), :func:`sample_euler` (first
order, one evaluation per step) and :func:`sample_euler_ancestral` (stochastic, DDPM-like); with
1000 steps the latter two are the paper's 1000-step regime, kept for comparison.
:func:`sample_feedback` (schedule :func:`feedback_sigmas`) is not an ODE solver: learned iterative
refinement, each evaluation after the first correcting the previous estimate made consistent by
``project`` (``RetargetModel.project``), for models trained on their own estimates
(``TrainConfig.feedback_frac``).
"""

from __future__ import annotations

from typing import Callable

import torch
from tqdm.auto import trange

from mer_models.config import EnergyConfig
from mer_models.solver.limits import limit_clip, limit_logit

__all__ = [
    "karras_sigmas",
    "sample_heun",
    "sample_euler",
    "sample_euler_ancestral",
    "feedback_sigmas",
    "sample_feedback",
    "EnergyGuidance",
    "CountingDenoiser",
]

Denoiser = Callable[[torch.Tensor, torch.Tensor, object], torch.Tensor]


def karras_sigmas(n: int, sigma_min: float = 0.002, sigma_max: float = 80.0, rho: float = 7.0, device=None) -> torch.Tensor:
    """EDM Eq. 5: ``n`` noise levels from sigma_max down to sigma_min, then a final 0; (n + 1,)."""
    ramp = torch.linspace(0, 1, n, device=device, dtype=torch.float64)
    lo, hi = sigma_min ** (1 / rho), sigma_max ** (1 / rho)
    sig = (hi + ramp * (lo - hi)) ** rho
    return torch.cat([sig, sig.new_zeros(1)]).to(torch.float32)


def _denoised(denoiser, x, sigma, cond, guidance):
    d = denoiser(x, sigma, cond)
    return guidance(d, sigma, cond) if guidance is not None else d


@torch.no_grad()
def sample_heun(
    denoiser: Denoiser,
    x: torch.Tensor,
    sigmas: torch.Tensor,
    cond: object,
    *,
    guidance: Callable | None = None,
    callback: Callable | None = None,
    disable: bool = True,
) -> torch.Tensor:
    """EDM Algorithm 1 (deterministic Heun, no churn); the last step to sigma 0 is an Euler step."""
    for i in trange(len(sigmas) - 1, disable=disable, desc="heun"):
        s, s_next = sigmas[i], sigmas[i + 1]
        d = _denoised(denoiser, x, s, cond, guidance)
        slope = (x - d) / s
        if s_next > 0:
            x_next = x + (s_next - s) * slope
            d2 = denoiser(x_next, s_next, cond)  # no guidance in the corrector (see module docstring)
            slope2 = (x_next - d2) / s_next
            x_next = x + (s_next - s) * (slope + slope2) / 2
        else:  # Euler step to sigma = 0 lands exactly on the denoised estimate
            x_next = d
        if callback is not None:
            callback({"i": i, "sigma": s, "x": x_next, "denoised": d})
        x = x_next
    return x


@torch.no_grad()
def sample_euler(
    denoiser: Denoiser,
    x: torch.Tensor,
    sigmas: torch.Tensor,
    cond: object,
    *,
    guidance: Callable | None = None,
    callback: Callable | None = None,
    disable: bool = True,
) -> torch.Tensor:
    """Euler steps of the probability-flow ODE (one evaluation per step)."""
    for i in trange(len(sigmas) - 1, disable=disable, desc="euler"):
        s, s_next = sigmas[i], sigmas[i + 1]
        d = _denoised(denoiser, x, s, cond, guidance)
        x = x + (s_next - s) * (x - d) / s if s_next > 0 else d
        if callback is not None:
            callback({"i": i, "sigma": s, "x": x, "denoised": d})
    return x


def feedback_sigmas(n: int, sigma_max: float, feedback_sigma: float, device=None) -> torch.Tensor:
    """The ``feedback`` schedule: ``sigma_max``, then ``n - 1`` times ``feedback_sigma``, then 0; (n + 1,)."""
    sig = [float(sigma_max)] + [float(feedback_sigma)] * (n - 1) + [0.0]
    return torch.tensor(sig, dtype=torch.float32, device=device)


@torch.no_grad()
def sample_feedback(
    denoiser: Denoiser,
    x: torch.Tensor,
    sigmas: torch.Tensor,
    cond: object,
    *,
    project: Callable[[torch.Tensor, object], torch.Tensor],
    guidance: Callable | None = None,
    callback: Callable | None = None,
    disable: bool = True,
) -> torch.Tensor:
    """Learned iterative refinement: ``d = D(x, sigmas[0])``, then ``d = D(project(d), sigma_i)`` for
    every further positive ``sigma_i`` (:func:`feedback_sigmas`); returns the last estimate.

    ``project(d, cond)`` maps an estimate to the input the network was trained to correct (the
    estimate made kinematically consistent, ``RetargetModel.project``). One evaluation per sigma.
    """
    n = int((sigmas > 0).sum())
    d = _denoised(denoiser, x, sigmas[0], cond, guidance)
    if callback is not None:
        callback({"i": 0, "sigma": sigmas[0], "x": x, "denoised": d})
    for i in trange(1, n, disable=disable, desc="feedback"):
        x = project(d, cond)
        d = _denoised(denoiser, x, sigmas[i], cond, guidance)
        if callback is not None:
            callback({"i": i, "sigma": sigmas[i], "x": x, "denoised": d})
    return d


@torch.no_grad()
def sample_euler_ancestral(
    denoiser: Denoiser,
    x: torch.Tensor,
    sigmas: torch.Tensor,
    cond: object,
    *,
    guidance: Callable | None = None,
    callback: Callable | None = None,
    disable: bool = True,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Ancestral sampling (fresh noise each step, as DDPM's sampler; one evaluation per step)."""
    for i in trange(len(sigmas) - 1, disable=disable, desc="ancestral"):
        s, s_next = sigmas[i], sigmas[i + 1]
        d = _denoised(denoiser, x, s, cond, guidance)
        sigma_up = torch.sqrt((s_next**2 * (s**2 - s_next**2) / s**2).clamp_min(0))
        sigma_down = torch.sqrt((s_next**2 - sigma_up**2).clamp_min(0))
        if s_next > 0:
            x = x + (sigma_down - s) * (x - d) / s
            x = x + torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype) * sigma_up
        else:
            x = d
        if callback is not None:
            callback({"i": i, "sigma": s, "x": x, "denoised": d})
    return x


class CountingDenoiser:
    """Wraps a denoiser and counts its network evaluations (``calls``)."""

    def __init__(self, denoiser: Denoiser) -> None:
        self.denoiser, self.calls = denoiser, 0

    def __call__(self, x, sigma, cond):
        self.calls += 1
        return self.denoiser(x, sigma, cond)


class EnergyGuidance:
    """Test-time guidance: each denoised estimate takes ``steps`` steps along ``-grad f_kin``.

    The energy is the model's ``f_kin`` (:meth:`RetargetModel.energy`) summed over frames (so the
    step does not depend on the window length). Joint angles move in the limit clip's logit space,
    so they stay inside the limits; everything else moves in the diffusion space. ``f_kin`` is
    stiff (its velocity terms scale with fps^2), so each step backtracks: a sample whose energy
    would rise retries with half the step, up to ``backtrack`` times, and otherwise stays put.

    Args:
        model: a :class:`~mer_models.diffusion.model.RetargetModel`.
        cfg: the energy weights.
        scale: initial step size.
        steps: gradient steps per denoised estimate.
        sigma_max: guide only at noise levels at or below this (high-noise estimates are blurry).
        backtrack: halvings tried before a step is skipped.
    """

    def __init__(
        self, model, cfg: EnergyConfig, scale: float, steps: int = 1, sigma_max: float = float("inf"), backtrack: int = 6
    ) -> None:
        self.model, self.cfg, self.scale, self.steps = model, cfg, scale, steps
        self.sigma_max, self.backtrack = sigma_max, backtrack

    def __call__(self, d: torch.Tensor, sigma: torch.Tensor, cond) -> torch.Tensor:
        if self.scale <= 0 or float(sigma) > self.sigma_max:
            return d
        g = cond.tgt_graph
        lo, hi = g.lower[:, None, 1:], g.upper[:, None, 1:]
        T = d.shape[1]

        def assemble(z, rest):
            q = limit_clip(z, lo, hi)
            return torch.cat([rest[:, :, :1], torch.cat([q[..., None], rest[:, :, 1:, 1:]], -1)], 2)

        def energy(z, rest):
            return self.model.energy(assemble(z, rest), cond, self.cfg)["total"] * T

        z = limit_logit(d[:, :, 1:, 0], lo, hi).detach()
        rest = d.detach().clone()
        for _ in range(self.steps):
            with torch.enable_grad():
                z.requires_grad_(True)
                rest.requires_grad_(True)
                e = energy(z, rest)
                gz, gr = torch.autograd.grad(e.sum(), [z, rest])
            z, rest = z.detach(), rest.detach()
            gr[:, :, 1:, 0] = 0
            step = torch.full((d.shape[0],), float(self.scale), dtype=d.dtype, device=d.device)
            accepted = torch.zeros(d.shape[0], dtype=torch.bool, device=d.device)
            new_z, new_rest = z, rest
            for _ in range(self.backtrack + 1):
                s = step.view(-1, 1, 1)
                cz = z - s * gz
                cr = rest - s[..., None] * gr
                with torch.no_grad():
                    ok = (energy(cz, cr) < e.detach()) & ~accepted
                m = ok.view(-1, 1, 1)
                new_z = torch.where(m, cz, new_z)
                new_rest = torch.where(m[..., None], cr, new_rest)
                accepted |= ok
                if bool(accepted.all()):
                    break
                step = torch.where(accepted, step, step / 2)
            z, rest = new_z, new_rest
        return assemble(z, rest) * g.mask[:, None, :, None]
