"""The stance foot's no-slip term: while the source's foot is down, the body-fixed point of the foot
that is lowest keeps its x, y from one frame to the next (the material point the artifact metrics
measure skating at, :mod:`mer_models.retarget.artifacts`).

A row couples frames t and t + 1: ``sqrt(w) e . (p_{t+1} - p_t)`` for e = x, y, ``p_f`` the point
(fixed in its shape, chosen at a round's start: :func:`lowest_foot_points`) moved with its node at
frame f. Its Gauss-Newton parts are the frames' own blocks and a dense block coupling t and t + 1,
which :func:`~.tridiagonal.block_tridiagonal_solve` takes beside the temporal prior's diagonal one
(:func:`~.ik.coupled_lm_ik`). Used by the constraint method (:mod:`.constrained`).
"""

from __future__ import annotations

from typing import Any

import torch

__all__ = ["lowest_foot_points", "slip_cost", "slip_terms"]


def lowest_foot_points(model: Any, pos: torch.Tensor, rot: torch.Tensor, feet: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Each foot's lowest vertex at node poses ``pos`` (B, T, J, 3), ``rot`` (B, T, J, 3, 3): its shape
    and vertex (B, T, 2) each (0 for a foot without shapes)."""
    B, T = pos.shape[:2]
    shape = torch.zeros(B, T, 2, dtype=torch.long, device=pos.device)
    vert = torch.zeros_like(shape)
    node = torch.as_tensor(model.node, device=pos.device)
    local = torch.as_tensor(model.vertices, dtype=pos.dtype, device=pos.device)
    for i, f in enumerate(feet):
        if not len(f):
            continue
        v = torch.einsum("btsij,svj->btsvi", rot[:, :, node[f]], local[f]) + pos[:, :, node[f], None]  # (B, T, F, V, 3)
        z, vi = v[..., 2].min(-1)  # (B, T, F)
        k = z.argmin(-1)
        shape[..., i] = f[k]
        vert[..., i] = torch.gather(vi, 2, k[..., None])[..., 0]
    return shape, vert


def _points(phys: Any, pos: torch.Tensor, rot: torch.Tensor, b, t, s, v) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Shape ``s``'s vertex ``v`` in the world at frames t and t + 1 of samples ``b`` (E,): (E, 3) each, and its node (E,)."""
    n = phys.node[s]
    local = phys.verts[s, v]  # (E, 3)
    pa = torch.einsum("eij,ej->ei", rot[b, t, n], local) + pos[b, t, n]
    pb = torch.einsum("eij,ej->ei", rot[b, t + 1, n], local) + pos[b, t + 1, n]
    return pa, pb, n


def _entries(slip: dict) -> list[tuple]:
    """The (b, t) of every stance pair of frames, per foot: (foot, b, t)."""
    out = []
    for i in range(2):
        b, t = slip["mask"][..., i].nonzero(as_tuple=True)
        if len(b):
            out.append((i, b, t))
    return out


def slip_cost(phys: Any, pos: torch.Tensor, rot: torch.Tensor, slip: dict) -> torch.Tensor:
    """(B, T) the term's cost, each pair of frames' share split between its two frames."""
    B, T = pos.shape[:2]
    out = pos.new_zeros(B, T)
    for i, b, t in _entries(slip):
        pa, pb, _ = _points(phys, pos, rot, b, t, slip["shape"][b, t, i], slip["vert"][b, t, i])
        e = slip["w"] * ((pb - pa)[:, :2] ** 2).sum(-1)
        out.index_put_((b, t), 0.5 * e, accumulate=True)
        out.index_put_((b, t + 1), 0.5 * e, accumulate=True)
    return out


def _jacobian(phys: Any, pos: torch.Tensor, rot: torch.Tensor, b, t, node, p, u) -> torch.Tensor:
    """(E, n) the rows ``u . dp`` of world points ``p`` (E, 3) moving with ``node`` (E,) at frames (b, t)."""
    a = (rot[b, t] @ phys.axes[b][..., None])[..., 0]  # (E, J, 3) joint axes in the world
    dq = (a * torch.linalg.cross(p, u, dim=-1)[:, None]).sum(-1) - (torch.linalg.cross(a, pos[b, t], dim=-1) * u[:, None]).sum(-1)
    jq = torch.einsum("ej,ejd->ed", dq * phys.moves[b, node], phys.fold[b])
    return torch.cat([jq, u, torch.linalg.cross(p - pos[b, t, 0], u, dim=-1)], -1)


def slip_terms(phys: Any, pos: torch.Tensor, rot: torch.Tensor, slip: dict):
    """The term's Gauss-Newton parts: the frames' blocks (B, T, n, n), the blocks coupling frames t
    and t + 1 (B, T-1, n, n; row t + 1's block on x_t) and ``J^T r`` (B, T, n); None without rows."""
    B, T = pos.shape[:2]
    n_cols = phys.fold.shape[-1] + 6
    ents = _entries(slip)
    if not ents:
        return None
    h = pos.new_zeros(B, T, n_cols, n_cols)
    c = pos.new_zeros(B, max(T - 1, 0), n_cols, n_cols)
    g = pos.new_zeros(B, T, n_cols)
    sw = slip["w"] ** 0.5
    for i, b, t in ents:
        pa, pb, node = _points(phys, pos, rot, b, t, slip["shape"][b, t, i], slip["vert"][b, t, i])
        for axis in range(2):
            u = pos.new_zeros(len(b), 3)
            u[:, axis] = 1
            ja, jb = sw * _jacobian(phys, pos, rot, b, t, node, pa, u), sw * _jacobian(phys, pos, rot, b, t + 1, node, pb, u)
            r = sw * (pb - pa)[:, axis]  # r = jb dx_{t+1} - ja dx_t + r0
            h.index_put_((b, t), ja[:, :, None] * ja[:, None, :], accumulate=True)
            h.index_put_((b, t + 1), jb[:, :, None] * jb[:, None, :], accumulate=True)
            c.index_put_((b, t), -(jb[:, :, None] * ja[:, None, :]), accumulate=True)
            g.index_put_((b, t), -ja * r[:, None], accumulate=True)
            g.index_put_((b, t + 1), jb * r[:, None], accumulate=True)
    return h, c, g
