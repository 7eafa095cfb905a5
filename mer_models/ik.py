"""Per-frame damped Gauss-Newton (Levenberg-Marquardt) IK on the key-point part of ``f_kin``.

The first stage of the optimisation baseline (:mod:`mer_models.optimize`): for every frame of every
sample at once it minimises ::

    w0 * mean_pairs || FK_i(q, base) - P_j ||^2 + w3 * mean_dof (q - q0)^2

over all joint angles and the base pose, with analytic Jacobians from the FK's world frames
(``dp_k/dq_j = a_j x (p_k - p_j)`` for every ancestor joint ``j`` of node ``k``; base translation
the identity; a world-frame base rotation ``delta`` gives ``-[p_k - p_0]x``), mimic joints folded
into their sources. Steps are projected onto the joint limits. Velocity terms are left to the
second stage.
"""

from __future__ import annotations

import torch

from mer_data.rotations import axis_angle_to_matrix

from .config import EnergyConfig
from .energy import keypoint_goals
from .kinematics import BatchGraph, batch_fk

__all__ = ["ancestors", "gauss_newton_ik"]


def ancestors(parents: torch.Tensor) -> torch.Tensor:
    """(B, J) parents (``-1`` at node 0) → (B, J, J) bool, ``[b, k, j]`` True iff j is a strict ancestor of k."""
    B, J = parents.shape
    anc = torch.zeros(B, J, J, dtype=torch.bool, device=parents.device)
    b = torch.arange(B, device=parents.device)[:, None].expand(B, J)
    k = torch.arange(J, device=parents.device)[None].expand(B, J)
    cur = parents.clone()
    while bool((cur >= 0).any()):
        v = cur >= 0
        anc[b[v], k[v], cur[v]] = True
        cur = torch.where(v, torch.gather(parents, 1, cur.clamp_min(0)), torch.full_like(cur, -1))
    return anc


def _skew(v: torch.Tensor) -> torch.Tensor:
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(v.shape + (3,))


def _pair_rows(pairs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, J) bool → (B, K) node indices of the pairs (padded with 0) and their (B, K) mask."""
    K = max(int(pairs.sum(-1).max()), 1)
    order = torch.argsort((~pairs).to(torch.int8), dim=1, stable=True)[:, :K]
    return order, torch.gather(pairs, 1, order)


@torch.no_grad()
def gauss_newton_ik(
    cfg: EnergyConfig,
    graph: BatchGraph,
    eta: torch.Tensor,
    goal: torch.Tensor,
    q: torch.Tensor,
    base_pos: torch.Tensor,
    base_rot: torch.Tensor,
    *,
    iters: int = 10,
    damping: float = 1e-2,
    chunk: int = 1024,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Refine (q (B, T, J), base_pos (B, T, 3), base_rot (B, T, 3, 3)) towards the key-point goals.

    Levenberg-Marquardt with a per-frame damping that shrinks after a step that lowers the
    frame's cost and grows (the step rejected) otherwise, so no frame ever gets worse. Returns the
    refined triple; angles stay inside [lower, upper]. Frames are independent: long motions are
    processed ``chunk`` frames at a time to bound memory.
    """
    B, T, J = q.shape
    if T > chunk:
        parts = [
            gauss_newton_ik(cfg, graph, eta, goal[:, a : a + chunk], q[:, a : a + chunk], base_pos[:, a : a + chunk],
                            base_rot[:, a : a + chunk], iters=iters, damping=damping, chunk=chunk)
            for a in range(0, T, chunk)
        ]  # fmt: skip
        return tuple(torch.cat([p[i] for p in parts], 1) for i in range(3))
    dtype, dev = q.dtype, q.device
    goals, pairs = keypoint_goals(eta.to(dtype), goal.to(dtype))
    pairs = pairs & graph.mask
    rows, row_mask = _pair_rows(pairs)  # (B,K)
    K = rows.shape[1]
    goals = torch.gather(goals, 2, rows[:, None, :, None].expand(B, T, K, 3))
    n_pairs = pairs.sum(-1).clamp_min(1).to(dtype)
    dof = graph.dof
    n_dof = dof.sum(-1).clamp_min(1).to(dtype)
    w_kp = ((cfg.w_kp / n_pairs)[:, None] * row_mask.to(dtype))[:, None, :]  # (B,1,K)
    w_reg = (cfg.w_norm / n_dof)[:, None] * dof.to(dtype)  # (B,J)
    anc = torch.gather(ancestors(graph.parents), 1, rows[..., None].expand(B, K, J)).to(dtype)  # (B,K,J)
    fold = torch.zeros(B, J, J, dtype=dtype, device=dev)  # (node m, its source): mimic columns → sources
    fold.scatter_(2, graph.mimic_source[..., None], (graph.mimic_multiplier * graph.revolute.to(dtype))[..., None])
    lower, upper = graph.lower[:, None], graph.upper[:, None]
    nominal = graph.nominal[:, None]
    n = J + 6
    eye = torch.eye(n, dtype=dtype, device=dev)
    zeros6 = torch.zeros(B, T, 6, dtype=dtype, device=dev)
    reg = torch.cat([w_reg, torch.zeros(B, 6, dtype=dtype, device=dev)], -1)[:, None]  # (B,1,n)

    def evaluate(q, bp, br):
        pos, rot = batch_fk(graph, q, bp, br)
        kp = torch.gather(pos, 2, rows[:, None, :, None].expand(B, T, K, 3))
        cost = (w_kp * ((kp - goals) ** 2).sum(-1)).sum(-1) + (w_reg[:, None] * (q - nominal) ** 2).sum(-1)
        return pos, rot, kp, cost

    pos, rot, kp, cost = evaluate(q, base_pos, base_rot)
    mu = torch.full((B, T), damping, dtype=dtype, device=dev)
    for _ in range(iters):
        axes_w = (rot @ graph.axes[:, None, :, :, None]).squeeze(-1)  # (B,T,J,3) world joint axes
        diff = kp[:, :, :, None, :] - pos[:, :, None, :, :]  # (B,T,K,J,3)
        jq = torch.linalg.cross(axes_w[:, :, None].expand_as(diff), diff) * anc[:, None, :, :, None]
        jq = torch.einsum("btkmd,bmj->btkjd", jq, fold) * dof[:, None, None, :, None]
        jb = torch.cat([torch.eye(3, dtype=dtype, device=dev).expand(B, T, K, 3, 3), -_skew(kp - pos[:, :, :1])], -1)
        jac = torch.cat([jq.transpose(-1, -2), jb], -1)  # (B,T,K,3,n)
        wj = jac * w_kp[..., None, None]
        h = torch.einsum("btkdi,btkdj->btij", wj, jac) + torch.diag_embed(reg.expand(B, T, n))
        g = torch.einsum("btkdi,btkd->bti", wj, kp - goals) + reg * torch.cat([q - nominal, zeros6], -1)
        diag = h.diagonal(dim1=-2, dim2=-1)
        h = h + mu[..., None, None] * torch.diag_embed(diag + 1e-9) + 1e-9 * eye
        step = -torch.linalg.solve(h, g[..., None])[..., 0]
        q_c = torch.minimum(torch.maximum(q + step[..., :J] * dof[:, None], lower), upper)
        bp_c = base_pos + step[..., J : J + 3]
        br_c = axis_angle_to_matrix(step[..., J + 3 :]) @ base_rot
        pos_c, rot_c, kp_c, cost_c = evaluate(q_c, bp_c, br_c)
        ok = cost_c < cost
        o1, o2, o3 = ok[..., None], ok[..., None, None], ok[..., None, None, None]
        q, base_pos, base_rot = torch.where(o1, q_c, q), torch.where(o1, bp_c, base_pos), torch.where(o2, br_c, base_rot)
        pos, kp = torch.where(o2, pos_c, pos), torch.where(o2, kp_c, kp)
        rot, cost = torch.where(o3, rot_c, rot), torch.where(ok, cost_c, cost)
        mu = torch.where(ok, mu / 3, mu * 4).clamp(1e-6, 1e6)
    return q, base_pos, base_rot
