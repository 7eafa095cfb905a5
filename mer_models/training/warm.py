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

import json
import logging
import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import torch
from torch.utils.data import DataLoader, Dataset

from mer_data.base.errors import CheckpointError, MerError
from mer_data.motion.samples import collate
from mer_models.batch import batch_features, graph_from_batch
from mer_models.config import RunConfig
from mer_models.hub.checkpoint_files import CONFIG, load_weights, save_checkpoint
from mer_models.warm.model import WarmModel

from .order import OrderSampler
from .train import LOG_FILE, TrainResult, _fingerprint, _lr, _resume_state, ema_decay, update_average

log = logging.getLogger(__name__)

__all__ = ["train_warm", "fill_teacher"]

_PER_FRAME = ("reference", "ref_scaled_pos", "ref_goal_rot", "teacher", "target")


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
    return {k: (v[:, s : s + frames] if k in _PER_FRAME and torch.is_tensor(v) else v) for k, v in batch.items()}


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
    step = 0
    averaged: dict[str, torch.Tensor] | None = None
    robots: dict[str, dict[str, str]] = {"targets": {}, "references": {}}
    for side, names in (known_robots or {}).items():
        robots.setdefault(side, {}).update(dict(names))
    if resume:
        if not (out / CONFIG).is_file():
            raise CheckpointError(f"nothing to resume in {out}", path=out, fix="drop --resume to start a new run")
        meta, state, rng, averaged = _resume_state(out, run, model, opt, 0, 1)
        step = int(state["step"])
        robots = {k: dict(v) for k, v in meta["robots"].items()}
        crop_gen.set_state(rng["noise.0"])
    elif (out / CONFIG).exists():
        raise CheckpointError(f"{out} already holds a checkpoint", path=out, fix="pass --resume to continue it, or choose another --out")
    elif init is not None:
        load_weights(model, Path(init))
    if run.train.ema > 0 and averaged is None:
        averaged = {k: v.detach().clone() for k, v in model.state_dict().items()}
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
        for side, key in (("targets", "tgt_names"), ("references", "ref_names")):
            for name in batch[key]:
                if name not in robots[side]:
                    robots[side][name] = _fingerprint(name)
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
            out.mkdir(parents=True, exist_ok=True)
            try:  # a planted link is refused, not followed
                fd = os.open(logf, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o666)
            except OSError as e:
                raise MerError(f"cannot append to the training log: {e.strerror}", path=logf,
                               fix="remove what is at that path (mer writes the log itself, never through a link)") from None  # fmt: skip
            with os.fdopen(fd, "a") as fh:
                fh.write(json.dumps(last) + "\n")
            log.info("step %d loss %.4f q %.4f fk %.5f energy %.5f", step, last["loss"], last["q"], last["fk"], last["energy"])
            if progress is not None:
                progress(last)
        if step % run.train.save_every == 0 or step == steps:
            save()
    return TrainResult(out, step, last)
