"""The self-penetration constraint's separating faces, fixed for one augmented-Lagrangian round.

At a round's start each (frame, pair) entry of the constraint method (:mod:`.constrained`) gets its
separating-axis choice (:func:`mer_data.kinematics.collision.contact_points`, ``"sat"``): the body
that reaches in, and the face of the other body (a plane in that body's node frame) along which the
overlap is least. Within the round the entry's depth is the overlap *along that face*: minus the
least signed distance of the reaching shape's vertices to the plane. That is exact at the round's
start, never below the separating-axis depth (which is the least overlap over all faces), so a
round that holds it under the margin holds the separating-axis depth there too; and it costs one
transform of a shape's vertices per entry instead of every vertex against every face of both
shapes. The next round chooses the faces again at its own start.
"""

from __future__ import annotations

from typing import Any

import torch

from mer_data.kinematics.collision import contact_points, padded_counts

__all__ = ["fix_faces", "face_points"]

POINT_SOFTNESS_M = 5e-4  # [m] vertices this much shallower than the deepest weigh 1/e of it in a row's point


def fix_faces(model: Any, pos: torch.Tensor, rot: torch.Tensor, entries: tuple, K: int, which: str = "sat", exact_over: float = float("inf")) -> dict:
    """Each entry's reaching shape and the other body's separating plane at node poses ``pos``
    (B, T, J, 3), ``rot`` (B, T, J, 3, 3): ``{"entries", "K", "reach" (E,) shape, "other" (E,) node,
    "n" (E, 3), "d" (E,), "exact"}``, the plane ``n . x + d = 0`` in the other node's frame (``n``
    outward); ``exact``: the entries deeper than ``exact_over`` [m] now, whose faces
    :func:`face_points` chooses again at every pose (a deep overlap's best face changes as it opens)."""
    depth, point, normal, na, nb = contact_points(model, pos, rot, entries, K, which)
    bi, ti, ki, sa, sb = entries
    node = torch.as_tensor(model.node, device=pos.device)
    reach_node, other = na[bi, ti, ki], nb[bi, ti, ki]
    reach = torch.where(reach_node == node[sa], sa, sb)
    ro, to = rot[bi, ti, other], pos[bi, ti, other]  # (E, 3, 3), (E, 3)
    n = torch.einsum("eji,ej->ei", ro, normal[bi, ti, ki])
    p = torch.einsum("eji,ej->ei", ro, point[bi, ti, ki] - to)
    d = -depth[bi, ti, ki] - (n * p).sum(-1)  # the deepest vertex's signed distance is minus the depth
    deep = depth[bi, ti, ki] > exact_over
    exact = tuple(x[deep] for x in entries) if bool(deep.any()) else None
    return {"entries": entries, "K": K, "reach": reach, "other": other, "n": n, "d": d, "exact": exact, "memo": []}


def face_points(model: Any, pos: torch.Tensor, rot: torch.Tensor, faces: dict, verts: torch.Tensor | None = None):
    """The entries' overlap along their fixed faces at a pose, laid out as
    :func:`~mer_data.kinematics.collision.contact_points` returns it: depth (B, T, K) [m] (``-inf``
    where no entry), the row's point (B, T, K, 3): the reaching shape's vertices weighted towards the
    deepest by a softmax (:data:`POINT_SOFTNESS_M`; vertices equally deep share it, the depth stays the
    deepest's), and the face's outward normal (B, T, K, 3) in the world, the reaching and the other node (B, T, K). ``verts``: the model's
    vertices as a tensor of ``pos``'s dtype (made here if omitted). The last two poses' results are
    kept in ``faces["memo"]``: a solver measures each accepted candidate again as its next iterate."""
    memo = faces.setdefault("memo", [])
    for p, r, outs in memo:
        if p.shape == pos.shape and torch.equal(p, pos) and torch.equal(r, rot):
            return outs
    B, T, K = pos.shape[0], pos.shape[1], faces["K"]
    bi, ti, ki, _, _ = faces["entries"]
    node = torch.as_tensor(model.node, device=pos.device)
    if verts is None:
        verts = torch.as_tensor(model.vertices, dtype=pos.dtype, device=pos.device)
    s, other = faces["reach"], faces["other"]
    rn = node[s]
    world = torch.einsum("eij,evj->evi", rot[bi, ti, rn], verts[s]) + pos[bi, ti, rn][:, None]  # (E, V, 3)
    ro, to = rot[bi, ti, other], pos[bi, ti, other]
    local = torch.einsum("eji,evj->evi", ro, world - to[:, None])
    dist = (local * faces["n"][:, None]).sum(-1) + faces["d"][:, None]  # (E, V) signed distance to the plane
    signed = dist.min(-1).values  # padding repeats a vertex
    out_d = torch.full((B, T, K), float("-inf"), dtype=pos.dtype, device=pos.device)
    out_p, out_n = pos.new_zeros(B, T, K, 3), pos.new_zeros(B, T, K, 3)
    out_a = torch.zeros(B, T, K, dtype=torch.long, device=pos.device)
    out_b = torch.zeros_like(out_a)
    out_d[bi, ti, ki] = -signed
    # the row's point: the vertices near the deepest, softly weighted (a face parallel to the plane has several
    # vertices at one depth; which of them is lowest flips with rounding, and with it the row's direction)
    # (the padding repeats vertex 0: left out, or a padded shape's vertex 0 would outweigh its tied neighbours)
    pad = torch.arange(dist.shape[1], device=pos.device) >= padded_counts(verts)[s][:, None]
    w = torch.softmax(-(dist - signed[:, None]).masked_fill(pad, float("inf")) / POINT_SOFTNESS_M, -1)
    out_p[bi, ti, ki] = (w[..., None] * world).sum(-2)
    out_n[bi, ti, ki] = torch.einsum("eij,ej->ei", ro, faces["n"])
    out_a[bi, ti, ki], out_b[bi, ti, ki] = rn, other
    outs = (out_d, out_p, out_n, out_a, out_b)
    if faces.get("exact") is not None:  # the deep entries: the separating-axis depth itself
        ex = faces["exact"]
        for o, x in zip(outs, contact_points(model, pos, rot, ex, K, "sat")):
            o[ex[0], ex[1], ex[2]] = x[ex[0], ex[1], ex[2]]
    memo[:] = [*memo[-1:], (pos.clone(), rot.clone(), outs)]
    return outs
