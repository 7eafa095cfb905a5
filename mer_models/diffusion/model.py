"""The retargeting model as users and samplers see it: batch → conditions → ``D(x, sigma, C)`` → motion.

:class:`RetargetModel` wraps the network (:mod:`mer_models.diffusion.network`) with

* the canonical frame of each window and the diffusion-space scaling (:mod:`mer_models.diffusion.representation`),
* EDM preconditioning with the joint-limit clip (:mod:`mer_models.diffusion.edm`),
* the energy of a prediction (:mod:`mer_models.solver.energy`),
* decoding of a denoised sample into a world-frame motion (joint angles + base pose).

The denoiser contract is k-diffusion's: ``model.denoise(x, sigma, cond) -> D`` with ``x`` (B, T, Jt, 9)
in the diffusion space; the encoded reference is computed once per :class:`Conditions` and reused
by every denoising step.

The base orientation channels of a sample are the rotation vector of the base's orientation, or,
with ``ModelConfig.goal_frame_rotation``, ``delta`` with ``R = R_goal Exp(delta)`` (the goal's
frame, :meth:`RetargetModel.base_goal_rotation`): every way into the diffusion space
(:meth:`RetargetModel.to_sample`, :meth:`RetargetModel.target_sample`, ``clean_samples`` of
training) and out of it (:meth:`RetargetModel.physical`, :meth:`RetargetModel.base_rotation`,
:meth:`RetargetModel.decode`, :meth:`RetargetModel.project`, the energy) goes through the model.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Mapping

import torch
from torch import nn

from mer_data.kinematics.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from mer_data.motion.features import finite_difference
from mer_models.batch import BatchGraph, batch_features, descendants, graph_from_batch, nearest_mapped_ancestor
from mer_models.config import EnergyConfig, ModelConfig
from mer_models.hub.pretrained import PretrainedMixin
from mer_models.solver.energy import f_kin, keypoint_goals, orientation_pairs

from .edm import combine, precondition
from .network import GOAL_DIM, RetargetNet
from .representation import (
    base_origin,
    canonical_rotation,
    denormalize,
    normalize,
    rotation_from_frame,
    rotation_in_frame,
    transform_features,
    transform_points,
    unwrap_rotvec,
)

__all__ = ["Conditions", "RetargetModel", "GOAL_DIM", "shared_rows"]


@dataclass
class Conditions:
    """The paper's ``C = (M, g^M, g^X, eta)`` of a batch, in the canonical frame.

    Attributes:
        reference: (B, T, Jr, 9) reference features, canonical frame, diffusion space.
        ref_graph, tgt_graph: the two sides' padded skeletons.
        eta: (B, Jt, Jr) float joint map.
        goal: (B, T, Jr, 3) body-part-scaled reference positions, canonical frame [m].
        rot: (B, 3, 3) canonical ← world rotation; origin: (B, 3) world point at the canonical origin
            (the scaled reference's first base position on the ground).
        fps: frame rate [Hz].
        goal_rot: (B, T, Jr, 3, 3) orientation goals, canonical frame, and rot_mask (B, Jr) the
            reference nodes that carry one (None: no orientation term).
        ref_shared: ``(first, inverse)`` of :func:`shared_rows` over the input references and their
            skeletons: the samples whose reference is encoded (U,) and each sample's (B,) (None: every
            sample is encoded).
        ref_tokens: the encoded reference (filled on first use, reused by every denoising step).
        goal_feats: (B, T, Jt, GOAL_DIM) the goal input of ``goal_input`` networks (filled on first use).
        prior: (B, T, Jt, 9) the goals as a sample, for ``goal_prior`` networks (filled on first use).
        base_goal: (B, T, 3, 3) the base's orientation goal, canonical frame, identity where it has
            none: the frame of ``goal_frame_rotation`` networks' base orientation (filled on first use).
    """

    reference: torch.Tensor
    ref_graph: BatchGraph
    tgt_graph: BatchGraph
    eta: torch.Tensor
    goal: torch.Tensor
    rot: torch.Tensor
    origin: torch.Tensor
    fps: float = 30.0
    goal_rot: torch.Tensor | None = None
    rot_mask: torch.Tensor | None = None
    ref_shared: tuple[torch.Tensor, torch.Tensor] | None = None
    ref_tokens: torch.Tensor | None = None
    goal_feats: torch.Tensor | None = None
    prior: torch.Tensor | None = None
    base_goal: torch.Tensor | None = None

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(B, T, Jt, 9): the shape of a target sample."""
        B, T = self.reference.shape[:2]
        return (B, T, self.tgt_graph.parents.shape[1], 9)


class RetargetModel(PretrainedMixin, nn.Module):
    """The guided-diffusion retargeter (network + preconditioning + representation)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        cfg.check_size()  # an absurd configuration is refused before anything is allocated
        self.cfg = cfg
        self.net = RetargetNet(cfg)

    # ---- conditions -------------------------------------------------------------------------
    def conditions(self, batch: Mapping, fps: float = 30.0) -> Conditions:
        """Canonical-frame conditions of a collated batch (:func:`mer_data.motion.samples.collate`)."""
        dev = next(self.parameters()).device
        ref = batch["reference"].to(dev, torch.float32)
        ref_graph = graph_from_batch(batch, "ref", dev)
        # samples with the same input reference (one window to several targets) get one canonical
        # frame and one encoding (the frame's arithmetic is not bitwise the same across batch rows)
        first, inverse = shared_rows(ref, *(getattr(ref_graph, f.name) for f in fields(BatchGraph)))
        shared = len(first) < ref.shape[0]
        own = ref[first] if shared else ref
        rot = canonical_rotation(own)
        reference = normalize(transform_features(own, rot, base_origin(own)), self.cfg)
        if shared:
            rot, reference = rot[inverse], reference[inverse]
        reference = reference * batch["ref_mask"].to(dev)[:, None, :, None]
        scaled = batch["ref_scaled_pos"].to(dev, torch.float32)
        origin = scaled[:, 0, 0].clone()
        origin[:, 2] = 0
        goal_rot = rot_mask = None
        if "ref_goal_rot" in batch:
            goal_rot = rot[:, None, None] @ batch["ref_goal_rot"].to(dev, torch.float32)
            rot_mask = batch["ref_rot_mask"].to(dev)
        return Conditions(
            reference=reference,
            ref_graph=ref_graph,
            ref_shared=(first, inverse),
            tgt_graph=graph_from_batch(batch, "tgt", dev),
            eta=batch["joint_map"].to(dev, torch.float32),
            goal=transform_points(scaled, rot, origin),
            rot=rot,
            origin=origin,
            fps=fps,
            goal_rot=goal_rot,
            rot_mask=rot_mask,
        )

    def target_sample(self, target: torch.Tensor, cond: Conditions) -> torch.Tensor:
        """A clean target window (B, T, Jt, 9) physical world features → diffusion space, canonical.

        The window is placed at its own first base position (the model learns to start at the
        scaled reference's), rotated like the reference.
        """
        t = transform_features(target.to(cond.rot.device, torch.float32), cond.rot, base_origin(target.to(cond.rot.device)))
        return self.to_sample(t, cond)

    def to_sample(self, feats: torch.Tensor, cond: Conditions, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Physical features in the canonical frame (B, T, Jt, 9) (base rotation as a rotation vector)
        → the diffusion space, padding zero; ``rows`` (B,): the samples of ``cond`` they belong to
        (all by default). With ``goal_frame_rotation`` the base's rotation becomes
        ``delta = Log(R_goal^T R)``, unwrapped along time; the inverse is :meth:`physical`.
        """
        mask = cond.tgt_graph.mask if rows is None else cond.tgt_graph.mask[rows]
        if self.cfg.goal_frame_rotation:
            frame = self.base_goal_rotation(cond)
            frame = frame if rows is None else frame[rows]
            feats = feats.clone()
            feats[:, :, 0, 0:3] = rotation_in_frame(feats[:, :, 0, 0:3], frame.to(feats.dtype))
        return normalize(feats, self.cfg) * mask[:, None, :, None]

    def base_goal_rotation(self, cond: Conditions) -> torch.Tensor:
        """(B, T, 3, 3) the base's orientation goal (canonical frame), identity for a sample whose base
        has none or without orientation goals (no parameters; computed once per :class:`Conditions`)."""
        if cond.base_goal is None:
            B, T = cond.reference.shape[:2]
            dev = cond.reference.device
            frame = torch.eye(3, device=dev).expand(B, T, 3, 3)
            if cond.goal_rot is not None and cond.rot_mask is not None:
                grot, has_rot = orientation_pairs(cond.eta, cond.goal_rot, cond.rot_mask)
                frame = torch.where(has_rot[:, None, :1, None], grot[:, :, 0], frame)
            cond.base_goal = frame.contiguous()
        return cond.base_goal

    # ---- denoiser ---------------------------------------------------------------------------
    def encode(self, cond: Conditions) -> torch.Tensor:
        """(B, T, Jr, H) the encoded reference, computed on first use; samples that share a reference
        (``cond.ref_shared``) are encoded once and share the tokens (the encoder sees each sample
        alone, so this equals encoding every sample)."""
        if cond.ref_tokens is None:
            if cond.ref_shared is not None and len(cond.ref_shared[0]) < cond.reference.shape[0]:
                first, inverse = cond.ref_shared
                tokens = self.net.encode_reference(cond.reference[first], cond.ref_graph.select(first))
                cond.ref_tokens = torch.index_select(tokens, 0, inverse)
            else:
                cond.ref_tokens = self.net.encode_reference(cond.reference, cond.ref_graph)
        return cond.ref_tokens

    def goal_features(self, cond: Conditions) -> torch.Tensor:
        """(B, T, Jt, GOAL_DIM) what each target node is asked to do, in the diffusion space.

        Per target node, from the joint map and the scaled reference (the goals of ``f_kin``):
        goal position / ``pos_scale``, the same relative to the base's goal, goal velocity /
        ``vel_scale``, a flag (the node has a position goal), its orientation goal's first two
        columns and a flag (the node's orientation is tracked); zero where a node has no goal. Then,
        in the frame of the base's orientation goal (what the joint angles are relative to): the
        node's goal relative to the base's, and its *segment*: from the goal of its nearest mapped
        ancestor to its own goal, or, for a node without one, to the mean goal of the mapped nodes
        below it (what its joint must turn towards; zero if there are none).
        Computed once per :class:`Conditions` (no parameters).
        """
        if cond.goal_feats is not None:
            return cond.goal_feats
        eta = cond.eta
        goals, has = keypoint_goals(eta, cond.goal)  # (B, T, Jt, 3), (B, Jt)
        has = has & cond.tgt_graph.mask
        m = has[:, None, :, None].to(goals.dtype)
        ps, vs = self.cfg.pos_scale, self.cfg.vel_scale
        rel = goals - goals[:, :, :1]
        vel = finite_difference(goals, cond.fps, dim=-3)
        B, T, Jt = goals.shape[:3]
        rot6 = goals.new_zeros(B, T, Jt, 6)
        has_rot = torch.zeros(B, Jt, dtype=torch.bool, device=goals.device)
        if cond.goal_rot is not None and cond.rot_mask is not None:
            grot, has_rot = orientation_pairs(eta, cond.goal_rot, cond.rot_mask)
            has_rot = has_rot & cond.tgt_graph.mask
            rot6 = grot[..., :, :2].transpose(-1, -2).reshape(B, T, Jt, 6)
        mr = has_rot[:, None, :, None].to(goals.dtype)
        g = cond.tgt_graph
        base_rot = grot[:, :, 0] if cond.goal_rot is not None and cond.rot_mask is not None and bool(has_rot[:, 0].all()) else None
        local = rel if base_rot is None else torch.einsum("btji,btnj->btni", base_rot, rel)  # R_b^T (g - g_0)
        below = descendants(g.parents) & g.mask[:, None, :] & has[:, None, :]  # (B, J, J): mapped nodes under (or at) j
        count = below.sum(-1)
        centroid = torch.einsum("bjk,btkd->btjd", below.to(local.dtype), local) / count.clamp_min(1)[:, None, :, None]
        anc, _ = nearest_mapped_ancestor(g.parents, has)  # (B, J) strict ancestor with a goal (0: the base)
        start = torch.gather(local, 2, anc[:, None, :, None].expand(B, T, Jt, 3))
        end = torch.where(has[:, None, :, None], local, centroid)
        seg = (end - start) * ((count > 0) & g.mask)[:, None, :, None].to(local.dtype)
        seg[:, :, 0] = 0
        feats = torch.cat(
            [goals / ps * m, rel / ps * m, vel / vs * m, m.expand(B, T, Jt, 1), rot6 * mr, mr.expand(B, T, Jt, 1),
             local / ps * m, seg / ps], -1
        )  # fmt: skip
        assert feats.shape[-1] == GOAL_DIM
        cond.goal_feats = feats
        return feats

    def goal_prior(self, cond: Conditions) -> torch.Tensor:
        """(B, T, Jt, 9) the goals as a sample in the diffusion space (``goal_prior``; no parameters).

        Base: its orientation goal (rotation vector, unwrapped along time; 0 without orientation
        goals; always 0 with ``goal_frame_rotation``, whose ``delta`` is relative to that goal), its
        goal position and velocity. Other nodes: angle 0; position and velocity of the
        node's goal, or of its nearest ancestor's that has one (the base's at worst). Padding: 0.
        """
        if cond.prior is not None:
            return cond.prior
        goals, has = keypoint_goals(cond.eta, cond.goal)  # (B, T, Jt, 3), (B, Jt)
        g = cond.tgt_graph
        has = has & g.mask
        B, T, Jt = goals.shape[:3]
        _, src = nearest_mapped_ancestor(g.parents, has)  # node whose goal stands in (itself, an ancestor, the base)
        pos = torch.gather(goals, 2, src[:, None, :, None].expand(B, T, Jt, 3))
        vel = finite_difference(pos, cond.fps, dim=-3)
        prior = goals.new_zeros(B, T, Jt, 9)
        ps, vs = self.cfg.pos_scale, self.cfg.vel_scale
        if cond.goal_rot is not None and cond.rot_mask is not None and not self.cfg.goal_frame_rotation:
            grot, has_rot = orientation_pairs(cond.eta, cond.goal_rot, cond.rot_mask)
            rv = unwrap_rotvec(matrix_to_axis_angle(grot[:, :, 0]))
            prior[:, :, 0, 0:3] = rv * has_rot[:, None, :1].to(rv.dtype)
        prior[:, :, 0, 3:6] = pos[:, :, 0] / ps
        prior[:, :, 0, 6:9] = vel[:, :, 0] / vs
        prior[:, :, 1:, 1:4] = pos[:, :, 1:] / ps
        prior[:, :, 1:, 4:7] = vel[:, :, 1:] / vs
        cond.prior = prior * g.mask[:, None, :, None].to(prior.dtype)
        return cond.prior

    def denoise(self, x: torch.Tensor, sigma: torch.Tensor | float, cond: Conditions) -> torch.Tensor:
        """``D(x, sigma, C)``: x (B, T, Jt, 9) diffusion space, sigma scalar or (B,) → (B, T, Jt, 9).

        Joint angles of the output are inside the target's limits by construction.
        """
        B = x.shape[0]
        sigma = torch.as_tensor(sigma, dtype=x.dtype, device=x.device).reshape(-1).expand(B)
        _, _, c_in, c_noise = precondition(sigma, self.cfg.sigma_data)
        goal = self.goal_features(cond) if self.cfg.goal_input else None
        prior = self.goal_prior(cond).to(x.dtype) if self.cfg.goal_prior else None
        if prior is not None:  # residual diffusion: denoise x - P, add P back (angles have P = 0)
            x = x - prior
        f = self.net(x * c_in.view(-1, 1, 1, 1), c_noise, self.encode(cond), cond.tgt_graph, cond.eta, goal)
        g = cond.tgt_graph
        d = combine(x, f.to(x.dtype), sigma, self.cfg.sigma_data, g.lower, g.upper, g.mask)
        return d if prior is None else d + prior

    # ---- physics of a prediction ------------------------------------------------------------
    def physical(self, d: torch.Tensor, cond: Conditions | None = None) -> torch.Tensor:
        """A sample (B, T, Jt, 9) in the diffusion space → physical canonical features, the base's
        rotation as a rotation vector [rad] (unwrapped along time). ``cond`` is needed (only) by
        ``goal_frame_rotation`` models, whose ``delta`` is relative to the base's goal."""
        p = denormalize(d, self.cfg)
        if not self.cfg.goal_frame_rotation:
            return p
        if cond is None:
            raise ValueError("this model's base rotation is relative to its goal (goal_frame_rotation): pass the conditions")
        rv = unwrap_rotvec(matrix_to_axis_angle(self._base_rotation(p, cond)))
        return torch.cat([torch.cat([rv[:, :, None], p[:, :, :1, 3:]], -1), p[:, :, 1:]], 2)

    def base_rotation(self, d: torch.Tensor, cond: Conditions) -> torch.Tensor:
        """(B, T, 3, 3) canonical ← base rotation of a sample (B, T, Jt, 9) in the diffusion space:
        ``Exp(r)``, or ``R_goal Exp(delta)`` with ``goal_frame_rotation``."""
        return self._base_rotation(denormalize(d, self.cfg), cond)

    def _base_rotation(self, p: torch.Tensor, cond: Conditions) -> torch.Tensor:
        """:meth:`base_rotation` of denormalized features ``p`` (B, T, Jt, 9)."""
        r = p[..., 0, 0:3]
        if self.cfg.goal_frame_rotation:
            return rotation_from_frame(r, self.base_goal_rotation(cond).to(r.dtype))
        return axis_angle_to_matrix(r)

    def energy(self, d: torch.Tensor, cond: Conditions, ecfg: EnergyConfig) -> dict[str, torch.Tensor]:
        """``f_kin`` terms of a denoised sample (B,) each (:func:`mer_models.solver.energy.f_kin`)."""
        return f_kin(ecfg, cond.tgt_graph, self.physical(d, cond), cond.eta, cond.goal, cond.fps, cond.goal_rot, cond.rot_mask)

    def project(self, d: torch.Tensor, cond: Conditions) -> torch.Tensor:
        """A denoised sample made kinematically consistent (B, T, Jt, 9), diffusion space: its joint
        angles and base pose kept, every position and velocity feature recomputed by FK of them
        (what the ``feedback`` sampler feeds back; the angles are the motion, :meth:`decode`)."""
        p = denormalize(d, self.cfg)
        q = torch.cat([torch.zeros_like(p[..., :1, 0]), p[..., 1:, 0]], -1) * cond.tgt_graph.revolute[:, None]
        feats = batch_features(cond.tgt_graph, q, p[..., 0, 3:6], self._base_rotation(p, cond), cond.fps)
        base = torch.cat([p[..., :1, 0:3], feats[..., :1, 3:]], -1)  # the base keeps its own (unwrapped) rotation
        feats = torch.cat([base, feats[..., 1:, :]], 2)
        return normalize(feats, self.cfg) * cond.tgt_graph.mask[:, None, :, None].to(d.dtype)

    def decode(self, d: torch.Tensor, cond: Conditions) -> dict[str, torch.Tensor]:
        """A denoised sample → world motion.

        Returns ``q`` (B, T, Jt) [rad] (0 at base, sites, padding), ``base_pos`` (B, T, 3) [m],
        ``base_rot`` (B, T, 3, 3) world ← base.
        """
        p = denormalize(d, self.cfg)
        q = torch.cat([torch.zeros_like(p[..., :1, 0]), p[..., 1:, 0]], -1) * cond.tgt_graph.revolute[:, None]
        rot_c = self._base_rotation(p, cond)
        base_rot = cond.rot.transpose(-1, -2)[:, None] @ rot_c
        base_pos = torch.einsum("bji,btj->bti", cond.rot, p[..., 0, 3:6]) + cond.origin[:, None]
        return {"q": q, "base_pos": base_pos, "base_rot": base_rot}

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def shared_rows(*tensors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Samples that are equal in every tensor (each (B, ...)): ``first`` (U,) the first sample of each
    distinct one, in batch order, and ``inverse`` (B,) the position in ``first`` of each sample's
    (``x[first][inverse]`` equals ``x`` for every tensor given). Bitwise equality; NaN equals nothing.

    Rows are matched by an integer checksum of their bits (exact: the same for equal rows wherever
    they sit in the batch, which a floating-point sum is not), then compared in full."""
    B = tensors[0].shape[0]
    dev = tensors[0].device
    rows = [t.detach().reshape(B, -1) for t in tensors]
    h = torch.zeros(B, dtype=torch.int64, device=dev)
    for r in rows:
        bits = (r if r.dtype == torch.float32 else r.to(torch.float32)).view(torch.int32) if r.is_floating_point() else r.to(torch.int32)
        w = torch.arange(r.shape[1], dtype=torch.int32, device=dev) % 32749 + 1
        h = h + (bits * w).sum(1)  # int32 products wrap, the int64 sum is exact: no rounding, no order
    match = h[:, None] == h[None, :]
    idx = torch.arange(B, device=dev)
    cand = match.to(torch.int8).argmax(1)  # the first row with the same checksum (itself at worst)
    dup = torch.nonzero(cand != idx).flatten()
    same = torch.ones(len(dup), dtype=torch.bool, device=dev)
    for r in rows:
        same &= (r[dup] == r[cand[dup]]).all(1)  # a checksum can collide, and NaN is unequal: compare in full
    cand = cand.index_put((dup[~same],), dup[~same])
    first, inverse = torch.unique(cand, return_inverse=True)  # sorted: batch order
    return first, inverse
