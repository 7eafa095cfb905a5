"""Resampling motions to a new frame rate (paper: "all motions are downsampled to 30 Hz").

Positions and joint angles are interpolated linearly, the root rotation by slerp
(:func:`mer_data.kinematics.rotations.quat_slerp`, shorter arc). The output grid is exact: frame ``k`` is at
``k / fps_out`` seconds from the first frame, for every ``k`` with ``k / fps_out <= duration``. So
the first frame is always kept, and the last frame is kept whenever it lies on the output grid
(120, 60, 50 Hz -> 30 Hz clips of whole 1/30 s lengths); a trailing remainder shorter than one
output frame is dropped rather than stretching time. Output frames that fall on input frames copy
them bit for bit, and input already at ``fps_out`` is returned untouched (the same object).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mer_data.base.errors import MotionFormatError
from mer_data.base.limits import check_motion_size, check_upsampling
from mer_data.kinematics.rotations import quat_slerp

from .lafan1 import Motion

__all__ = ["resample", "output_times"]

_SNAP = 1e-9  # input-frame positions this close to an integer are treated as on the input grid


def output_times(num_frames: int, fps_in: float, fps_out: float) -> np.ndarray:
    """(F_out,) positions of the output frames on the input frame axis (fractional input indices)."""
    if num_frames <= 0:
        return np.zeros(0)
    duration_frames_out = (num_frames - 1) * fps_out / fps_in
    n_out = int(math.floor(duration_frames_out + _SNAP)) + 1
    u = np.arange(n_out, dtype=np.float64) * fps_in / fps_out
    near = np.abs(u - np.round(u)) < _SNAP * np.maximum(1.0, u)
    u[near] = np.round(u[near])
    return np.minimum(u, num_frames - 1)


def resample(motion: Motion, fps_out: float = 30.0, *, path=None) -> Motion:
    """``motion`` at ``fps_out`` [Hz] (see module docstring); the same object if already there.

    What it would produce is bounded before anything is allocated: at most ``MER_MAX_UPSAMPLING``
    times the motion's frames, and ``MER_MAX_MOTION_VALUES`` numbers (:mod:`mer_data.base.limits`);
    past either, :class:`MotionFormatError` naming ``path`` (the motion's file, for the message).
    """
    if fps_out <= 0:
        raise ValueError(f"fps_out must be positive, got {fps_out}")
    if motion.fps == fps_out:
        return motion
    F = motion.num_frames
    check_upsampling(motion.fps, fps_out, error=MotionFormatError, path=path)
    n_out = int(math.floor((F - 1) * fps_out / motion.fps + _SNAP)) + 1 if F > 0 else 0
    check_motion_size(n_out, 7 + motion.joints.shape[1], what=f"the motion resampled to {fps_out:g} Hz",
                      error=MotionFormatError, path=path)  # fmt: skip
    u = output_times(F, motion.fps, fps_out)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(F - 2, 0))
    w = u - i0
    i1 = np.minimum(i0 + 1, F - 1)
    on_grid = u == np.round(u)
    exact = u[on_grid].astype(np.int64)  # output frames that are input frames: copied bit for bit

    def lerp(a: np.ndarray) -> np.ndarray:
        out = a[i0] * (1.0 - w[:, None]) + a[i1] * w[:, None]
        out[on_grid] = a[exact]
        return out

    quat = quat_slerp(
        torch.from_numpy(motion.base_quat[i0]), torch.from_numpy(motion.base_quat[i1]), torch.from_numpy(w)
    ).numpy()
    quat[on_grid] = motion.base_quat[exact]
    return motion.with_arrays(
        fps=float(fps_out),
        base_pos=lerp(motion.base_pos),
        base_quat=np.ascontiguousarray(quat),
        joints=lerp(motion.joints),
    )
