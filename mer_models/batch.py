"""Kinematics of padded, mixed-robot batches: the batch's graph tensors, FK and motion features.

A batch from :func:`mer_data.motion.samples.collate` carries each side's skeletons as padded tensors
(``tgt_parents`` (B, J), ``tgt_offsets`` (B, J, 3), ...). :class:`BatchGraph` gathers one side;
:func:`batch_fk` runs the foundation's FK (:func:`mer_data.kinematics.fk.forward_kinematics`) on it with
per-sample offsets, axes and parents, mimic joints applied.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Mapping

import torch

from mer_data.kinematics.fk import apply_mimic, forward_kinematics
from mer_data.kinematics.rotations import matrix_to_axis_angle
from mer_data.motion.features import FEATURE_DIM, finite_difference

__all__ = ["BatchGraph", "graph_from_batch", "batch_fk", "batch_features", "yaw_of", "rot_z", "descendants", "nearest_mapped_ancestor", "ancestors"]


@dataclass(frozen=True)
class BatchGraph:
    """One side's padded skeleton tensors (B samples, J nodes).

    Shapes: ``parents`` (B, J) long (``-1`` at node 0, padding hangs off the base); ``offsets``,
    ``axes`` (B, J, 3); ``lower``, ``upper``, ``nominal``, ``mimic_multiplier``, ``mimic_offset``
    (B, J); ``mimic_source`` (B, J) long; ``psi`` (B, J, J) long; ``revolute``, ``mask`` (B, J) bool.
    """

    parents: torch.Tensor
    offsets: torch.Tensor
    axes: torch.Tensor
    lower: torch.Tensor
    upper: torch.Tensor
    nominal: torch.Tensor
    mimic_source: torch.Tensor
    mimic_multiplier: torch.Tensor
    mimic_offset: torch.Tensor
    psi: torch.Tensor
    revolute: torch.Tensor
    mask: torch.Tensor

    @property
    def dof(self) -> torch.Tensor:
        """(B, J) bool: independently actuated joints (revolute, not mimic)."""
        J = self.parents.shape[1]
        own = self.mimic_source == torch.arange(J, device=self.parents.device)
        return self.revolute & own & self.mask

    def to(self, device: torch.device | str) -> "BatchGraph":
        return BatchGraph(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def select(self, index: torch.Tensor | slice) -> "BatchGraph":
        return BatchGraph(**{f.name: getattr(self, f.name)[index] for f in fields(self)})


def graph_from_batch(batch: Mapping, prefix: str, device: torch.device | str | None = None) -> BatchGraph:
    """The ``ref`` or ``tgt`` side of a collated batch."""
    kw = {f.name: batch[f"{prefix}_{f.name}"] for f in fields(BatchGraph)}
    g = BatchGraph(**kw)
    return g.to(device) if device is not None else g


def batch_fk(
    graph: BatchGraph, q: torch.Tensor, base_pos: torch.Tensor, base_rot: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """World node positions and rotations of a padded batch.

    Args:
        q: (B, T, J) angles [rad] (mimic entries are recomputed from their sources).
        base_pos: (B, T, 3) [m]; base_rot: (B, T, 3, 3) world ← base.

    Returns:
        pos (B, T, J, 3) [m], rot (B, T, J, 3, 3).
    """
    q = apply_mimic(
        q, graph.mimic_source[:, None], graph.mimic_multiplier[:, None], graph.mimic_offset[:, None]
    )
    return forward_kinematics(q, base_pos, base_rot, graph.offsets[:, None], graph.axes[:, None], graph.parents)


def batch_features(
    graph: BatchGraph, q: torch.Tensor, base_pos: torch.Tensor, base_rot: torch.Tensor, fps: float = 30.0
) -> torch.Tensor:
    """(B, T, J, 9) motion features of a padded batch (as :func:`mer_data.motion.features.motion_features`).

    Padding nodes are zero. Base rotation vectors are canonical (angle in [0, pi]).
    """
    pos, _ = batch_fk(graph, q, base_pos, base_rot)
    vel = finite_difference(pos, fps, dim=-3)
    q_eff = apply_mimic(
        q, graph.mimic_source[:, None], graph.mimic_multiplier[:, None], graph.mimic_offset[:, None]
    ) * graph.revolute[:, None].to(q.dtype)
    B, T, J = q.shape
    feats = q.new_zeros(B, T, J, FEATURE_DIM)
    feats[..., 1:, 0] = q_eff[..., 1:]
    feats[..., 1:, 1:4] = pos[..., 1:, :]
    feats[..., 1:, 4:7] = vel[..., 1:, :]
    feats[..., 0, 0:3] = matrix_to_axis_angle(base_rot)
    feats[..., 0, 3:6] = pos[..., 0, :]
    feats[..., 0, 6:9] = vel[..., 0, :]
    return feats * graph.mask[:, None, :, None].to(feats.dtype)


def yaw_of(rot: torch.Tensor) -> torch.Tensor:
    """Heading [rad] of (..., 3, 3) rotations: the angle of the body x axis projected on the ground."""
    return torch.atan2(rot[..., 1, 0], rot[..., 0, 0])


def rot_z(angle: torch.Tensor) -> torch.Tensor:
    """(...,) [rad] → (..., 3, 3) rotation about world z."""
    c, s = torch.cos(angle), torch.sin(angle)
    z, o = torch.zeros_like(angle), torch.ones_like(angle)
    return torch.stack([c, -s, z, s, c, z, z, z, o], -1).reshape(angle.shape + (3, 3))


def descendants(parents: torch.Tensor) -> torch.Tensor:
    """(B, J) parent indices (-1 at the root; parents before children) → (B, J, J) bool: ``k`` is ``j`` or below it."""
    B, J = parents.shape
    eye = torch.eye(J, dtype=torch.bool, device=parents.device).expand(B, J, J)
    anc = eye.clone()  # anc[b, k, j]: j is an ancestor-or-self of k
    for k in range(1, J):
        p = parents[:, k].clamp_min(0)
        anc[:, k] = anc[:, k] | anc[torch.arange(B, device=parents.device), p]
    return anc.transpose(1, 2)


def nearest_mapped_ancestor(parents: torch.Tensor, has: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, J) the nearest strict ancestor of each node that has a goal, and (B, J) the same counting
    the node itself; the base (node 0) at worst."""
    B, J = parents.shape
    idx = torch.arange(B, device=parents.device)
    self_or = torch.zeros(B, J, dtype=torch.long, device=parents.device)  # nearest mapped ancestor-or-self
    out = torch.zeros(B, J, dtype=torch.long, device=parents.device)
    for k in range(1, J):
        p = parents[:, k].clamp_min(0)
        out[:, k] = self_or[idx, p]
        self_or[:, k] = torch.where(has[:, k], torch.full_like(p, k), out[:, k])
    return out, self_or


def ancestors(parents: torch.Tensor) -> torch.Tensor:
    """(B, J) parents (``-1`` at node 0) → (B, J, J) bool, ``[b, k, j]`` True iff j is a strict ancestor of k."""
    B, J = parents.shape
    anc = torch.zeros(B, J, J, dtype=torch.bool, device=parents.device)
    b = torch.arange(B, device=parents.device)[:, None].expand(B, J)
    k = torch.arange(J, device=parents.device)[None].expand(B, J)
    cur = parents.clone()
    while bool((cur >= 0).any()):
        v = cur >= 0
        anc[b[v], k[v], cur[v]] = True
        cur = torch.where(v, torch.gather(parents, 1, cur.clamp_min(0)), torch.full_like(cur, -1))
    return anc
