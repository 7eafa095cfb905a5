"""Where a robot's collision polytopes are, and how deep they reach: into the floor and into each other.

Works on a :class:`~mer_data.robots.collision.CollisionModel` (shapes attached to skeleton nodes,
in node frames) and node poses from FK: positions ``pos`` (..., J, 3) [m] and rotations ``rot``
(..., J, 3, 3), node frames as :func:`~mer_data.kinematics.fk.fk_skeleton` returns them. Torch,
batched over leading dimensions, differentiable.

**Penetration depth** of shape A into shape B: the deepest of A's surface sample points inside B,
measured to B's nearest face (``-max_f (n_f . p + d_f)``); a pair's depth is the larger of A-in-B
and B-in-A. Positive: interpenetrating by that much [m]; negative: apart, by at least that much
(pairs far apart are not computed exactly: the gap between their bounding spheres, else between
their world-axis-aligned boxes, else across a face plane of either that has all of the other's
vertices outside, else the polyhedral distance of the nearest sample point).

**Separating-axis depth** (``which="sat"``, the solver's): the least overlap of the two shapes'
projections over the face normals of both, ``-max_f min_p (n_f . p + d_f)`` over B's faces with A's
vertices and the other way round. It is exact at vertices (a polytope's extreme point along any
axis is a vertex), it bounds the true penetration depth from above and the sample-point depth
with it (a point of A as deep as ``delta`` inside B needs A moved at least ``delta`` in any
direction), so a solver that holds it under a margin holds the metric there too; and its axis is
the direction that separates the shapes with the least motion (side by side feet: across, not
along the foot nor up, where the deepest point's nearest face often points).
"""

from __future__ import annotations

from typing import Any

import torch

__all__ = ["shape_points", "lowest_points", "pair_depths", "pair_contacts", "contact_points", "padded_counts"]


def _t(a: Any, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(a, dtype=like.dtype, device=like.device)


def shape_points(model: Any, pos: torch.Tensor, rot: torch.Tensor, which: str = "vertices") -> torch.Tensor:
    """World coordinates of every shape's ``vertices`` or surface ``points``: (..., S, P, 3) [m]."""
    local = _t(getattr(model, which), pos)  # (S, P, 3)
    node = torch.as_tensor(model.node, device=pos.device)
    r = rot[..., node, :, :]  # (..., S, 3, 3)
    return torch.einsum("...sij,spj->...spi", r, local) + pos[..., node, None, :]


def lowest_points(model: Any, pos: torch.Tensor, rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Height of each shape's lowest vertex (..., S) [m] and which vertex it is (..., S)."""
    z = shape_points(model, pos, rot, "vertices")[..., 2]
    return z.min(-1)


def pair_depths(model: Any, pos: torch.Tensor, rot: torch.Tensor, pairs: Any = None, *, margin: float = 0.0,
                chunk: int = 2048, which: str = "points", where: torch.Tensor | None = None, exact: float | None = None) -> torch.Tensor:  # fmt: skip
    """Penetration depth of each checked pair (see the module docstring): (..., K) [m].

    Args:
        pairs: (K, 2) shape indices (default ``model.pairs``).
        where: optional bool (..., K): only these (frame, pair) entries are computed; the rest are ``-inf``.
        margin: pairs whose bounding spheres are more than ``margin`` apart are not computed exactly.
        exact: only the pairs within this [m] (default ``margin``) by the cheap bounds are computed
            exactly; the others up to ``margin`` keep a bound (``-gap``, the gap at least that): a
            caller that asks "within margin?" of them gets a superset, and exact values near contact.
        chunk: (frame, pair) entries computed at once (memory ~ chunk * points * planes).
        which: the sample points whose depth is measured: ``points`` (vertices and edge points,
            the metrics) or ``vertices`` (about a tenth of them); or ``sat``, the separating-axis
            depth (module docstring: the solver's).
    """
    pairs = torch.as_tensor(model.pairs if pairs is None else pairs, device=pos.device).reshape(-1, 2)
    lead = pos.shape[:-2]
    K = pairs.shape[0]
    if K == 0:
        return pos.new_zeros((*lead, 0))
    node = torch.as_tensor(model.node, device=pos.device)
    center = _t(model.center, pos)
    radius = _t(model.radius, pos)
    p2 = pos.reshape(-1, *pos.shape[-2:])
    r2 = rot.reshape(-1, *rot.shape[-3:])
    a, b = pairs[:, 0], pairs[:, 1]
    keep = None if where is None else where.reshape(-1, K).to(device=pos.device)
    fr = None if keep is None else keep.any(-1).nonzero().flatten()  # only the frames asked for
    pf, rf = (p2, r2) if fr is None else (p2[fr], r2[fr])
    us, inv = torch.unique(torch.cat([a, b]), return_inverse=True)  # only the shapes in the pairs
    ua, ub = inv[:K], inv[K:]
    c = torch.einsum("fsij,sj->fsi", rf[:, node[us]], center[us]) + pf[:, node[us]]  # (B, U, 3): once per shape, not per pair
    if 4 * K < len(us) ** 2:  # a few pairs (a repair's): gathered
        gap = (c[:, ua] - c[:, ub]).norm(dim=-1)
    else:  # many: all distances at once is cheaper than gathering (B, K, 3)
        gap = torch.cdist(c, c, compute_mode="donot_use_mm_for_euclid_dist")[:, ua, ub]
    gap = gap - (radius[a] + radius[b])  # (B, K): bounding spheres
    if fr is not None:
        gap = gap.new_full((p2.shape[0], K), float("inf")).index_copy(0, fr, gap)
    out = -gap.clamp_min(0)
    near = gap <= margin
    if keep is not None:
        out = out.masked_fill(~keep, float("-inf"))
        near &= keep
    if bool(near.any()):  # then world-axis-aligned boxes of the vertices: tighter for long bodies
        with torch.no_grad():
            f, k = near.nonzero(as_tuple=True)  # only the entries still near, and their frames
            fu, slot = torch.unique(f, return_inverse=True)
            nu = node[us]
            v = torch.einsum("fsij,spj->fspi", r2[fu][:, nu], _t(model.vertices, pos)[us]) + p2[fu][:, nu, None]  # (B', U, V, 3)
            lo, hi = v.amin(-2), v.amax(-2)
            ka, kb = ua[k], ub[k]
            sep = torch.maximum(lo[slot, ka] - hi[slot, kb], lo[slot, kb] - hi[slot, ka]).amax(-1)  # gap between the boxes
        apart = sep > 0
        out = out.index_put((f[apart], k[apart]), -sep[apart])
        far = sep > margin
        near[f[far], k[far]] = False
    near = near.nonzero()
    within = margin if exact is None else min(exact, margin)
    if len(near):
        sat = which == "sat"
        pts, verts = _t(model.vertices if sat else getattr(model, which), pos), _t(model.vertices, pos)
        planes = _t(model.planes, pos)
        vals = []
        for s in range(0, len(near), chunk):
            f, k = near[s : s + chunk, 0], near[s : s + chunk, 1]
            sa, sb = a[k], b[k]
            # a face of either shape with all of the other's vertices outside separates them: cheap, and most near pairs are;
            # first the other's bounding sphere against the faces (a lower bound of that gap, one point per entry)
            sep_gap = torch.maximum(_sphere_gap(center, radius, planes, node, p2, r2, f, sa, sb),
                                    _sphere_gap(center, radius, planes, node, p2, r2, f, sb, sa))
            test = (sep_gap <= max(within, 0.0)).nonzero().flatten()  # the rest are apart by more than `within` already
            if len(test):
                sep_gap = sep_gap.index_put((test,), _by_size(_inside, verts, planes, node, p2, r2, f[test], sa[test], sb[test], gap=True))
            other = test[sep_gap[test] <= max(within, 0.0)]
            if len(other):
                sep_gap = sep_gap.index_put((other,), torch.maximum(sep_gap[other], _by_size(_inside, verts, planes, node, p2, r2, f[other], sb[other], sa[other], gap=True)))
            v = -sep_gap
            close = sep_gap <= 0
            if not sat and bool(close.any()):
                fc, sac, sbc = f[close], sa[close], sb[close]
                v = v.clone()
                v[close] = torch.maximum(_by_size(_inside, pts, planes, node, p2, r2, fc, sac, sbc),
                                         _by_size(_inside, pts, planes, node, p2, r2, fc, sbc, sac))
            vals.append(v)
        out = out.index_put((near[:, 0], near[:, 1]), torch.cat(vals))
    return out.reshape(*lead, K)


_SIZES = (8, 16, 32, 64, 128, 256, 512)  # size classes of shapes' point and plane counts (_by_size)
TIE_M = 1e-5  # [m] overlaps closer than this are a tie: the separating axis is then the first shape's (float32 rounding is ~1e-7 m)


def padded_counts(x: torch.Tensor) -> torch.Tensor:
    """(S,) how many of each shape's rows of ``x`` (S, N, k) come before its padding (copies of its
    first row at the end)."""
    same = (x == x[:, :1]).all(-1)
    return (x.shape[1] - same.flip(-1).to(torch.int64).cumprod(-1).sum(-1)).clamp_min(1)


def _by_size(fn, pts, planes, node, pos, rot, f, sa, sb, **kw):
    """``fn(pts, planes, node, pos, rot, f, sa, sb, **kw)`` with the entries grouped by how many of
    ``sa``'s points and ``sb``'s planes they need, each group's arrays cut to its largest: the same
    result without computing the padding (a box is 8 vertices and 6 planes, padded to a 48-vertex
    hull's 48 and ~90)."""
    npt, npl = padded_counts(pts), padded_counts(planes)
    sizes = torch.tensor(_SIZES, device=npt.device)
    key = torch.bucketize(npt[sa], sizes) * (len(_SIZES) + 1) + torch.bucketize(npl[sb], sizes)
    keys = torch.unique(key)
    out = None
    for k in keys:
        idx = None if len(keys) == 1 else (key == k).nonzero().flatten()
        fi, ai, bi = (f, sa, sb) if idx is None else (f[idx], sa[idx], sb[idx])
        res = fn(pts[:, : int(npt[ai].max())], planes[:, : int(npl[bi].max())], node, pos, rot, fi, ai, bi, **kw)
        if idx is None:
            return res
        res = res if isinstance(res, tuple) else (res,)
        if out is None:
            out = [r.new_empty((len(sa), *r.shape[1:])) for r in res]
        for o, r in zip(out, res):
            o[idx] = r
    if out is None:  # no entries
        return fn(pts, planes, node, pos, rot, f, sa, sb, **kw)
    return tuple(out) if len(out) > 1 else out[0]


def _signed(pts, planes, node, pos, rot, f, sa, sb):
    """Signed distances (E, P, F) [m] of shape ``sa``'s points to shape ``sb``'s face planes at
    frames ``f`` (entries E; > 0: outside that face), the points in the world (E, P, 3) and ``sb``'s
    node rotations (E, 3, 3)."""
    ra, ta = rot[f, node[sa]], pos[f, node[sa]]
    rb, tb = rot[f, node[sb]], pos[f, node[sb]]
    world = torch.einsum("eij,epj->epi", ra, pts[sa]) + ta[:, None]
    local = torch.einsum("eji,epj->epi", rb, world - tb[:, None])  # into sb's node frame
    pl = planes[sb]  # (E, F, 4)
    return torch.einsum("epj,efj->epf", local, pl[..., :3]).add_(pl[:, None, :, 3]), world, rb  # in place: (E, P, F) made once


def _sphere_gap(center, radius, planes, node, pos, rot, f, sa, sb) -> torch.Tensor:
    """(E,) a lower bound of :func:`_inside`'s ``gap``: how far the best of ``sb``'s face planes has
    ``sa``'s bounding sphere (so every one of its vertices) outside, at frames ``f`` [m]."""
    ra, ta = rot[f, node[sa]], pos[f, node[sa]]
    rb, tb = rot[f, node[sb]], pos[f, node[sb]]
    c = torch.einsum("eij,ej->ei", rb.transpose(-1, -2), torch.einsum("eij,ej->ei", ra, center[sa]) + ta - tb)  # in sb's node frame
    pl = planes[sb]  # (E, F, 4)
    return (torch.einsum("ej,efj->ef", c, pl[..., :3]) + pl[..., 3] - radius[sa, None] * pl[..., :3].norm(dim=-1)).amax(-1)


def _inside(pts, planes, node, pos, rot, f, sa, sb, gap: bool = False) -> torch.Tensor:
    """Depth of shape ``sa``'s points inside shape ``sb`` at frames ``f`` (entries E): (E,).

    With ``gap``: instead, how far the best of ``sb``'s face planes has all of those points outside
    (> 0: that face separates the shapes by at least this much)."""
    signed = _signed(pts, planes, node, pos, rot, f, sa, sb)[0]
    if gap:
        return signed.amin(1).amax(-1)
    return (-signed.amax(-1)).amax(-1)


def pair_contacts(model: Any, pos: torch.Tensor, rot: torch.Tensor, *, margin: float = 0.0, top: int = 8, pairs: Any = None,
                  which: str = "points", mask: torch.Tensor | None = None):  # fmt: skip
    """The ``top`` deepest checked pairs of every frame, and their deepest points (what pushes bodies apart).

    Args:
        pos, rot: (B, T, J, 3), (B, T, J, 3, 3) node poses.
        pairs: (K, 2) the shape pairs to look at (default ``model.pairs``).
        which: the sample points (:func:`pair_depths`).
        mask: (B, K) bool, the pairs each sample looks at, or (B, T, K), each frame of each sample
            (default: all); the others are not computed.

    Returns:
        None if no pair is within ``margin``; else ``(entries, contacts)``: entries ``(b, t, slot,
        shape_a, shape_b)`` (E,) each, which :func:`contact_points` takes, and its result for them.
    """
    B, T = pos.shape[:2]
    pairs = torch.as_tensor(model.pairs if pairs is None else pairs, device=pos.device).reshape(-1, 2)
    where = None if mask is None else (mask[:, None, :] if mask.dim() == 2 else mask).expand(B, T, pairs.shape[0])
    d = pair_depths(model, pos, rot, pairs, margin=margin, which=which, where=where)  # (B, T, K)
    K = min(top, d.shape[-1])
    if K == 0:
        return None
    depth, k = d.topk(K, dim=-1)
    sel = depth > -margin
    if not bool(sel.any()):
        return None
    bi, ti, ki = sel.nonzero(as_tuple=True)
    pk = k[bi, ti, ki]
    entries = (bi, ti, ki, pairs[pk, 0], pairs[pk, 1])
    return entries, contact_points(model, pos, rot, entries, K, which)


def contact_points(model: Any, pos: torch.Tensor, rot: torch.Tensor, entries: tuple, K: int, which: str = "points"):
    """Depth and deepest point of given (frame, pair) entries (:func:`pair_contacts`), laid out (B, T, K).

    Returns:
        depth (B, T, K) [m] (``-inf`` where no entry), point (B, T, K, 3) the deepest point (world)
        of the body that reaches in, normal (B, T, K, 3) the outward normal (world) of the face of
        the other body it is nearest to, and the nodes (B, T, K) of the reaching body and of the
        other one. ``depth`` falls as the point moves along ``normal`` relative to the other body:
        ``d depth = -normal . (dp_point - dp_other)``.
    """
    B, T = pos.shape[:2]
    bi, ti, ki, sa, sb = entries
    node = torch.as_tensor(model.node, device=pos.device)
    sat = which == "sat"
    pts, planes = _t(model.vertices if sat else getattr(model, which), pos), _t(model.planes, pos)
    p2, r2 = pos.reshape(B * T, *pos.shape[2:]), rot.reshape(B * T, *rot.shape[2:])
    f = bi * T + ti
    fn = _separating if sat else _deepest
    da, pa, na = _by_size(fn, pts, planes, node, p2, r2, f, sa, sb)
    db, pb, nb = _by_size(fn, pts, planes, node, p2, r2, f, sb, sa)
    # the separating axis: the lesser overlap; a tie (mirror-symmetric bodies) goes to sa, not to rounding
    a_in = ((da <= db + TIE_M) if sat else (da >= db))[:, None]
    point = torch.where(a_in, pa, pb)
    normal = torch.where(a_in, na, nb)
    reach = torch.where(a_in[:, 0], node[sa], node[sb])
    other = torch.where(a_in[:, 0], node[sb], node[sa])
    out_d = torch.full((B, T, K), float("-inf"), dtype=pos.dtype, device=pos.device)
    out_p = pos.new_zeros(B, T, K, 3)
    out_n = pos.new_zeros(B, T, K, 3)
    out_a = torch.zeros(B, T, K, dtype=torch.long, device=pos.device)
    out_b = torch.zeros(B, T, K, dtype=torch.long, device=pos.device)
    out_d[bi, ti, ki] = torch.minimum(da, db) if sat else torch.maximum(da, db)
    out_p[bi, ti, ki], out_n[bi, ti, ki], out_a[bi, ti, ki], out_b[bi, ti, ki] = point, normal, reach, other
    return out_d, out_p, out_n, out_a, out_b


def _deepest(pts, planes, node, pos, rot, f, sa, sb):
    """Shape ``sa``'s deepest point inside ``sb`` at frames ``f``: depth (E,), the point (E, 3) and the
    outward normal (E, 3) of ``sb``'s nearest face, in the world."""
    signed, world, rb = _signed(pts, planes, node, pos, rot, f, sa, sb)
    near, face = signed.max(-1)  # per point: its nearest face (the largest signed distance)
    depth, p = (-near).max(-1)
    e = torch.arange(len(f), device=pos.device)
    n_local = planes[sb, face[e, p], :3]
    return depth, world[e, p], torch.einsum("eij,ej->ei", rb, n_local)


def _separating(verts, planes, node, pos, rot, f, sa, sb):
    """The overlap of shape ``sa`` with shape ``sb`` along ``sb``'s best separating face normal at
    frames ``f``: overlap (E,) [m] (negative: that face separates them), ``sa``'s vertex deepest
    along it (E, 3) and the face's outward normal (E, 3), in the world."""
    signed, world, rb = _signed(verts, planes, node, pos, rot, f, sa, sb)
    low, p = signed.min(1)  # per face: how far all of sa's vertices are outside it, and the one least
    gap, face = low.max(-1)
    e = torch.arange(len(f), device=pos.device)
    n_local = planes[sb, face, :3]
    return -gap, world[e, p[e, face]], torch.einsum("eij,ej->ei", rb, n_local)
