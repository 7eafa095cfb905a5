"""Rigid-body dynamics of a skeleton motion: centre of mass, centroidal momentum, the contact wrench
the motion demands, its zero-moment point, and the joint torques (linear in the contact forces).

Works on a :class:`~mer_data.robots.inertia.MassModel` (each node's mass, centre of mass and inertia
in the node frame) and node frames from FK over F frames at ``fps``: positions ``pos`` (F, J, 3) [m],
rotations ``rot`` (F, J, 3, 3). Torch, differentiable; world z up, gravity ``(0, 0, -GRAVITY)``.

Derivatives are **central differences** of each body's trajectory: the velocity of its centre of
mass ``x_i`` and its angular velocity ``w_i = vee(log(R_i(t+1) R_i(t-1)^T)) fps / 2``, then its
acceleration and the rate of its spin momentum ``h_i = R_i I_i R_i^T w_i`` as central differences
again. Each body then needs the force ``F_i = m_i (a_i - g)`` and the moment about its centre of
mass ``N_i = dh_i/dt``. **One smoothing filter**: ``F_i`` and ``N_i`` are averaged over time with
the 5-tap binomial kernel (1, 4, 6, 4, 1) / 16 (half power at 0.18 of the frame rate: 5.5 Hz at
30 frames/s; a constant or linear acceleration passes unchanged), edges repeated. The first and
last :data:`EDGE` frames have no central differences; their values repeat their neighbours'.

From these:

* the demanded contact wrench: force ``f = sum F_i = M (c'' - g)``, moment about the centre of
  mass ``n = sum (x_i - c) x F_i + N_i = dL/dt`` (the rate of the centroidal angular momentum);
* the zero-moment point on the floor ``z = h``: ``p_x = c_x - ((c_z - h) f_x + n_y) / f_z``,
  ``p_y = c_y - ((c_z - h) f_y - n_x) / f_z`` (undefined where ``f_z <= 0``);
* joint torques: ``tau_j = a_j . sum_{i below j} (N_i + (x_i - o_j) x F_i)`` minus, for each
  contact force ``f_k`` at ``p_k`` on a node below ``j``, ``a_j . ((p_k - o_j) x f_k)``
  (``a_j``, ``o_j``: the joint's world axis and centre): the torque the joint's motor must give.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import torch

__all__ = ["GRAVITY", "EDGE", "BINOMIAL", "Demand", "body_wrenches", "demand", "zmp", "joint_torques", "contact_torque_map",
           "centroidal_momentum", "smooth", "subtree_matrix"]  # fmt: skip

GRAVITY = 9.81  # [m/s^2]
#: Frames at each end without central differences of the momentum rate (two stencils of 3).
EDGE = 2
#: The smoothing kernel over frames.
BINOMIAL = (1.0, 4.0, 6.0, 4.0, 1.0)


def _t(a: Any, like: torch.Tensor) -> torch.Tensor:
    if isinstance(a, torch.Tensor):
        return a.to(dtype=like.dtype, device=like.device)
    return torch.tensor(a, dtype=like.dtype, device=like.device)  # a copy: the model's arrays are read-only


def _pad_edges(x: torch.Tensor, n: int) -> torch.Tensor:
    """(F - 2n, ...) → (F, ...): the first and last rows repeated ``n`` times."""
    return torch.cat([x[:1].expand(n, *x.shape[1:]), x, x[-1:].expand(n, *x.shape[1:])]) if n else x


def _central(x: torch.Tensor, fps: float) -> torch.Tensor:
    """Central difference over frames (dim 0), edges repeated: (F, ...) → (F, ...)."""
    return _pad_edges((x[2:] - x[:-2]) * (fps / 2), 1)


def smooth(x: torch.Tensor) -> torch.Tensor:
    """The binomial filter (:data:`BINOMIAL`) over frames (dim 0), edges repeated: (F, ...) → (F, ...)."""
    if x.shape[0] < 2:
        return x
    w = _t(BINOMIAL, x) / sum(BINOMIAL)
    h = len(BINOMIAL) // 2
    xp = torch.cat([x[:1].expand(h, *x.shape[1:]), x, x[-1:].expand(h, *x.shape[1:])])
    F = x.shape[0]
    return sum(w[k] * xp[k : k + F] for k in range(len(BINOMIAL)))


def _vee_log(r: torch.Tensor) -> torch.Tensor:
    """Rotation vector of (..., 3, 3) rotations [rad] (differentiable away from pi)."""
    tr = (r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1) / 2
    angle = torch.acos(tr.clamp(-1 + 1e-12, 1 - 1e-12))
    v = torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    s = torch.sin(angle)
    scale = torch.where(s.abs() > 1e-6, angle / (2 * s.where(s.abs() > 1e-6, torch.ones_like(s))), 0.5 + angle**2 / 12)
    return v * scale[..., None]


def _world(model: Any, pos: torch.Tensor, rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Masses (J,), world centres of mass (F, J, 3) and world inertias (F, J, 3, 3)."""
    m = _t(model.mass, pos)
    x = pos + torch.einsum("fjab,jb->fja", rot, _t(model.com, pos))
    inertia = rot @ _t(model.inertia, pos) @ rot.transpose(-1, -2)
    return m, x, inertia


def _angular_velocity(rot: torch.Tensor, fps: float) -> torch.Tensor:
    """World angular velocity of every node (F, J, 3) [rad/s] by central differences."""
    if rot.shape[0] < 3:
        return rot.new_zeros(*rot.shape[:-1])
    rel = rot[2:] @ rot[:-2].transpose(-1, -2)
    return _pad_edges(_vee_log(rel) * (fps / 2), 1)


class BodyWrenches(NamedTuple):
    """What each node's bodies need, per frame: ``force`` (F, J, 3) [N] (gravity included),
    ``moment`` (F, J, 3) [N m] about their centre of mass ``com`` (F, J, 3) [m]."""

    force: torch.Tensor
    moment: torch.Tensor
    com: torch.Tensor


def body_wrenches(model: Any, pos: torch.Tensor, rot: torch.Tensor, fps: float, filtered: bool = True,
                  spin: bool = True) -> BodyWrenches:  # fmt: skip
    """Each node's demanded force and moment (module docstring), smoothed unless ``filtered=False``.

    ``spin=False`` leaves out the bodies' own spin momentum rates ``N_i`` (their centres of mass still
    count): every frame then depends on its two neighbours only (a solver's three-frame coupling)."""
    if pos.shape[0] < 2 * EDGE + 1:
        raise ValueError(f"the dynamics need at least {2 * EDGE + 1} frames, got {pos.shape[0]}")
    m, x, inertia = _world(model, pos, rot)
    acc = _pad_edges((x[2:] - 2 * x[1:-1] + x[:-2]) * fps**2, 1)
    g = _t([0.0, 0.0, -GRAVITY], pos)
    force = m[:, None] * (acc - g)
    if spin:
        h = (inertia @ _angular_velocity(rot, fps)[..., None])[..., 0]
        moment = _pad_edges((h[3:-1] - h[1:-3]) * (fps / 2), EDGE)  # h at 0 and F-1 repeats its neighbour's
    else:
        moment = torch.zeros_like(force)
    if filtered:
        force, moment = smooth(force), smooth(moment)
    return BodyWrenches(force, moment, x)


class Demand(NamedTuple):
    """The contact wrench a motion demands, per frame: ``force`` (F, 3) [N], ``moment`` (F, 3)
    [N m] about the centre of mass ``com`` (F, 3) [m]; ``mass`` [kg]."""

    force: torch.Tensor
    moment: torch.Tensor
    com: torch.Tensor
    mass: torch.Tensor


def demand(model: Any, w: BodyWrenches) -> Demand:
    """Sum the bodies' wrenches into the demanded contact wrench about the centre of mass."""
    m = _t(model.mass, w.force)
    mass = m.sum()
    c = (m[:, None] * w.com).sum(-2) / mass
    n = torch.linalg.cross(w.com - c[:, None], w.force, dim=-1).sum(-2) + w.moment.sum(-2)
    return Demand(w.force.sum(-2), n, c, mass)


def zmp(d: Demand, floor: float = 0.0) -> torch.Tensor:
    """(F, 2) zero-moment point on the floor ``z = floor`` [m]; NaN where ``f_z <= 0``."""
    f, n, c = d.force, d.moment, d.com
    fz = f[:, 2]
    ok = fz > 0
    fz = torch.where(ok, fz, torch.ones_like(fz))
    hgt = c[:, 2] - floor
    px = c[:, 0] - (hgt * f[:, 0] + n[:, 1]) / fz
    py = c[:, 1] - (hgt * f[:, 1] - n[:, 0]) / fz
    p = torch.stack([px, py], -1)
    return torch.where(ok[:, None], p, torch.full_like(p, float("nan")))


def centroidal_momentum(model: Any, pos: torch.Tensor, rot: torch.Tensor, fps: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Centre of mass (F, 3) [m], linear momentum (F, 3) [kg m/s] and angular momentum about the
    centre of mass (F, 3) [kg m^2/s], by central differences (unfiltered; edges repeated)."""
    m, x, inertia = _world(model, pos, rot)
    v = _central(x, fps)
    c = (m[:, None] * x).sum(-2) / m.sum()
    vc = (m[:, None] * v).sum(-2) / m.sum()
    spin = (inertia @ _angular_velocity(rot, fps)[..., None])[..., 0]
    orbit = torch.linalg.cross(x - c[:, None], m[:, None] * (v - vc[:, None]), dim=-1)
    return c, m.sum() * vc, (orbit + spin).sum(-2)


def subtree_matrix(parents: Any, J: int, like: torch.Tensor) -> torch.Tensor:
    """(J, J) ``S[j, i]`` = 1 where node ``i`` is ``j`` or below it."""
    s = torch.eye(J, dtype=like.dtype, device=like.device)
    par = [int(p) for p in parents]
    for i in range(J - 1, 0, -1):
        s[par[i]] = s[par[i]] + s[i]
    return s.clamp_max(1)


def _joint_axes(skel_axes: Any, rot: torch.Tensor) -> torch.Tensor:
    """World axis of every node's joint (F, J, 3): the node's rotation applied to its rest axis."""
    return torch.einsum("fjab,jb->fja", rot, _t(skel_axes, rot))


def joint_torques(skel: Any, w: BodyWrenches, pos: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """(F, J) torque each node's joint must give with no contact force [N m] (0 at base and sites)."""
    J = pos.shape[-2]
    s = subtree_matrix(skel.parents, J, pos)  # (J, J)
    own = w.moment + torch.linalg.cross(w.com, w.force, dim=-1)  # moment about the world origin
    tot_m = torch.einsum("ji,fia->fja", s, own)
    tot_f = torch.einsum("ji,fia->fja", s, w.force)
    about = tot_m - torch.linalg.cross(pos, tot_f, dim=-1)  # about each joint's centre
    return (about * _joint_axes(skel.axes, rot)).sum(-1)


def contact_torque_map(skel: Any, pos: torch.Tensor, rot: torch.Tensor, points: torch.Tensor, nodes: torch.Tensor,
                       subtree: torch.Tensor | None = None) -> torch.Tensor:  # fmt: skip
    """How contact forces change the joint torques, for one frame: ``tau = tau0 - A @ f.flatten()``.

    Args:
        pos, rot: (J, 3), (J, 3, 3) node frames of the frame; points (K, 3) contact points [m]
            on ``nodes`` (K,); subtree: :func:`subtree_matrix` of the skeleton, if at hand.

    Returns:
        A: (J, 3K) [m]; row ``j``, block ``k`` is ``a_j x (p_k - o_j)`` where ``nodes[k]`` is ``j``
        or below it, else 0.
    """
    J, K = pos.shape[0], points.shape[0]
    s = (subtree_matrix(skel.parents, J, pos) if subtree is None else subtree)[:, nodes]  # (J, K)
    a = _joint_axes(skel.axes, rot[None])[0]  # (J, 3)
    arm = points[None] - pos[:, None]  # (J, K, 3)
    blk = torch.linalg.cross(a[:, None].expand(J, K, 3), arm, dim=-1) * s[..., None]
    return blk.reshape(J, 3 * K)
