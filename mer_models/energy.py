"""The kinematic energy ``f_kin = L_kp + L_cst + L_vel + L_norm`` (paper, Eq. 5-9).

All terms are computed through the foundation's FK (:func:`mer_data.fk.forward_kinematics`, via
:func:`mer_models.kinematics.batch_fk`) on each sample's own (possibly augmented, padded) target
skeleton, in SI units, each a mean so that robots with different node and key-point counts weigh
the same (one weight setting for all robots)::

    L_kp   = w0 * mean_{t, (i,j): eta_ij = 1} || FK_i(t) - P_j(t) ||^2            [m^2]
    L_cst  = w1 * mean_{t, i}                 || FK_i(t) - p_hat_i(t) ||^2        [m^2]
    L_vel  = w2 * mean_{t, (i,j): eta_ij = 1} || dFK_i/dt - dP_j/dt ||^2          [(m/s)^2]
    L_norm = w3 * ( mean_{actuated i} mean_t (q_i - q0_i)^2 + mean_{t, i} || dFK_i/dt ||^2 )

``P`` are the reference node positions body-part scaled to the target (``ref_scaled_pos``), ``FK``
the node positions of the predicted angles and base pose, ``p_hat`` the predicted position
features, ``q0`` the nominal angles; time derivatives are the second-order finite differences of
:func:`mer_data.features.finite_difference`. Only positions are matched (the paper's pose
difference ``⊖`` is not specified further; reference and target link frames differ in rest
orientation, so orientations are not compared).
"""

from __future__ import annotations

import torch

from mer_data.features import finite_difference
from mer_data.rotations import axis_angle_to_matrix

from .config import EnergyConfig
from .kinematics import BatchGraph, batch_fk

__all__ = ["keypoint_goals", "energy_terms", "f_kin", "split_motion", "TERMS"]

TERMS = ("kp", "cst", "vel", "norm")


def keypoint_goals(eta: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per target node goal positions and pair mask.

    eta (B, Jt, Jr), goal (B, T, Jr, 3) → goals (B, T, Jt, 3), pair mask (B, Jt) bool.
    """
    count = eta.sum(-1)
    w = eta / count.clamp_min(1)[..., None]
    return torch.einsum("bij,btjd->btid", w, goal), count > 0


def split_motion(feats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(B, T, J, 9) features → q (B, T, J) (0 at the base), base_pos (B, T, 3), base_rot (B, T, 3, 3)."""
    q = torch.cat([torch.zeros_like(feats[..., :1, 0]), feats[..., 1:, 0]], -1)
    return q, feats[..., 0, 3:6], axis_angle_to_matrix(feats[..., 0, 0:3])


def _masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """x (B, T, J), mask (B, J) → (B,) mean over T and the masked J."""
    m = mask[:, None, :].to(x.dtype)
    return (x * m).sum((1, 2)) / (m.sum((1, 2)) * x.shape[1]).clamp_min(1)


def energy_terms(
    cfg: EnergyConfig,
    graph: BatchGraph,
    q: torch.Tensor,
    base_pos: torch.Tensor,
    base_rot: torch.Tensor,
    eta: torch.Tensor,
    goal: torch.Tensor,
    fps: float = 30.0,
    pred_pos: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """Weighted terms of ``f_kin`` per sample, each (B,), plus ``"total"``.

    Args:
        graph: the target side of the batch.
        q (B, T, Jt) [rad], base_pos (B, T, 3) [m], base_rot (B, T, 3, 3): the motion.
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m], same frame.
        pred_pos: (B, T, Jt, 3) predicted position features for ``L_cst`` (0 when omitted).
    """
    fk_pos, _ = batch_fk(graph, q, base_pos, base_rot)
    goals, pairs = keypoint_goals(eta.to(fk_pos.dtype), goal.to(fk_pos.dtype))
    pairs = pairs & graph.mask
    fk_vel = finite_difference(fk_pos, fps, dim=-3)
    goal_vel = finite_difference(goals, fps, dim=-3)
    out = {
        "kp": cfg.w_kp * _masked_mean(((fk_pos - goals) ** 2).sum(-1), pairs),
        "vel": cfg.w_vel * _masked_mean(((fk_vel - goal_vel) ** 2).sum(-1), pairs),
    }
    if pred_pos is None:
        out["cst"] = fk_pos.new_zeros(fk_pos.shape[0])
    else:
        out["cst"] = cfg.w_cst * _masked_mean(((fk_pos - pred_pos) ** 2).sum(-1), graph.mask)
    dq = (q - graph.nominal[:, None]) ** 2
    out["norm"] = cfg.w_norm * (_masked_mean(dq, graph.dof) + _masked_mean((fk_vel**2).sum(-1), graph.mask))
    out["total"] = out["kp"] + out["cst"] + out["vel"] + out["norm"]
    return out


def f_kin(
    cfg: EnergyConfig, graph: BatchGraph, feats: torch.Tensor, eta: torch.Tensor, goal: torch.Tensor, fps: float = 30.0
) -> dict[str, torch.Tensor]:
    """:func:`energy_terms` of predicted features (B, T, Jt, 9) in physical units (``L_cst`` included)."""
    q, base_pos, base_rot = split_motion(feats)
    pred_pos = torch.cat([feats[..., :1, 3:6], feats[..., 1:, 1:4]], dim=-2)
    return energy_terms(cfg, graph, q, base_pos, base_rot, eta, goal, fps, pred_pos=pred_pos)
