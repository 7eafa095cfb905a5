"""The model's view of motion features: a canonical frame per window and the diffusion-space scaling.

**Canonical frame.** Each window is expressed in the frame whose origin is the first frame's base
position on the ground (x, y, z = 0) and whose x axis is the reference base's heading at the first
frame: a rigid motion about world z, the same for the reference, its scaled key points and the
target. The model therefore sees every window facing +x from the origin (heading and position
invariance by construction); outputs are mapped back to the world exactly.

**Base orientation.** Rotation vectors are unwrapped along time (:func:`unwrap_rotvec`), so a
window that turns through 180 degrees has no jump from +pi to -pi. With
``ModelConfig.goal_frame_rotation`` the diffusion space holds the base orientation relative to the
base's orientation goal instead: ``R = R_goal Exp(delta)``, ``delta = Log(R_goal^T R)`` in the goal's
frame (:func:`rotation_in_frame`, :func:`rotation_from_frame`).

**Diffusion space.** Features are divided per channel by fixed scales (angles 1 rad, positions
``pos_scale`` m, velocities ``vel_scale`` m/s): no data statistics, so any robot and any dataset
share one normalisation and nothing can silently go missing from a checkpoint.
"""

from __future__ import annotations

import math

import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from mer_models.batch import rot_z, yaw_of
from mer_models.config import ModelConfig

__all__ = [
    "canonical_rotation",
    "base_origin",
    "transform_features",
    "transform_points",
    "unwrap_rotvec",
    "rotation_in_frame",
    "rotation_from_frame",
    "channel_scales",
    "normalize",
    "denormalize",
]


def canonical_rotation(reference: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) canonical ← world rotation: minus the heading of the reference base at frame 0.

    ``reference``: (B, T, J, 9) features.
    """
    rot0 = axis_angle_to_matrix(reference[:, 0, 0, 0:3])
    return rot_z(-yaw_of(rot0))


def base_origin(feats: torch.Tensor) -> torch.Tensor:
    """(B, 3) the first frame's base position dropped to the ground (z = 0)."""
    o = feats[:, 0, 0, 3:6].clone()
    o[:, 2] = 0
    return o


def transform_points(points: torch.Tensor, rot: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """``rot @ (p - origin)`` for points (B, T, J, 3); rot (B, 3, 3); origin (B, 3)."""
    return torch.einsum("bij,btnj->btni", rot, points - origin[:, None, None, :])


def inverse_points(points: torch.Tensor, rot: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`transform_points`."""
    return torch.einsum("bji,btnj->btni", rot, points) + origin[:, None, None, :]


def transform_features(
    feats: torch.Tensor, rot: torch.Tensor, origin: torch.Tensor, *, inverse: bool = False
) -> torch.Tensor:
    """Apply the rigid motion ``p -> rot (p - origin)`` to (B, T, J, 9) features (or its inverse).

    Positions and velocities rotate (positions also shift); joint angles are unchanged; the base
    orientation becomes ``rot @ R_base``, re-expressed as a rotation vector unwrapped along time.
    """
    out = feats.clone()
    pos = torch.cat([feats[:, :, :1, 3:6], feats[:, :, 1:, 1:4]], dim=2)
    vel = torch.cat([feats[:, :, :1, 6:9], feats[:, :, 1:, 4:7]], dim=2)
    if inverse:
        pos = inverse_points(pos, rot, origin)
        vel = torch.einsum("bji,btnj->btni", rot, vel)
        r = rot.transpose(-1, -2)
    else:
        pos = transform_points(pos, rot, origin)
        vel = torch.einsum("bij,btnj->btni", rot, vel)
        r = rot
    base_rot = r[:, None] @ axis_angle_to_matrix(feats[:, :, 0, 0:3])
    out[:, :, 0, 0:3] = unwrap_rotvec(matrix_to_axis_angle(base_rot))
    out[:, :, :1, 3:6] = pos[:, :, :1]
    out[:, :, 1:, 1:4] = pos[:, :, 1:]
    out[:, :, :1, 6:9] = vel[:, :, :1]
    out[:, :, 1:, 4:7] = vel[:, :, 1:]
    return out


def unwrap_rotvec(r: torch.Tensor) -> torch.Tensor:
    """Make rotation vectors (B, T, 3) continuous along T.

    ``r`` and ``r - 2 pi k r/|r|`` are the same rotation; each frame takes the representative
    closest to the previous frame's (the first frame is kept). Pure function, no gradient issue:
    it adds a piecewise-constant multiple of the unit axis.
    """
    if r.shape[1] < 2:
        return r
    out = [r[:, 0]]
    for t in range(1, r.shape[1]):
        cur = r[:, t]
        prev = out[-1]
        n = cur.norm(dim=-1, keepdim=True)
        unit = cur / n.clamp_min(1e-9)
        # candidate k in {-1, 0, 1, 2...}: pick the k minimising |cur + 2 pi k unit - prev|
        proj = ((prev - cur) * unit).sum(-1, keepdim=True)
        k = torch.round(proj / (2 * math.pi))
        k = torch.where(n < 1e-6, torch.zeros_like(k), k)
        out.append(cur + 2 * math.pi * k * unit)
    return torch.stack(out, dim=1)


def rotation_in_frame(rotvec: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """``delta = Log(frame^T Exp(rotvec))``, unwrapped along time: (B, T, 3) rotation vectors [rad] and
    (B, T, 3, 3) frames → (B, T, 3), the rotation seen from ``frame`` (|delta| is the geodesic angle
    between the two at the first frame)."""
    rel = frame.transpose(-1, -2) @ axis_angle_to_matrix(rotvec)
    return unwrap_rotvec(matrix_to_axis_angle(rel))


def rotation_from_frame(delta: torch.Tensor, frame: torch.Tensor) -> torch.Tensor:
    """``frame Exp(delta)``: (..., 3) [rad] and (..., 3, 3) → (..., 3, 3), the inverse of :func:`rotation_in_frame`."""
    return frame @ axis_angle_to_matrix(delta)


def channel_scales(cfg: ModelConfig, J: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """(J, 9) divisors from physical features to the diffusion space."""
    ps, vs = cfg.pos_scale, cfg.vel_scale
    base = [1.0, 1.0, 1.0, ps, ps, ps, vs, vs, vs]
    joint = [1.0, ps, ps, ps, vs, vs, vs, 1.0, 1.0]
    s = torch.tensor([base] + [joint] * (J - 1), dtype=dtype, device=device)
    return s


def normalize(feats: torch.Tensor, cfg: ModelConfig) -> torch.Tensor:
    """Physical features (..., J, 9) → diffusion space."""
    return feats / channel_scales(cfg, feats.shape[-2], feats.device, feats.dtype)


def denormalize(x: torch.Tensor, cfg: ModelConfig) -> torch.Tensor:
    """Diffusion space (..., J, 9) → physical features."""
    return x * channel_scales(cfg, x.shape[-2], x.device, x.dtype)
