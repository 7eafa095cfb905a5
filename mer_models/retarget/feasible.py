"""The last step of a retarget with physical terms: the motion made feasible where the energy left it not.

The optimiser's physical terms (:mod:`mer_models.solver.physics`) are penalties: weighed against the
key points, they leave a little (a foot 1-2 cm into the floor where the goals of a larger robot lie
under it, a joint a few percent over its speed where the goals turn fast). A tracker cannot learn
that, so after the solve, on the whole motion:

1. **Joint speed**: every actuated joint's angle path is projected onto ``|q_{t+1} - q_t| <= d``
   (``d`` = ``speed_fraction`` x the URDF velocity limit / fps) by the mean of a forward and a
   backward clamp. Each clamp is feasible (it moves a frame only towards its feasible
   neighbour) and so is their mean (|a + b| <= |a| + |b|); the mean is symmetric in time, so
   a spike is flattened in place instead of dragged forward. Both stay within the joint limits
   (each clamped value lies between a limited angle and a limited neighbour). Mimic joints
   follow their drivers afterwards.
2. **Floor**: the base is raised, frame by frame, by how far the lowest vertex of any collision
   shape is below z = 0, through a smooth upper envelope (a running maximum over
   ``2 * floor_window + 1`` frames, then a running mean over the same frames: never below the
   lift each frame needs, and without steps). Only frames near a penetration move. After the
   constraint method (``PhysicsConfig.method`` "constraints") each frame is raised by its own
   need only (no envelope): its rounds leave few frames in the floor, and easing a lift over the
   neighbours raised their stance feet off the floor (G1 -> TALOS / Atlas, walk1, dance1 and
   fallAndGetUp1, frames 601-900: hovering 3.6 / 2.8 % of contact samples with the envelope,
   0.9 / 0.9 % without, 0.2 / 0.0 % with no lift; docs/decisions.md §Physics as constraints).

Both only ever move a motion towards feasibility, and neither touches a motion that is already
feasible. What they cost in g-mpbpe is measured in docs/decisions.md §Physical terms.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import torch

from mer_data.kinematics.collision import shape_points
from mer_models.export.writers import TargetMotion

log = logging.getLogger(__name__)

__all__ = ["FeasibleReport", "make_feasible", "clamp_speed", "floor_lift", "feasible_motion"]

_CHUNK = 1024  # frames per FK batch of the floor pass


@dataclass(frozen=True)
class FeasibleReport:
    """What :func:`make_feasible` changed: the largest angle change [rad], frames whose angles
    moved, the largest base lift [m] and frames lifted."""

    max_angle_change: float
    frames_clamped: int
    max_lift: float
    frames_lifted: int


def clamp_speed(q: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Project angle paths onto ``|q_{t+1} - q_t| <= step``.

    Args:
        q: (F, J) angles [rad]; step: (J,) the largest change per frame [rad] (inf: free).

    Returns:
        (F, J): the mean of the forward and the backward clamp (module docstring).
    """
    q = np.asarray(q, np.float64)
    F = q.shape[0]
    if F < 2:
        return q.copy()
    fwd, bwd = q.copy(), q.copy()
    for t in range(1, F):
        fwd[t] = np.clip(q[t], fwd[t - 1] - step, fwd[t - 1] + step)
    for t in range(F - 2, -1, -1):
        bwd[t] = np.clip(q[t], bwd[t + 1] - step, bwd[t + 1] + step)
    return 0.5 * (fwd + bwd)


def _running(x: np.ndarray, r: int, fn) -> np.ndarray:
    pad = np.concatenate([np.full(r, x[0]), x, np.full(r, x[-1])])
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * r + 1)
    return fn(win, axis=-1)


def floor_lift(lowest: np.ndarray, window: int) -> np.ndarray:
    """(F,) base lift [m] >= ``max(0, -lowest)`` each frame: the running mean of the running
    maximum over ``2 * window + 1`` frames (module docstring); ``lowest`` (F,) [m]."""
    need = np.clip(-np.asarray(lowest, np.float64), 0.0, None)
    if window <= 0 or not need.any():
        return need
    # the mean of maxima each at least need[t] (every window around t's neighbours contains t)
    return np.maximum(_running(_running(need, window, np.max), window, np.mean), need)


def _lowest(motion: TargetMotion, model) -> np.ndarray:
    """(F,) the lowest z of any collision vertex [m]."""
    pos, rot = motion.forward_kinematics()
    out = np.empty(motion.num_frames)
    for a in range(0, motion.num_frames, _CHUNK):
        v = shape_points(model, torch.from_numpy(pos[a : a + _CHUNK]), torch.from_numpy(rot[a : a + _CHUNK]), "vertices")
        out[a : a + _CHUNK] = v[..., 2].flatten(1).min(1).values.numpy()
    return out


def make_feasible(motion: TargetMotion, model, *, speed_fraction: float = 0.95, floor_window: int = 3,
                  speed: bool = True, floor: bool = True) -> tuple[TargetMotion, FeasibleReport]:  # fmt: skip
    """``motion`` with every actuated joint within ``speed_fraction`` of its URDF velocity limit
    and no collision vertex below the floor (module docstring).

    Args:
        motion: the retarget; model: its robot's :class:`~mer_data.robots.collision.CollisionModel`.
        floor_window: frames each side over which a lift is eased in and out.
    """
    skel = motion.skeleton
    J = skel.num_nodes
    q = np.asarray(motion.q, np.float64)
    new_q = q.copy()
    changed = np.zeros(motion.num_frames, bool)
    if speed and motion.num_frames > 1:
        lim = np.asarray(model.velocity_limit, np.float64)[:J]
        free = skel.dof_mask & np.isfinite(lim) & (lim > 0)
        if free.any():
            step = lim[free] * speed_fraction / motion.fps
            cols = np.flatnonzero(free)
            new_q[:, cols] = clamp_speed(q[:, cols], step)
            src = np.asarray(skel.mimic_source)
            mim = np.flatnonzero(src >= 0)
            if len(mim):
                new_q[:, mim] = skel.mimic_multiplier[mim] * new_q[:, src[mim]] + skel.mimic_offset[mim]
            changed = np.abs(new_q - q).max(1) > 1e-9
    out = replace(motion, q=new_q)
    lift = np.zeros(motion.num_frames)
    if floor:
        lift = floor_lift(_lowest(out, model), floor_window)
        if lift.any():
            base = np.array(out.base_pos, np.float64)
            base[:, 2] += lift
            out = replace(out, base_pos=base)
    report = FeasibleReport(float(np.abs(new_q - q).max()) if q.size else 0.0, int(changed.sum()),
                            float(lift.max()) if lift.size else 0.0, int((lift > 0).sum()))  # fmt: skip
    return out, report


def feasible_motion(motion: TargetMotion, geometry, physics) -> TargetMotion:
    """``motion`` made feasible after a solve with ``physics`` (a
    :class:`~mer_models.solver.physics.PhysicsConfig`) if it asks for it
    (:func:`mer_models.retarget.feasible.make_feasible`)."""
    if not physics.feasible:
        return motion
    window = 0 if physics.method == "constraints" else 3  # the constraint method: no envelope (module docstring)
    out, rep = make_feasible(motion, geometry, speed_fraction=physics.speed_fraction, floor_window=window)
    if rep.frames_clamped or rep.frames_lifted:
        log.info("feasible: %d frames' angles slowed (at most %.3f rad), %d frames lifted (at most %.1f cm)",
                 rep.frames_clamped, rep.max_angle_change, rep.frames_lifted, 100 * rep.max_lift)  # fmt: skip
    return out
