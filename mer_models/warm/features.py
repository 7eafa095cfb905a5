"""What the warm-start network reads, per frame and target node (no parameters).

Every quantity is expressed in a frame attached to the goals of that frame, so the network is
invariant to where the motion is and where it faces:

* the **base goal orientation** ``R_b`` (B, T, 3, 3): the orientation goal of the target's base
  where it has one, else the reference base's orientation (what the optimiser starts from);
* the **heading frame** ``H``: the rotation about world z by the yaw of ``R_b``, at the base goal
  position dropped to the floor (heights stay absolute: the floor is at z = 0).

Per target node ``j`` (:func:`node_inputs`, :data:`INPUT_DIM` channels): whether it has a position
goal; its goal in the heading frame [m], relative to the base goal in ``R_b`` [m], its *segment*
(from the goal of its nearest mapped ancestor to its own, or to the mean goal of the mapped nodes
below it) in ``R_b`` [m], its goal velocity in the heading frame / ``vel_scale``; its orientation
goal in the heading frame (first two columns) with a flag; the skeleton's own data of the node
(joint axis, offset from the parent [m] and its length, limits, nominal angle [rad], flags); the
features of its mapped reference joint gathered through the joint map (that joint's angle [rad]
and axis); and, broadcast to every node, ``R_b`` in the heading frame (the base's tilt) and the
base goal's height [m].

:func:`relations` gives the codes of the spatial attention's relation bias: self, parent, child,
ancestor and descendant at two and at three or more hops, and unrelated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.features import finite_difference
from mer_models.batch import BatchGraph, descendants, nearest_mapped_ancestor, rot_z, yaw_of
from mer_models.solver.energy import keypoint_goals, orientation_pairs

__all__ = ["INPUT_DIM", "NUM_CODES", "Anchor", "anchor", "node_inputs", "relations"]

INPUT_DIM = 45
#: Relation codes: 0 unrelated or padding, 1 self, 2 parent, 3 child, 4 grandparent, 5 grandchild,
#: 6 ancestor >= 3 hops, 7 descendant >= 3 hops.
NUM_CODES = 8
_ANGLE_BOUND = 6.3  # [rad] limits beyond a turn are shown as a turn (continuous joints)


@dataclass
class Anchor:
    """The goal frame of every frame: ``rot_b`` (B, T, 3, 3) the base goal orientation (world ←
    base), ``heading`` (B, T, 3, 3) its yaw alone, ``pos_b`` (B, T, 3) the base goal position [m],
    ``origin`` (B, T, 3) the same on the floor."""

    rot_b: torch.Tensor
    heading: torch.Tensor
    pos_b: torch.Tensor
    origin: torch.Tensor


def anchor(batch: Mapping, goals: torch.Tensor, has: torch.Tensor, device,
           goal_rot: tuple[torch.Tensor, torch.Tensor] | None = None) -> Anchor:  # fmt: skip
    """The :class:`Anchor` of a collated batch, from the per-node goals ``goals`` (B, T, Jt, 3) with
    their mask ``has`` (B, Jt) and the per-node orientation goals ``goal_rot`` ((B, T, Jt, 3, 3) and
    their mask (B, Jt), :func:`~mer_models.solver.energy.orientation_pairs`; None: the batch has none)."""
    rot_ref = axis_angle_to_matrix(batch["reference"][:, :, 0, 0:3].to(device, torch.float32))
    rot_b = rot_ref
    if goal_rot is not None:
        grot, has_rot = goal_rot
        rot_b = torch.where(has_rot[:, None, :1, None], grot[:, :, 0], rot_ref)
    base_scaled = batch["ref_scaled_pos"][:, :, 0].to(device, torch.float32)
    pos_b = torch.where(has[:, None, :1], goals[:, :, 0], base_scaled)
    origin = torch.cat([pos_b[..., :2], torch.zeros_like(pos_b[..., 2:])], -1)
    return Anchor(rot_b, rot_z(yaw_of(rot_b)), pos_b, origin)


def _in(rot: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``rot^T v`` for rot (B, T, 3, 3) and vectors (B, T, J, 3)."""
    return torch.einsum("btij,btni->btnj", rot, v)


def node_inputs(batch: Mapping, g: BatchGraph, ref: BatchGraph, fps: float, vel_scale: float, device) -> tuple[torch.Tensor, Anchor]:
    """(B, T, Jt, :data:`INPUT_DIM`) inputs of every target node (zero on padding) and the batch's :class:`Anchor`."""
    eta = batch["joint_map"].to(device, torch.float32)
    goal = batch["ref_scaled_pos"].to(device, torch.float32)
    goals, has = keypoint_goals(eta, goal)
    has = has & g.mask
    pairs = None  # the orientation goal of each node (its reference partner's), once for the anchor and the inputs
    if "ref_goal_rot" in batch:
        pairs = orientation_pairs(eta, batch["ref_goal_rot"].to(device, torch.float32), batch["ref_rot_mask"].to(device))
    a = anchor(batch, goals, has, device, pairs)
    B, T, Jt = goals.shape[:3]
    m = has[:, None, :, None].to(goals.dtype)
    head = _in(a.heading, goals - a.origin[:, :, None]) * m
    rel = goals - a.pos_b[:, :, None]
    local = _in(a.rot_b, rel) * m
    below = descendants(g.parents) & g.mask[:, None, :] & has[:, None, :]
    count = below.sum(-1)
    centroid = torch.einsum("bjk,btkd->btjd", below.to(local.dtype), local) / count.clamp_min(1)[:, None, :, None]
    anc, _ = nearest_mapped_ancestor(g.parents, has)
    start = torch.gather(local, 2, anc[:, None, :, None].expand(B, T, Jt, 3))
    end = torch.where(has[:, None, :, None], local, centroid)
    seg = (end - start) * ((count > 0) & g.mask)[:, None, :, None].to(local.dtype)
    seg[:, :, 0] = 0
    vel = _in(a.heading, finite_difference(goals, fps, dim=-3)) / vel_scale * m
    rot6 = goals.new_zeros(B, T, Jt, 6)
    has_rot = torch.zeros(B, Jt, dtype=torch.bool, device=device)
    if pairs is not None:
        grot, has_rot = pairs
        has_rot = has_rot & g.mask
        local_rot = a.heading.transpose(-1, -2)[:, :, None] @ grot
        rot6 = local_rot[..., :, :2].transpose(-1, -2).reshape(B, T, Jt, 6) * has_rot[:, None, :, None]
    mr = has_rot[:, None, :, None].to(goals.dtype)
    lo, hi = g.lower.clamp(-_ANGLE_BOUND, _ANGLE_BOUND), g.upper.clamp(-_ANGLE_BOUND, _ANGLE_BOUND)
    base_flag = torch.zeros(B, Jt, device=device)
    base_flag[:, 0] = 1
    graph = torch.cat([g.axes, g.offsets, g.offsets.norm(dim=-1, keepdim=True),
                       torch.stack([lo, hi, hi - lo, g.nominal.clamp(-_ANGLE_BOUND, _ANGLE_BOUND), g.revolute.float(),
                                    g.dof.float(), base_flag], -1)], -1)  # fmt: skip
    w = eta / eta.sum(-1, keepdim=True).clamp_min(1)
    ref_angle = batch["reference"][..., 0].to(device, torch.float32).clone()
    ref_angle[:, :, 0] = 0  # the base's channel 0 is a rotation vector component, not an angle
    mapped_angle = torch.einsum("bij,btj->bti", w, ref_angle)[..., None]
    mapped_axis = torch.einsum("bij,bjd->bid", w, ref.axes)
    tilt = (a.heading.transpose(-1, -2) @ a.rot_b)[..., :, :2].transpose(-1, -2).reshape(B, T, 1, 6).expand(B, T, Jt, 6)
    height = a.pos_b[:, :, None, 2:3].expand(B, T, Jt, 1)
    x = torch.cat([m.expand(B, T, Jt, 1), head, local, seg, vel, mr.expand(B, T, Jt, 1), rot6, graph[:, None].expand(B, T, Jt, graph.shape[-1]), mapped_angle,
                   mapped_axis[:, None].expand(B, T, Jt, 3), tilt, height], -1)  # fmt: skip
    assert x.shape[-1] == INPUT_DIM, x.shape
    return x * g.mask[:, None, :, None], a


def relations(parents: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, J, J) long relation codes (:data:`NUM_CODES`) of node ``j`` as seen from node ``i``."""
    B, J = parents.shape
    depth = torch.zeros(B, J, dtype=torch.long, device=parents.device)
    rows = torch.arange(B, device=parents.device)
    for k in range(1, J):
        depth[:, k] = depth[rows, parents[:, k].clamp_min(0)] + 1
    below = descendants(parents)  # below[b, i, k]: k is i or under i
    hops = depth[:, None, :] - depth[:, :, None]  # depth(j) - depth(i)
    codes = torch.zeros(B, J, J, dtype=torch.long, device=parents.device)
    anc = below.transpose(1, 2)  # anc[b, i, j]: j is i or above i
    desc = below
    codes = torch.where(anc & (hops <= -3), torch.full_like(codes, 6), codes)
    codes = torch.where(anc & (hops == -2), torch.full_like(codes, 4), codes)
    codes = torch.where(anc & (hops == -1), torch.full_like(codes, 2), codes)
    codes = torch.where(desc & (hops >= 3), torch.full_like(codes, 7), codes)
    codes = torch.where(desc & (hops == 2), torch.full_like(codes, 5), codes)
    codes = torch.where(desc & (hops == 1), torch.full_like(codes, 3), codes)
    eye = torch.eye(J, dtype=torch.bool, device=parents.device)[None]
    codes = torch.where(eye, torch.ones_like(codes), codes)
    pair = mask[:, :, None] & mask[:, None, :]
    return codes * pair
