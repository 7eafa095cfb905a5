"""Fixed-length, origin-normalized windows of a motion, and their per-joint features.

Windows (paper, Experiment Setup: "clipped into 60-frame motion clips ... we set the starting base
position of each motion segment to the origin, maintaining a constant height"):

* starts ``0, stride, 2*stride, ...`` while a whole window fits, plus one final window ending at
  the last frame when the stride does not land there, so every frame is in at least one window;
* origin normalization: the base x, y of a window's first frame is subtracted from every position
  of the window (base and all nodes); heights, orientations and velocities are unchanged.

Stored form (what a shard keeps per window, float32): node positions ``pos`` (T, J, 3) [m], node
angles ``q`` (T, J) [rad] (mimic joints applied, 0 at the base and sites) and the base rotation
vector ``base_rotvec`` (T, 3) [rad]: the values :func:`mer_data.motion.features.motion_features` puts in
the features, computed by the same FK call on the same batch. Velocities are not stored:
:func:`window_features` recomputes them from ``pos`` with :func:`mer_data.motion.features.finite_difference`
(the same float32 operations ``motion_features`` performs), so the features it returns are
bit-identical to ``motion_features`` of the windows as built. (FK of a different batch of frames
can differ in the last float32 bit, ~1e-8 m, because batched matmuls may pick other kernels.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mer_data.kinematics.fk import SkeletonTensors, apply_mimic, fk_skeleton, skeleton_tensors
from mer_data.kinematics.rotations import quat_to_axis_angle
from mer_data.skeleton import Skeleton

from .features import FEATURE_DIM, finite_difference
from .lafan1 import Motion

__all__ = ["window_starts", "WindowBatch", "make_windows", "window_features", "stored_arrays", "stored_from_features"]

_BATCH_FRAMES = 1920  # frames per FK call: small batches stay in cache (~20% faster than 16k)


def window_starts(num_frames: int, window: int, stride: int) -> np.ndarray:
    """(N,) int64 start frames of the windows of a clip (empty when the clip is shorter than a window)."""
    if window < 1 or stride < 1:
        raise ValueError(f"window and stride must be >= 1, got {window} and {stride}")
    if num_frames < window:
        return np.zeros(0, np.int64)
    starts = np.arange(0, num_frames - window + 1, stride, dtype=np.int64)
    if starts[-1] != num_frames - window:
        starts = np.append(starts, num_frames - window)
    return starts


@dataclass(frozen=True, eq=False)
class WindowBatch:
    """The windows of one clip, in stored form.

    Attributes (N windows of T frames, J nodes):
        start_frame: (N,) int64 first frame of each window in the (resampled) clip.
        origin_xy: (N, 2) float64 world x, y subtracted from the window's positions [m].
        pos: (N, T, J, 3) float32 node positions [m], origin-normalized.
        q: (N, T, J) float32 node angles [rad].
        base_rotvec: (N, T, 3) float32 base orientation, axis-angle [rad].
    """

    start_frame: np.ndarray
    origin_xy: np.ndarray
    pos: np.ndarray
    q: np.ndarray
    base_rotvec: np.ndarray

    def __len__(self) -> int:
        return int(self.start_frame.shape[0])


def stored_from_features(feats: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(..., T, J, 9) features -> stored ``pos`` (..., T, J, 3), ``q`` (..., T, J), ``base_rotvec`` (..., T, 3)."""
    pos = torch.cat([feats[..., :1, 3:6], feats[..., 1:, 1:4]], dim=-2)
    q = feats[..., 0].clone()
    q[..., 0] = 0
    return pos.numpy(), q.numpy(), feats[..., 0, 0:3].numpy().copy()


def make_windows(
    motion: Motion,
    skel: Skeleton,
    starts: np.ndarray,
    window: int,
    *,
    st: SkeletonTensors | None = None,
) -> WindowBatch:
    """Cut ``motion`` into windows at ``starts``, origin-normalize them and compute their features.

    FK runs in float32 on the origin-shifted windows (so positions stay near the origin, where
    float32 resolves ~0.1 um), with the foundation's :func:`mer_data.kinematics.fk.fk_skeleton`.
    """
    st = st or skeleton_tensors(skel, torch.float32)
    n, J = len(starts), skel.num_nodes
    idx = starts[:, None] + np.arange(window)[None, :]  # (N, T)
    origin = motion.base_pos[starts, :2].copy()
    out_pos = np.empty((n, window, J, 3), np.float32)
    out_q = np.empty((n, window, J), np.float32)
    out_rv = np.empty((n, window, 3), np.float32)
    q_nodes = motion.node_angles(skel)
    per = max(1, _BATCH_FRAMES // window)
    for a in range(0, n, per):
        sel = idx[a : a + per]
        base = motion.base_pos[sel].copy()
        base[..., :2] -= origin[a : a + per, None, :]
        pos, q, rv = stored_arrays(
            st,
            torch.from_numpy(base.astype(np.float32)),
            torch.from_numpy(motion.base_quat[sel].astype(np.float32)),
            torch.from_numpy(q_nodes[sel].astype(np.float32)),
        )
        out_pos[a : a + per], out_q[a : a + per], out_rv[a : a + per] = pos.numpy(), q.numpy(), rv.numpy()
    return WindowBatch(starts.astype(np.int64), origin, out_pos, out_q, out_rv)


def stored_arrays(
    st: SkeletonTensors, base_pos: torch.Tensor, base_quat: torch.Tensor, q: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The stored form of a motion batch: node positions, node angles, base rotation vector.

    Exactly the values :func:`mer_data.motion.features.motion_features` puts into the features (same
    FK call, same operations), without building the feature tensor and the velocities.
    """
    pos, _ = fk_skeleton(st, q, base_pos, base_quat=base_quat)
    revolute = (st.axes.abs().sum(-1) > 0).to(q.dtype)
    q_eff = apply_mimic(q, st.mimic_source, st.mimic_multiplier, st.mimic_offset) * revolute
    q_eff[..., 0] = 0
    return pos, q_eff, quat_to_axis_angle(base_quat)


def window_features(pos: np.ndarray, q: np.ndarray, base_rotvec: np.ndarray, fps: float = 30.0) -> np.ndarray:
    """Stored window arrays -> (..., T, J, 9) float32 features (paper layout, see :mod:`mer_data.motion.features`)."""
    p = torch.from_numpy(np.ascontiguousarray(pos))
    vel = finite_difference(p, fps, dim=-3)
    feats = torch.zeros(p.shape[:-1] + (FEATURE_DIM,), dtype=p.dtype)
    feats[..., 1:, 0] = torch.from_numpy(np.ascontiguousarray(q))[..., 1:]
    feats[..., 1:, 1:4] = p[..., 1:, :]
    feats[..., 1:, 4:7] = vel[..., 1:, :]
    feats[..., 0, 0:3] = torch.from_numpy(np.ascontiguousarray(base_rotvec))
    feats[..., 0, 3:6] = p[..., 0, :]
    feats[..., 0, 6:9] = vel[..., 0, :]
    return feats.numpy()
