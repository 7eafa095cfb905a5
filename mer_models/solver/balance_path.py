"""The balance term's path correction: the centre of mass's horizontal path moved until the ZMP is in the support.

The two-stage balance (:class:`~.balance_term.BalanceConfig` ``method="path"``, docs/model.md §Balance):

1. **A correction of the centre of mass's horizontal path** ``dc`` (T, 2) [m] over the whole window, from
   the motion's own dynamics as the balance metric measures them (:mod:`mer_data.kinematics.dynamics`).
   The ZMP ``p = c_xy - (c_z f_xy + (n_y, -n_x)) / f_z`` with ``f_xy = M A c_xy`` (``A`` the metric's
   filtered second difference, :func:`accel_operator`) moves, for the whole body carried by ``dc``, by
   ``dp = dc - (c_z M / f_z) A dc``: exactly linear (the moment about the centre of mass and ``f_z`` do
   not change under a horizontal translation of every body). The correction is the least
   ``|dc|^2 + smooth (c_z / g)^2 |A dc|^2`` that puts every contact frame's ZMP inside its support
   polygon moved ``margin`` inward (the polygon of the metric: the hull of the collision vertices within
   2 cm of the floor) and, in flight frames, the horizontal acceleration to 0 (ballistic): a banded
   least-squares problem in ``2 T`` unknowns with the polygons' rows as an active set of penalties
   (:func:`path_correction`; sparse, milliseconds for hundreds of frames).
   **A vertical correction** ``dz`` (T,) [m] of the whole body, feet included (:func:`vertical_correction`):
   a flight phase (no collision vertex within 2 cm of the floor) whose lowest point stays under
   ``hover`` is a foot held a few millimetres too high and is put down; any other is a jump, made
   ballistic (``f_z = 0``, the filtered vertical acceleration ``-g``); contact frames stay on the floor.
2. **The whole-body solve tracks it**: every key-point goal moves by the horizontal correction, scaled
   per node by how far up the leg it is (feet 0, the hips and everything above 1), so the body above the
   hips moves rigidly, the feet stay where they were and the legs take up the difference, and by the
   vertical correction whole; a few whole-window Levenberg-Marquardt iterations from the motion with its
   base moved.

The centre of mass moves less than the base (the legs stay behind): each round measures the ZMP of the
solved motion again and corrects what is left.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch

from mer_data.kinematics.dynamics import BINOMIAL, GRAVITY

log = logging.getLogger(__name__)

__all__ = ["accel_operator", "polygon_rows", "path_correction", "vertical_correction", "flight_phases", "leg_weights"]


def accel_operator(T: int, fps: float):
    """(T, T) sparse ``A``: the metric's filtered acceleration ``A x`` [m/s^2] of a trajectory ``x`` (T,) [m]:
    the central second difference (end frames repeat their neighbour's), then the 5-tap binomial filter
    (ends repeated), as :func:`mer_data.kinematics.dynamics.body_wrenches`."""
    from scipy.sparse import coo_matrix

    w = np.asarray(BINOMIAL) / sum(BINOMIAL)
    h = len(BINOMIAL) // 2
    t = np.arange(T)
    rows, cols, vals = [], [], []
    for j, wj in enumerate(w):
        s = np.clip(t + j - h, 0, T - 1)
        a = np.clip(s, 1, T - 2)
        for o, c in ((-1, 1.0), (0, -2.0), (1, 1.0)):
            rows.append(t)
            cols.append(a + o)
            vals.append(np.full(T, wj * c * fps**2))
    return coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(T, T)).tocsr()


def polygon_rows(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-planes ``n . p + d <= 0`` (unit outward ``n`` (E, 2), ``d`` (E,)) of the convex hull of ``pts``
    (N, 2); a segment or a point: the thin strip around it (its sides and its ends)."""
    from mer_data.kinematics.support import hull_indices

    h = pts[hull_indices(pts)]
    if len(h) >= 3:
        e = np.roll(h, -1, 0) - h
        n = np.stack([e[:, 1], -e[:, 0]], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-15
        return n, -(n * h).sum(-1)
    a, b = h[0], h[-1]
    u = b - a
    if np.linalg.norm(u) < 1e-9:
        u = np.array([1.0, 0.0])
    u = u / np.linalg.norm(u)
    v = np.array([-u[1], u[0]])
    n = np.stack([u, -u, v, -v])
    return n, -np.array([u @ b, -(u @ a), v @ a, -(v @ a)])


def path_correction(zmp: np.ndarray, com_z: np.ndarray, fz: np.ndarray, polys: list, flight: np.ndarray, acc_xy: np.ndarray,
                    fps: float, *, margin: float = 0.0, smooth: float = 1.0, flight_weight: float = 1.0,
                    penalty: float = 1e4, iters: int = 30, prior: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """The least correction ``dc`` (T, 2) [m] of the centre of mass's horizontal path (module docstring).

    Args:
        zmp: (T, 2) the ZMP now [m] (any value where undefined); com_z: (T,) the centre of mass's height
            above the floor [m]; fz: (T,) the demanded vertical force per unit mass [m/s^2]; polys: per frame
            None (no constraint) or the half-planes ``(n (E, 2), d (E,))`` of its support polygon;
            flight: (T,) bool; acc_xy: (T, 2) the filtered horizontal acceleration now [m/s^2].
        margin: how far inside the polygon the ZMP is put [m]; smooth: the weight of the filtered
            acceleration's change, in ZMP units (``(c_z / g) A dc``); flight_weight: of the flight
            frames' horizontal acceleration, in the same units; penalty: of a polygon row's excess;
            prior: (T, 2) the correction earlier rounds made [m]: the least ``prior + dc`` is sought.
    """
    from scipy.sparse import bmat, csr_matrix, diags, identity

    T = len(zmp)
    A = accel_operator(T, fps)
    ok = fz > 0.2 * GRAVITY
    h = np.where(ok, com_z / np.where(ok, fz, 1.0), 0.0)
    L = identity(T, format="csr") - diags(h) @ A  # dp = L dc, per axis
    s = diags(np.mean(com_z) / GRAVITY * np.ones(T)) @ A
    Q = identity(2 * T, format="csr") * 1.0
    Q = Q + smooth * bmat([[s.T @ s, None], [None, s.T @ s]])
    rhs = np.zeros(2 * T)
    fl = np.flatnonzero(flight)
    if len(fl) and flight_weight > 0:
        sf = s[fl]
        Q = Q + flight_weight * bmat([[sf.T @ sf, None], [None, sf.T @ sf]])
        k = np.mean(com_z) / GRAVITY
        rhs -= flight_weight * np.concatenate([sf.T @ (k * acc_xy[fl, 0]), sf.T @ (k * acc_xy[fl, 1])])
    if prior is not None:
        rhs -= Q @ np.concatenate([prior[:, 0], prior[:, 1]])
    # the polygon rows: n . (p + L dc) + d + margin <= 0, one row per edge of every constrained frame
    ri, nx, ny, b = [], [], [], []
    for t, poly in enumerate(polys):
        if poly is None or not ok[t]:
            continue
        n, d = poly
        ri += [t] * len(n)
        nx.append(n[:, 0])
        ny.append(n[:, 1])
        b.append(n @ zmp[t] + d + margin)
    if not ri:
        ri, nx, ny, b = [0], [np.zeros(1)], [np.zeros(1)], [np.full(1, -1.0)]  # no polygon: no row ever active
    ri_a = np.asarray(ri)
    nx_a, ny_a, b_a = np.concatenate(nx), np.concatenate(ny), np.concatenate(b)
    Lr = L[ri_a]  # (R, T)
    G = csr_matrix(bmat([[diags(nx_a) @ Lr, diags(ny_a) @ Lr]]))  # (R, 2T)
    x = _active_set(Q, rhs, G, b_a, penalty, iters)
    return np.stack([x[:T], x[T:]], -1)


def _active_set(Q: Any, rhs: np.ndarray, G: Any, b: np.ndarray, penalty: float, iters: int) -> np.ndarray:
    """The least ``x^T Q x / 2 - rhs^T x`` (sparse ``Q`` (n, n)) with the rows ``G x + b <= 0`` (sparse
    ``G`` (R, n), ``b`` (R,)) as an active set of quadratic penalties of weight ``penalty``: the violated
    rows join, the met ones leave, until the set repeats or ``iters`` solves."""
    from scipy.sparse.linalg import spsolve

    x = spsolve(Q.tocsc(), rhs)
    active = np.zeros(len(b), bool)
    for _ in range(iters):
        viol = G @ x + b > 0
        if np.array_equal(viol, active):
            break
        active = viol
        Ga = G[active]
        x = spsolve((Q + penalty * (Ga.T @ Ga)).tocsc(), rhs - penalty * (Ga.T @ b[active]))
    return x


def flight_phases(flight: np.ndarray, low: np.ndarray, hover: float, fz: np.ndarray | None = None,
                  held: float = 0.5) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Split the flight frames (T,) bool into **hovers** (a maximal run of flight frames whose lowest collision
    vertex ``low`` (T,) [m] stays below ``hover`` and, given ``fz`` (T,) [m/s^2] (``f_z / M``), whose body is
    held up rather than falling: mean ``f_z / M`` over ``held g``; a foot held a few centimetres too high,
    put down by :func:`vertical_correction`) and **jumps** (the rest, a run's short flights among them:
    made ballistic). Returns both (T,) bool."""
    hov = np.zeros(len(flight), bool)
    t = 0
    while t < len(flight):
        if not flight[t]:
            t += 1
            continue
        e = t
        while e < len(flight) and flight[e]:
            e += 1
        hov[t:e] = low[t:e].max() < hover and (fz is None or fz[t:e].mean() > held * GRAVITY)
        t = e
    return flight & hov, flight & ~hov


def vertical_correction(low: np.ndarray, fz: np.ndarray, contact: np.ndarray, hover: np.ndarray, jump: np.ndarray, com_z: float,
                        fps: float, *, top: float, smooth: float = 0.1, flight_weight: float = 1.0, penalty: float = 1e4,
                        iters: int = 30, prior: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """The least vertical translation ``dz`` (T,) [m] of the whole body that makes every jump frame ballistic
    and keeps (or puts) the lowest point of every contact (and hover) frame on the floor.

    Least ``|dz|^2 + smooth |k A dz|^2 + flight_weight sum_jump |k (A dz + f_z / M)|^2`` (``k = c_z / g``: ZMP
    units, as :func:`path_correction`; ``f_z / M = c_z'' + g`` filtered, 0 in free fall) with, as an active
    set of penalties, ``low + dz <= top`` in contact and hover frames (the support's vertices stay within
    the metric's 2 cm; a hover comes down to it) and ``low + dz >= min(low, 0)`` everywhere (nothing lower
    than the floor, or than it already is).

    Args:
        low: (T,) the lowest collision vertex's height [m]; fz: (T,) the demanded vertical force per unit mass
            [m/s^2]; contact, hover, jump: (T,) bool (:func:`flight_phases`); com_z: the centre of mass's mean
            height [m]; top: the highest the lowest vertex of a contact frame may end [m]; prior: (T,) the
            vertical correction earlier rounds made [m]: the least ``prior + dz`` is sought.
    """
    from scipy.sparse import csr_matrix, identity, vstack

    T = len(low)
    A = accel_operator(T, fps)
    k = com_z / GRAVITY
    R = identity(T, format="csr") + smooth * k**2 * (A.T @ A)  # the size and smoothness of prior + dz
    Q = R
    rhs = -(R @ prior) if prior is not None else np.zeros(T)
    j = np.flatnonzero(jump)
    if len(j) and flight_weight > 0:
        Q = Q + flight_weight * k**2 * (A[j].T @ A[j])
        rhs -= flight_weight * k**2 * (A[j].T @ fz[j])
    # rows g . dz + b <= 0: the lowest vertex under ``top`` where the floor supports, over the floor everywhere
    up = np.flatnonzero(contact | hover)
    eye = identity(T, format="csr")
    G = csr_matrix(vstack([eye[up], -eye]))
    b = np.concatenate([low[up] - top, -(low - np.minimum(low, 0.0))])
    return _active_set(Q, rhs, G, b, penalty, iters)


def leg_weights(parents: np.ndarray, foot_nodes: list[int], height: np.ndarray) -> np.ndarray:
    """(J,) how much of the correction each node's goal takes: 0 on a foot (and below it), 1 at the root and
    everything not on a leg, between them along each leg by height (``height`` (J,) of a standing pose [m])."""
    J = len(parents)
    w = np.ones(J)
    for f in foot_nodes:
        chain, n = [], f
        while n > 0:
            chain.append(n)
            n = int(parents[n])
        if not chain:
            continue
        top, low = height[0], height[f]
        for n in chain:
            w[n] = min(w[n], float(np.clip((height[n] - low) / max(top - low, 1e-6), 0.0, 1.0)))
        for n in range(J):  # below the foot (toes): 0
            m = n
            while m > 0 and m != f:
                m = int(parents[m])
            if m == f:
                w[n] = 0.0
    return w


def com_gain(mass: np.ndarray, weights: np.ndarray) -> float:
    """How far the centre of mass moves per metre the goals move (their mass-weighted share) [1]."""
    return float((mass * weights[: len(mass)]).sum() / mass.sum())


def torch_weights(eta: torch.Tensor, node_w: torch.Tensor) -> torch.Tensor:
    """(B, Jr) each reference goal's share of the correction from its target nodes' (B, Jt) through the
    joint map ``eta`` (B, Jt, Jr); goals no target node maps to take all of it."""
    s = eta.sum(1)
    return torch.where(s > 0, (eta * node_w[..., None]).sum(1) / s.clamp_min(1e-12), torch.ones_like(s))


def _frames(inputs, pos: torch.Tensor, rot: torch.Tensor):
    """One sample's ZMP (T, 2), centre-of-mass height (T,), ``f_z / M`` (T,), filtered horizontal acceleration
    (T, 2), support polygons (per frame half-planes or None), flight frames (T,) and the lowest collision
    vertex's height (T,) [m] from node frames."""
    from mer_data.kinematics import dynamics as dyn
    from mer_data.kinematics.collision import shape_points
    from mer_data.kinematics.support import CONTACT_HEIGHT, support_kind

    d = dyn.demand(inputs.model, dyn.body_wrenches(inputs.model, pos, rot, inputs.fps))
    M = float(d.mass)
    zmp = torch.nan_to_num(dyn.zmp(d)).numpy()
    verts = shape_points(inputs.geometry, pos, rot, "vertices").numpy()
    low = verts[..., 2] < CONTACT_HEIGHT
    kind = support_kind(np.asarray(inputs.geometry.foot), low)
    T = len(kind)
    valid = np.zeros(T, bool)
    valid[dyn.EDGE : T - dyn.EDGE] = True
    polys = [polygon_rows(verts[t][low[t]][:, :2]) if kind[t] > 0 and valid[t] else None for t in range(T)]
    f = d.force.numpy() / M
    return zmp, d.com[:, 2].numpy(), f[:, 2], f[:, :2], polys, (kind == 0) & valid, verts[..., 2].reshape(T, -1).min(-1)


def solve_path(inputs, cfg, graph, eta, goal, q, base_pos, base_rot, *, smooth: float, tol: float, goal_rot=None, rot_mask=None,
               physics=None):  # fmt: skip
    """The two-stage balance (module docstring) of :class:`~.balance_term.BalanceInputs` ``inputs``: ``rounds``
    of (the path correction, then ``iters`` whole-window Levenberg-Marquardt iterations on the goals it moved);
    arguments and return as :meth:`~.balance_term.BalanceInputs.solve` (``physics``: the solve's physical terms,
    kept in the iterations)."""
    from mer_models.batch import batch_fk

    from .ik import coupled_lm_ik

    c = inputs.cfg
    B, T, Jt = q.shape
    J = len(inputs.mass)
    geo = inputs.geometry
    feet = sorted({int(n) for n, f in zip(np.asarray(geo.node), np.asarray(geo.foot)) if f > 0})
    eye = torch.eye(3, dtype=q.dtype, device=q.device).expand(B, 1, 3, 3)
    stand, _ = batch_fk(graph, torch.zeros_like(q[:, :1]), torch.zeros_like(base_pos[:, :1]), eye)
    parents = graph.parents.cpu().numpy()
    node_w = np.stack([leg_weights(parents[b], feet, stand[b, 0, :, 2].double().cpu().numpy()) for b in range(B)])
    gain = [com_gain(inputs.mass, node_w[b]) for b in range(B)]
    goal_w = torch_weights(eta, torch.as_tensor(node_w, dtype=eta.dtype, device=eta.device))  # (B, Jr)
    total = torch.zeros(B, T, 3, dtype=goal.dtype, device=goal.device)
    gkw = {"goal_rot": goal_rot, "rot_mask": rot_mask}
    if c.physics_gain == 0:
        physics = None
    if physics is not None and c.physics_gain != 1:  # the floor and the joint speeds held harder while the legs take up the path
        import dataclasses

        pc = physics.cfg
        physics = dataclasses.replace(physics, cfg=dataclasses.replace(pc, w_floor=pc.w_floor * c.physics_gain,
                                                                       w_speed=pc.w_speed * c.physics_gain))  # fmt: skip
    for _ in range(c.rounds):
        pos, rot = batch_fk(graph, q, base_pos, base_rot)
        step = torch.zeros_like(total)
        for b in range(B):
            zmp, cz, fz, acc, polys, flight, low = _frames(inputs, pos[b, :, :J].double().cpu(), rot[b, :, :J].double().cpu())
            out = [float(np.max(n @ zmp[t] + d)) for t, (n, d) in ((t, p) for t, p in enumerate(polys) if p is not None)]
            log.debug("balance round %d, sample %d: %d of %d contact frames with the ZMP > 2 cm out (median %.3f m)", _, b,
                      int((np.asarray(out) > 0.02).sum()), len(out), float(np.median(out)) if out else 0.0)  # fmt: skip
            prior = total[b, :, :2].double().cpu().numpy() * gain[b]
            dc = path_correction(zmp, cz, fz, polys, flight, acc, inputs.fps, margin=c.margin, smooth=c.path_smooth,
                                 flight_weight=c.flight_weight, prior=prior)  # fmt: skip
            step[b, :, :2] = torch.as_tensor(dc / gain[b], dtype=goal.dtype, device=goal.device)
            if c.hover is not None:  # the whole body moved vertically: jumps ballistic, hovering feet put down
                hov, jump = flight_phases(flight, low, c.hover, fz)
                contact = np.asarray([p is not None for p in polys])
                dz = vertical_correction(low, fz, contact, hov, jump, float(np.mean(cz)), inputs.fps, top=c.top, smooth=c.path_smooth,
                                         flight_weight=c.flight_weight, prior=total[b, :, 2].double().cpu().numpy())  # fmt: skip
                step[b, :, 2] = torch.as_tensor(dz, dtype=goal.dtype, device=goal.device)
        total = total + step
        base_pos = base_pos + step
        lift = torch.zeros_like(total)
        lift[..., 2] = total[..., 2]  # every goal, the feet's too, moves with the vertical correction
        moved = goal + goal_w[:, None, :, None] * (total - lift)[:, :, None, :] + lift[:, :, None, :]
        q, base_pos, base_rot = coupled_lm_ik(cfg, graph, eta, moved, q, base_pos, base_rot, iters=c.iters, smooth=smooth, tol=tol,
                                              physics=physics, **gkw)  # fmt: skip
    return q, base_pos, base_rot
