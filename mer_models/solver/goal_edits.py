"""Goal edits of the physical terms' penalty method (``PhysicsConfig.method`` "penalty"): the
position goals of a stance foot held at its stance phase's mean x, y (:func:`lock_goals`), and the
feet's goals kept the target's foot width apart (:func:`separate_feet`); measured in
docs/decisions.md §Physical terms. The constraint method leaves the goals as they are.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

__all__ = ["lock_goals", "separate_feet", "foot_extent", "blend", "phase_mean"]


def lock_goals(inputs: Any, goal: torch.Tensor) -> torch.Tensor:
    """The position goals (B, T, Jr, 3) with each stance foot's sole points (``ref_feet``: the
    reference's ankle and toe nodes) held at their stance phase's mean x, y, blended in and out
    over ``cfg.lock_blend`` frames: the goals of a planted foot do not slide."""
    if inputs.contacts is None or inputs.cfg.lock_blend < 0:
        return goal
    out = goal.clone()
    for i, nodes in enumerate(inputs.ref_feet):
        if not nodes:
            continue
        down = inputs.contacts[..., i].to(goal.device)
        w = inputs.cfg.lock_weight * blend(down, inputs.cfg.lock_blend).to(goal.dtype)[..., None]  # (B, T, 1)
        for n in nodes:
            xy = goal[:, :, n, :2]
            out[:, :, n, :2] = w * phase_mean(xy, down) + (1 - w) * xy
    return out

def separate_feet(inputs: Any, goal: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """The position goals (B, T, Jr, 3) with the feet at least the target's foot width apart.

    Per frame, in the heading frame of ``heading`` (B, T, 3, 3) (the reference base's x axis
    in the floor plane): where the two ankles' goals are side by side (closer along the heading
    than the target's foot length) and closer across it than the target's foot width plus
    ``cfg.feet_gap``, each foot's sole goals move out by half the shortfall (the knees by a
    quarter). Segment scaling keeps a source's leg adduction, so a robot with wide feet on a
    narrow pelvis (TALOS, Valkyrie) would otherwise be asked to put one foot through the other.
    """
    width, length = foot_extent(inputs.model)
    (lf, rf), (lk, rk) = inputs.ref_feet, inputs.ref_knees
    if inputs.cfg.feet_gap < 0 or not lf or not rf or width <= 0:
        return goal
    fwd = heading[..., :, 0].clone()
    fwd[..., 2] = 0
    fwd = fwd / fwd.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    lat = torch.stack([-fwd[..., 1], fwd[..., 0], torch.zeros_like(fwd[..., 0])], -1)  # z x forward: to the left
    d = goal[:, :, lf[0]] - goal[:, :, rf[0]]
    sep, along = (d * lat).sum(-1), (d * fwd).sum(-1)
    side = ((length - along.abs()) / (0.25 * length)).clamp(0, 1)  # 1: side by side, 0: one ahead of the other
    push = (0.5 * (width + inputs.cfg.feet_gap - sep)).clamp_min(0) * side  # (B, T)
    if not bool((push > 0).any()):
        return goal
    out = goal.clone()
    step = push[..., None] * lat
    for nodes, sign in ((lf, 1.0), (rf, -1.0)):
        for n in nodes:
            out[:, :, n] += sign * step
    for n, sign in ((lk, 1.0), (rk, -1.0)):
        if n >= 0:
            out[:, :, n] += 0.5 * sign * step
    return out


def foot_extent(model: Any) -> tuple[float, float]:
    """The target's foot width and length [m]: the widest foot's collision vertices across and
    along the root frame's y and x at the zero pose (node frames are root-aligned there); 0 without feet."""
    foot = np.asarray(model.foot)
    width = length = 0.0
    for side in (1, 2):
        shapes = np.flatnonzero(foot == side)
        if not len(shapes):
            continue
        v = np.concatenate([np.asarray(model.vertices[s]) for s in shapes])
        v = v[np.isfinite(v).all(1)]
        if len(v):
            width, length = max(width, float(np.ptp(v[:, 1]))), max(length, float(np.ptp(v[:, 0])))
    return width, length



def blend(down: torch.Tensor, k: int) -> torch.Tensor:
    """(B, T) weight: 1 in the middle of a stance phase, easing to 0 over ``k`` frames at its ends."""
    if k <= 0:
        return down.float()
    x = down.float()
    T = x.shape[1]
    dist = torch.full_like(x, float(k))  # frames to the nearest non-stance frame, capped at k
    for d in range(1, k + 1):
        left = torch.cat([torch.zeros_like(x[:, :d]), x[:, :-d]], 1) if d < T else torch.zeros_like(x)
        right = torch.cat([x[:, d:], torch.zeros_like(x[:, :d])], 1) if d < T else torch.zeros_like(x)
        edge = (left == 0) | (right == 0)
        dist = torch.where(edge & (dist == k), torch.full_like(x, float(d - 1)), dist)
    t = (dist + 1) / (k + 1)
    return x * (t * t * (3 - 2 * t))


def phase_mean(xy: torch.Tensor, down: torch.Tensor) -> torch.Tensor:
    """Mean x, y of each stance phase, per frame: xy (B, T, 2), down (B, T) → (B, T, 2)."""
    B, T = down.shape
    start = down & torch.cat([torch.ones_like(down[:, :1]), ~down[:, :-1]], 1)
    seg = torch.cumsum(start.long(), 1) * down.long()  # 0 outside stance, 1.. per phase
    n = int(seg.max()) + 1 if seg.numel() else 1
    sums = torch.zeros(B, n, 2, dtype=xy.dtype, device=xy.device).scatter_add_(1, seg[..., None].expand(B, T, 2), xy * down[..., None])
    counts = torch.zeros(B, n, dtype=xy.dtype, device=xy.device).scatter_add_(1, seg, down.to(xy.dtype))
    mean = sums / counts.clamp_min(1)[..., None]
    return torch.gather(mean, 1, seg[..., None].expand(B, T, 2))


