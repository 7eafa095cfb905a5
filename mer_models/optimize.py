"""The optimisation baseline: minimise ``f_kin`` directly over the joint trajectory and the base.

The same energy as the model's guidance (:mod:`mer_models.energy`, with ``L_cst = 0`` because
positions come from FK), minimised per window or per whole motion, batched over samples of mixed
robots through the foundation's FK. It is

* the peer the model is compared against (GMR-style IK on the same energy, no hand-tuned tables),
* the reference for how close the model gets to the energy's optimum,
* the clean sample ``x`` of the EDM term for targets without motion data (docs/model.md),
* a fallback retargeter when no model is at hand (``mer retarget --method optimize``).

Two stages. (1) Per-frame Levenberg-Marquardt IK on the key-point and nominal-pose terms
(:func:`mer_models.ik.gauss_newton_ik`, projected onto the limits), from the nominal angles, the
scaled reference's base trajectory and the reference's base orientation. (2) Adam on the whole
``f_kin`` (velocity terms included) with limits by construction: ``q = lower + (upper - lower)
sigmoid(z)``, base position free, base rotation ``R = R_1 Exp(omega)``, a cosine-decayed step.
The loss is the *sum* over samples, so each sample's result does not depend on the batch.
"""

from __future__ import annotations

import logging
import math

import torch

from mer_data.rotations import axis_angle_to_matrix

from .config import EnergyConfig
from .edm import _logit_of, limit_clip
from .energy import energy_terms
from .ik import gauss_newton_ik
from .kinematics import BatchGraph

log = logging.getLogger(__name__)

__all__ = ["optimize_motion", "DEFAULT_ITERS", "DEFAULT_GN_ITERS"]

DEFAULT_ITERS = 100
DEFAULT_GN_ITERS = 20


def optimize_motion(
    cfg: EnergyConfig,
    graph: BatchGraph,
    eta: torch.Tensor,
    goal: torch.Tensor,
    ref_base_rot: torch.Tensor,
    *,
    iters: int = DEFAULT_ITERS,
    gn_iters: int = DEFAULT_GN_ITERS,
    lr: float = 0.02,
    fps: float = 30.0,
    init: dict[str, torch.Tensor] | None = None,
) -> dict[str, torch.Tensor]:
    """Minimise ``f_kin`` for a batch.

    Args:
        graph: target side (B samples, Jt nodes).
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m].
        ref_base_rot: (B, T, 3, 3) reference base orientation (initial base orientation).
        iters: Adam iterations of stage 2 (0 skips it).
        gn_iters: Levenberg-Marquardt iterations of stage 1 (0 skips it).
        lr: step of the angle logits [1] and base rotation [rad]; the base position uses lr/5 [m].
        init: optional warm start ``{"q", "base_pos", "base_rot"}`` (e.g. a model's output).

    Returns:
        ``q`` (B, T, Jt) [rad] inside the limits, ``base_pos`` (B, T, 3), ``base_rot`` (B, T, 3, 3),
        and ``energy`` (B,) the final weighted ``f_kin``; all detached.
    """
    B, T = goal.shape[:2]
    J = graph.parents.shape[1]
    lower, upper = graph.lower[:, None].expand(B, T, J), graph.upper[:, None].expand(B, T, J)
    with torch.no_grad():
        if init is None:
            q0 = graph.nominal[:, None].expand(B, T, J)
            p0 = goal[:, :, 0].clone()
            r0 = ref_base_rot.clone()
        else:
            q0, p0, r0 = init["q"], init["base_pos"].clone(), init["base_rot"].clone()
        if gn_iters > 0:
            q0, p0, r0 = gauss_newton_ik(cfg, graph, eta, goal, q0.clone(), p0, r0, iters=gn_iters)
        z = _logit_of(q0, lower, upper).clone()
    z.requires_grad_(True)
    pos = p0.clone().requires_grad_(True)
    omega = torch.zeros(B, T, 3, dtype=goal.dtype, device=goal.device, requires_grad=True)
    opt = torch.optim.Adam([{"params": [z, omega], "lr": lr}, {"params": [pos], "lr": lr / 5}])
    base_lrs = [g["lr"] for g in opt.param_groups]

    def motion():
        return limit_clip(z, lower, upper), pos, r0 @ axis_angle_to_matrix(omega)

    for it in range(iters):
        for g, base in zip(opt.param_groups, base_lrs):
            g["lr"] = base * 0.5 * (1 + math.cos(math.pi * it / iters))
        q, p, r = motion()
        e = energy_terms(cfg, graph, q, p, r, eta, goal, fps)["total"]
        opt.zero_grad(set_to_none=True)
        e.sum().backward()
        opt.step()
    with torch.no_grad():
        q, p, r = motion()
        q = q * graph.revolute[:, None]
        e = energy_terms(cfg, graph, q, p, r, eta, goal, fps)["total"]
    log.debug("optimize_motion: %d iterations, mean f_kin %.5f", iters, float(e.mean()))
    return {"q": q.detach(), "base_pos": p.detach(), "base_rot": r.detach(), "energy": e.detach()}
