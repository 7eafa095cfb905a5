"""Training samples and their batching: the contract between the shards and the model.

A :class:`TrainingSample` is the paper's ``C = (M, g^M, g^X, eta)`` plus, when the target robot has
motion data for the same clip, the target window itself. :func:`collate` pads a list of samples
(robots of different node counts) into one batch of tensors with masks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.kinematics.orientation import orientation_goals
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.kinematics.scaling import ScalingMethod, scale_reference_positions
from mer_data.skeleton import Skeleton

__all__ = ["TrainingSample", "graph_arrays", "collate", "reference_goals", "GRAPH_KEYS"]

GRAPH_KEYS = ("parents", "offsets", "axes", "lower", "upper", "nominal", "psi", "mimic_source",
              "mimic_multiplier", "mimic_offset", "revolute")  # fmt: skip


@dataclass(frozen=True, eq=False)
class TrainingSample:
    """One training (or evaluation) sample.

    Attributes:
        reference: (T, J_ref, 9) float32 features of the reference window (origin-normalized).
        reference_skeleton: the reference robot's skeleton (never augmented).
        target_skeleton: the target skeleton (link-scaled when augmented).
        joint_map: (J_target, J_ref) uint8 ``eta`` (correspondences may have been dropped).
        target: (T, J_target, 9) float32 features of the same window on the target robot, when
            that robot has data for the clip (unaugmented targets only); else None.
        provenance: robot, clip, start frame, source sha256, target, augmentation index.
        teacher: (T, J_target, 9) float32 features of the optimiser's solution for this sample
            (window frame; from the shard's teacher file, :mod:`mer_data.shards.teacher`), or None.
    """

    reference: np.ndarray
    reference_skeleton: Skeleton
    target_skeleton: Skeleton
    joint_map: np.ndarray
    target: np.ndarray | None = None
    provenance: dict = field(default_factory=dict)
    teacher: np.ndarray | None = None


def graph_arrays(skel: Skeleton) -> dict[str, np.ndarray]:
    """A skeleton's graph conditions as arrays (see :data:`GRAPH_KEYS`)."""
    J = skel.num_nodes
    return {
        "parents": skel.parents.astype(np.int64),
        "offsets": skel.offsets.astype(np.float32),
        "axes": skel.axes.astype(np.float32),
        "lower": skel.lower.astype(np.float32),
        "upper": skel.upper.astype(np.float32),
        "nominal": skel.nominal.astype(np.float32),
        "psi": skel.psi.astype(np.int64),
        "mimic_source": np.where(skel.mimic_source >= 0, skel.mimic_source, np.arange(J)).astype(np.int64),
        "mimic_multiplier": skel.mimic_multiplier.astype(np.float32),
        "mimic_offset": skel.mimic_offset.astype(np.float32),
        "revolute": skel.revolute_mask,
    }


def _pad_graphs(skels: Sequence[Skeleton], prefix: str) -> dict[str, torch.Tensor]:
    B = len(skels)
    J = max(s.num_nodes for s in skels)
    out: dict[str, torch.Tensor] = {
        f"{prefix}_mask": torch.zeros(B, J, dtype=torch.bool),
        f"{prefix}_parents": torch.zeros(B, J, dtype=torch.long),  # padding hangs off the base
        f"{prefix}_mimic_source": torch.arange(J).repeat(B, 1),
        f"{prefix}_mimic_multiplier": torch.ones(B, J),
        f"{prefix}_psi": torch.zeros(B, J, J, dtype=torch.long),
    }
    for k in ("offsets", "axes"):
        out[f"{prefix}_{k}"] = torch.zeros(B, J, 3)
    for k in ("lower", "upper", "nominal", "mimic_offset"):
        out[f"{prefix}_{k}"] = torch.zeros(B, J)
    out[f"{prefix}_revolute"] = torch.zeros(B, J, dtype=torch.bool)
    for b, s in enumerate(skels):
        g = graph_arrays(s)
        n = s.num_nodes
        out[f"{prefix}_mask"][b, :n] = True
        out[f"{prefix}_parents"][b, :n] = torch.from_numpy(g["parents"])
        out[f"{prefix}_parents"][b, 0] = -1
        for k in ("offsets", "axes", "lower", "upper", "nominal", "mimic_multiplier", "mimic_offset"):
            out[f"{prefix}_{k}"][b, :n] = torch.from_numpy(g[k])
        out[f"{prefix}_mimic_source"][b, :n] = torch.from_numpy(g["mimic_source"])
        out[f"{prefix}_psi"][b, :n, :n] = torch.from_numpy(g["psi"])
        out[f"{prefix}_revolute"][b, :n] = torch.from_numpy(g["revolute"])
    return out


def _positions(features: np.ndarray) -> np.ndarray:
    """(T, J, 9) features → (T, J, 3) world positions (base at 3:6, other nodes at 1:4)."""
    f = np.asarray(features, np.float64)
    return np.concatenate([f[:, :1, 3:6], f[:, 1:, 1:4]], axis=1)


def reference_goals(
    features: np.ndarray, ref: Skeleton, target: Skeleton, *, scaling: ScalingMethod = "segments"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The goals a reference sets a target (:mod:`mer_data.kinematics.scaling`).

    Args:
        features: (T, J_ref, 9) reference features (world or window frame).

    Returns:
        scaled positions (T, J_ref, 3) [m], orientation goals (T, J_ref, 3, 3) and their mask (J_ref,).
    """
    f = np.asarray(features, np.float64)
    st = skeleton_tensors(ref, torch.float64)
    q = torch.from_numpy(f[:, :, 0].copy())
    q[:, 0] = 0
    base_rot = axis_angle_to_matrix(torch.from_numpy(f[:, 0, 0:3].copy()))
    _, rot = fk_skeleton(st, q, torch.from_numpy(f[:, 0, 3:6].copy()), base_rot=base_rot)
    scaled = scale_reference_positions(_positions(f), ref, target, rotations=rot.numpy(), method=scaling)
    goal_rot, mask = orientation_goals(rot.numpy(), ref, target)
    return scaled, goal_rot, mask


def collate(samples: Sequence[TrainingSample], *, scaling: ScalingMethod = "segments") -> dict:
    """Pad samples into a batch.

    Returns tensors ``reference`` (B, T, Jr, 9), ``target`` (B, T, Jt, 9) (zeros where absent) with
    ``has_target`` (B,), ``teacher`` (B, T, Jt, 9) with ``has_teacher`` (B,) likewise, ``joint_map`` (B, Jt, Jr), ``ref_scaled_pos`` (B, T, Jr, 3) (the reference
    node positions scaled to the target by ``scaling``, :mod:`mer_data.kinematics.scaling`), ``ref_goal_rot``
    (B, T, Jr, 3, 3) and ``ref_rot_mask`` (B, Jr) (orientation goals: :func:`reference_goals`),
    and per side (``ref_*``, ``tgt_*``) the graph
    arrays of :data:`GRAPH_KEYS` padded to the batch's node count plus a node ``mask``; padding
    nodes hang off the base with zero offset and axis, so FK of a padded batch is valid. Also
    ``ref_names`` / ``tgt_names`` (robot names) and ``provenance`` (list of dicts).

    The goals are computed once per (reference, target) skeleton object pair, on the frames of all
    its samples stacked (they are per frame): a batch of one robot pair costs one FK and one
    scaling call, not one per window.
    """
    if not samples:
        raise ValueError("cannot collate an empty list of samples")
    T = samples[0].reference.shape[0]
    if any(s.reference.shape[0] != T for s in samples):
        raise ValueError("all samples of a batch must have the same number of frames")
    refs = [s.reference_skeleton for s in samples]
    tgts = [s.target_skeleton for s in samples]
    batch: dict = {}
    batch.update(_pad_graphs(refs, "ref"))
    batch.update(_pad_graphs(tgts, "tgt"))
    B, Jr, Jt = len(samples), batch["ref_mask"].shape[1], batch["tgt_mask"].shape[1]
    batch["reference"] = torch.zeros(B, T, Jr, 9)
    batch["target"] = torch.zeros(B, T, Jt, 9)
    batch["has_target"] = torch.zeros(B, dtype=torch.bool)
    batch["teacher"] = torch.zeros(B, T, Jt, 9)
    batch["has_teacher"] = torch.zeros(B, dtype=torch.bool)
    batch["joint_map"] = torch.zeros(B, Jt, Jr)
    batch["ref_scaled_pos"] = torch.zeros(B, T, Jr, 3)
    batch["ref_goal_rot"] = torch.eye(3).expand(B, T, Jr, 3, 3).clone()
    batch["ref_rot_mask"] = torch.zeros(B, Jr, dtype=torch.bool)
    groups: dict[tuple[int, int], list[int]] = {}  # samples sharing a (reference, target) skeleton pair
    for b, s in enumerate(samples):
        groups.setdefault((id(s.reference_skeleton), id(s.target_skeleton)), []).append(b)
    for idx in groups.values():  # the goals are per frame: one call on the group's frames stacked
        s0, jr = samples[idx[0]], samples[idx[0]].reference.shape[1]
        frames = np.concatenate([np.asarray(samples[b].reference, np.float64) for b in idx])
        scaled, goal_rot, rot_mask = reference_goals(frames, s0.reference_skeleton, s0.target_skeleton, scaling=scaling)
        batch["ref_scaled_pos"][idx, :, :jr] = torch.from_numpy(scaled.reshape(len(idx), T, jr, 3)).float()
        batch["ref_goal_rot"][idx, :, :jr] = torch.from_numpy(goal_rot.reshape(len(idx), T, jr, 3, 3)).float()
        batch["ref_rot_mask"][idx, :jr] = torch.from_numpy(rot_mask)
    for b, s in enumerate(samples):
        jr, jt = s.reference.shape[1], s.target_skeleton.num_nodes
        batch["reference"][b, :, :jr] = torch.from_numpy(np.asarray(s.reference, np.float32))
        if s.target is not None:
            batch["target"][b, :, :jt] = torch.from_numpy(np.asarray(s.target, np.float32))
            batch["has_target"][b] = True
        if s.teacher is not None:
            batch["teacher"][b, :, :jt] = torch.from_numpy(np.asarray(s.teacher, np.float32))
            batch["has_teacher"][b] = True
        batch["joint_map"][b, :jt, :jr] = torch.from_numpy(s.joint_map.astype(np.float32))
    batch["ref_names"] = [s.name for s in refs]
    batch["tgt_names"] = [s.name for s in tgts]
    batch["provenance"] = [dict(s.provenance) for s in samples]
    return batch
