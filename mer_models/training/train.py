"""Training: EDM denoising + energy guidance (paper, Eq. 4), checkpoints, exact resume, DDP.

Loss per sample::

    weight(sigma) * mean || D(x + n, sigma, C) - x ||^2  +  lambda * f_kin(D(x + n, sigma, C))

with ``ln sigma ~ N(P_mean, P_std^2)``. ``x`` is the optimiser's solution of the sample: read from
the shards' teacher files (``mer shards solve``), or, as the fallback, solved on the fly
(:func:`clean_samples`; docs/model.md says why).

Exact resume: the data order is a pure function of (seed, epoch), the position in the epoch,
the noise generator, the global torch RNG (dropout) and the optimiser moments are all saved, so
``train(steps=4)`` and ``train(steps=2)`` + ``train(steps=4, resume=True)`` give the same weights.

Multi-process: under ``torchrun`` (``WORLD_SIZE > 1``) the model is wrapped in
``DistributedDataParallel`` (gloo on CPU, nccl on CUDA); each rank takes its share of every
global batch; rank 0 writes the checkpoints and the log.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import DataLoader, Dataset

from mer_data.base.errors import ConfigError
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.samples import collate
from mer_models.batch import batch_features
from mer_models.config import RunConfig
from mer_models.diffusion.edm import denoising_loss, sample_sigma
from mer_models.diffusion.model import Conditions, RetargetModel
from mer_models.diffusion.precision import native_bf16
from mer_models.diffusion.representation import denormalize, transform_features
from mer_models.hub.checkpoint_files import (
    save_checkpoint,
)
from mer_models.solver.optimize import optimize_motion

from .loop import LOG_FILE, TrainResult, _dist, _lr, append_log, ema_decay, note_robots, start_state, update_average
from .order import OrderSampler, reference_groups

log = logging.getLogger(__name__)

__all__ = ["train", "TrainResult", "clean_samples", "native_bf16", "reference_groups", "ema_decay", "update_average", "LOG_FILE"]

class _Step(nn.Module):
    """What DDP wraps: one denoiser evaluation (reference encoding included)."""

    def __init__(self, model: RetargetModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: torch.Tensor, sigma: torch.Tensor, cond: Conditions) -> torch.Tensor:
        cond.ref_tokens = None
        return self.model.denoise(x, sigma, cond)


def clean_samples(model: RetargetModel, batch: Mapping, cond: Conditions, run: RunConfig) -> torch.Tensor:
    """The clean ``x`` of every sample (diffusion space, canonical frame): the optimiser's solution.

    Read from the shards' teacher files where the batch has them (``has_teacher``: ``mer shards
    solve``); else solved on the fly (``run.train.opt_iters`` Levenberg-Marquardt iterations), the
    fallback. A target robot's own motion window is never ``x``: it is not what the energy tracks
    (the scaled reference), so one teacher serves every target (docs/model.md). Both enter the
    diffusion space through :meth:`RetargetModel.to_sample` (for ``goal_frame_rotation`` models the
    base rotation becomes ``delta = Log(R_goal^T R_teacher)``, what the sampler decodes).
    """
    dev = cond.rot.device
    B = cond.rot.shape[0]
    has = batch["has_teacher"].to(dev) if "has_teacher" in batch else torch.zeros(B, dtype=torch.bool, device=dev)
    x = torch.zeros(cond.shape, device=dev)
    if bool(has.any()):
        t = transform_features(batch["teacher"].to(dev, torch.float32), cond.rot, cond.origin)
        x = torch.where(has[:, None, None, None], model.to_sample(t, cond), x)
    if bool((~has).any()):
        with torch.no_grad():
            sel = torch.nonzero(~has).flatten()
            g = cond.tgt_graph.select(sel)
            ref = denormalize(cond.reference[sel], model.cfg)
            out = optimize_motion(
                run.energy, g, cond.eta[sel], cond.goal[sel], axis_angle_to_matrix(ref[:, :, 0, 0:3]),
                iters=0, gn_iters=run.train.opt_iters, fps=cond.fps,
                goal_rot=None if cond.goal_rot is None else cond.goal_rot[sel],
                rot_mask=None if cond.rot_mask is None else cond.rot_mask[sel],
            )
            feats = batch_features(g, out["q"], out["base_pos"], out["base_rot"], cond.fps)
            eye = torch.eye(3, device=feats.device).expand(len(sel), 3, 3)
            feats = transform_features(feats, eye, torch.zeros(len(sel), 3, device=feats.device))  # unwrap rotvecs
            x = x.index_copy(0, sel, model.to_sample(feats, cond, sel))
    return x


def _at_sampler_start(
    model: RetargetModel, cond: Conditions, run: RunConfig, x_in: torch.Tensor, sigma: torch.Tensor, unit: torch.Tensor, k: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The first ``k`` samples of the batch moved to where the sampler starts (``start_frac``).

    ``sigma = sigma_max`` and the input is the sampler's initial state: ``init_noise * sigma_max``
    times the sample's unit noise ``unit`` (B, T, J, 9), about the goals for a ``goal_prior``
    network (as :func:`mer_models.retarget.inference.sample_conditions` starts). The clean target is unchanged.
    """
    s_max = float(run.sampler.sigma_max)
    start = unit[:k] * (run.sampler.init_noise * s_max)
    if model.cfg.goal_prior:
        start = start + model.goal_prior(cond)[:k].to(start.dtype)
    sigma = torch.cat([torch.full_like(sigma[:k], s_max), sigma[k:]])
    return torch.cat([start, x_in[k:]]), sigma


def _at_feedback(
    model: RetargetModel, cond: Conditions, run: RunConfig, x_in: torch.Tensor, sigma: torch.Tensor, unit: torch.Tensor,
    k: int, kf: int, bf16: bool,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Samples ``k .. k + kf`` of the batch moved to where the ``feedback`` sampler's second evaluation
    runs (``feedback_frac``): ``sigma = feedback_sigma`` and the input is the network's own estimate
    from the sampler's start, without gradient, made kinematically consistent (:meth:`RetargetModel.project`).

    The first evaluation runs on the whole batch (the conditions are batched), under the training's
    autocast; the reference encoding it caches is dropped, so the trained evaluation encodes again
    with gradients. The clean target is unchanged.
    """
    s_max = float(run.sampler.sigma_max)
    start = unit * (run.sampler.init_noise * s_max)
    if model.cfg.goal_prior:
        start = start + model.goal_prior(cond).to(start.dtype)
    with torch.no_grad(), torch.autocast(x_in.device.type, dtype=torch.bfloat16, enabled=bf16):
        d = model.denoise(start, s_max, cond)
    cond.ref_tokens = None
    sel = slice(k, k + kf)
    fed = model.project(d.float(), cond)[sel]
    x_in = torch.cat([x_in[:k], fed, x_in[k + kf :]])
    sigma = torch.cat([sigma[:k], torch.full_like(sigma[sel], float(run.sampler.feedback_sigma)), sigma[k + kf :]])
    return x_in, sigma


def train(
    run: RunConfig,
    dataset: Dataset,
    out: str | Path,
    *,
    steps: int,
    resume: bool = False,
    device: str = "cpu",
    bf16: bool = False,
    num_workers: int = 0,
    data_info: Mapping[str, Any] | None = None,
    progress: Callable[[dict], None] | None = None,
    init: str | Path | None = None,
    known_robots: Mapping[str, Mapping[str, str]] | None = None,
) -> TrainResult:
    """Train (or resume) until ``steps`` total steps; the checkpoint folder is ``out``.

    Args:
        run: the configuration (a preset, possibly modified).
        dataset: a Dataset of :class:`~mer_data.motion.samples.TrainingSample` (e.g. ``ShardDataset``).
        steps: total optimiser steps (on resume: including those already done).
        data_info: recorded in ``config.json`` (shards, split, ...).
        progress: called on rank 0 with each log record.
        init: a ``model.safetensors`` to start from (fine-tuning: the base's weights, loaded strictly;
            the optimiser starts fresh). Ignored on resume, which restores its own weights.
        known_robots: robots (``targets``/``references`` -> name -> fingerprint) recorded in the
            checkpoint in addition to those the batches show (fine-tuning: the base's robots).
    """
    if run.kind == "warm":  # the warm-start model has its own loop (one process)
        from .warm import train_warm

        return train_warm(run, dataset, out, steps=steps, resume=resume, device=device, bf16=bf16, num_workers=num_workers,
                          data_info=data_info, progress=progress, init=init, known_robots=known_robots)  # fmt: skip
    out = Path(out)
    rank, world = _dist()
    if run.train.batch_size % world:
        raise ConfigError(
            f"batch size {run.train.batch_size} is not divisible by {world} processes", element="train.batch_size"
        )
    dev = torch.device(device)
    if bf16 and not native_bf16(dev):
        log.warning("bf16 requested on a CPU without native bfloat16 (%s; no AMX or AVX512-BF16): PyTorch emulates it, "
                    "several times slower than float32 here; train without --bf16", torch.backends.cpu.get_cpu_capability())
    torch.manual_seed(run.train.seed)
    model = RetargetModel(run.model).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=run.train.lr, weight_decay=run.train.weight_decay)
    noise_gen = torch.Generator(device=dev).manual_seed(run.train.seed * 1000 + rank)
    start = start_state(out, run, model, opt, resume=resume, init=init, known_robots=known_robots, rank=rank, world=world)
    step, robots, averaged, rng = start.step, start.robots, start.averaged, start.rng
    if resume:
        noise_gen.set_state(rng[f"noise.{rank}"])
    net: nn.Module = _Step(model)
    if world > 1:
        net = nn.parallel.DistributedDataParallel(net)
    k_ref = run.train.ref_group
    groups = reference_groups(dataset) if k_ref > 1 else None
    sampler = OrderSampler(len(dataset), run.train.batch_size, run.train.seed, step, rank, world, groups, k_ref)
    start_step = step
    loader = iter(DataLoader(dataset, batch_sampler=sampler, collate_fn=collate, num_workers=num_workers))
    if resume:  # after the loader's iterator, which draws its base seed from this generator at every start
        torch.set_rng_state(rng[f"torch.{rank}"])
    logf = out / LOG_FILE
    last: dict[str, float] = {}
    t0 = time.time()

    def save() -> None:
        rngs = {f"noise.{rank}": noise_gen.get_state(), f"torch.{rank}": torch.get_rng_state()}
        if world > 1:
            gathered: list[Any] = [None] * world
            dist.all_gather_object(gathered, rngs)
            rngs = {k: v for d in gathered for k, v in d.items()}
        if rank != 0:
            return
        log_text = logf.read_text() if logf.is_file() else ""
        save_checkpoint(
            out, model, run, robots=robots, data=data_info, metrics={"train": last}, step=step, optimizer=opt,
            trainer_state={"step": step, "epoch": step // sampler.per_epoch, "world_size": world},
            rng_tensors=rngs, extra_files={LOG_FILE: log_text}, averaged=averaged,
        )

    model.train()
    while step < steps:
        batch = next(loader)
        note_robots(robots, batch)
        for g in opt.param_groups:
            g["lr"] = _lr(run, step)
        cond = model.conditions(batch)
        x = clean_samples(model, batch, cond, run)
        B = x.shape[0]
        sigma = sample_sigma(B, run.train.p_mean, run.train.p_std, noise_gen, dev)
        unit = torch.randn(x.shape, generator=noise_gen, device=dev)
        x_in = x + unit * sigma.view(-1, 1, 1, 1)
        k = round(run.train.start_frac * B)
        if k:
            x_in, sigma = _at_sampler_start(model, cond, run, x_in, sigma, unit, k)
        kf = round(run.train.feedback_frac * B)
        if kf:
            x_in, sigma = _at_feedback(model, cond, run, x_in, sigma, unit, k, kf, bf16)
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16):
            d = net(x_in, sigma, cond)
        d = d.float()
        l_edm = denoising_loss(d, x, sigma, run.model.sigma_data, cond.tgt_graph.mask)
        energy = model.energy(d, cond, run.energy)
        loss = (l_edm + run.energy.lam * energy["total"]).mean()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at step {step}; lower --lr or check the data")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), run.train.grad_clip)
        opt.step()
        step += 1
        if averaged is not None:
            update_average(averaged, model, ema_decay(run.train.ema, step))
        last = {"step": step, "loss": loss.item(), "edm": l_edm.mean().item(), "grad_norm": gnorm.item(), "lr": opt.param_groups[0]["lr"]}
        last.update({f"f_{k}": v.mean().item() for k, v in energy.items()})
        if world > 1:
            gathered = [None] * world
            dist.all_gather_object(gathered, robots)
            for other in gathered:
                for side in robots:
                    robots[side].update(other[side])
        if rank == 0 and (step % run.train.log_every == 0 or step == steps):
            last["sec_per_step"] = (time.time() - t0) / max(1, step - start_step)
            append_log(out, last)
            log.info("step %d loss %.4f edm %.4f f_kin %.5f", step, last["loss"], last["edm"], last["f_total"])
            if progress is not None:
                progress(last)
        if step % run.train.save_every == 0 or step == steps:
            save()
    if world > 1:
        dist.barrier()
    return TrainResult(out, step, last)
