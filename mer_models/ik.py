"""Per-frame damped Gauss-Newton (Levenberg-Marquardt) IK on the key-point and orientation energy.

The optimiser of :mod:`mer_models.optimize`, batched over samples *and* frames. For every frame of
every sample at once it minimises ::

    w_kp  * mean_pairs    || FK_i(q, base) - P_j ||^2                 key-point positions [m^2]
  + w_ori * mean_oriented || R_i(q, base) - G_j ||_F^2 / 2            base, feet, hands (chordal ~ angle^2)
  + w_norm * mean_dof (q - q0)^2                                      nominal pose [rad^2]
  + smooth * mean_dof (q - (q_prev + q_next) / 2)^2                   temporal smoothness [rad^2]

over all joint angles and the base pose, with analytic Jacobians from the FK's world frames:
``dp_k/dq_j = a_j x (p_k - p_j)`` for every ancestor joint ``j`` of node ``k``, ``dR_k/dq_j =
[a_j]x R_k`` (the node's own joint included), base translation the identity, a world-frame base
rotation ``delta`` ``-[p_k - p_0]x`` and ``-[R_k e_l]x``; mimic joints are folded into their
sources. Steps are projected onto the joint limits.

The smoothness term couples neighbouring frames; it is handled Jacobi-style: the neighbours'
mean is taken from the previous iterate, so every frame still solves a small dense system of its
own and all frames run in one batched solve. It damps the frame-to-frame jitter that redundant
joints (wrists, waist) otherwise pick up between independently solved frames.

Each frame keeps its own Levenberg-Marquardt damping: it shrinks after a step that lowers the
frame's cost and grows (the step rejected) otherwise. A sample stops once none of its frames'
cost moved by more than ``tol`` (relative) in an iteration; the loop ends when every sample has.
Nothing couples samples, so a sample's result does not depend on the rest of the batch (up to
floating-point rounding of differently padded systems).
"""

from __future__ import annotations

import torch

from mer_data.rotations import axis_angle_to_matrix

from .config import EnergyConfig
from .energy import keypoint_goals, orientation_pairs
from .kinematics import BatchGraph, batch_fk

__all__ = ["ancestors", "gauss_newton_ik", "DEFAULT_SMOOTH", "DEFAULT_TOL"]

#: Weight of the temporal smoothness prior, relative to ``w_kp`` [m^2 / rad^2] (docs/model.md).
DEFAULT_SMOOTH = 0.05
#: Relative cost change under which a frame counts as converged.
DEFAULT_TOL = 1e-4


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


def _rows(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, J) bool → (B, K) indices of the True entries (padded with 0) and their (B, K) mask."""
    K = max(int(mask.sum(-1).max()), 1)
    order = torch.argsort((~mask).to(torch.int8), dim=1, stable=True)[:, :K]
    return order, torch.gather(mask, 1, order)


def _neighbour_mean(q: torch.Tensor) -> torch.Tensor:
    """(B, T, J) → the mean of each frame's neighbours in time (the one neighbour at the ends)."""
    if q.shape[1] < 2:
        return q
    prev = torch.cat([q[:, 1:2], q[:, :-1]], 1)
    nxt = torch.cat([q[:, 1:], q[:, -2:-1]], 1)
    return 0.5 * (prev + nxt)


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
    goal_rot: torch.Tensor | None = None,
    rot_mask: torch.Tensor | None = None,
    iters: int = 30,
    damping: float = 1e-2,
    smooth: float = DEFAULT_SMOOTH,
    tol: float = DEFAULT_TOL,
    stats: dict | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Refine (q (B, T, J), base_pos (B, T, 3), base_rot (B, T, 3, 3)) towards the goals.

    Args:
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m].
        goal_rot: (B, T, Jr, 3, 3) orientation goals and rot_mask (B, Jr) the reference nodes that
            carry one (:func:`mer_data.scaling.orientation_goals`); omitted: positions only.
        iters: at most this many iterations; smooth: weight of the temporal prior (0: frames
            independent); tol: early stop (relative cost change of every frame).
        stats: receives ``iterations`` (the most any sample ran) and ``cost`` (B, T).

    Returns the refined triple; angles stay inside [lower, upper].
    """
    B, T, J = q.shape
    dtype, dev = q.dtype, q.device
    goals, pairs = keypoint_goals(eta.to(dtype), goal.to(dtype))
    pairs = pairs & graph.mask
    rows, row_mask = _rows(pairs)  # (B, K)
    K = rows.shape[1]
    goals = torch.gather(goals, 2, rows[:, None, :, None].expand(B, T, K, 3))
    w_kp = ((cfg.w_kp / pairs.sum(-1).clamp_min(1).to(dtype))[:, None] * row_mask.to(dtype))[:, None, :]  # (B,1,K)
    if goal_rot is not None and rot_mask is not None and cfg.w_ori > 0:
        rgoal, opairs = orientation_pairs(eta.to(dtype), goal_rot.to(dtype), rot_mask)
        opairs = opairs & graph.mask
        orows, orow_mask = _rows(opairs)
        M = orows.shape[1]
        rgoal = torch.gather(rgoal, 2, orows[:, None, :, None, None].expand(B, T, M, 3, 3))
        w_o = (cfg.w_ori / 2 / opairs.sum(-1).clamp_min(1).to(dtype))[:, None] * orow_mask.to(dtype)  # (B,M)
        w_o = w_o.repeat_interleave(3, dim=1)[:, None]  # (B,1,3M): one row per rotation column
        gcols = rgoal.transpose(-1, -2).reshape(B, T, 3 * M, 3)  # rows: the goal's columns
    else:
        M = 0
    dof = graph.dof
    n_dof = dof.sum(-1).clamp_min(1).to(dtype)
    w_reg = (cfg.w_norm / n_dof)[:, None] * dof.to(dtype)  # (B,J)
    w_smooth = (smooth * cfg.w_kp / n_dof)[:, None] * dof.to(dtype) if T > 1 else torch.zeros_like(w_reg)
    # columns: the actuated joints only (mimic nodes folded into their sources, sites and padding dropped)
    cols, col_mask = _rows(dof)  # (B, D)
    D = cols.shape[1]
    src = torch.where(graph.revolute & graph.mask, graph.mimic_source, torch.full_like(graph.mimic_source, -1))
    fold = (src[:, :, None] == cols[:, None, :]) & col_mask[:, None, :]  # (B, J, D) node → its driving column
    fold = fold.to(dtype) * torch.where(graph.mimic_source == torch.arange(J, device=dev), 1.0, graph.mimic_multiplier.to(dtype))[..., None]
    anc = ancestors(graph.parents)
    anc_p = torch.gather(anc, 1, rows[..., None].expand(B, K, J)).to(dtype)  # (B,K,J)
    if M:
        own = anc | torch.eye(J, dtype=torch.bool, device=dev)
        anc_o = torch.gather(own, 1, orows[..., None].expand(B, M, J)).to(dtype).repeat_interleave(3, dim=1)  # (B,3M,J)
        orow_node = orows.repeat_interleave(3, dim=1)
        col_of_row = torch.arange(3, device=dev).repeat(M)  # which column of R each row is
    anc_rows = torch.cat([anc_p, anc_o], 1) if M else anc_p  # (B,R,J) which joints move each row
    lower = torch.gather(graph.lower, 1, cols)[:, None]
    upper = torch.gather(graph.upper, 1, cols)[:, None]
    nominal = torch.gather(graph.nominal, 1, cols)[:, None]
    reg = torch.gather(w_reg, 1, cols)[:, None]  # (B,1,D)
    sm = torch.gather(w_smooth, 1, cols)[:, None]
    n = D + 6
    eye = torch.eye(n, dtype=dtype, device=dev)
    pad = (~col_mask).to(dtype)[:, None]  # padding columns: identity rows keep the system regular
    qd = torch.gather(q, 2, cols[:, None].expand(B, T, D))

    def full_q(qd):
        out = q.clone()
        out.scatter_(2, cols[:, None].expand(B, T, D), torch.where(col_mask[:, None], qd, torch.gather(q, 2, cols[:, None].expand(B, T, D))))
        return out

    def residual_cost(pos, rot):
        kp = torch.gather(pos, 2, rows[:, None, :, None].expand(B, T, K, 3))
        cost = (w_kp * ((kp - goals) ** 2).sum(-1)).sum(-1)
        ocols = None
        if M:
            r = torch.gather(rot, 2, orow_node[:, None, :, None, None].expand(B, T, 3 * M, 3, 3))
            ocols = r[..., :, :].gather(-1, col_of_row[None, None, :, None, None].expand(B, T, 3 * M, 3, 1))[..., 0]
            cost = cost + (w_o * ((ocols - gcols) ** 2).sum(-1)).sum(-1)
        return kp, ocols, cost

    def prior(qd, qbar):
        return (reg * (qd - nominal) ** 2).sum(-1) + (sm * (qd - qbar) ** 2).sum(-1)

    pos, rot = batch_fk(graph, full_q(qd), base_pos, base_rot)
    kp, ocols, cost_fit = residual_cost(pos, rot)
    mu = torch.full((B, T), damping, dtype=dtype, device=dev)
    active = torch.ones(B, dtype=torch.bool, device=dev)  # samples still iterating (each stops on its own)
    done = 0
    for it in range(iters):
        qbar = _neighbour_mean(qd)
        cost = cost_fit + prior(qd, qbar)
        axes_w = (rot @ graph.axes[:, None, :, :, None]).squeeze(-1)  # (B,T,J,3) world joint axes
        # a_j x (p_k - p_j) = [a_j]x p_k - a_j x p_j; rotation columns: a_j x c_l = [a_j]x c_l
        vecs = torch.cat([kp, ocols], 2) if M else kp  # (B,T,R,3)
        jrows = torch.einsum("btjde,btre->btrdj", _skew(axes_w), vecs)  # (B,T,R,3,J)
        jrows[:, :, :K] -= torch.linalg.cross(axes_w, pos).transpose(-1, -2)[:, :, None]
        res = [(kp - goals) * w_kp[..., None].sqrt()]
        jb = [torch.cat([torch.eye(3, dtype=dtype, device=dev).expand(B, T, K, 3, 3), -_skew(kp - pos[:, :, :1])], -1)]
        wr = [w_kp]
        if M:
            res.append((ocols - gcols) * w_o[..., None].sqrt())
            jb.append(torch.cat([torch.zeros(B, T, 3 * M, 3, 3, dtype=dtype, device=dev), -_skew(ocols)], -1))
            wr.append(w_o)
        jrows = jrows * anc_rows[:, None, :, None, :]
        jq = (jrows.flatten(1, 3) @ fold).view(B, T, -1, 3, D)  # (B,T,R,3,D): mimic nodes folded into their sources
        jac = torch.cat([jq, torch.cat(jb, 2)], -1)  # (B,T,R,3,n)
        sw = torch.cat(wr, -1).sqrt()[..., None, None]  # (B,1,R,1,1)
        jw = (jac * sw).flatten(2, 3)  # (B,T,3R,n) weighted
        r = torch.cat(res, 2).flatten(2, 3)  # (B,T,3R) weighted residuals
        h = jw.transpose(-1, -2) @ jw
        g = (jw.transpose(-1, -2) @ r[..., None])[..., 0]
        prior_h = torch.cat([reg + sm, torch.zeros(B, 1, 6, dtype=dtype, device=dev)], -1)
        g = g + torch.cat([reg * (qd - nominal) + sm * (qd - qbar), torch.zeros(B, T, 6, dtype=dtype, device=dev)], -1)
        h = h + torch.diag_embed(prior_h.expand(B, T, n))
        diag = h.diagonal(dim1=-2, dim2=-1)
        padd = torch.cat([pad, torch.zeros(B, 1, 6, dtype=dtype, device=dev)], -1)
        h = h + mu[..., None, None] * torch.diag_embed(diag + 1e-9) + torch.diag_embed(padd.expand(B, T, n)) + 1e-9 * eye
        L, info = torch.linalg.cholesky_ex(h)
        step = -torch.cholesky_solve(g[..., None], L)[..., 0]
        step = torch.where((info == 0)[..., None], step, torch.zeros_like(step))
        qd_c = torch.minimum(torch.maximum(qd + step[..., :D] * col_mask[:, None], lower), upper)
        bp_c = base_pos + step[..., D : D + 3]
        br_c = axis_angle_to_matrix(step[..., D + 3 :]) @ base_rot
        pos_c, rot_c = batch_fk(graph, full_q(qd_c), bp_c, br_c)
        kp_c, ocols_c, fit_c = residual_cost(pos_c, rot_c)
        cost_c = fit_c + prior(qd_c, qbar)
        ok = (cost_c < cost) & active[:, None]
        o1, o2, o3 = ok[..., None], ok[..., None, None], ok[..., None, None, None]
        qd, base_pos, base_rot = torch.where(o1, qd_c, qd), torch.where(o1, bp_c, base_pos), torch.where(o2, br_c, base_rot)
        pos, kp = torch.where(o2, pos_c, pos), torch.where(o2, kp_c, kp)
        rot, cost_fit = torch.where(o3, rot_c, rot), torch.where(ok, fit_c, cost_fit)
        if M:
            ocols = torch.where(o2, ocols_c, ocols)
        mu = torch.where(active[:, None], torch.where(ok, mu / 3, mu * 4).clamp(1e-7, 1e6), mu)
        done = it + 1
        change = torch.where(ok, (cost - cost_c) / cost.clamp_min(1e-12), torch.zeros_like(cost))
        if it >= 2:
            active = active & ~(change < tol).all(-1)
            if not bool(active.any()):
                break
    if stats is not None:
        stats["iterations"] = done
        stats["cost"] = cost_fit + prior(qd, _neighbour_mean(qd))
    return full_q(qd), base_pos, base_rot
