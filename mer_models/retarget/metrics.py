"""Evaluation metrics (paper, Evaluation Metrics; after Xie et al.), for cross-robot retargeting.

The paper names the metrics but not what a "body" or the ground truth is when the target robot is
not the source robot. mer's definitions (docs/model.md):

* **Bodies** are the key points the target and the reference share (the pairs of the joint map
  ``eta``, the floating bases included); TRON1 has 8 + base, the humanoids 14 + base.
* **Ground truth** is the reference motion body-part scaled to the target (``ref_scaled_pos``),
  in the world frame, and the reference's own node orientations.

Per window (then averaged over windows, reported as mean ± std):

* ``g_mpbpe`` [m]: mean over frames and bodies of ``|| p_i - p*_j ||`` (global positions, no root
  alignment).
* ``mpbve`` [m/s]: the same on velocities (second-order finite differences at the frame rate).
* ``mpboe`` [rad]: mean geodesic angle between the target's body orientation and its goal, over
  the bodies whose orientation the energy tracks (base, feet, hands:
  :func:`mer_data.kinematics.orientation.orientation_goals`): how far each has turned from its robot's zero pose,
  compared with the reference's, hands calibrated for differing rest poses of the arms.
* ``jerk`` [rad/s^3]: mean over frames and actuated joints of ``|d^3 q / dt^3|`` (third forward
  difference times fps^3). ``ref_jerk_frame``: the reference motion's own, for scale (a retarget
  smoother than its source is not the goal). ``jerk_frame`` is the same in rad/frame^3 (without fps^3), the scale of
  the paper's ``E_smooth`` values.
* ``limit_violation`` [fraction]: frames in which any actuated joint is outside its limits by more
  than 1e-6 rad.
* ``kp/<name>`` [m] (with ``keypoints=``): the position error of each key point (and ``kp/base``).

When the target robot has its own motion for the window (G1 and H1 share LAFAN1 clips), the same
position, velocity and orientation errors against *that* motion over all of its nodes are added as
``gt_mpbpe``, ``gt_mpbve``, ``gt_mpboe``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import torch

from mer_data.kinematics.rotations import rotation_angle_between
from mer_data.motion.features import finite_difference
from mer_models.batch import BatchGraph, batch_fk, graph_from_batch
from mer_models.solver.energy import orientation_pairs, split_motion

__all__ = ["METRICS", "GT_METRICS", "window_metrics", "summarize", "LIMIT_TOL", "AT_LIMIT_TOL"]

METRICS = ("g_mpbpe", "mpboe", "mpbve", "jerk", "jerk_frame", "ref_jerk_frame", "limit_violation")
GT_METRICS = ("gt_mpbpe", "gt_mpboe", "gt_mpbve")
LIMIT_TOL = 1e-6
#: A joint within this of a limit [rad] counts as held by it (``at_limit/<joint>``).
AT_LIMIT_TOL = 2e-3


def _mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """x (B, T, J), mask (B, J) → (B,)."""
    m = mask[:, None].to(x.dtype)
    return (x * m).sum((1, 2)) / (m.sum((1, 2)) * x.shape[1]).clamp_min(1)


def _pair_index(eta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, Jt, Jr) → reference node of each target node (B, Jt) and the pair mask (B, Jt)."""
    return eta.argmax(-1), eta.sum(-1) > 0


def window_metrics(
    motion: Mapping[str, torch.Tensor],
    batch: Mapping,
    fps: float = 30.0,
    keypoints: Mapping[str, int] | None = None,
    joints: Mapping[str, int] | None = None,
) -> dict[str, np.ndarray]:
    """Metrics of retargeted windows.

    Args:
        motion: ``q`` (B, T, Jt), ``base_pos`` (B, T, 3), ``base_rot`` (B, T, 3, 3), in the frame of
            the batch's ``ref_scaled_pos``.
        batch: the collated batch the motion was retargeted from.
        keypoints: key point name → target node (one target robot for the whole batch) to add
            the per-key-point errors ``kp/<name>``.
        joints: joint name → target node (one target robot) to add ``at_limit/<name>``: the share
            of frames the joint spends within :data:`AT_LIMIT_TOL` of a limit (which limits hold a
            solution back).

    Returns:
        name → (B,) float64 per window (``gt_*`` are NaN where the batch has no target motion).
    """
    dt = torch.float64
    tg = _as(graph_from_batch(batch, "tgt"), dt)
    q, bp, br = (motion[k].to(dt).cpu() for k in ("q", "base_pos", "base_rot"))
    pos, rot = batch_fk(tg, q, bp, br)
    goal = batch["ref_scaled_pos"].to(dt)
    eta = batch["joint_map"].to(dt)
    j_of, pairs = _pair_index(eta)
    pairs = pairs & tg.mask
    B, T, Jt = q.shape
    g = torch.gather(goal, 2, j_of[:, None, :, None].expand(B, T, Jt, 3))
    vel, gvel = finite_difference(pos, fps, dim=-3), finite_difference(g, fps, dim=-3)
    err = (pos - g).norm(dim=-1)
    out = {
        "g_mpbpe": _mean(err, pairs),
        "mpbve": _mean((vel - gvel).norm(dim=-1), pairs),
    }
    if "ref_goal_rot" in batch:
        gr, opairs = orientation_pairs(eta, batch["ref_goal_rot"].to(dt), batch["ref_rot_mask"])
        out["mpboe"] = _mean(rotation_angle_between(rot, gr), opairs & tg.mask)
    else:
        out["mpboe"] = torch.full((B,), float("nan"), dtype=dt)
    for name, i in (keypoints or {}).items():
        if i >= 0:
            out[f"kp/{name}"] = torch.where(pairs[:, i], err[:, :, i].mean(1), torch.full((B,), float("nan"), dtype=dt))
    dof = tg.dof
    if T >= 4:
        d3 = (q[:, 3:] - 3 * q[:, 2:-1] + 3 * q[:, 1:-2] - q[:, :-3]).abs()
        out["jerk_frame"] = _mean(d3, dof)
        out["jerk"] = out["jerk_frame"] * fps**3
        rq = batch["reference"].to(dt)[..., 0]
        r3 = (rq[:, 3:] - 3 * rq[:, 2:-1] + 3 * rq[:, 1:-2] - rq[:, :-3]).abs()
        rg = graph_from_batch(batch, "ref")
        out["ref_jerk_frame"] = _mean(r3, rg.dof)
    else:
        out["jerk_frame"] = out["jerk"] = out["ref_jerk_frame"] = torch.full((B,), float("nan"), dtype=dt)
    outside = (q < tg.lower[:, None] - LIMIT_TOL) | (q > tg.upper[:, None] + LIMIT_TOL)
    out["limit_violation"] = (outside & dof[:, None]).any(-1).to(dt).mean(-1)
    at = ((q - tg.lower[:, None]).abs() < AT_LIMIT_TOL) | ((q - tg.upper[:, None]).abs() < AT_LIMIT_TOL)
    for name, i in (joints or {}).items():
        out[f"at_limit/{name}"] = torch.where(dof[:, i], at[:, :, i].to(dt).mean(1), torch.full((B,), float("nan"), dtype=dt))
    has = batch["has_target"]
    nan = torch.full((B,), float("nan"), dtype=dt)
    out.update({k: nan.clone() for k in GT_METRICS})
    if bool(has.any()):
        tq, tbp, tbr = split_motion(batch["target"].to(dt))
        gpos, grot = batch_fk(tg, tq, tbp, tbr)
        # the target window is origin-normalized on its own first frame: compare in that frame
        shift = (bp[:, :1, :2] - tbp[:, :1, :2])
        gpos = gpos.clone()
        gpos[..., :2] += shift[:, :, None, :]
        gvel = finite_difference(gpos, fps, dim=-3)
        m = tg.mask
        for k, v in {
            "gt_mpbpe": _mean((pos - gpos).norm(dim=-1), m),
            "gt_mpbve": _mean((vel - gvel).norm(dim=-1), m),
            "gt_mpboe": _mean(rotation_angle_between(rot, grot), m),
        }.items():
            out[k] = torch.where(has, v, nan)
    return {k: v.numpy() for k, v in out.items()}


def _as(g: BatchGraph, dtype: torch.dtype) -> BatchGraph:
    return BatchGraph(**{k: (v.to(dtype) if v.is_floating_point() else v) for k, v in g.__dict__.items()})


def summarize(values: Mapping[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """name → {"mean", "std", "n"} over windows (NaNs ignored)."""
    out = {}
    for k, v in values.items():
        v = np.asarray(v, np.float64)
        v = v[np.isfinite(v)]
        out[k] = {"mean": float(v.mean()) if v.size else float("nan"), "std": float(v.std()) if v.size else float("nan"), "n": int(v.size)}
    return out
