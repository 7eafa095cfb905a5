"""The warm-start model as users see it: a collated batch → a motion for the optimiser to finish.

:class:`WarmModel` runs :class:`~mer_models.warm.network.WarmNet` on the node inputs of
:mod:`mer_models.warm.features` and turns its outputs into a world-frame motion:

* joint angles ``q = lower + (upper - lower) * sigmoid(logit(nominal) + z)``: inside the limits by
  construction, the nominal pose where the network outputs zero (the joint-limit
  parametrisation of :mod:`mer_models.solver.limits`);
* base orientation ``R = R_b · Exp(δ)``: a rotation about the base goal orientation ``R_b``,
  well conditioned at any tilt (lying, getting up);
* base position: the base goal plus a residual in the heading frame [m].

:meth:`WarmModel.loss` is the training objective: regression on the teacher's solution (angles,
body positions by FK, base pose) plus the teacher's energy ``f_kin`` of the output.
"""

from __future__ import annotations

from typing import Mapping

import torch
from torch import nn

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_models.batch import BatchGraph, batch_fk, graph_from_batch
from mer_models.config import EnergyConfig, RunConfig, WarmConfig
from mer_models.hub.pretrained import PretrainedMixin
from mer_models.solver.energy import energy_terms
from mer_models.solver.limits import limit_clip, limit_logit

from .features import node_inputs, relations
from .network import WarmNet

__all__ = ["WarmModel", "key_frames", "interpolate", "frames_of"]

#: The per-frame entries of a collated batch (B, T, ...); the rest describe the skeletons and the samples.
PER_FRAME = ("reference", "ref_scaled_pos", "ref_goal_rot", "teacher", "target")


def frames_of(batch: Mapping, lo: int, hi: int) -> dict:
    """The batch restricted to frames ``lo:hi`` (its per-frame entries sliced, the rest shared)."""
    return {k: (v[:, lo:hi] if k in PER_FRAME and torch.is_tensor(v) else v) for k, v in batch.items()}


def key_frames(T: int, stride: int, offset: int = 0) -> torch.Tensor:
    """(K,) the frames the network runs on: every ``stride``-th from ``offset``, with the first and last."""
    keys = torch.arange(offset % stride, T, stride)
    if len(keys) == 0 or keys[0] != 0:
        keys = torch.cat([torch.zeros(1, dtype=keys.dtype), keys])
    if keys[-1] != T - 1:
        keys = torch.cat([keys, torch.tensor([T - 1])])
    return keys


def interpolate(v: torch.Tensor, keys: torch.Tensor, T: int) -> torch.Tensor:
    """(B, K, ...) values at the frames ``keys`` → (B, T, ...), linear in between."""
    t = torch.arange(T, dtype=torch.float32)
    hi = torch.searchsorted(keys, torch.arange(T), right=False).clamp(1, len(keys) - 1)
    lo = hi - 1
    w = ((t - keys[lo]) / (keys[hi] - keys[lo]).clamp_min(1)).clamp(0, 1).to(v.dtype).view(1, T, *([1] * (v.dim() - 2)))
    return v[:, lo] * (1 - w) + v[:, hi] * w


class WarmModel(PretrainedMixin, nn.Module):
    """The warm-start network with its input features and output parametrisation."""

    kind = "warm"

    @staticmethod
    def config_of(run: RunConfig) -> WarmConfig:
        return run.warm

    def __init__(self, cfg: WarmConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.net = WarmNet(cfg)

    def forward_batch(self, batch: Mapping, fps: float = 30.0, offset: int = 0) -> dict[str, torch.Tensor]:
        """A collated batch (:func:`mer_data.motion.samples.collate`) → ``q`` (B, T, Jt) [rad] (0 at
        the base, sites and padding), ``base_pos`` (B, T, 3) [m], ``base_rot`` (B, T, 3, 3) world ←
        base, in the batch's frame (that of ``ref_scaled_pos``); differentiable. The network runs on
        the key frames of ``WarmConfig.stride`` (from ``offset``: training draws it)."""
        dev = next(self.parameters()).device
        g = graph_from_batch(batch, "tgt", dev)
        ref = graph_from_batch(batch, "ref", dev)
        x, a = node_inputs(batch, g, ref, fps, self.cfg.vel_scale, dev)
        keys = key_frames(x.shape[1], self.cfg.stride, offset)
        z, base = self.net(x[:, keys], relations(g.parents, g.mask), g.mask)
        if len(keys) < x.shape[1]:
            z, base = interpolate(z.float(), keys, x.shape[1]), interpolate(base.float(), keys, x.shape[1])
        return self._motion(g, z.float(), base.float(), a)

    def _motion(self, g: BatchGraph, z: torch.Tensor, base: torch.Tensor, a) -> dict[str, torch.Tensor]:
        z0 = limit_logit(g.nominal, g.lower, g.upper)[:, None]
        q = limit_clip(z0 + z, g.lower[:, None], g.upper[:, None]) * g.dof[:, None].to(z.dtype)
        rot = a.rot_b @ axis_angle_to_matrix(base[..., 0:3])
        pos = a.pos_b + torch.einsum("btij,btj->bti", a.heading, base[..., 3:6])
        return {"q": q, "base_pos": pos, "base_rot": rot}

    @torch.no_grad()
    def predict(self, batch: Mapping, fps: float = 30.0, chunk: int = 256) -> dict[str, torch.Tensor]:
        """:meth:`forward_batch` without gradient, over time chunks of ``chunk`` frames with the
        network's receptive field as margin on each side (any length at bounded memory; the same
        result as one pass)."""
        T = batch["reference"].shape[1]
        margin = self.cfg.stride * (self.cfg.layers * (self.cfg.kernel // 2) + 1) + 1  # + 1: the goal velocities
        if T <= chunk + 2 * margin:
            return self.forward_batch(batch, fps)
        outs: dict[str, list[torch.Tensor]] = {"q": [], "base_pos": [], "base_rot": []}
        chunk = max(self.cfg.stride, chunk - chunk % self.cfg.stride)  # every chunk starts on a key frame
        margin += (-margin) % self.cfg.stride
        for s in range(0, T, chunk):
            lo, hi = max(0, s - margin), min(T, s + chunk + margin)
            part = frames_of(batch, lo, hi)
            out = self.forward_batch(part, fps)
            for k in outs:
                outs[k].append(out[k][:, s - lo : s - lo + min(chunk, T - s)])
        return {k: torch.cat(v, 1) for k, v in outs.items()}

    def loss(self, batch: Mapping, energy: EnergyConfig, fps: float = 30.0, offset: int = 0) -> dict[str, torch.Tensor]:
        """The training objective of a batch with teacher solutions (``has_teacher``), each term (B,)
        and ``total``: angle regression [rad^2], FK body positions [m^2], base orientation (chordal)
        and position [m^2] against the teacher, and the energy ``f_kin`` of the output."""
        dev = next(self.parameters()).device
        g = graph_from_batch(batch, "tgt", dev)
        out = self.forward_batch(batch, fps, offset)
        t = batch["teacher"].to(dev, torch.float32)
        q_t = torch.cat([torch.zeros_like(t[..., :1, 0]), t[..., 1:, 0]], -1) * g.dof[:, None].to(t.dtype)
        rot_t, pos_t = axis_angle_to_matrix(t[..., 0, 0:3]), t[..., 0, 3:6]
        dof = g.dof[:, None].to(t.dtype)
        n_dof = (dof.sum(-1) * t.shape[1]).sum(-1).clamp_min(1)
        l_q = ((out["q"] - q_t) ** 2 * dof).sum((1, 2)) / n_dof
        fk = batch_fk(g, out["q"], out["base_pos"], out["base_rot"])
        p_out = fk[0]
        with torch.no_grad():
            p_t, _ = batch_fk(g, q_t, pos_t, rot_t)
        m = g.mask[:, None].to(t.dtype)
        l_fk = (((p_out - p_t) ** 2).sum(-1) * m).sum((1, 2)) / (m.sum(-1) * t.shape[1]).sum(-1).clamp_min(1)
        l_rot = ((out["base_rot"] - rot_t) ** 2).sum((-1, -2)).mean(1) / 2
        l_pos = ((out["base_pos"] - pos_t) ** 2).sum(-1).mean(1)
        rkw = {}
        if "ref_goal_rot" in batch:
            rkw = {"goal_rot": batch["ref_goal_rot"].to(dev, torch.float32), "rot_mask": batch["ref_rot_mask"].to(dev)}
        e = energy_terms(energy, g, out["q"], out["base_pos"], out["base_rot"], batch["joint_map"].to(dev, torch.float32),
                         batch["ref_scaled_pos"].to(dev, torch.float32), fps, fk=fk, **rkw)["total"]  # fmt: skip
        c = self.cfg
        has = batch["has_teacher"].to(dev, torch.float32)
        reg = has * (c.w_q * l_q + c.w_fk * l_fk + c.w_rot * l_rot + c.w_pos * l_pos)
        total = reg + c.w_energy * e
        return {"q": l_q, "fk": l_fk, "rot": l_rot, "pos": l_pos, "energy": e, "total": total}

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())
