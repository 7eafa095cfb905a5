"""A PNG of stick figures over time: the retargeted motion at a glance (matplotlib, Agg backend).

A film strip of ``panels`` evenly spaced frames, each drawn from the side (looking along the
motion's initial left direction, so forward is to the right) with the bones of the skeleton, its
key points, and, when given, the scaled reference key points (red crosses) the energy tracks.
Every panel shares one scale, so sizes and heights compare across frames.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from mer_data.base.atomic import atomic_write
from mer_data.skeleton import Skeleton

from .writers import TargetMotion

__all__ = ["plot_motion"]


def plot_motion(
    path: str | Path,
    motion: TargetMotion,
    *,
    reference_points: np.ndarray | None = None,
    panels: int = 8,
    title: str | None = None,
) -> Path:
    """Write the film strip.

    Args:
        motion: the retargeted motion.
        reference_points: (F, K, 3) scaled reference key points [m] (optional).
        panels: number of frames shown.
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from .writers import check_motion_finite

    check_motion_finite(motion, path)
    skel: Skeleton = motion.skeleton
    pos, _ = motion.forward_kinematics()
    F = pos.shape[0]
    frames = np.unique(np.linspace(0, F - 1, min(panels, F)).round().astype(int))
    # side view: x axis = initial heading, vertical = z
    r0 = motion.base_rot[0]
    heading = np.arctan2(r0[1, 0], r0[0, 0])
    fwd = np.array([np.cos(heading), np.sin(heading), 0.0])

    def project(p: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (p - base) @ fwd, p[..., 2]

    fig, axes = plt.subplots(1, len(frames), figsize=(1.8 * len(frames), 3.2), sharey=True, squeeze=False)
    zmax = max(float(pos[..., 2].max()), 0.5) + 0.1
    zmin = min(float(pos[..., 2].min()), 0.0) - 0.05
    key = [j for j in skel.keypoints.values() if j >= 0]
    for ax, f in zip(axes[0], frames):
        base = pos[f, 0]
        x, z = project(pos[f], base)
        for j in range(1, skel.num_nodes):
            p = skel.parents[j]
            ax.plot([x[p], x[j]], [z[p], z[j]], color="tab:blue", lw=1.5)
        ax.scatter(x[key], z[key], s=8, color="tab:orange", zorder=3)
        if reference_points is not None:
            rx, rz = project(reference_points[f], base)
            ax.scatter(rx, rz, s=14, marker="x", color="tab:red", zorder=4, lw=1)
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.set_title(f"t = {f / motion.fps:.2f} s", fontsize=8)
        ax.set_xlim(-0.9, 0.9)
        ax.set_ylim(zmin, zmax)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    axes[0][0].set_ylabel("z [m]", fontsize=8)
    fig.suptitle(title or f"{skel.name}: {F} frames at {motion.fps:g} Hz (blue: robot, red x: scaled reference)", fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return atomic_write(path, buf.getvalue())
