"""The FK kernel behind :func:`mer_data.kinematics.fk.forward_kinematics` (shared topology), with an
analytic backward.

Layout: nodes node-major in depth order, so that each tree level is one contiguous block; with
geometry shared by the batch, each level is one GEMM of the parents' rotation rows against
``[K | K^2 | offset]``. The backward uses the geometric Jacobian (for joint ``j`` with world axis
``w_j``: ``dR_l/dq_j = [w_j]x R_l``, ``dp_l/dq_j = w_j x (p_l - p_j)`` for every ``l`` below ``j``)
with subtree sums, instead of replaying the forward graph.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch

__all__ = ["fk_core", "axis_matrices", "rodrigues", "broadcast_shapes"]


def broadcast_shapes(*shapes: tuple[int, ...]) -> torch.Size:
    """``torch.broadcast_shapes`` without its first call's cost (it imports torch's symbolic-shape
    machinery and sympy: about a second of every command's start-up)."""
    return torch.Size(np.broadcast_shapes(*(tuple(s) for s in shapes)))


def axis_matrices(axes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``[a]x`` and ``[a]x^2 = a a^T - |a|^2 I`` for (..., 3) axes → two (..., 3, 3)."""
    x, y, z = axes.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(x.shape + (3, 3))
    eye = torch.eye(3, dtype=axes.dtype, device=axes.device)
    kk = axes[..., :, None] * axes[..., None, :] - (axes * axes).sum(-1)[..., None, None] * eye
    return k, kk


def rodrigues(k: torch.Tensor, kk: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    out = torch.addcmul(eye, torch.sin(q)[..., None, None], k)
    return torch.addcmul(out, (1 - torch.cos(q))[..., None, None], kk)


@dataclass(frozen=True)
class _Plan:
    """Evaluation order of a tree: nodes grouped by depth, levels contiguous."""

    order: np.ndarray  # (J,) node indices in level order (level 0 = [0])
    bounds: tuple[tuple[int, int], ...]  # per level d >= 1: [start, stop) into ``order``
    parent_pos: tuple[np.ndarray | None, ...]  # per level: parent's position in level d-1 (None: all the first)


@lru_cache(maxsize=256)
def _plan(parents: tuple[int, ...]) -> _Plan:
    J = len(parents)
    depth = np.zeros(J, np.int64)
    for j in range(1, J):
        depth[j] = depth[parents[j]] + 1
    levels = [np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1)]
    pos_in_level = np.zeros(J, np.int64)
    for nodes in levels:
        pos_in_level[nodes] = np.arange(len(nodes))
    bounds, parent_pos, start = [], [], 1
    for nodes in levels[1:]:
        pp = pos_in_level[np.asarray(parents)[nodes]]
        parent_pos.append(None if np.all(pp == 0) and len(levels[len(bounds)]) == 1 else pp)
        bounds.append((start, start + len(nodes)))
        start += len(nodes)
    return _Plan(np.concatenate(levels), tuple(bounds), tuple(parent_pos))


def fk_core(q, base_pos, base_rot, offsets, axes, par: tuple[int, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Shared-topology FK (arguments as :func:`mer_data.kinematics.fk.forward_kinematics`).

    Uses the analytic backward when gradients flow to ``q`` or the base pose only; when the
    geometry itself requires gradients, autograd differentiates the kernel instead.
    """
    if torch.is_grad_enabled() and not (offsets.requires_grad or axes.requires_grad) and (
        q.requires_grad or base_pos.requires_grad or base_rot.requires_grad
    ):
        return _AnalyticFK.apply(q, base_pos, base_rot, offsets, axes, par)
    return _kernel(q, base_pos, base_rot, offsets, axes, par)


def _kernel(q, base_pos, base_rot, offsets, axes, par, node_major: bool = False):
    """FK; with ``node_major`` also returns ``pos``/``rot`` as (J, n, 3[, 3]) in the plan's level order."""
    J = len(par)
    batch = broadcast_shapes(q.shape[:-1], base_pos.shape[:-1], base_rot.shape[:-2], offsets.shape[:-2], axes.shape[:-2])
    n = int(np.prod(batch)) if len(batch) else 1
    plan = _plan(par)
    order = torch.as_tensor(plan.order, device=q.device)
    sizes = [1] + [b - a for a, b in plan.bounds]
    # node-major layout in level order (J, n, ...), split into levels (split's backward is one cat;
    # slicing per level would build a full-size zero gradient per slice)
    q_lv = q.expand(batch + (J,)).reshape(n, J).t().index_select(0, order).split(sizes)
    ax = _node_major(axes, batch, n, J).index_select(0, order)  # (J, n or 1, 3)
    off = _node_major(offsets, batch, n, J).index_select(0, order)  # (J, n or 1, 3)
    shared_axes, shared_off = ax.shape[1] == 1, off.shape[1] == 1
    k, kk = axis_matrices(ax[:, 0] if shared_axes else ax)  # (J, 3, 3) or (J, n, 3, 3)
    # shared geometry: one GEMM per level, rows of the parents' rotations times [K | K^2 | offset]
    parts = ([k, kk] if shared_axes else []) + ([off[:, 0, :, None]] if shared_off else [])
    rhs_lv = torch.cat(parts, -1).split(sizes) if parts else None
    k_lv = None if shared_axes else (k.split(sizes), kk.split(sizes))
    off_lv = None if shared_off else off.split(sizes)

    rot_prev = base_rot.expand(batch + (3, 3)).reshape(1, n, 3, 3)
    pos_prev = base_pos.expand(batch + (3,)).reshape(1, n, 3)
    rots, poss = [rot_prev], [pos_prev]
    for d, pp in enumerate(plan.parent_pos, start=1):
        L = sizes[d]
        if pp is None:  # every node of the level hangs off the single node above
            r_par, p_par = rot_prev.expand(L, -1, -1, -1), pos_prev
        else:
            pidx = torch.as_tensor(pp, device=q.device)
            r_par, p_par = rot_prev.index_select(0, pidx), pos_prev.index_select(0, pidx)
        if rhs_lv is not None:  # (split, not slices: one gradient concatenation instead of zero-filled copies)
            prod = (r_par.reshape(L, n * 3, 3) @ rhs_lv[d]).reshape(L, n, 3, -1)
            prod = prod.split([3, 3, 1] if shared_axes and shared_off else [3, 3] if shared_axes else [1], -1)
        if shared_axes:
            s, c1 = torch.sin(q_lv[d])[..., None, None], (1 - torch.cos(q_lv[d]))[..., None, None]
            rot_prev = torch.addcmul(torch.addcmul(r_par, s, prod[0]), c1, prod[1])
        else:
            rot_prev = r_par @ rodrigues(k_lv[0][d], k_lv[1][d], q_lv[d])
        if shared_off:
            pos_prev = p_par + prod[-1].squeeze(-1)
        else:
            pos_prev = p_par + (r_par * off_lv[d][:, :, None, :]).sum(-1)
        rots.append(rot_prev)
        poss.append(pos_prev)
    # back to node order, batch-major: one gather each
    inv = torch.as_tensor(np.argsort(plan.order), device=q.device)
    rot_nm, pos_nm = torch.cat(rots, 0), torch.cat(poss, 0)
    rot = rot_nm.transpose(0, 1).index_select(1, inv).reshape(batch + (J, 3, 3))
    pos = pos_nm.transpose(0, 1).index_select(1, inv).reshape(batch + (J, 3))
    if node_major:
        return pos, rot, pos_nm, rot_nm
    return pos, rot


def _node_major(t: torch.Tensor, batch: torch.Size, n: int, J: int) -> torch.Tensor:
    """(..., J, 3) broadcastable to ``batch`` → (J, n, 3), or (J, 1, 3) when shared by the batch."""
    lead = t.shape[:-2]
    if int(np.prod(lead)) == 1 if len(lead) else True:
        return t.reshape(J, 1, 3)
    return t.expand(batch + (J, 3)).reshape(n, J, 3).transpose(0, 1)


def _cross(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """``x × y`` over the last axis (faster than ``torch.linalg.cross`` on CPU for strided inputs)."""
    x0, x1, x2 = x.unbind(-1)
    y0, y1, y2 = y.unbind(-1)
    return torch.stack([x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0], -1)


def _reduce_to(grad: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    """Sum a gradient over the dimensions an input was broadcast along."""
    while grad.dim() > len(shape):
        grad = grad.sum(0)
    for i, (g, s) in enumerate(zip(grad.shape, shape)):
        if s == 1 and g != 1:
            grad = grad.sum(i, keepdim=True)
    return grad


class _AnalyticFK(torch.autograd.Function):
    """FK with the geometric-Jacobian backward; geometry (offsets, axes) gets no gradient."""

    @staticmethod
    def forward(ctx, q, base_pos, base_rot, offsets, axes, par):
        pos, rot, pos_nm, rot_nm = _kernel(q, base_pos, base_rot, offsets, axes, par, node_major=True)
        ctx.par = par
        ctx.shapes = (q.shape, base_pos.shape, base_rot.shape, pos.shape[:-2])
        ctx.save_for_backward(pos_nm, rot_nm, axes)
        return pos, rot

    @staticmethod
    def backward(ctx, g_pos, g_rot):
        pos, rot, axes = ctx.saved_tensors  # (J, n, 3), (J, n, 3, 3), node-major in level order
        par = ctx.par
        q_shape, bp_shape, br_shape, batch = ctx.shapes
        J, n = pos.shape[0], pos.shape[1]
        plan = _plan(par)
        order = torch.as_tensor(plan.order, device=pos.device)
        inv = torch.as_tensor(np.argsort(plan.order), device=pos.device)

        def node_major(g, tail):
            if g is None:
                return torch.zeros((J, n) + tail, dtype=pos.dtype, device=pos.device)
            return g.reshape((n, J) + tail).transpose(0, 1).index_select(0, order)

        gp, gr = node_major(g_pos, (3,)), node_major(g_rot, (3, 3))
        # a: moment of each node's gradient about the world origin, vee(R G^T - G R^T) + p x g_p;
        # b: its force g_p
        m = (rot.reshape(-1, 3, 3) @ gr.reshape(-1, 3, 3).transpose(1, 2)).reshape(rot.shape)
        tau = torch.stack([m[..., 1, 2] - m[..., 2, 1], m[..., 2, 0] - m[..., 0, 2], m[..., 0, 1] - m[..., 1, 0]], -1)
        a = tau + _cross(pos, gp)
        b = gp.clone()
        # subtree sums, deepest level first; levels are contiguous blocks of the plan order
        sizes = [1] + [hi - lo for lo, hi in plan.bounds]
        starts = [0] + [lo for lo, _ in plan.bounds]
        for d in range(len(sizes) - 1, 0, -1):
            lo, hi, plo = starts[d], starts[d] + sizes[d], starts[d - 1]
            pp = plan.parent_pos[d - 1]
            if pp is None:
                a[plo] += a[lo:hi].sum(0)
                b[plo] += b[lo:hi].sum(0)
            else:  # children → parents as one GEMM with the level's 0/1 incidence matrix
                inc = torch.zeros(lo - plo, hi - lo, dtype=a.dtype, device=a.device)
                inc[torch.as_tensor(pp, device=a.device), torch.arange(hi - lo, device=a.device)] = 1
                a[plo:lo] += (inc @ a[lo:hi].reshape(hi - lo, -1)).reshape(lo - plo, n, 3)
                b[plo:lo] += (inc @ b[lo:hi].reshape(hi - lo, -1)).reshape(lo - plo, n, 3)
        g_base_pos = b[0]
        # world axis of node j: R_j a_j (= R_parent a_j); its joint torque (w . (a - p x b))
        ax = _node_major(axes, batch, n, J).index_select(0, order)  # (J, n or 1, 3)
        world_axes = (rot * ax[:, :, None, :]).sum(-1)
        g_q_nm = (world_axes * (a - _cross(pos, b))).sum(-1)  # (J, n)
        g_q = g_q_nm.index_select(0, inv).t().reshape(batch + (J,))
        out_q = out_bp = out_br = None
        if ctx.needs_input_grad[0]:
            out_q = _reduce_to(g_q, q_shape)
        if ctx.needs_input_grad[1]:
            out_bp = _reduce_to(g_base_pos.reshape(batch + (3,)), bp_shape)
        if ctx.needs_input_grad[2]:
            # d/dR0 = (sum_j g_p,j (p_j - p_0)^T + G_j R_j^T) R0
            rel = pos - pos[:1]
            s = torch.einsum("jna,jnb->nab", gp, rel) + torch.einsum("jnab,jncb->nac", gr, rot)
            out_br = _reduce_to((s @ rot[0]).reshape(batch + (3, 3)), br_shape)
        return out_q, out_bp, out_br, None, None, None
