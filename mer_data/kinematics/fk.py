"""Batched, differentiable forward kinematics of skeleton graphs, in torch.

The kinematics take the skeleton's geometry as tensors **per sample**: one batch can mix robots
(padded to a common node count, with per-sample ``parents``) and augmented, link-scaled skeletons.
That is what pytorch_kinematics cannot do, and why mer has its own kernel.

Model (see :mod:`mer_data.skeleton`): every node frame is aligned with the root frame at the zero
pose, so with ``R_j``, ``p_j`` the world rotation and position of node ``j``::

    R_0 = base_rot,                       p_0 = base_pos
    R_j = R_parent(j) @ Rot(axes_j, q_j),  p_j = p_parent(j) + R_parent(j) @ offsets_j

``Rot(a, q) = I + sin(q) [a]x + (1 - cos q) [a]x^2`` is the identity for a zero axis (base, sites).

The tree is evaluated level by level (all nodes at one depth in one batched product; a node's
parent is always one level up), so the cost is ``depth`` batched steps, not ``J`` steps.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from mer_data.skeleton import Skeleton

from .fk_kernel import axis_matrices, broadcast_shapes, fk_core, rodrigues
from .rotations import quat_to_matrix

__all__ = [
    "forward_kinematics",
    "SkeletonTensors",
    "skeleton_tensors",
    "fk_skeleton",
    "joint_rotations",
    "apply_mimic",
    "link_rotations",
]


@dataclass(frozen=True)
class SkeletonTensors:
    """A skeleton's arrays as torch tensors, ready for :func:`forward_kinematics`.

    Shapes: ``parents`` (J,) long; ``offsets``, ``axes`` (J, 3); ``lower``, ``upper``, ``nominal``
    (J,); ``mimic_source`` (J,) long (index of the driving node, the node itself where none),
    ``mimic_multiplier``, ``mimic_offset`` (J,); ``rest_rotations`` (J, 3, 3).
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
    rest_rotations: torch.Tensor


def skeleton_tensors(
    skel: Skeleton, dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> SkeletonTensors:
    """Convert a :class:`Skeleton` to tensors (once per robot; reuse across batches)."""
    J = skel.num_nodes
    src = np.where(skel.mimic_source >= 0, skel.mimic_source, np.arange(J))
    f = lambda a: torch.tensor(np.asarray(a), dtype=dtype, device=device)  # noqa: E731 (copies)
    return SkeletonTensors(
        parents=torch.tensor(skel.parents, dtype=torch.long, device=device),
        offsets=f(skel.offsets),
        axes=f(skel.axes),
        lower=f(skel.lower),
        upper=f(skel.upper),
        nominal=f(skel.nominal),
        mimic_source=torch.tensor(src, dtype=torch.long, device=device),
        mimic_multiplier=f(skel.mimic_multiplier),
        mimic_offset=f(skel.mimic_offset),
        rest_rotations=f(skel.rest_rotations),
    )


def apply_mimic(q: torch.Tensor, source: torch.Tensor, multiplier: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """Replace mimic joints' angles: ``q_j <- multiplier_j * q[source_j] + offset_j``.

    ``source`` is the node itself (and multiplier 1, offset 0) where there is no mimic, so the
    result equals ``q`` there. Shapes broadcast as ``q`` (..., J).
    """
    if source.dim() == 1:
        driven = q[..., source]
    else:
        driven = torch.gather(q, -1, source.expand(q.shape))
    return multiplier * driven + offset


def joint_rotations(axes: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Rodrigues rotations ``Rot(axes_j, q_j)``: (..., J, 3), (..., J) → (..., J, 3, 3).

    ``I + sin(q) [a]x + (1 - cos q) [a]x^2``: the identity wherever the axis is zero.
    """
    k, kk = axis_matrices(axes)
    return rodrigues(k, kk, q)


def forward_kinematics(
    q: torch.Tensor,
    base_pos: torch.Tensor,
    base_rot: torch.Tensor,
    offsets: torch.Tensor,
    axes: torch.Tensor,
    parents: Sequence[int] | torch.Tensor | np.ndarray,
) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions and rotations of every node.

    Args:
        q: (..., J) joint angles [rad]; entries of the base and of sites are ignored (zero axes).
            Apply :func:`apply_mimic` first if the skeleton has mimic joints.
        base_pos: (..., 3) base position in the world [m].
        base_rot: (..., 3, 3) world ← base rotation.
        offsets: (..., J, 3) parent → node vectors, root frame at zero pose [m].
        axes: (..., J, 3) unit joint axes, root frame at zero pose (zero for base and sites).
        parents: (J,) shared parent indices with ``parents[0] = -1`` and ``parents[j] < j``, or a
            (B, J) tensor with one row per sample of a mixed batch (``q`` then has shape (B, ..., J);
            padding nodes may hang off node 0 with zero offset and axis).

    All leading dimensions broadcast against each other, so per-sample skeletons of shape
    (B, 1, J, 3) go with a motion batch (B, T, J).

    Returns:
        pos: (..., J, 3) world positions [m].
        rot: (..., J, 3, 3) world ← node rotations (node frames are root-aligned at zero pose;
            multiply by ``rest_rotations`` for the URDF link orientation).
    """
    if isinstance(parents, torch.Tensor) and parents.dim() == 2 or (
        isinstance(parents, np.ndarray) and parents.ndim == 2
    ):
        return _forward_kinematics_mixed(q, base_pos, base_rot, offsets, axes, torch.as_tensor(parents))
    par = tuple(int(p) for p in (parents.tolist() if hasattr(parents, "tolist") else parents))
    J = len(par)
    if q.shape[-1] != J:
        raise ValueError(f"q has {q.shape[-1]} joints, the skeleton has {J} nodes")
    return fk_core(q, base_pos, base_rot, offsets, axes, par)


def _forward_kinematics_mixed(q, base_pos, base_rot, offsets, axes, parents: torch.Tensor):
    """Mixed batch: run the shared-topology kernel once per distinct ``parents`` row."""
    B, J = parents.shape
    if q.shape[0] != B:
        raise ValueError(f"parents has {B} rows but q has batch size {q.shape[0]}")
    batch = broadcast_shapes(q.shape[:-1], base_pos.shape[:-1], base_rot.shape[:-2], offsets.shape[:-2], axes.shape[:-2])
    rows, inverse = torch.unique(parents.cpu(), dim=0, return_inverse=True)
    pos_parts, rot_parts, index_parts = [], [], []
    for g, row in enumerate(rows):
        sel = torch.nonzero(inverse == g).flatten().to(q.device)

        def pick(t: torch.Tensor, tail: int) -> torch.Tensor:
            return t.expand(batch + t.shape[t.dim() - tail :]).index_select(0, sel)

        off, ax = _shared(offsets, sel, B), _shared(axes, sel, B)
        if off is None or ax is None:
            off, ax = pick(offsets, 2), pick(axes, 2)
        else:  # the dtype the per-sample products would have promoted to
            dtype = functools.reduce(torch.promote_types, (q.dtype, base_pos.dtype, base_rot.dtype, off.dtype, ax.dtype))
            off, ax = off.to(dtype), ax.to(dtype)
        p, r = forward_kinematics(pick(q, 1), pick(base_pos, 1), pick(base_rot, 2), off, ax, row.tolist())
        pos_parts.append(p)
        rot_parts.append(r)
        index_parts.append(sel)
    back = torch.argsort(torch.cat(index_parts))
    return torch.cat(pos_parts).index_select(0, back), torch.cat(rot_parts).index_select(0, back)


def _shared(t: torch.Tensor, sel: torch.Tensor, B: int) -> torch.Tensor | None:
    """(J, 3) when the (..., J, 3) geometry ``t`` is the same for every selected sample and frame (a
    batch of one robot: the kernel's shared-geometry path, one GEMM per level), else None; never
    for geometry that requires gradients (each sample's own gradient)."""
    if t.requires_grad:
        return None
    part = t.index_select(0, sel) if t.dim() > 2 and t.shape[0] == B else t
    flat = part.reshape(-1, *t.shape[-2:])
    if flat.shape[0] > 1 and not bool((flat == flat[:1]).all()):
        return None
    return flat[0]


def fk_skeleton(
    st: SkeletonTensors,
    q: torch.Tensor,
    base_pos: torch.Tensor,
    base_quat: torch.Tensor | None = None,
    base_rot: torch.Tensor | None = None,
    offsets: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """FK of one skeleton (mimic joints applied). Give ``base_quat`` (..., 4) wxyz or ``base_rot``.

    ``offsets`` overrides the skeleton's (e.g. an augmented copy); returns as :func:`forward_kinematics`.
    """
    if base_rot is None:
        if base_quat is None:
            raise ValueError("give base_quat or base_rot")
        base_rot = quat_to_matrix(base_quat)
    q = apply_mimic(q, st.mimic_source, st.mimic_multiplier, st.mimic_offset)
    return forward_kinematics(
        q, base_pos, base_rot, st.offsets if offsets is None else offsets, st.axes, st.parents
    )


def link_rotations(node_rot: torch.Tensor, rest_rotations: torch.Tensor) -> torch.Tensor:
    """World orientation of each node's URDF link: (..., J, 3, 3) @ (J, 3, 3)."""
    return node_rot @ rest_rotations
