"""Physics as constraints: the least change to the unconstrained solution that makes it physical.

``PhysicsConfig.method`` "constraints". The optimiser first solves the plain problem (key points,
orientations, nominal pose, temporal prior: the paper's energy, no goal edit); :func:`constrain`
then minimises the same energy subject to

* **floor**: every collision shape's lowest vertex at or above z = 0 (every body, not only feet);
* **self-penetration**: every checked pair of bodies (:mod:`mer_data.robots.collision`) apart by
  ``self_margin`` along its separating axis (the depth that bounds the metric's from above);
* **stance**: while the source's foot is down, the foot's lowest point at most ``hover`` above the
  floor, and (``stance_xy``) its lowest body-fixed point not sliding from one frame to the next
  (:mod:`.stance`, a penalty of weight ``rho * xy_weight``: its point is re-chosen each round);

by an augmented Lagrangian around the whole-window Levenberg-Marquardt of
:func:`~.ik.coupled_lm_ik`: each round takes ``al_iters`` of its steps (from at most ``al_tries``
linearisations: a refused step does not use one up) with one-sided rows
``sqrt(rho) min(0, c(x) - s)`` per constraint ``c(x) >= 0`` (the shift ``s = lambda / rho`` is the
multiplier, so rows exist only where a constraint is active and the block-tridiagonal system is
kept), then updates ``s <- max(0, s - c(x))``; at most ``al_rounds`` updates, none once every
constraint is met to :data:`TOLERANCE_M` (sliding, a penalty, does not keep the rounds going). The
rounds add a temporal prior on the *change* from the plain solution (``al_smooth`` times the
solve's), so the change is smooth without pulling what the plain solve fitted, and hold frames
farther than ``al_reach`` from every active constraint; from round ``al_focus`` on, from every
constraint not yet met, and each run of the frames that move is solved as on its own (:func:`_segments`;
the runs side by side in one call, each its own damping and step test: :func:`_frames`).
Within a round a self row is the overlap along the separating face chosen at its start
(:mod:`.faces`), and pairs are looked for again (among those within ``al_search`` at the first
round) only before the rounds would stop. Frames a round's solve did not take keep their
measures (lowest points, self depths) into the next round; the first search is exact only near
contact (the rest of its candidates keep a bound). The base
is first raised where a foot is in the floor (a start the floor's linearisation holds from). After
``al_rounds`` rounds, a pair still :data:`DEEP_M` short of its margin gets up to ``al_extra`` more, each
only after a round that brought it :data:`PROGRESS_M` nearer. Joint
limits are the solver's projection; joint speed is the solver's coupled term and the feasibility
pass after (:mod:`mer_models.retarget.feasible`) takes the rest exactly. What each choice measured:
docs/decisions.md §Physics as constraints.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import torch

from mer_data.kinematics.collision import lowest_points, pair_depths
from mer_models.batch import batch_fk

from .faces import face_points, fix_faces
from .ik import coupled_lm_ik
from .repair import SELF_POINTS, widen
from .stance import lowest_foot_points

__all__ = ["constrain", "NEAR_M", "TOLERANCE_M"]

log = logging.getLogger(__name__)

NEAR_M = 0.002  # pairs closer than self_margin + this are in a round's self rows (active or not)
LIFT_MARGIN_M = -1e-5  # [m] the first lift stops this far short of the floor: its rows start active, never at their bound
TOLERANCE_M = 0.002  # a constraint met to within this [m] needs no further round
PROGRESS_M = 0.002  # [m] an extra round only after a round that brought the worst pair this much nearer its margin
DEEP_M = 0.01  # [m] a pair this far short of its margin after the rounds gets up to al_extra more (the metric's deep self-penetration: 1 cm)
SLIDE_TOL_M = 0.0015  # a stance foot's material point slower than this per frame [m] needs no further round


def _foot_nodes(model: Any, dev: torch.device) -> tuple[list[torch.Tensor], list[int]]:
    """Each foot's shapes (left, right) and the node carrying most of it (-1: no such foot)."""
    foot, node = torch.as_tensor(model.foot, device=dev), torch.as_tensor(model.node, device=dev)
    shapes = [torch.nonzero(foot == s).flatten() for s in (1, 2)]
    return shapes, [int(torch.mode(node[f]).values) if len(f) else -1 for f in shapes]


def _slide(model: Any, pos: torch.Tensor, rot: torch.Tensor, shape: torch.Tensor, vert: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, T-1) the largest horizontal step [m] of a stance foot's material point (shape, vertex (B, T, 2)) from
    frame t to t + 1 where ``mask`` (B, T-1, 2)."""
    node = torch.as_tensor(model.node, device=pos.device)[shape[:, :-1]]  # (B, T-1, 2)
    local = torch.as_tensor(model.vertices, dtype=pos.dtype, device=pos.device)[shape[:, :-1], vert[:, :-1]]  # (B, T-1, 2, 3)
    B, T1 = node.shape[:2]
    bi = torch.arange(B, device=pos.device)[:, None, None]
    ti = torch.arange(T1, device=pos.device)[None, :, None]
    pa = torch.einsum("btfij,btfj->btfi", rot[bi, ti, node], local) + pos[bi, ti, node]
    pb = torch.einsum("btfij,btfj->btfi", rot[bi, ti + 1, node], local) + pos[bi, ti + 1, node]
    return ((pb - pa)[..., :2].norm(dim=-1) * mask).amax(-1)


def _lows(model: Any, pos: torch.Tensor, rot: torch.Tensor, shift: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """(B, T, S) each shape's lowest vertex height [m] at node poses ``pos``, ``rot`` where its bounding
    sphere reaches down to its floor shift ``shift`` (B, T, S) [m] (>= 0) or ``keep`` (S,) bool (the feet);
    elsewhere the sphere's bottom, a lower bound above the shift, where the multiplier update
    (``max(0, shift - low)``) and the violation (``-low``, < 0) come out as from the vertices."""
    node = torch.as_tensor(model.node, device=pos.device)
    centre = torch.as_tensor(model.center, dtype=pos.dtype, device=pos.device)
    radius = torch.as_tensor(model.radius, dtype=pos.dtype, device=pos.device)
    low = (rot[..., node, 2, :] * centre).sum(-1) + pos[..., node, 2] - radius  # (B, T, S)
    bi, ti, si = ((low <= shift) | keep).nonzero(as_tuple=True)
    if len(bi):
        verts = torch.as_tensor(model.vertices, dtype=pos.dtype, device=pos.device)[si]  # (E, V, 3)
        z = (verts @ rot[bi, ti, node[si], 2, :, None])[..., 0] + pos[bi, ti, node[si], 2, None]
        low = low.index_put((bi, ti, si), z.amin(-1))
    return low


def _entries(known: torch.Tensor, pairs: torch.Tensor, shift: torch.Tensor):
    """(B, T, K) bool entries → the ``(b, t, slot, shape_a, shape_b)`` layout of
    :func:`mer_data.kinematics.collision.contact_points`, its slot count, and the shifts per slot."""
    B, T, _ = known.shape
    bi, ti, ki = known.nonzero(as_tuple=True)
    if not len(bi):
        return None, 1, shift.new_zeros(B, T, 1)
    slot = (known.long().cumsum(-1) - 1)[bi, ti, ki]
    K = int(slot.max()) + 1
    per_slot = shift.new_zeros(B, T, K)
    per_slot[bi, ti, slot] = shift[bi, ti, ki]
    return (bi, ti, slot, pairs[ki, 0], pairs[ki, 1]), K, per_slot


def _along_faces(model: Any, pos: torch.Tensor, rot: torch.Tensor, faces: dict, K: int) -> torch.Tensor:
    """(B, T, K) the depth [m] of the entries of ``faces`` (:func:`.faces.fix_faces`) along their faces, ``-inf`` elsewhere."""
    bi, ti, slot, _, _ = faces["entries"]
    depth = face_points(model, pos, rot, faces)[0]
    out = depth.new_full((*pos.shape[:2], K), float("-inf"))
    out[bi, ti, faces["pair"]] = depth[bi, ti, slot]
    return out


def _segments(free: torch.Tensor, gap: int) -> list[tuple[int, int]]:
    """The frame ranges [a, b) a round solves: each run of frames free in some sample (``free`` (B, T)),
    with one held frame on each side, runs closer than ``gap`` frames joined; the whole window when
    they cover most of it (one solve is then cheaper than several)."""
    T = free.shape[1]
    idx = free.any(0).nonzero().flatten().tolist()
    if not idx:
        return []
    runs = [[max(idx[0] - 1, 0), idx[0] + 2]]
    for t in idx[1:]:
        if t - 1 <= runs[-1][1] + gap:
            runs[-1][1] = t + 2
        else:
            runs.append([t - 1, t + 2])
    runs = [(a, min(b, T)) for a, b in runs]
    return [(0, T)] if sum(b - a for a, b in runs) > 0.75 * T else runs


def _window(idx: torch.Tensor | None, **tensors: torch.Tensor | None) -> dict:
    """Frames ``idx`` (dimension 1; None: all) of each tensor (None stays None)."""
    return {k: v if v is None or idx is None else v[:, idx] for k, v in tensors.items()}


def _frames(segs: list[tuple[int, int]], T: int, dev: torch.device) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The frames of the ranges ``segs`` (:func:`_segments`) one after another, and each one's range
    (None, None: the whole window). Each range starts and ends at a held frame (or the window's end),
    so ranges side by side are coupled only between held frames, by terms that stay constant: one
    solve of them all, each range its own damping and step test (``coupled_lm_ik(groups=...)``),
    takes the steps a solve of each would, without a call's fixed cost per range."""
    if segs == [(0, T)]:
        return None, None
    idx = torch.cat([torch.arange(a, b, device=dev) for a, b in segs])
    groups = torch.cat([torch.full((b - a,), i, dtype=torch.long, device=dev) for i, (a, b) in enumerate(segs)])
    return idx, groups


def _window_terms(terms: Any, idx: torch.Tensor | None) -> Any:
    """The physical terms (:class:`~.physics.PhysicsInputs` with a round's state ``al``) of frames ``idx`` (None: all)."""
    if idx is None:
        return terms
    T = terms.al["floor"].shape[1]
    new = torch.full((T,), -1, dtype=torch.long, device=idx.device)
    new[idx] = torch.arange(len(idx), device=idx.device)  # each frame's place in the solve (-1: not in it)
    al = dict(terms.al)
    for k in ("floor", "self", "stance_z"):
        al[k] = al[k][:, idx]
    if al["entries"] is not None:
        keep = new[al["entries"][1]] >= 0
        bi, ti, slot, sa, sb = (x[keep] for x in al["entries"])
        al["entries"] = (bi, new[ti], slot, sa, sb) if len(bi) else None
        if "faces" in al:
            f = al["faces"]
            al["faces"] = {**f, "entries": al["entries"], "memo": [], **{k: f[k][keep] for k in ("reach", "other", "n", "d", "pair")}}
            if f["exact"] is not None:
                kx = new[f["exact"][1]] >= 0
                ex = tuple(x[kx] for x in f["exact"])
                al["faces"]["exact"] = (ex[0], new[ex[1]], *ex[2:]) if bool(kx.any()) else None
            if al["entries"] is None:
                del al["faces"]
    if al.get("slip") is not None:  # a pair of frames side by side only where they are neighbours
        sl = al["slip"]
        nb = (idx[1:] == idx[:-1] + 1)[None, :, None]
        al["slip"] = {**sl, "shape": sl["shape"][:, idx], "vert": sl["vert"][:, idx], "mask": sl["mask"][:, idx[:-1].clamp_max(T - 2)] & nb}
    contacts = None if terms.contacts is None else terms.contacts[:, idx]
    return dataclasses.replace(terms, contacts=contacts, al=al)


@torch.no_grad()
def constrain(cfg: Any, graph: Any, eta: torch.Tensor, goal: torch.Tensor, q: torch.Tensor, base_pos: torch.Tensor,
              base_rot: torch.Tensor, *, physics: Any, smooth: float, tol: float, goal_rot: torch.Tensor | None = None,
              rot_mask: torch.Tensor | None = None, stats: dict | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
    """The least change (in the energy ``cfg``) to the solution ``q`` (B, T, J), ``base_pos`` (B, T, 3),
    ``base_rot`` (B, T, 3, 3) that meets the physical constraints of ``physics`` (a
    :class:`~.physics.PhysicsInputs`; module docstring). Arguments as :func:`~.ik.coupled_lm_ik`;
    ``stats`` receives ``rounds`` (multiplier updates run) and ``violation`` (B,) the largest left [m]."""
    c = physics.cfg
    model = physics.model
    B, T = q.shape[:2]
    dev, dt = q.device, q.dtype
    S = len(model.node)
    pairs = torch.as_tensor(model.pairs, device=dev).reshape(-1, 2) if c.w_self > 0 else torch.zeros(0, 2, dtype=torch.long, device=dev)
    Kp = len(pairs)
    contacts = None if physics.contacts is None else torch.as_tensor(physics.contacts, device=dev)
    feet, foot_node = _foot_nodes(model, dev)
    has_feet = contacts is not None and any(len(f) for f in feet)
    terms_cfg = dataclasses.replace(c, w_floor=c.rho, w_self=c.rho if Kp else 0.0, w_stance=c.rho if has_feet else 0.0,
                                    w_anchor=0.0, w_flat=0.0, w_swing=0.0)  # fmt: skip
    pos, rot = batch_fk(graph, q, base_pos, base_rot)
    plain = q
    low0 = lowest_points(model, pos, rot)[0]
    sole = torch.cat(feet) if any(len(f) for f in feet) else torch.arange(S, device=dev)
    need = (-low0[..., sole].amin(-1)).clamp_min(0)  # (B, T): the base lifted first where a foot is in the floor
    need = torch.where(need > 0, (need + LIFT_MARGIN_M).clamp_min(0), need)  # a row exactly at its bound flips with rounding
    if c.al_lift and bool((need > 0).any()):  # (a start the floor's linearisation holds from; the rounds then take back what they can)
        base_pos = base_pos.clone()
        base_pos[..., 2] += need
        pos = pos.clone()
        pos[..., 2] += need[..., None]
    down = contacts.to(dt) if has_feet else q.new_zeros(B, T, 2)
    s_floor, s_self = q.new_zeros(B, T, S), q.new_zeros(B, T, Kp)
    s_z = q.new_zeros(B, T, 2)
    known = torch.zeros(B, T, Kp, dtype=torch.bool, device=dev)
    search = torch.ones(B, T, dtype=torch.bool, device=dev)
    rounds, worst = 0, q.new_zeros(B)
    faces, cand = None, None  # cand: the (frame, pair) entries the later rounds look at, set by round 0
    moved = torch.ones(T, dtype=torch.bool, device=dev)  # the frames the last round's solve took (the rest: measured before, unchanged)
    low = q.new_zeros(B, T, S)
    is_foot = torch.zeros(S, dtype=torch.bool, device=dev).index_fill(0, sole, True) if any(len(f) for f in feet) else torch.zeros(S, dtype=torch.bool, device=dev)
    dc = q.new_full((B, T, Kp), float("-inf"))  # each entry's last measure (+ self_margin)
    last, rnd = c.al_rounds, -1
    deepest = 0.0  # [m] how far the worst pair was short of its margin at the last measure
    while rnd < last:
        rnd += 1
        if rnd == last and stats is None and not (deepest > DEEP_M and last < c.al_rounds + c.al_extra):
            break  # the last round's measures only fill stats (or decide on one more round): nothing moves after it
        m = None if bool(moved.all()) else moved.nonzero().flatten()
        low = _lows(model, pos, rot, s_floor, is_foot) if m is None else low.index_copy(1, m, _lows(model, pos[:, m], rot[:, m], s_floor[:, m], is_foot))  # (B, T, S)
        foot_z = torch.stack([low[..., f].amin(-1) if len(f) else low.new_full((B, T), float("inf")) for f in feet], -1)
        up = (foot_z - c.hover) * down  # (B, T, 2) > 0: hovering
        slip, slide = None, q.new_zeros(B, T)
        if has_feet and c.stance_xy and T > 1:  # this round's material points: each stance foot's lowest vertex
            shape, vert = lowest_foot_points(model, pos, rot, feet)
            mask = contacts[:, 1:] & contacts[:, :-1]  # (B, T-1, 2)
            slip = {"shape": shape, "vert": vert, "mask": mask, "w": c.rho * c.xy_weight * cfg.w_kp}
            slide[:, :-1] = _slide(model, pos, rot, shape, vert, mask)
        slide = torch.where(slide > SLIDE_TOL_M, slide, torch.zeros_like(slide))
        d = q.new_zeros(B, T, 0)
        if Kp:
            d = None
            if faces is not None and rnd < last and (c.al_look <= 0 or rnd % c.al_look):  # the last solve's entries along their round's faces (.faces: an upper bound)
                fd = _along_faces(model, pos, rot, faces, Kp) + c.self_margin
                d = torch.where(fd > float("-inf"), fd, dc)  # the other entries' frames have not moved since measured
                rest = torch.stack([(-low).amax(-1), d.amax(-1), up.amax(-1)], -1)
                if not bool((rest > TOLERANCE_M).any()):
                    d = None  # about to stop: every pair looked at first, new ones included
            if d is None:
                where = (search[..., None] & (cand | known)) if rnd else None  # the frames moved since the last look
                reach = NEAR_M if rnd else NEAR_M + c.al_search
                d = pair_depths(model, pos, rot, margin=c.self_margin + reach, which=SELF_POINTS, where=where, exact=c.self_margin + NEAR_M) + c.self_margin
                if rnd:  # the known entries of frames not moved since: as last measured
                    d = torch.where(search[..., None], d, torch.where(known, dc, torch.full_like(dc, float("-inf"))))
                else:  # the later rounds look only at the (frame, pair) entries within al_search of active now
                    cand = d > -(NEAR_M + c.al_search)
                known |= d > -NEAR_M
                search = torch.zeros_like(search)  # the frames moved since this look
            dc = d
        if rnd:  # multiplier updates
            k = c.al_step
            s_floor = (s_floor - k * low).clamp_min(0)
            s_self = torch.where(known, (s_self + k * d).clamp_min(0), torch.zeros_like(s_self))
            s_z = (s_z + k * up).clamp_min(0) * down
        viol = torch.stack([(-low).amax(-1), d.amax(-1) if Kp else q.new_zeros(B, T), up.amax(-1), slide], -1)
        worst = viol.clamp_min(0).amax((1, 2))
        if log.isEnabledFor(logging.DEBUG):
            log.debug("round %d: worst floor %.4f self %.4f hover %.4f slide %.4f m; frames unmet %d", rnd, *viol.clamp_min(0).amax((0, 1)).tolist(),
                      int((viol[..., :3] > TOLERANCE_M).any(-1).sum()))  # fmt: skip
        deepest, was = (float(d.amax()) if d.numel() else 0.0), (deepest if rnd else float("inf"))
        if rnd == last and deepest > DEEP_M and last < c.al_rounds + c.al_extra and deepest < was - PROGRESS_M:
            last += 1  # a pair still 1 cm short of its margin, and the last round brought it nearer: one more round
        if rnd == last or not bool((viol[..., :3] > TOLERANCE_M).any()):  # the constraints met (sliding is a penalty)
            break
        if rnd >= c.al_focus >= 0:  # the later rounds: only where a constraint is not met yet (the rest held)
            active = (viol[..., :3] > TOLERANCE_M).any(-1)
        else:
            active = (viol > 0).any(-1) | (s_floor > 0).any(-1) | (s_self > 0).any(-1) | (s_z > 0).any(-1)
            if slip is not None:
                active |= contacts.any(-1)
        free = widen(active[..., None], c.al_reach)[..., 0] if c.al_reach >= 0 else torch.ones_like(active)
        segs = _segments(free, c.al_gap)
        if not segs:  # nothing moves: every later round the same
            break
        idx, groups = _frames(segs, T, dev)
        moved = torch.ones(T, dtype=torch.bool, device=dev) if idx is None else torch.zeros(T, dtype=torch.bool, device=dev).index_fill(0, idx, True)
        entries, slots, s_slot = _entries(known & moved[None, :, None], pairs, s_self)  # the solve's frames' entries
        al = {"floor": s_floor, "entries": entries, "slots": slots, "self": s_slot, "stance_z": s_z, "anchor": [None, None], "slip": slip}
        faces = None
        if entries is not None and c.fixed_faces:  # the self rows along faces chosen now (.faces)
            faces = al["faces"] = fix_faces(model, pos, rot, entries, slots, SELF_POINTS, exact_over=c.face_exact)
            faces["pair"] = (known & moved[None, :, None]).nonzero(as_tuple=True)[2]
        terms = dataclasses.replace(physics, cfg=terms_cfg, al=al, pairs=None, pair_mask=None)
        # every run of free frames, with a held frame at each end, in one solve
        sub = _window(idx, goal=goal, q=q, base_pos=base_pos, base_rot=base_rot, plain=plain, hold=~free, goal_rot=goal_rot)
        qs, ps, rs = coupled_lm_ik(cfg, graph, eta, sub["goal"], sub["q"], sub["base_pos"], sub["base_rot"], iters=c.al_iters, tries=c.al_tries, smooth=smooth, tol=tol,
                                   change_of=sub["plain"], change_smooth=smooth * c.al_smooth, physics=_window_terms(terms, idx),
                                   hold=sub["hold"], goal_rot=sub["goal_rot"], rot_mask=rot_mask, groups=groups)  # fmt: skip
        if idx is None:
            q, base_pos, base_rot = qs, ps, rs
            pos, rot = batch_fk(graph, q, base_pos, base_rot)
        else:
            q, base_pos, base_rot = q.clone(), base_pos.clone(), base_rot.clone()
            q[:, idx], base_pos[:, idx], base_rot[:, idx] = qs, ps, rs
            pn, rn = batch_fk(graph, qs, ps, rs)
            pos, rot = pos.index_copy(1, idx, pn), rot.index_copy(1, idx, rn)
        search, rounds = search | free, rnd + 1
    if stats is not None:
        stats["rounds"], stats["violation"] = rounds, worst
    return q, base_pos, base_rot
