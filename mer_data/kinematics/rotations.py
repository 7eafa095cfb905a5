"""Rotation conversions in torch (work on CPU or GPU, batched over leading dims, differentiable).

Convention inside mer: quaternions are **scalar-first (w, x, y, z)**, unit norm, Hamilton product,
active rotations; rotation matrices map body coordinates to world coordinates (``v_w = R @ v_b``).
Files that store scalar-last quaternions (LAFAN1 CSV: x, y, z, w) are converted at the edge with
:func:`xyzw_to_wxyz` / :func:`wxyz_to_xyzw`.
"""

from __future__ import annotations

import torch

__all__ = [
    "xyzw_to_wxyz",
    "wxyz_to_xyzw",
    "quat_normalize",
    "quat_to_matrix",
    "matrix_to_quat",
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "quat_to_axis_angle",
    "axis_angle_to_quat",
    "quat_multiply",
    "quat_conjugate",
    "quat_slerp",
    "quat_canonical",
    "rotation_angle_between",
]


def xyzw_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) scalar-last → scalar-first."""
    return torch.cat([q[..., 3:4], q[..., :3]], dim=-1)


def wxyz_to_xyzw(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) scalar-first → scalar-last."""
    return torch.cat([q[..., 1:4], q[..., 0:1]], dim=-1)


def quat_normalize(q: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def quat_canonical(q: torch.Tensor) -> torch.Tensor:
    """Flip sign so that w >= 0 (q and -q are the same rotation)."""
    return torch.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a ⊗ b of (..., 4) wxyz quaternions (apply b, then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) wxyz (normalized here) → (..., 3, 3)."""
    q = quat_normalize(q)
    w, x, y, z = q.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
        2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
        2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation → (..., 4) wxyz with w >= 0 (numerically stable branch selection)."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # four candidate (unnormalized) quaternions, each accurate where its diagonal term is largest
    cands = torch.stack(
        [
            torch.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], -1),
            torch.stack([m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20], -1),
            torch.stack([m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21], -1),
            torch.stack([m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22], -1),
        ],
        dim=-2,
    )
    diag = torch.stack([m00 + m11 + m22, m00, m11, m22], -1)
    best = diag.argmax(-1, keepdim=True)
    q = torch.gather(cands, -2, best[..., None].expand(best.shape[:-1] + (1, 4))).squeeze(-2)
    return quat_canonical(quat_normalize(q))


def axis_angle_to_matrix(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) rotation vector (axis * angle [rad]) → (..., 3, 3), Rodrigues; smooth at 0."""
    theta2 = (v * v).sum(-1, keepdim=True)
    theta = theta2.clamp_min(1e-30).sqrt()
    small = theta2 < 1e-12
    # sin(t)/t and (1-cos t)/t^2 with Taylor fallbacks near zero
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2.clamp_min(1e-30))
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(v.shape[:-1] + (3, 3))
    eye = torch.eye(3, dtype=v.dtype, device=v.device).expand(k.shape)
    return eye + a[..., None] * k + b[..., None] * (k @ k)


def quat_to_axis_angle(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) wxyz → (..., 3) rotation vector with angle in [0, pi]."""
    q = quat_canonical(quat_normalize(q))
    w = q[..., :1].clamp(-1.0, 1.0)
    xyz = q[..., 1:]
    s = xyz.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(s, w)
    scale = torch.where(s < 1e-8, 2.0 / w.clamp_min(1e-8), angle / s.clamp_min(1e-30))
    return xyz * scale


def axis_angle_to_quat(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) rotation vector → (..., 4) wxyz."""
    theta2 = (v * v).sum(-1, keepdim=True)
    theta = theta2.clamp_min(1e-30).sqrt()
    small = theta2 < 1e-12
    half_sinc = torch.where(small, 0.5 - theta2 / 48, torch.sin(theta / 2) / theta)
    return torch.cat([torch.cos(theta / 2), v * half_sinc], dim=-1)


def matrix_to_axis_angle(m: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) → (..., 3) rotation vector."""
    return quat_to_axis_angle(matrix_to_quat(m))


def quat_slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation along the shorter arc. q0, q1: (..., 4) wxyz; t: (...) in [0, 1]."""
    q0 = quat_normalize(q0)
    q1 = quat_normalize(q1)
    dot = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(dot < 0, -q1, q1)
    dot = dot.abs().clamp(max=1.0)
    t = t[..., None]
    omega = torch.acos(dot)
    so = torch.sin(omega)
    near = so < 1e-6
    w0 = torch.where(near, 1 - t, torch.sin((1 - t) * omega) / so.clamp_min(1e-12))
    w1 = torch.where(near, t, torch.sin(t * omega) / so.clamp_min(1e-12))
    return quat_normalize(w0 * q0 + w1 * q1)


def rotation_angle_between(r_a: torch.Tensor, r_b: torch.Tensor) -> torch.Tensor:
    """Geodesic angle [rad] between (..., 3, 3) rotations, in [0, pi]."""
    rel = r_a.transpose(-1, -2) @ r_b
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    # atan2 form is accurate near 0 and pi, unlike acos
    skew = torch.stack(
        [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1
    )
    sin = skew.norm(dim=-1) / 2
    return torch.atan2(sin, cos)
