"""What both training loops share (:mod:`.train`, the diffusion model's; :mod:`.warm`, the warm start's):
the process group, the learning-rate schedule, the start of a run (resume, refusing an occupied folder,
init weights, the moving average, the robots known), the weights' moving average, robot bookkeeping,
the log and the result."""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import torch
import torch.distributed as dist
from safetensors.torch import load_file
from torch import nn

from mer_data.base.errors import CheckpointError, ConfigError, MerError
from mer_data.robots.registry import get_skeleton
from mer_models.config import RunConfig, from_dict
from mer_models.diffusion.model import RetargetModel
from mer_models.hub.checkpoint_files import (
    CONFIG,
    OPTIMIZER,
    STATE,
    TRAINED_PREFIX,
    WEIGHTS,
    load_weights,
    read_meta,
)

log = logging.getLogger(__name__)

__all__ = ["LOG_FILE", "TrainResult", "ema_decay", "update_average", "start_state", "note_robots", "append_log"]

LOG_FILE = "train_log.jsonl"


@dataclass
class TrainResult:
    path: Path
    step: int
    last: dict[str, float]


def _dist() -> tuple[int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if torch.cuda.is_available() and os.environ.get("MER_DDP_BACKEND") != "gloo" else "gloo")
    return (dist.get_rank(), dist.get_world_size()) if world > 1 else (0, 1)


def _lr(run: RunConfig, step: int) -> float:
    """Linear warm-up, then constant or a cosine decay to ``lr * lr_min_ratio`` (:class:`TrainConfig`)."""
    t = run.train
    if step < t.warmup:
        return t.lr * (step + 1) / t.warmup
    if t.lr_decay_steps <= 0:
        return t.lr
    u = min(1.0, (step - t.warmup) / t.lr_decay_steps)
    return t.lr * (t.lr_min_ratio + (1 - t.lr_min_ratio) * 0.5 * (1 + math.cos(math.pi * u)))


def _fingerprint(name: str) -> str:
    try:
        return get_skeleton(name).fingerprint
    except Exception:  # noqa: BLE001 - a robot from a shard that is not registered here
        return ""


def _resume_state(out: Path, run: RunConfig, model: RetargetModel, opt: torch.optim.Optimizer, rank: int, world: int):
    meta = read_meta(out)
    saved = from_dict(meta["run"]).replace(sampler=run.sampler)  # sampling settings do not change training
    if saved != run:
        a, b = saved.to_dict(), run.to_dict()
        diff = [f"{s}.{k}" for s in a if isinstance(a[s], dict) for k in a[s] if a[s][k] != b[s][k]]
        diff += [s for s in a if not isinstance(a[s], dict) and a[s] != b[s]]
        raise ConfigError(
            f"cannot resume: the configuration differs from the checkpoint's in {', '.join(diff)}",
            path=out / CONFIG,
            element=diff[0] if diff else None,
            fix="resume with the same --config and options, or train into a new --out folder",
        )
    if not (out / OPTIMIZER).is_file() or not (out / STATE).is_file():
        raise CheckpointError("the checkpoint has no optimiser state to resume from", path=out, fix="train into a new --out folder")
    load_weights(model, out / WEIGHTS)
    state = json.loads((out / STATE).read_text())
    if state.get("world_size", 1) != world:
        raise ConfigError(
            f"the checkpoint was trained with {state.get('world_size')} processes, not {world}",
            element="world_size",
            fix="resume with the same number of processes (the data order depends on it)",
        )
    tensors = load_file(str(out / OPTIMIZER))
    sd_state: dict[int, dict[str, torch.Tensor]] = {}
    for k, v in tensors.items():
        if k.startswith("state."):
            _, idx, name = k.split(".", 2)
            sd_state.setdefault(int(idx), {})[name] = v
    try:
        opt.load_state_dict({"state": sd_state, "param_groups": state["param_groups"]})
    except (ValueError, KeyError) as exc:
        raise CheckpointError(f"the optimiser state does not match the model: {exc}", path=out / OPTIMIZER) from None
    rng = {k[4:]: v for k, v in tensors.items() if k.startswith("rng.")}
    averaged = None
    if run.train.ema > 0:  # the weights file holds the average; the trained weights are in the optimiser file
        trained = {k[len(TRAINED_PREFIX):]: v for k, v in tensors.items() if k.startswith(TRAINED_PREFIX)}
        averaged = {k: v.detach().clone() for k, v in model.state_dict().items()}
        try:
            model.load_state_dict(trained, strict=True)
        except RuntimeError as exc:
            raise CheckpointError(f"the checkpoint's trained weights (next to its average) do not match the model: {exc}",
                                  path=out / OPTIMIZER, fix="train into a new --out folder") from None
    return meta, state, rng, averaged


def ema_decay(ema: float, step: int) -> float:
    """The moving average's decay after ``step`` optimiser steps: ``min(ema, (1 + step) / (10 + step))``
    (short memory early on, so the average does not hold the initial weights for long)."""
    return min(ema, (1 + step) / (10 + step))


@torch.no_grad()
def update_average(averaged: Mapping[str, torch.Tensor], model: nn.Module, decay: float) -> None:
    """``avg <- decay * avg + (1 - decay) * theta`` for every floating tensor of the state dict
    (others, e.g. integer buffers, are copied)."""
    for k, v in model.state_dict().items():
        a = averaged[k]
        if a.is_floating_point():
            a.lerp_(v.detach(), 1.0 - decay)
        else:
            a.copy_(v)


@dataclass
class _Start:
    """Where a run starts: its step, robots, moving average and the RNG states a resume restores."""

    step: int
    robots: dict[str, dict[str, str]]
    averaged: dict[str, torch.Tensor] | None
    rng: dict[str, torch.Tensor]


def start_state(out: Path, run: RunConfig, model: nn.Module, opt: torch.optim.Optimizer, *, resume: bool, init: str | Path | None,
                known_robots: Mapping[str, Mapping[str, str]] | None, rank: int = 0, world: int = 1) -> _Start:
    """Resume ``out`` (weights, optimiser, step, robots, RNG), or start fresh from ``init``'s weights
    (or the model as built) with ``known_robots``; a checkpoint already in ``out`` without ``resume``
    is refused. Both training loops (:func:`train`, :func:`mer_models.training.warm.train_warm`) start here."""
    robots: dict[str, dict[str, str]] = {"targets": {}, "references": {}}
    for side, names in (known_robots or {}).items():
        robots.setdefault(side, {}).update(dict(names))
    step, averaged, rng = 0, None, {}
    if resume:
        if not (out / CONFIG).is_file():
            raise CheckpointError(f"nothing to resume in {out}", path=out, fix="drop --resume to start a new run")
        meta, state, rng, averaged = _resume_state(out, run, model, opt, rank, world)
        step = int(state["step"])
        robots = {k: dict(v) for k, v in meta["robots"].items()}
    elif (out / CONFIG).exists():
        raise CheckpointError(f"{out} already holds a checkpoint", path=out, fix="pass --resume to continue it, or choose another --out")
    elif init is not None:
        load_weights(model, Path(init))
    if run.train.ema > 0 and averaged is None:
        averaged = {k: v.detach().clone() for k, v in model.state_dict().items()}
    return _Start(step, robots, averaged, rng)


def note_robots(robots: dict[str, dict[str, str]], batch: Mapping) -> None:
    """Record the target and reference robots of ``batch`` (with their skeleton fingerprints) in ``robots``."""
    for side, key in (("targets", "tgt_names"), ("references", "ref_names")):
        for name in batch[key]:
            if name not in robots[side]:
                robots[side][name] = _fingerprint(name)


def append_log(out: Path, record: Mapping[str, Any]) -> None:
    """Append one JSON line to ``out``'s training log (a planted link is refused, not followed)."""
    out.mkdir(parents=True, exist_ok=True)
    logf = out / LOG_FILE
    try:
        fd = os.open(logf, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    except OSError as e:
        raise MerError(f"cannot append to the training log: {e.strerror}", path=logf,
                       fix="remove what is at that path (mer writes the log itself, never through a link)") from None  # fmt: skip
    with os.fdopen(fd, "a") as fh:
        fh.write(json.dumps(dict(record)) + "\n")


