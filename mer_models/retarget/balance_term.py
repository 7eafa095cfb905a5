"""A prototype of the balance term (issue 54, deliverable 2): residuals a whole-window solver can
drive to zero, and their Jacobian. Not wired into the optimiser (``mer_models/solver/``); the
lead integrates it there.

Residuals per frame, from the motion's own dynamics (:mod:`mer_data.kinematics.dynamics`):

* **ZMP in the stance foot** (single-support frames): for each edge ``n . p + d <= 0`` of the stance
  foot's support polygon (fixed from the kinematic solution: :func:`stance_planes`), the ZMP's
  excess ``relu(n . p + d - tol)`` written without the division by ``f_z``:
  ``relu(n . (c_xy f_z - c_z f_xy - (n_y, -n_x)) + (d - tol) f_z) / (M g)`` [m] (equal to the excess
  where ``f_z = M g``; smooth in the motion, and a pulling frame cannot hide behind ``f_z < 0``);
* **ballistic flight**: ``f / (M g)`` (3,) in flight frames (0 for a ballistic centre of mass).

With ``filtered=False, spin=False`` (the defaults here) each frame's residual depends on its two
neighbours only (the centre of mass' second difference): the block-tridiagonal solver's coupling.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from mer_data.kinematics import dynamics as dyn
from mer_data.kinematics.fk import fk_skeleton

from .balance import _hull, balance_frames

__all__ = ["stance_planes", "balance_residual", "balance_jacobian"]


def stance_planes(pos: np.ndarray, rot: np.ndarray, fps: float, skel: Any, masses: Any, geometry: Any,
                  max_edges: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The stance foot's support polygon of every single-support frame of a (kinematic) motion.

    Returns:
        planes: (F, E, 3) edges ``[n_x, n_y, d]`` with ``n . p + d <= 0`` inside (padded with
            ``[0, 0, -1]``, never violated); single: (F,) bool; flight: (F,) bool.
    """
    from mer_data.kinematics.collision import shape_points

    b = balance_frames(pos, rot, fps, skel, masses, geometry, torques=False)
    verts = shape_points(geometry, torch.as_tensor(pos), torch.as_tensor(rot), "vertices").numpy()
    F = len(pos)
    planes = np.tile(np.array([0.0, 0.0, -1.0]), (F, max_edges, 1))
    single = b["support"] == 1
    for f in np.flatnonzero(single):
        pts = verts[f][verts[f][..., 2] < 0.02][:, :2]
        h = pts[_hull(pts)]
        if len(h) < 3:
            single[f] = False
            continue
        e = np.roll(h, -1, axis=0) - h  # counter-clockwise: the outward normal is (e_y, -e_x)
        n = np.stack([e[:, 1], -e[:, 0]], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        k = min(len(n), max_edges)
        planes[f, :k, :2] = n[:k]
        planes[f, :k, 2] = -(n[:k] * h[:k]).sum(-1)
    return planes, single, b["support"] == 0


def balance_residual(q: torch.Tensor, base_pos: torch.Tensor, base_rot: torch.Tensor, st: Any, skel: Any, masses: Any,
                     fps: float, planes: torch.Tensor, single: torch.Tensor, flight: torch.Tensor, tol: float = 0.01,
                     filtered: bool = False, spin: bool = False) -> torch.Tensor:  # fmt: skip
    """(F, E + 3) residuals [m] (module docstring) of the motion ``q`` (F, J), ``base_pos`` (F, 3),
    ``base_rot`` (F, 3, 3) of the skeleton tensors ``st``; zero outside single support and flight."""
    pos, rot = fk_skeleton(st, q, base_pos, base_rot=base_rot)
    w = dyn.body_wrenches(masses, pos, rot, fps, filtered=filtered, spin=spin)
    d = dyn.demand(masses, w)
    weight = d.mass * dyn.GRAVITY
    f, n, c = d.force, d.moment, d.com
    arm = c[:, :2] * f[:, 2:3] - c[:, 2:3] * f[:, :2] - torch.stack([n[:, 1], -n[:, 0]], -1)  # f_z p
    excess = torch.relu((planes[..., :2] * arm[:, None]).sum(-1) + (planes[..., 2] - tol) * f[:, 2:3]) / weight
    zmp_r = excess * single[:, None].to(excess.dtype)
    flight_r = f / weight * flight[:, None].to(f.dtype)
    return torch.cat([zmp_r, flight_r], -1)


def balance_jacobian(q: torch.Tensor, base_pos: torch.Tensor, base_rot: torch.Tensor, *args, **kw) -> tuple[torch.Tensor, torch.Tensor]:
    """Residuals (F, R) and their Jacobian with respect to ``q`` and the base position:
    (F, R, F, J + 3) (dense; banded: frame ``t`` depends on frames ``t - 1 .. t + 1`` with the defaults)."""

    def fn(qq, bp):
        return balance_residual(qq, bp, base_rot, *args, **kw)

    r = fn(q, base_pos)
    jq, jb = torch.autograd.functional.jacobian(fn, (q, base_pos), vectorize=True)
    return r, torch.cat([jq, jb], -1)
