"""Training the warm-start model (:mod:`mer_models.warm`): ``mer train --config warm``.

Each step draws ``batch_size`` windows (of many samples, robots and augmentations: each window is
``T`` frames, so a step sees ``batch_size * T`` frames), optionally cropped to ``WarmConfig.crop``
frames at a random offset, and minimises :meth:`~mer_models.warm.model.WarmModel.loss`: regression on
the teacher's solution (``mer shards solve``) plus the teacher's energy. A sample without a teacher
(a new robot being fine-tuned for, shards never solved) gets the optimiser's solution on the fly
(``TrainConfig.opt_iters`` iterations), as the diffusion trainer does.

Optimiser, learning-rate schedule, data order, checkpoints (atomic, resumable, with the optimiser
state and RNG) and the training log are the diffusion trainer's (:mod:`.train`).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from torch.utils.data import DataLoader, Dataset

from mer_data.base.errors import MerError
from mer_data.motion.samples import collate
from mer_models.batch import batch_features, graph_from_batch
from mer_models.config import RunConfig
from mer_models.hub.checkpoint_files import save_checkpoint
from mer_models.warm.model import WarmModel, frames_of

from .loop import LOG_FILE, TrainResult, _lr, append_log, ema_decay, note_robots, start_state, update_average
from .order import OrderSampler

log = logging.getLogger(__name__)

__all__ = ["train_warm", "fill_teacher"]



def fill_teacher(batch: dict, run: RunConfig, fps: float = 30.0) -> None:
    """Give every sample of ``batch`` without a teacher solution (``has_teacher`` False) the
    optimiser's (``run.train.opt_iters`` LM iterations, no physical terms), in place."""
    from mer_data.kinematics.rotations import axis_angle_to_matrix
    from mer_models.solver.optimize import optimize_motion

    missing = torch.nonzero(~batch["has_teacher"]).flatten()
    if len(missing) == 0:
        return
    g = graph_from_batch(batch, "tgt").select(missing)
    rkw = {"goal_rot": batch["ref_goal_rot"][missing], "rot_mask": batch["ref_rot_mask"][missing]} if "ref_goal_rot" in batch else {}
    with torch.no_grad():
        out = optimize_motion(run.energy, g, batch["joint_map"][missing], batch["ref_scaled_pos"][missing],
                              axis_angle_to_matrix(batch["reference"][missing][:, :, 0, 0:3]), iters=0,
                              gn_iters=run.train.opt_iters, fps=fps, **rkw)  # fmt: skip
        feats = batch_features(g, out["q"], out["base_pos"], out["base_rot"], fps)
    batch["teacher"][missing] = feats.float()
    batch["has_teacher"][missing] = True


def _crop(batch: dict, frames: int, gen: torch.Generator) -> dict:
    T = batch["reference"].shape[1]
    if frames <= 0 or frames >= T:
        return batch
    s = int(torch.randint(0, T - frames + 1, (1,), generator=gen))
    return frames_of(batch, s, s + frames)


def train_warm(
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
    """Train (or resume) the warm-start model until ``steps`` total steps into the checkpoint folder
    ``out``; the arguments are :func:`mer_models.training.train.train`'s (one process)."""
    if run.kind != "warm":
        raise MerError(f"train_warm trains the warm kind, not {run.kind!r}", element="run.kind")
    out = Path(out)
    dev = torch.device(device)
    torch.manual_seed(run.train.seed)
    model = WarmModel(run.warm).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=run.train.lr, weight_decay=run.train.weight_decay)
    crop_gen = torch.Generator().manual_seed(run.train.seed)
    start = start_state(out, run, model, opt, resume=resume, init=init, known_robots=known_robots)
    step, robots, averaged, rng = start.step, start.robots, start.averaged, start.rng
    if resume:
        crop_gen.set_state(rng["noise.0"])
    sampler = OrderSampler(len(dataset), run.train.batch_size, run.train.seed, step, 0, 1, None, 1)
    start_step = step
    loader = iter(DataLoader(dataset, batch_sampler=sampler, collate_fn=collate, num_workers=num_workers))
    if resume:
        torch.set_rng_state(rng["torch.0"])
    logf = out / LOG_FILE
    last: dict[str, float] = {}
    t0 = time.time()

    def save() -> None:
        log_text = logf.read_text() if logf.is_file() else ""
        save_checkpoint(
            out, model, run, robots=robots, data=data_info, metrics={"train": last}, step=step, optimizer=opt,
            trainer_state={"step": step, "epoch": step // sampler.per_epoch, "world_size": 1},
            rng_tensors={"noise.0": crop_gen.get_state(), "torch.0": torch.get_rng_state()}, extra_files={LOG_FILE: log_text},
            averaged=averaged,
        )  # fmt: skip

    model.train()
    while step < steps:
        batch = next(loader)
        note_robots(robots, batch)
        for g in opt.param_groups:
            g["lr"] = _lr(run, step)
        batch = _crop(batch, run.warm.crop, crop_gen)  # first: a sample without a teacher is solved on the frames trained on
        fill_teacher(batch, run)
        offset = int(torch.randint(0, run.warm.stride, (1,), generator=crop_gen))  # which frames are key frames
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16):
            terms = model.loss(batch, run.energy, offset=offset)
        loss = terms["total"].mean()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at step {step}; lower --lr or check the data")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), run.train.grad_clip)
        opt.step()
        step += 1
        if averaged is not None:
            update_average(averaged, model, ema_decay(run.train.ema, step))
        last = {"step": step, "loss": loss.item(), "grad_norm": gnorm.item(), "lr": opt.param_groups[0]["lr"]}
        last.update({k: v.mean().item() for k, v in terms.items() if k != "total"})
        if step % run.train.log_every == 0 or step == steps:
            last["sec_per_step"] = (time.time() - t0) / max(1, step - start_step)
            append_log(out, last)
            log.info("step %d loss %.4f q %.4f fk %.5f energy %.5f", step, last["loss"], last["q"], last["fk"], last["energy"])
            if progress is not None:
                progress(last)
        if step % run.train.save_every == 0 or step == steps:
            save()
    return TrainResult(out, step, last)
