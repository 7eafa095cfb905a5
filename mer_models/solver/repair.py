"""The penalty method's self-penetration repair (``PhysicsConfig.method`` "penalty"): after the
solve, the samples, frames and pairs it left interpenetrating get whole-window iterations with the
self term (:func:`repair`); docs/decisions.md §Physical terms.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch

__all__ = ["SELF_POINTS", "repair", "held_frames", "widen"]

SELF_POINTS = "sat"  # the solver's self-penetration depth: the separating-axis one (mer_data.kinematics.collision)


def repair(inputs: Any, pos: torch.Tensor, rot: torch.Tensor, first: bool = True, seen: torch.Tensor | None = None,
           moved: torch.Tensor | None = None) -> tuple[torch.Tensor, Any] | None:  # fmt: skip
    """The repair iterations' samples and terms for a solution with node poses ``pos`` (B, T, J, 3),
    ``rot`` (B, T, J, 3, 3), or None when no sample needs one.

    A frame needs it where a pair of bodies interpenetrates by more than ``cfg.repair_depth``,
    or where a body other than a foot is lower than ``cfg.repair_touch`` (lying, kneeling: the
    floor term switching on and off there kinks the motion, which the repair's stiffer temporal
    prior smooths). Returns the samples with such a frame, (N,) indices, and their terms: the
    self term on the pairs found (each looked for within ``cfg.repair_reach`` frames of where it
    was found), and every frame farther than ``repair_reach`` from a found one held where it is
    (:meth:`held_frames`). Each sample on its own: its result does not depend on the rest of the batch.

    A later round (``first`` False) is triggered by pairs alone; ``seen`` (B, T, K) bool, the
    (frame, pair) entries earlier rounds found, stay in its self term (else it would push those
    pairs back together). The entries found so far are on the terms, as ``found``. ``moved``
    (B, T) bool: the only frames that can have a new pair (the last round's free ones; the
    rest are as that round found them, without any), the only ones searched.
    """
    from mer_data.kinematics.collision import lowest_points, pair_depths

    if not inputs.repairs:
        return None
    B, T, K = pos.shape[0], pos.shape[1], len(inputs.model.pairs)
    if inputs.cfg.w_self > 0 and K:
        where = None if moved is None else moved.to(pos.device)[..., None].expand(B, T, K)
        hit = pair_depths(inputs.model, pos, rot, which=SELF_POINTS, where=where) > inputs.cfg.repair_depth  # (B, T, K)
    else:
        hit = torch.zeros(B, T, K, dtype=torch.bool, device=pos.device)
    frames = hit.any(-1)
    body = torch.as_tensor(inputs.model.foot, device=pos.device) == 0
    if first and inputs.cfg.repair_touch is not None and bool(body.any()):
        frames = frames | (lowest_points(inputs.model, pos, rot)[0][..., body].amin(-1) < inputs.cfg.repair_touch)
    rows = frames.any(1).nonzero().flatten()
    if not len(rows):
        return None
    both = hit if seen is None else hit | seen
    any_pair = both[rows].any((0, 1))
    contacts = None if inputs.contacts is None else inputs.contacts[rows.to(inputs.contacts.device)]
    pairs = torch.as_tensor(inputs.model.pairs, device=pos.device).reshape(-1, 2)[any_pair]
    mask = both[rows][..., any_pair]  # (N, T, K'): where each pair was found
    free = frames[rows]  # (N, T)
    if inputs.cfg.repair_reach >= 0:  # widened by repair_reach frames
        mask, free = widen(mask, inputs.cfg.repair_reach), widen(free[..., None], inputs.cfg.repair_reach)[..., 0]
    else:
        mask, free = mask.any(1), torch.ones_like(free)
    return rows, dataclasses.replace(inputs, contacts=contacts, pairs=pairs, pair_mask=mask, free=free, found=both)


def held_frames(inputs: Any) -> torch.Tensor | None:
    """(B, T) bool: the frames a repair leaves where they are (farther than ``cfg.repair_reach``
    frames from any it found interpenetrating); None: none held."""
    return None if inputs.free is None else ~torch.as_tensor(inputs.free)


def widen(mask: torch.Tensor, r: int) -> torch.Tensor:
    """(N, T, K) bool, each (n, k) series widened by ``r`` frames either way."""
    n, T, k = mask.shape
    if not mask.numel():
        return mask
    wide = torch.nn.functional.max_pool1d(mask.permute(0, 2, 1).reshape(n * k, 1, T).float(), 2 * r + 1, 1, r)
    return wide.reshape(n, k, T).permute(0, 2, 1) > 0



