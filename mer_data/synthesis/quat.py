"""Small numpy quaternion helpers (w, x, y, z; unit) for the synthetic motion generator."""

from __future__ import annotations

import numpy as np

__all__ = ["qmul", "qaxis", "qrotvec", "qslerp", "qmatrix", "qangle", "qcontinuous"]


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)  # fmt: skip


def qaxis(axis: int, angle: np.ndarray | float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about coordinate axis 0 (x), 1 (y) or 2 (z): (..., 4)."""
    angle = np.asarray(angle, float)
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(angle / 2)
    q[..., 1 + axis] = np.sin(angle / 2)
    return q


def qrotvec(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors [rad] -> (..., 4) quaternions."""
    angle = np.linalg.norm(v, axis=-1)
    scale = np.where(angle > 1e-12, np.sin(angle / 2) / np.maximum(angle, 1e-12), 0.5)
    return np.concatenate([np.cos(angle / 2)[..., None], v * scale[..., None]], axis=-1)


def qangle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] between orientations ``a`` and ``b`` (sign-agnostic)."""
    d = np.abs(np.sum(a * b, axis=-1))
    return 2 * np.arccos(np.clip(d, 0.0, 1.0))


def qslerp(a: np.ndarray, b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Shorter-arc slerp from ``a`` (4,) to ``b`` (4,) at fractions ``s`` (F,) -> (F, 4)."""
    if np.dot(a, b) < 0:
        b = -b
    d = float(np.clip(np.dot(a, b), -1.0, 1.0))
    theta = np.arccos(d)
    if theta < 1e-9:
        return np.broadcast_to(a, (len(s), 4)).copy()
    s = s[:, None]
    return (np.sin((1 - s) * theta) * a + np.sin(s * theta) * b) / np.sin(theta)


def qmatrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)  # fmt: skip


def qcontinuous(q: np.ndarray) -> np.ndarray:
    """(F, 4) with signs flipped so consecutive quaternions have a non-negative dot product."""
    out = q.copy()
    flip = np.sum(out[1:] * out[:-1], axis=-1) < 0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flip) % 2 == 1, -1.0, 1.0)])
    return out * sign[:, None]
