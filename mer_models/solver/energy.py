"""The kinematic energy ``f_kin = L_kp + L_cst + L_vel + L_norm`` (paper, Eq. 5-9).

All terms are computed through the foundation's FK (:func:`mer_data.kinematics.fk.forward_kinematics`, via
:func:`mer_models.batch.batch_fk`) on each sample's own (possibly augmented, padded) target
skeleton, in SI units, each a mean so that robots with different node and key-point counts weigh
the same (one weight setting for all robots)::

    L_kp   = w0 * mean_{t, (i,j): eta_ij = 1} || FK_i(t) - P_j(t) ||^2            [m^2]
    L_cst  = w1 * mean_{t, i}                 || FK_i(t) - p_hat_i(t) ||^2        [m^2]
    L_vel  = w2 * mean_{t, (i,j): eta_ij = 1} || dFK_i/dt - dP_j/dt ||^2          [(m/s)^2]
    L_norm = w3 * ( mean_{actuated i} mean_t (q_i - q0_i)^2 + mean_{t, i} || dFK_i/dt ||^2 )
    L_ori  = w_ori * mean_{t, oriented (i,j)} || R_i(t) - G_j(t) ||_F^2 / 2                [~rad^2]

``P`` are the reference node positions scaled to the target (``ref_scaled_pos``,
:mod:`mer_data.kinematics.scaling`), ``FK`` the node positions of the predicted angles and base pose, ``p_hat``
the predicted position features, ``q0`` the nominal angles; time derivatives are the second-order
finite differences of :func:`mer_data.motion.features.finite_difference`.

``L_ori`` is the orientation half of the paper's pose difference ``⊖``: the base, the feet and the
hands (``ref_goal_rot``, ``ref_rot_mask``: :func:`mer_data.kinematics.orientation.orientation_goals`), each
relative to its robot's zero-pose frame. The chordal distance ``||R - G||_F^2 / 2 = 2 (1 - cos
angle)`` is ``angle^2`` for small angles and smooth everywhere.
"""

from __future__ import annotations

import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.features import finite_difference
from mer_models.batch import BatchGraph, batch_fk
from mer_models.config import EnergyConfig

__all__ = ["keypoint_goals", "orientation_pairs", "energy_terms", "f_kin", "split_motion", "TERMS"]

TERMS = ("kp", "cst", "vel", "norm", "ori")


def keypoint_goals(eta: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per target node goal positions and pair mask.

    eta (B, Jt, Jr), goal (B, T, Jr, 3) → goals (B, T, Jt, 3), pair mask (B, Jt) bool.
    """
    count = eta.sum(-1)
    w = eta / count.clamp_min(1)[..., None]
    return torch.einsum("bij,btjd->btid", w, goal), count > 0


def orientation_pairs(eta: torch.Tensor, goal_rot: torch.Tensor, rot_mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per target node orientation goal and pair mask.

    eta (B, Jt, Jr), goal_rot (B, T, Jr, 3, 3), rot_mask (B, Jr) bool → goals (B, T, Jt, 3, 3)
    (the goal of the node's reference partner), mask (B, Jt) bool (nodes paired with a tracked one).
    """
    em = eta * rot_mask[:, None, :].to(eta.dtype)
    partner = em.argmax(-1)  # (B, Jt)
    B, T = goal_rot.shape[:2]
    Jt = eta.shape[1]
    g = torch.gather(goal_rot, 2, partner[:, None, :, None, None].expand(B, T, Jt, 3, 3))
    return g, em.sum(-1) > 0


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
    goal_rot: torch.Tensor | None = None,
    rot_mask: torch.Tensor | None = None,
    fk: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict[str, torch.Tensor]:
    """Weighted terms of ``f_kin`` per sample, each (B,), plus ``"total"``.

    Args:
        graph: the target side of the batch.
        q (B, T, Jt) [rad], base_pos (B, T, 3) [m], base_rot (B, T, 3, 3): the motion.
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m], same frame.
        pred_pos: (B, T, Jt, 3) predicted position features for ``L_cst`` (0 when omitted).
        goal_rot, rot_mask: (B, T, Jr, 3, 3) orientation goals and (B, Jr) the tracked reference
            nodes, for ``L_ori`` (0 when omitted).
        fk: ``batch_fk(graph, q, base_pos, base_rot)`` when the caller has it already.
    """
    fk_pos, fk_rot = fk if fk is not None else batch_fk(graph, q, base_pos, base_rot)
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
    if goal_rot is None or rot_mask is None or cfg.w_ori == 0:
        out["ori"] = fk_pos.new_zeros(fk_pos.shape[0])
    else:
        rgoal, opairs = orientation_pairs(eta.to(fk_pos.dtype), goal_rot.to(fk_pos.dtype), rot_mask)
        chord = ((fk_rot - rgoal) ** 2).sum((-1, -2)) / 2
        out["ori"] = cfg.w_ori * _masked_mean(chord, opairs & graph.mask)
    out["total"] = out["kp"] + out["cst"] + out["vel"] + out["norm"] + out["ori"]
    return out


def f_kin(
    cfg: EnergyConfig,
    graph: BatchGraph,
    feats: torch.Tensor,
    eta: torch.Tensor,
    goal: torch.Tensor,
    fps: float = 30.0,
    goal_rot: torch.Tensor | None = None,
    rot_mask: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """:func:`energy_terms` of predicted features (B, T, Jt, 9) in physical units (``L_cst`` included)."""
    q, base_pos, base_rot = split_motion(feats)
    pred_pos = torch.cat([feats[..., :1, 3:6], feats[..., 1:, 1:4]], dim=-2)
    return energy_terms(cfg, graph, q, base_pos, base_rot, eta, goal, fps, pred_pos=pred_pos, goal_rot=goal_rot, rot_mask=rot_mask)
