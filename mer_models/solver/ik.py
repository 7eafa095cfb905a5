"""Per-frame damped Gauss-Newton (Levenberg-Marquardt) IK on the key-point and orientation energy.

The optimiser of :mod:`mer_models.solver.optimize`, batched over samples *and* frames. For every frame of
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

:func:`coupled_lm_ik`, for warm starts (``--refine K``), solves the same terms with the frames
coupled exactly instead: one block-tridiagonal system per sample and iteration (block cyclic
reduction), joints at a limit the gradient pushes past held, one damping per sample. Its prior has
the Jacobi prior's gradient, so both share their fixed point; it gets there in a few iterations
where the Jacobi prior needs dozens (docs/model.md §The optimiser as a refinement).

In :func:`gauss_newton_ik` each frame keeps its own Levenberg-Marquardt damping: it shrinks after
a step that lowers the frame's cost and grows (the step rejected) otherwise. A sample stops once none of its frames'
cost moved by more than ``tol`` (relative) in an iteration; the loop ends when every sample has.
Nothing couples samples, so a sample's result does not depend on the rest of the batch (up to
floating-point rounding of differently padded systems).

With ``physics`` (:mod:`mer_models.solver.physics`) both solvers add the physical terms' rows to
every frame's system (joint speed, in :func:`coupled_lm_ik` only, to the block-tridiagonal one), and
in :func:`gauss_newton_ik` a rejected step no longer counts as convergence (one-sided terms often
reject the first steps): a frame is done after an accepted small step or once its damping reaches 1e3.
"""

from __future__ import annotations

from typing import Any

import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_models.batch import BatchGraph, ancestors, batch_fk  # noqa: F401  (ancestors: imported from here too)
from mer_models.config import EnergyConfig

from .energy import keypoint_goals, orientation_pairs
from .progress import report
from .tridiagonal import block_tridiagonal_solve

__all__ = ["ancestors", "gauss_newton_ik", "coupled_lm_ik", "DEFAULT_SMOOTH", "DEFAULT_TOL"]

#: Weight of the temporal smoothness prior, relative to ``w_kp`` [m^2 / rad^2] (docs/model.md).
DEFAULT_SMOOTH = 0.05
#: Relative cost change under which a frame counts as converged.
DEFAULT_TOL = 1e-4


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


class _Problem:
    """One batch's key-point, orientation and nominal-pose terms in the form both solvers use:
    the actuated joints as columns (mimic nodes folded into their sources, sites and padding
    dropped), the goals gathered per row, and the analytic Jacobian (module docstring)."""

    def __init__(self, cfg, graph, eta, goal, q, goal_rot, rot_mask) -> None:
        B, T, J = q.shape
        dtype, dev = q.dtype, q.device
        self.B, self.T, self.J, self.dtype, self.dev, self.graph, self.q = B, T, J, dtype, dev, graph, q
        goals, pairs = keypoint_goals(eta.to(dtype), goal.to(dtype))
        pairs = pairs & graph.mask
        rows, row_mask = _rows(pairs)  # (B, K)
        K = self.K = rows.shape[1]
        self.rows = rows
        self.goals = torch.gather(goals, 2, rows[:, None, :, None].expand(B, T, K, 3))
        self.w_kp = ((cfg.w_kp / pairs.sum(-1).clamp_min(1).to(dtype))[:, None] * row_mask.to(dtype))[:, None, :]  # (B,1,K)
        self.M = 0
        if goal_rot is not None and rot_mask is not None and cfg.w_ori > 0:
            rgoal, opairs = orientation_pairs(eta.to(dtype), goal_rot.to(dtype), rot_mask)
            opairs = opairs & graph.mask
            orows, orow_mask = _rows(opairs)
            M = self.M = orows.shape[1]
            rgoal = torch.gather(rgoal, 2, orows[:, None, :, None, None].expand(B, T, M, 3, 3))
            w_o = (cfg.w_ori / 2 / opairs.sum(-1).clamp_min(1).to(dtype))[:, None] * orow_mask.to(dtype)  # (B,M)
            self.w_o = w_o.repeat_interleave(3, dim=1)[:, None]  # (B,1,3M): one row per rotation column
            self.gcols = rgoal.transpose(-1, -2).reshape(B, T, 3 * M, 3)  # rows: the goal's columns
        dof = graph.dof
        self.n_dof = dof.sum(-1).clamp_min(1).to(dtype)
        w_reg = (cfg.w_norm / self.n_dof)[:, None] * dof.to(dtype)  # (B,J)
        cols, col_mask = _rows(dof)  # (B, D)
        self.cols, self.col_mask = cols, col_mask
        D = self.D = cols.shape[1]
        src = torch.where(graph.revolute & graph.mask, graph.mimic_source, torch.full_like(graph.mimic_source, -1))
        fold = (src[:, :, None] == cols[:, None, :]) & col_mask[:, None, :]  # (B, J, D) node → its driving column
        self.fold = fold.to(dtype) * torch.where(graph.mimic_source == torch.arange(J, device=dev), 1.0, graph.mimic_multiplier.to(dtype))[..., None]
        anc = ancestors(graph.parents)
        anc_p = torch.gather(anc, 1, rows[..., None].expand(B, K, J)).to(dtype)  # (B,K,J)
        if self.M:
            own = anc | torch.eye(J, dtype=torch.bool, device=dev)
            anc_o = torch.gather(own, 1, orows[..., None].expand(B, M, J)).to(dtype).repeat_interleave(3, dim=1)  # (B,3M,J)
            self.orow_node = orows.repeat_interleave(3, dim=1)
            self.col_of_row = torch.arange(3, device=dev).repeat(M)  # which column of R each row is
        self.anc_rows = torch.cat([anc_p, anc_o], 1) if self.M else anc_p  # (B,R,J) which joints move each row
        # linearise's Jacobian, one small product per frame: the joint nodes that drive a column ("entries": the
        # columns' own nodes, and mimic nodes), which rows each moves, and the fold of entries into columns
        ents, ent_mask = _rows((self.fold != 0).any(-1))  # (B, E)
        E = self.E = ents.shape[1]
        self.ents = ents
        moves = torch.gather(self.anc_rows, 2, ents[:, None, :].expand(B, self.anc_rows.shape[1], E))
        self.moves_e = (moves * ent_mask[:, None].to(dtype)).repeat_interleave(3, dim=1)[:, None]  # (B, 1, 3R, E)
        ent_fold = torch.gather(self.fold, 1, ents[..., None].expand(B, E, D)) * ent_mask[..., None].to(dtype)  # (B, E, D)
        plain = E == D and torch.equal(ent_fold, torch.diag_embed(col_mask.to(dtype)))  # no mimic joints: entries = columns
        self.ent_fold = None if plain else ent_fold
        self.lower = torch.gather(graph.lower, 1, cols)[:, None]
        self.upper = torch.gather(graph.upper, 1, cols)[:, None]
        self.nominal = torch.gather(graph.nominal, 1, cols)[:, None]
        self.reg = torch.gather(w_reg, 1, cols)[:, None]  # (B,1,D)
        self.n = D + 6
        self.pad = (~col_mask).to(dtype)[:, None]  # padding columns: identity rows keep the system regular
        self.padd = torch.cat([self.pad, torch.zeros(B, 1, 6, dtype=dtype, device=dev)], -1)  # (B,1,n)

    def dof_weight(self, weight: float) -> torch.Tensor:
        """(B, 1, D): ``weight / n_dof`` on every actuated column (0 on padding): a per-DoF mean's weight."""
        return torch.gather((weight / self.n_dof)[:, None] * self.graph.dof.to(self.dtype), 1, self.cols)[:, None]

    def columns(self, q: torch.Tensor) -> torch.Tensor:
        return torch.gather(q, 2, self.cols[:, None].expand(self.B, self.T, self.D))

    def full_q(self, qd: torch.Tensor) -> torch.Tensor:
        out = self.q.clone()
        idx = self.cols[:, None].expand(self.B, self.T, self.D)
        out.scatter_(2, idx, torch.where(self.col_mask[:, None], qd, torch.gather(self.q, 2, idx)))
        return out

    def fit(self, qd, base_pos, base_rot):
        """FK and the fit terms: world positions, rotations, key points, rotation columns, cost (B, T)."""
        pos, rot = batch_fk(self.graph, self.full_q(qd), base_pos, base_rot)
        return (pos, rot, *self.residual_cost(pos, rot))

    def residual_cost(self, pos, rot):
        B, T, K, M = self.B, self.T, self.K, self.M
        kp = torch.gather(pos, 2, self.rows[:, None, :, None].expand(B, T, K, 3))
        cost = (self.w_kp * ((kp - self.goals) ** 2).sum(-1)).sum(-1)
        ocols = None
        if M:
            r = torch.gather(rot, 2, self.orow_node[:, None, :, None, None].expand(B, T, 3 * M, 3, 3))
            ocols = r[..., :, :].gather(-1, self.col_of_row[None, None, :, None, None].expand(B, T, 3 * M, 3, 1))[..., 0]
            cost = cost + (self.w_o * ((ocols - self.gcols) ** 2).sum(-1)).sum(-1)
        return kp, ocols, cost

    def linearise(self, pos, rot, kp, ocols) -> tuple[torch.Tensor, torch.Tensor]:
        """Gauss-Newton normal equations of the fit terms: ``J^T J`` (B, T, n, n) and ``J^T r`` (B, T, n).

        Per frame the weighted Jacobian and residual ``[J | r]`` (3R, n + 1) are one product
        ``[L | r] (3R, 7) @ W (7, E + 7)``, masked by which joints move each row (then folded into
        the columns where mimic joints drive one), and ``[J | r]^T [J | r]`` holds both:
        a key point's row ``i`` is ``[-[v]x_i, -e_i]`` (``v`` the point), an orientation row
        ``[-[c]x_i, 0]`` (``c`` the rotation column); ``W``'s columns are each joint's ``[a_j; a_j x p_j]``
        (so a row gets ``a_j x (v - p_j)``, resp. ``a_j x c``), the base translation's ``[0; -e_k]``
        and the base rotation's ``[e_k; -[p_0]x e_k]`` (``-[v - p_0]x``), and ``r``'s ``e_7``.
        """
        B, T, K, M, D, E, dtype, dev = self.B, self.T, self.K, self.M, self.D, self.E, self.dtype, self.dev
        R = K + 3 * M
        vecs = torch.cat([kp, ocols], 2) if M else kp  # (B,T,R,3)
        x, y, z = vecs.unbind(-1)
        left = torch.zeros(B, T, R, 3, 7, dtype=dtype, device=dev)
        left[..., 0, 1], left[..., 0, 2], left[..., 1, 0] = z, -y, -z
        left[..., 1, 2], left[..., 2, 0], left[..., 2, 1] = x, y, -x
        left[:, :, :K, :, 3:6] = -torch.eye(3, dtype=dtype, device=dev)
        w = torch.cat([self.w_kp, self.w_o], -1) if M else self.w_kp  # (B,1,R)
        left[..., :6] *= w.sqrt()[..., None, None]
        left[:, :, :K, :, 6] = (kp - self.goals) * self.w_kp[..., None].sqrt()
        if M:
            left[:, :, K:, :, 6] = (ocols - self.gcols) * self.w_o[..., None].sqrt()
        idx = self.ents[:, None, :, None]
        axes = torch.gather(self.graph.axes, 1, self.ents[..., None].expand(B, E, 3))  # (B,E,3)
        a = (torch.gather(rot, 2, idx[..., None].expand(B, T, E, 3, 3)) @ axes[:, None, :, :, None])[..., 0]  # (B,T,E,3) world
        right = torch.zeros(B, T, 7, E + 7, dtype=dtype, device=dev)
        right[:, :, 0:3, :E] = a.transpose(-1, -2)
        right[:, :, 3:6, :E] = torch.linalg.cross(a, torch.gather(pos, 2, idx.expand(B, T, E, 3))).transpose(-1, -2)
        eye = torch.eye(3, dtype=dtype, device=dev)
        right[:, :, 3:6, E : E + 3] = -eye
        right[:, :, 0:3, E + 3 : E + 6] = eye
        right[:, :, 3:6, E + 3 : E + 6] = -_skew(pos[:, :, 0])
        right[:, :, 6, E + 6] = 1
        jr = left.flatten(2, 3) @ right  # (B,T,3R,E+7): [J | r] before the ancestor mask
        jr[..., :E] *= self.moves_e
        if self.ent_fold is not None:  # mimic joints: entries folded into the columns that drive them
            jr = torch.cat([jr[..., :E] @ self.ent_fold[:, None], jr[..., E:]], -1)
        hg = jr.transpose(-1, -2) @ jr  # (B,T,n+1,n+1)
        n = D + 6
        return hg[..., :n, :n].contiguous(), hg[..., :n, n].contiguous()

    def damp(self, h: torch.Tensor, mu: torch.Tensor) -> torch.Tensor:
        """Marquardt damping ``mu * diag(h)`` (mu broadcast to (B, T)) and identity rows on the padding."""
        diag = h.diagonal(dim1=-2, dim2=-1)
        out = h.clone()
        out.diagonal(dim1=-2, dim2=-1).copy_(diag + mu[..., None] * (diag + 1e-9) + self.padd + 1e-9)
        return out

    def candidate(self, qd, base_pos, base_rot, step):
        """Apply a step (B, T, n): angles projected onto the limits, the base rotation in the world frame."""
        D = self.D
        qd_c = torch.minimum(torch.maximum(qd + step[..., :D] * self.col_mask[:, None], self.lower), self.upper)
        return qd_c, base_pos + step[..., D : D + 3], axis_angle_to_matrix(step[..., D + 3 :]) @ base_rot

    def zeros(self, *shape) -> torch.Tensor:
        return torch.zeros(*shape, dtype=self.dtype, device=self.dev)


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
    physics: Any = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Refine (q (B, T, J), base_pos (B, T, 3), base_rot (B, T, 3, 3)) towards the goals.

    Args:
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m].
        goal_rot: (B, T, Jr, 3, 3) orientation goals and rot_mask (B, Jr) the reference nodes that
            carry one (:func:`mer_data.kinematics.orientation.orientation_goals`); omitted: positions only.
        iters: at most this many iterations; smooth: weight of the temporal prior (0: frames
            independent); tol: early stop (relative cost change of every frame).
        stats: receives ``iterations`` (the most any sample ran) and ``cost`` (B, T).
        physics: :class:`~mer_models.solver.physics.PhysicsInputs`: the physical terms too.

    Returns the refined triple; angles stay inside [lower, upper].
    """
    B, T, J = q.shape
    P = _Problem(cfg, graph, eta, goal, q, goal_rot, rot_mask)
    D = P.D
    phys = physics.build(P, cfg.w_kp) if physics is not None else None
    sm = P.dof_weight(smooth * cfg.w_kp) if T > 1 else P.zeros(B, 1, D)
    reg, nominal = P.reg, P.nominal
    qd = P.columns(q)

    def prior(qd, qbar):
        return (reg * (qd - nominal) ** 2).sum(-1) + (sm * (qd - qbar) ** 2).sum(-1)

    pos, rot, kp, ocols, cost_fit = P.fit(qd, base_pos, base_rot)
    mu = torch.full((B, T), damping, dtype=P.dtype, device=P.dev)
    active = torch.ones(B, dtype=torch.bool, device=P.dev)  # samples still iterating (each stops on its own)
    done = 0
    for it in range(iters):
        report(it, iters)
        qbar = _neighbour_mean(qd)
        cost = cost_fit + prior(qd, qbar)
        h, g = P.linearise(pos, rot, kp, ocols)
        if phys is not None:
            state = phys.freeze(pos, rot, qd)
            ph, pg, pc = phys.linearise(pos, rot, qd, state, with_cost=True)
            cost = cost + pc
            h, g = h + ph, g + pg
        prior_h = torch.cat([reg + sm, P.zeros(B, 1, 6)], -1)
        g = g + torch.cat([reg * (qd - nominal) + sm * (qd - qbar), P.zeros(B, T, 6)], -1)
        h.diagonal(dim1=-2, dim2=-1).add_(prior_h)
        L, info = torch.linalg.cholesky_ex(P.damp(h, mu))
        step = -torch.cholesky_solve(g[..., None], L)[..., 0]
        step = torch.where((info == 0)[..., None], step, torch.zeros_like(step))
        qd_c, bp_c, br_c = P.candidate(qd, base_pos, base_rot, step)
        pos_c, rot_c, kp_c, ocols_c, fit_c = P.fit(qd_c, bp_c, br_c)
        cost_c = fit_c + prior(qd_c, qbar)
        if phys is not None:
            cost_c = cost_c + phys.cost(pos_c, rot_c, qd_c, state)
        ok = (cost_c < cost) & active[:, None]
        o1, o2, o3 = ok[..., None], ok[..., None, None], ok[..., None, None, None]
        qd, base_pos, base_rot = torch.where(o1, qd_c, qd), torch.where(o1, bp_c, base_pos), torch.where(o2, br_c, base_rot)
        pos, kp = torch.where(o2, pos_c, pos), torch.where(o2, kp_c, kp)
        rot, cost_fit = torch.where(o3, rot_c, rot), torch.where(ok, fit_c, cost_fit)
        if P.M:
            ocols = torch.where(o2, ocols_c, ocols)
        mu = torch.where(active[:, None], torch.where(ok, mu / 3, mu * 4).clamp(1e-7, 1e6), mu)
        done = it + 1
        change = torch.where(ok, (cost - cost_c) / cost.clamp_min(1e-12), torch.zeros_like(cost))
        if it >= 2:
            if phys is None:
                active = active & ~(change < tol).all(-1)
            else:  # one-sided terms make early steps fail: a rejected step is not convergence
                active = active & ~((ok & (change < tol)) | (mu >= 1e3)).all(-1)
            if not bool(active.any()):
                break
    if stats is not None:
        stats["iterations"] = done
        stats["cost"] = cost_fit + prior(qd, _neighbour_mean(qd))
    return P.full_q(qd), base_pos, base_rot


def _velocity_prior(qd: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Per-frame share (B, T) of ``sum_t w . (q_{t+1} - q_t)^2``: each difference split between its two frames."""
    d = (w * (qd[:, 1:] - qd[:, :-1]) ** 2).sum(-1)  # (B, T-1)
    out = torch.zeros(qd.shape[:2], dtype=qd.dtype, device=qd.device)
    if qd.shape[1] > 1:
        out[:, 1:] += 0.5 * d
        out[:, :-1] += 0.5 * d
    return out


@torch.no_grad()
def coupled_lm_ik(
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
    iters: int = 5,
    damping: float = 1e-2,
    smooth: float = DEFAULT_SMOOTH,
    tol: float = DEFAULT_TOL,
    stats: dict | None = None,
    physics: Any = None,
    hold: torch.Tensor | None = None,
    change_of: torch.Tensor | None = None,
    change_smooth: float = 0.0,
    groups: torch.Tensor | None = None, tries: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Levenberg-Marquardt on a whole window at once: the temporal prior couples the frames exactly.

    The same terms as :func:`gauss_newton_ik`, except the prior: ``smooth / 4 * mean_dof
    (q_{t+1} - q_t)^2`` summed over consecutive frames, whose gradient in the interior is exactly
    the Jacobi prior's ``smooth * (q_t - (q_{t-1} + q_{t+1}) / 2)`` — so both solvers share their
    fixed point (up to the two end frames), but here every step solves the linearised problem of
    all frames together (a block-tridiagonal system, :func:`~.tridiagonal.block_tridiagonal_solve`) instead of
    pulling each frame towards its neighbours' previous iterate. One damping per sample; a step is
    kept if it lowers that sample's whole cost. Meant for warm starts (``--refine K``), where the
    Jacobi prior needs many iterations to let the frames move together.

    Arguments and return as :func:`gauss_newton_ik`; ``stats["cost"]`` (B, T) splits each
    difference of the prior between its two frames. ``hold`` (B, T) bool: frames that stay where
    they are (their neighbours' prior still sees them: a repair of a few frames eases in and out).
    ``change_of`` (B, T, J) angles and ``change_smooth``: a second temporal prior, of that weight
    (relative to ``w_kp``), on the change from those angles (a smooth change of a solution).
    ``groups`` (T,) long: frames of a group (0..G-1) share a damping and keep or refuse a step by
    their own cost (groups coupled only through held frames then solve as separate windows would).
    ``tries``: at most this many linearisations (default ``iters``), a group stopping after ``iters`` steps.
    """
    B, T, J = q.shape
    P = _Problem(cfg, graph, eta, goal, q, goal_rot, rot_mask)
    D = P.D
    phys = physics.build(P, cfg.w_kp) if physics is not None else None
    w = P.dof_weight(smooth * cfg.w_kp)[:, 0] / 4 if T > 1 else P.zeros(B, D)  # (B, D) per difference
    reg, nominal = P.reg, P.nominal
    qd = P.columns(q)
    ref = P.columns(change_of.to(P.dtype)) if change_of is not None and change_smooth > 0 and T > 1 else None
    wc = P.dof_weight(change_smooth * cfg.w_kp)[:, 0] / 4 if ref is not None else P.zeros(B, D)
    neighbours = torch.full((T,), 2.0, dtype=P.dtype, device=P.dev)
    neighbours[0] = neighbours[-1] = 1.0 if T > 1 else 0.0
    prior_h = torch.cat([reg + 2 * (w + wc)[:, None] * neighbours[None, :, None], P.zeros(B, T, 6)], -1)  # (B, T, n)
    coupling = torch.cat([-2 * (w + wc), P.zeros(B, 6)], -1)  # (B, n)

    def frame_cost(fit, qd):
        out = fit + (reg * (qd - nominal) ** 2).sum(-1) + _velocity_prior(qd, w[:, None])
        return out if ref is None else out + _velocity_prior(qd - ref, wc[:, None])

    def prior_grad(qd):
        gq = reg * (qd - nominal)
        if T > 1:
            d = 2 * w[:, None] * (qd[:, 1:] - qd[:, :-1])  # (B, T-1, D): d/dq_{t+1} of each difference
            if ref is not None:
                dc = qd - ref
                d = d + 2 * wc[:, None] * (dc[:, 1:] - dc[:, :-1])
            gq = gq + torch.cat([P.zeros(B, 1, D), d], 1) - torch.cat([d, P.zeros(B, 1, D)], 1)
        return torch.cat([gq, P.zeros(B, T, 6)], -1)

    pos, rot, kp, ocols, fit = P.fit(qd, base_pos, base_rot)
    cost = frame_cost(fit, qd)
    G, cut = 1, P.zeros(B, T)  # cut: the costs of neighbouring frames of two groups (held: constant), left out of each group's
    for t in [] if groups is None else (groups[1:] != groups[:-1]).nonzero().flatten().tolist():
        pair = qd[:, t : t + 2]
        cut[:, t : t + 2] += _velocity_prior(pair, w[:, None]) + (0 if ref is None else _velocity_prior(pair - ref[:, t : t + 2], wc[:, None]))
        cut[:, t : t + 2] += 0 if phys is None else phys.speed_cost(pair, P.cols)
    if groups is not None:
        G = int(groups.max()) + 1
    per_frame = (lambda x: x) if groups is None else (lambda x: x[:, groups])  # (B, G) -> (B, T) or (B, 1)
    per_group = (lambda x: x.sum(-1, keepdim=True)) if groups is None else (lambda x: (x - cut).new_zeros(B, G).index_add_(1, groups, x - cut))
    mu, active = torch.full((B, G), damping, dtype=P.dtype, device=P.dev), torch.ones(B, G, dtype=torch.bool, device=P.dev)
    done, accepted = 0, torch.zeros(B, G, dtype=torch.long, device=P.dev)
    same = None  # the last iteration's linearisation, kept while no group accepts a step (the iterate is the same)
    most = iters if tries is None else max(tries, iters)  # linearisations at most
    for it in range(most):
        report(it, most)
        if same is not None:  # a refused step: the same point, so the same system; only the damping differs
            h, g, c_speed, dense, state = same[0].clone(), *same[1:]
        else:
            h, g = P.linearise(pos, rot, kp, ocols)
            h.diagonal(dim1=-2, dim2=-1).add_(prior_h)
            g = g + prior_grad(qd)
            c_speed = dense = state = None
            if phys is not None:  # the physical terms, their coupled parts held at this iterate
                state = phys.freeze(pos, rot, qd)
                ph, pg, pc = phys.linearise(pos, rot, qd, state, with_cost=True)  # cost and rows from one evaluation
                cost = frame_cost(fit, qd) + pc + phys.speed_cost(qd, P.cols)
                h, g = h + ph, g + pg
                sp = phys.speed_terms(qd, P.cols)  # joint speed: exact coupling of neighbouring frames
                if sp is not None:
                    diag, off, grad = sp
                    h.diagonal(dim1=-2, dim2=-1)[..., :D].add_(diag)
                    g = g + torch.cat([grad, P.zeros(B, T, 6)], -1)
                    c_speed = torch.cat([off, P.zeros(B, T - 1, 6)], -1)
                dense = phys.coupled_terms(pos, rot, state)  # two-frame rows with dense blocks (a stance foot's no-slip)
                if dense is not None:
                    h, g, dense = h + dense[0], g + dense[2], dense[1]
            same = (h.clone(), g, c_speed, dense, state)
        # active set: a joint at a limit that the gradient pushes further out stays where it is
        gq = g[..., :D]
        fixed = ((qd <= P.lower) & (gq > 0)) | ((qd >= P.upper) & (gq < 0))  # (B, T, D)
        free = torch.cat([~fixed, torch.ones(B, T, 6, dtype=torch.bool, device=P.dev)], -1)
        free = (free if hold is None else free & ~hold.to(P.dev)[..., None]).to(P.dtype)
        h = h.mul_(free[..., :, None]).mul_(free[..., None, :])
        h.diagonal(dim1=-2, dim2=-1).add_(1 - free)
        g = g * free
        c = coupling[:, None] if c_speed is None else coupling[:, None] + c_speed
        c = c * free[:, 1:] * free[:, :-1]  # (B, T-1, n): a held joint is coupled to nothing
        if dense is not None:
            c = torch.diag_embed(c) + dense * free[:, 1:, :, None] * free[:, :-1, None, :]
        step, solved = block_tridiagonal_solve(P.damp(h, per_frame(mu)), c, -g)
        qd_c, bp_c, br_c = P.candidate(qd, base_pos, base_rot, step)
        pos_c, rot_c, kp_c, ocols_c, fit_c = P.fit(qd_c, bp_c, br_c)
        cost_c = frame_cost(fit_c, qd_c)
        if phys is not None:
            cost_c = cost_c + phys.cost(pos_c, rot_c, qd_c, state) + phys.speed_cost(qd_c, P.cols)
        total, total_c = per_group(cost), per_group(cost_c)
        ok = (total_c < total) & active & solved[:, None]
        o1 = per_frame(ok)[..., None]
        o2, o3 = o1[..., None], o1[..., None, None]
        qd, base_pos, base_rot = torch.where(o1, qd_c, qd), torch.where(o1, bp_c, base_pos), torch.where(o2, br_c, base_rot)
        pos, kp, rot = torch.where(o2, pos_c, pos), torch.where(o2, kp_c, kp), torch.where(o3, rot_c, rot)
        cost, fit = torch.where(o1[..., 0], cost_c, cost), torch.where(o1[..., 0], fit_c, fit)
        ocols = torch.where(o2, ocols_c, ocols) if P.M else ocols
        mu = torch.where(active, torch.where(ok, mu / 3, mu * 4).clamp(1e-7, 1e6), mu)
        done, accepted = it + 1, accepted + ok.long()
        change = torch.where(ok, (total - total_c) / total.clamp_min(1e-12), torch.zeros_like(total))
        active = active & ~(ok & (change < tol)) & (accepted < iters)
        same = None if bool(ok.any()) else same
        if not bool(active.any()):
            break
    if stats is not None:
        stats.update(iterations=done, cost=cost, accepted=accepted)
    return P.full_q(qd), base_pos, base_rot
