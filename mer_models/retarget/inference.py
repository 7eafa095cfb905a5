"""Retarget a batch of independent windows: sample with the model, or optimise (the baseline).

Both return the same world-frame motion: ``q`` (B, T, Jt) [rad], ``base_pos`` (B, T, 3) [m],
``base_rot`` (B, T, 3, 3), in the frame of the batch's ``ref_scaled_pos`` (for origin-normalized
windows: the window's own frame).
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_models.batch import graph_from_batch
from mer_models.config import EnergyConfig, SamplerConfig
from mer_models.diffusion.model import Conditions, RetargetModel
from mer_models.diffusion.precision import network_autocast
from mer_models.diffusion.sampling import (
    CountingDenoiser,
    EnergyGuidance,
    feedback_sigmas,
    karras_sigmas,
    sample_euler,
    sample_euler_ancestral,
    sample_feedback,
    sample_heun,
)
from mer_models.solver.energy import energy_terms
from mer_models.solver.ik import DEFAULT_SMOOTH
from mer_models.solver.optimize import DEFAULT_FINE, DEFAULT_GN_ITERS, DEFAULT_ITERS, optimize_motion

__all__ = ["SAMPLERS", "sample_conditions", "sample_batch", "model_batch", "optimize_batch", "initial_noise"]

SAMPLERS = {"heun": sample_heun, "euler": sample_euler, "ancestral": sample_euler_ancestral, "feedback": sample_feedback}


def initial_noise(shape, sigma_max: float, generator: torch.Generator | None, device) -> torch.Tensor:
    """``sigma_max * N(0, I)`` drawn on the generator's device (so a CPU seed gives the same noise
    on any device), then moved to ``device``."""
    gdev = generator.device if generator is not None else device
    return (torch.randn(shape, generator=generator, device=gdev) * sigma_max).to(device)


def sample_conditions(
    model: RetargetModel,
    cond: Conditions,
    sampler: SamplerConfig,
    *,
    energy: EnergyConfig | None = None,
    method: str | None = None,
    steps: int | None = None,
    generator: torch.Generator | None = None,
    denoiser_wrapper: Callable | None = None,
    stats: dict | None = None,
    bf16: bool = False,
) -> torch.Tensor:
    """Sample ``D`` (B, T, Jt, 9) in the diffusion space for prepared conditions.

    ``method``/``steps`` override ``sampler.method``/``sampler.steps``; ``denoiser_wrapper(denoiser) -> denoiser`` can add
    in-painting; ``stats`` receives ``nfe`` (network evaluations). ``bf16``: the network (reference
    encoder and denoiser) under bfloat16 autocast (:mod:`mer_models.diffusion.precision`); the sampler's
    arithmetic, the guidance and the returned ``D`` stay float32.
    """
    method = method or sampler.method
    if method not in SAMPLERS:
        raise ValueError(f"unknown sampler {method!r}; known: {', '.join(SAMPLERS)}")
    dev = cond.rot.device
    if method == "feedback":
        sigmas = feedback_sigmas(steps or sampler.steps, sampler.sigma_max, sampler.feedback_sigma, device=dev)
    else:
        sigmas = karras_sigmas(steps or sampler.steps, sampler.sigma_min, sampler.sigma_max, sampler.rho, device=dev)
    def denoise(x, sigma, c):
        with network_autocast(dev, bf16):
            return model.denoise(x, sigma, c).float()  # float32 already unless bf16: no copy

    den = CountingDenoiser(denoise)
    fn = denoiser_wrapper(den) if denoiser_wrapper is not None else den
    guidance = None
    if sampler.guidance > 0:
        if energy is None:
            raise ValueError("energy guidance needs the energy configuration")
        guidance = EnergyGuidance(model, energy, sampler.guidance)
    x = initial_noise(cond.shape, float(sigmas[0]), generator, dev) * sampler.init_noise
    if model.cfg.goal_prior:  # residual diffusion: the noise is about the goals
        x = x + model.goal_prior(cond)
    kw = {"generator": generator} if method == "ancestral" else {"project": model.project} if method == "feedback" else {}
    with torch.no_grad():
        with network_autocast(dev, bf16):
            model.encode(cond)
        out = SAMPLERS[method](fn, x, sigmas, cond, guidance=guidance, **kw)
    if stats is not None:
        stats["nfe"] = den.calls
    return out


def sample_batch(model: RetargetModel, batch: Mapping, sampler: SamplerConfig, **kw) -> dict[str, torch.Tensor]:
    """Sample and decode a collated batch (see :func:`sample_conditions` for options)."""
    cond = model.conditions(batch)
    d = sample_conditions(model, cond, sampler, **kw)
    return model.decode(d, cond)


def model_batch(model, batch: Mapping, sampler: SamplerConfig, *, bf16: bool = False, **kw) -> dict[str, torch.Tensor]:
    """The model's motion of a collated batch, whatever its kind: the warm-start network's one pass
    (:meth:`mer_models.warm.model.WarmModel.predict`; sampler options do not apply), or the diffusion
    model's samples (:func:`sample_batch` with ``kw``). ``bf16``: the network under bfloat16 autocast."""
    from mer_models.warm.model import WarmModel

    if isinstance(model, WarmModel):
        with network_autocast(next(model.parameters()).device, bf16):
            out = model.predict(batch)
        return {k: v.float() for k, v in out.items()}
    return sample_batch(model, batch, sampler, bf16=bf16, **kw)


def optimize_batch(
    energy: EnergyConfig,
    batch: Mapping,
    *,
    iters: int = DEFAULT_ITERS,
    gn_iters: int = DEFAULT_GN_ITERS,
    device: str | torch.device = "cpu",
    init: Mapping[str, torch.Tensor] | None = None,
    smooth: float = DEFAULT_SMOOTH,
    fine: str = DEFAULT_FINE,
    physics=None,
    geometry=None,
    ref_skeleton=None,
    fps: float = 30.0,
    target_skeleton=None,
    balance=None,
) -> dict[str, torch.Tensor]:
    """The optimiser on a collated batch, in the batch's frame (no model needed).

    ``init`` warm-starts it (``q``, ``base_pos``, ``base_rot``: e.g. a model's output to refine;
    ``gn_iters`` iterations on whole windows, :func:`mer_models.solver.ik.coupled_lm_ik`); ``smooth``:
    the weight of its temporal prior; ``fine``: the solver of its fine stage without ``init``
    (:data:`mer_models.solver.optimize.DEFAULT_FINE`). ``physics``: a
    :class:`~mer_models.solver.physics.PhysicsConfig` for a batch of one target robot, whose
    collision model is ``geometry``, every sample's reference of ``ref_skeleton`` (the source's
    foot contacts are read from the batch's reference features, at ``fps`` [Hz]); with
    ``target_skeleton`` (the batch's one target) each window is then made feasible
    (:func:`mer_models.retarget.feasible.feasible_motion`). ``balance``: the target's
    :class:`~mer_models.solver.balance_term.BalanceInputs` (the balance term, docs/model.md §Balance).
    """
    g = graph_from_batch(batch, "tgt", device)
    goal = batch["ref_scaled_pos"].to(device, torch.float32)
    ref_rot = axis_angle_to_matrix(batch["reference"][:, :, 0, 0:3].to(device, torch.float32))
    rkw = {}
    if "ref_goal_rot" in batch:
        rkw = {"goal_rot": batch["ref_goal_rot"].to(device, torch.float32), "rot_mask": batch["ref_rot_mask"].to(device)}
    phys = None
    if physics is not None:
        from mer_data.motion.contacts import foot_contacts
        from mer_data.motion.features import split_features
        from mer_models.solver.physics import PhysicsInputs

        pos = split_features(batch["reference"].double())["pos"].numpy()
        contacts = torch.from_numpy(np.stack([foot_contacts(p, ref_skeleton, fps) for p in pos]))
        phys = PhysicsInputs.of_reference(geometry, contacts, fps, physics, ref_skeleton)
    out = optimize_motion(energy, g, batch["joint_map"].to(device, torch.float32), goal, ref_rot, iters=iters, gn_iters=gn_iters,
                          init=init, smooth=smooth, fine=fine, physics=phys, fps=fps, balance=balance, **rkw)  # fmt: skip
    res = {"q": out["q"], "base_pos": out["base_pos"], "base_rot": out["base_rot"], "energy": out["energy"]}
    if phys is not None and target_skeleton is not None and physics.feasible:
        from mer_models.export.writers import TargetMotion

        from .feasible import feasible_motion

        J = target_skeleton.num_nodes
        for b in range(res["q"].shape[0]):
            m = TargetMotion(target_skeleton, fps, res["q"][b, :, :J].double().cpu().numpy(),
                             res["base_pos"][b].double().cpu().numpy(), res["base_rot"][b].double().cpu().numpy())  # fmt: skip
            m = feasible_motion(m, geometry, physics)
            res["q"][b, :, :J] = torch.from_numpy(m.q).to(res["q"])
            res["base_pos"][b] = torch.from_numpy(m.base_pos).to(res["base_pos"])
        with torch.no_grad():  # the energy of what is returned
            res["energy"] = energy_terms(energy, g, res["q"], res["base_pos"], res["base_rot"], batch["joint_map"].to(device, torch.float32),
                                         goal, fps, **rkw)["total"]  # fmt: skip
    return res

