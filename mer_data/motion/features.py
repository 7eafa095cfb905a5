"""Per-joint motion features (paper, Motion representation): ``(T, J, 9)``.

Layout of the last axis (``D = 9``):

* base (node 0): ``[axis-angle r0 (3), position p0 (3), linear velocity v0 (3)]``
* every other node: ``[angle q (1), global position p (3), linear velocity v (3), 0, 0]``
  (sites have ``q = 0``).

Positions are world positions [m] from :func:`mer_data.kinematics.fk.forward_kinematics`; axis-angle is the
base orientation as a rotation vector [rad]; velocities [m/s] are finite differences at ``fps``
(:func:`finite_difference`: second-order central differences inside, second-order one-sided
differences at the two ends, i.e. ``numpy.gradient(..., edge_order=2)``).
"""

from __future__ import annotations

import numpy as np
import torch

from mer_data.kinematics.fk import SkeletonTensors, apply_mimic, fk_skeleton, skeleton_tensors
from mer_data.kinematics.rotations import axis_angle_to_quat, quat_to_axis_angle
from mer_data.skeleton import Skeleton

__all__ = [
    "source_features",
    "FEATURE_DIM",
    "finite_difference",
    "motion_features",
    "split_features",
]

FEATURE_DIM = 9


def finite_difference(x: torch.Tensor, fps: float, dim: int = -3) -> torch.Tensor:
    """Time derivative along ``dim`` [unit/s], second order everywhere: ``torch.gradient(edge_order=2)``.

    Interior: ``(x[t+1] - x[t-1]) / 2h``; ends: ``(-3 x0 + 4 x1 - x2) / 2h`` and its mirror, as
    ``numpy.gradient(..., edge_order=2)`` (tests/data/motion/test_windows.py). ``torch.gradient`` needs 3 frames
    for that; with 2 this is the first-order difference, with fewer zeros. Differentiable (autograd).
    """
    T = x.shape[dim]
    if T < 2:
        return torch.zeros_like(x)
    return torch.gradient(x, spacing=1.0 / fps, dim=dim, edge_order=2 if T > 2 else 1)[0]


def motion_features(
    st: SkeletonTensors,
    base_pos: torch.Tensor,
    base_quat: torch.Tensor,
    q: torch.Tensor,
    fps: float = 30.0,
    offsets: torch.Tensor | None = None,
) -> torch.Tensor:
    """Features of a motion: (..., T, 3), (..., T, 4) wxyz, (..., T, J) → (..., T, J, 9).

    ``q`` holds one angle per node (base and site entries are ignored and written as 0). Mimic
    joints are recomputed from their masters. ``offsets`` overrides the skeleton's (augmented copy).
    """
    pos, _ = fk_skeleton(st, q, base_pos, base_quat=base_quat, offsets=offsets)
    vel = finite_difference(pos, fps, dim=-3)
    J = q.shape[-1]
    feats = pos.new_zeros(pos.shape[:-1] + (FEATURE_DIM,))
    revolute = (st.axes.abs().sum(-1) > 0).to(q.dtype)
    q_eff = apply_mimic(q, st.mimic_source, st.mimic_multiplier, st.mimic_offset) * revolute
    feats[..., 1:, 0] = q_eff[..., 1:]
    feats[..., 1:, 1:4] = pos[..., 1:, :]
    feats[..., 1:, 4:7] = vel[..., 1:, :]
    feats[..., 0, 0:3] = quat_to_axis_angle(base_quat)
    feats[..., 0, 3:6] = pos[..., 0, :]
    feats[..., 0, 6:9] = vel[..., 0, :]
    assert feats.shape[-2] == J
    return feats


def source_features(base_pos: np.ndarray, base_quat: np.ndarray, q: np.ndarray, skel: Skeleton, fps: float) -> np.ndarray:
    """(F, J, 9) float64 features of a motion given as arrays: base position (F, 3) [m], base
    orientation (F, 4) wxyz, one angle per node (F, J) [rad], at ``fps`` [Hz]."""
    st = skeleton_tensors(skel, torch.float64)
    f = motion_features(st, torch.from_numpy(np.asarray(base_pos, np.float64)), torch.from_numpy(np.asarray(base_quat, np.float64)),
                        torch.from_numpy(np.asarray(q, np.float64)), fps)  # fmt: skip
    return f.numpy()


def split_features(feats: torch.Tensor) -> dict[str, torch.Tensor]:
    """Inverse view of :func:`motion_features`.

    Returns ``base_rotvec`` (..., T, 3), ``base_quat`` (..., T, 4) wxyz, ``q`` (..., T, J) (0 at the
    base), ``pos`` (..., T, J, 3), ``vel`` (..., T, J, 3).
    """
    q = torch.cat([torch.zeros_like(feats[..., :1, 0]), feats[..., 1:, 0]], dim=-1)
    pos = torch.cat([feats[..., :1, 3:6], feats[..., 1:, 1:4]], dim=-2)
    vel = torch.cat([feats[..., :1, 6:9], feats[..., 1:, 4:7]], dim=-2)
    rotvec = feats[..., 0, 0:3]
    return {"base_rotvec": rotvec, "base_quat": axis_angle_to_quat(rotvec), "q": q, "pos": pos, "vel": vel}
