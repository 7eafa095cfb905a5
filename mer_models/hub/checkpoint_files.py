"""The checkpoint folder format: a folder with ``config.json`` + ``model.safetensors`` (+ training state to resume).

Layout (format version :data:`FORMAT_VERSION`)::

    CKPT/
      config.json            format, format_version, mer_version, run (model/energy/sampler/train
                             configuration), robots (targets and references seen, with skeleton
                             fingerprints), data (shards, split, sample count), metrics, step
      model.safetensors      the weights (with ``TrainConfig.ema``: their moving average)
      optimizer.safetensors  optimiser moments and RNG states (only for resuming; with
                             ``TrainConfig.ema`` also the trained weights, ``train.<name>``)
      trainer_state.json     step, epoch, position in the epoch, optimiser hyper-parameters

Weights load only through safetensors, strictly: every key of the model must be present with its
shape and nothing else may be there; otherwise :class:`~mer_data.base.errors.CheckpointError` lists the
keys. No pickle anywhere (``torch.load`` is never called). A folder is written into a temporary
sibling and renamed into place, so an interrupted save never leaves a half-written checkpoint.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import logging
from pathlib import Path
from typing import Any, Mapping

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from mer_data.base.atomic import atomic_dir
from mer_data.base.errors import CheckpointError, ConfigError
from mer_data.base.finite import require_finite
from mer_data.base.safe_io import decode_utf8, read_regular_file
from mer_models._version import __version__
from mer_models.config import RunConfig, from_dict

log = logging.getLogger(__name__)

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "CONFIG",
    "WEIGHTS",
    "OPTIMIZER",
    "STATE",
    "TRAINED_PREFIX",
    "save_checkpoint",
    "read_meta",
    "read_run",
    "load_weights",
    "is_dir",
]

FORMAT = "mer-checkpoint"
FORMAT_VERSION = 1
CONFIG, WEIGHTS, OPTIMIZER, STATE = "config.json", "model.safetensors", "optimizer.safetensors", "trainer_state.json"
TRAINED_PREFIX = "train."  # the trained weights in the optimiser file of a checkpoint whose weights are an average


def _optimizer_tensors(opt: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict]:
    sd = opt.state_dict()
    tensors = {}
    for idx, st in sd["state"].items():
        for k, v in st.items():
            tensors[f"state.{idx}.{k}"] = torch.as_tensor(v).detach().cpu().contiguous()
    return tensors, {"param_groups": sd["param_groups"]}


def save_checkpoint(
    path: str | Path,
    model: torch.nn.Module,
    run: RunConfig,
    *,
    robots: Mapping[str, Mapping[str, str]],
    data: Mapping[str, Any] | None = None,
    metrics: Mapping[str, Any] | None = None,
    step: int = 0,
    optimizer: torch.optim.Optimizer | None = None,
    trainer_state: Mapping[str, Any] | None = None,
    rng_tensors: Mapping[str, torch.Tensor] | None = None,
    extra_files: Mapping[str, str] | None = None,
    averaged: Mapping[str, torch.Tensor] | None = None,
) -> Path:
    """Write a checkpoint folder atomically (see module docstring). Returns its path.

    ``extra_files`` maps file names to text written into the same folder (e.g. the training log),
    so they appear together with the weights or not at all. ``averaged``: a moving average of the
    model's state dict (``TrainConfig.ema``); the weights file then holds it (what inference loads)
    and the optimiser file the model's own weights as ``train.<name>`` (what resume continues)."""
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "mer_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "run": run.to_dict(),
        "robots": {k: dict(v) for k, v in robots.items()},
        "data": dict(data or {}),
        "metrics": dict(metrics or {}),
        "step": int(step),
    }
    trained = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    require_finite(trained, path=path, what="model weights")  # a diverged run is refused, not saved
    weights = trained
    if averaged is not None:
        if set(averaged) != set(trained):
            raise ValueError("the averaged weights do not have the model's tensors")
        weights = {k: v.detach().cpu().contiguous() for k, v in averaged.items()}
        require_finite(weights, path=path, what="averaged model weights")

    def write(tmp: Path) -> None:
        (tmp / CONFIG).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        save_file(weights, str(tmp / WEIGHTS), metadata={"format": FORMAT, "format_version": str(FORMAT_VERSION)})
        if optimizer is not None:
            tensors, groups = _optimizer_tensors(optimizer)
            for k, v in (rng_tensors or {}).items():
                tensors[f"rng.{k}"] = v.detach().cpu().contiguous()
            if averaged is not None:
                tensors.update({f"{TRAINED_PREFIX}{k}": v for k, v in trained.items()})
            save_file(tensors, str(tmp / OPTIMIZER))
            (tmp / STATE).write_text(json.dumps({**groups, **dict(trainer_state or {})}, indent=2, sort_keys=True) + "\n")
        for fname, text in (extra_files or {}).items():
            if Path(fname).name != fname or fname in (CONFIG, WEIGHTS, OPTIMIZER, STATE):
                raise ValueError(f"extra checkpoint file {fname!r} must be a plain file name other than the checkpoint's own")
            (tmp / fname).write_text(text, encoding="utf-8")

    atomic_dir(Path(path), write)
    return Path(path)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _check_fields(meta: dict, cfg: Path) -> None:
    """The types of the top-level fields other than ``run`` (checked by :func:`from_dict`)."""
    step = meta["step"]
    if not isinstance(step, int) or isinstance(step, bool) or step < 0:
        raise CheckpointError(f"step must be an integer >= 0, not {step!r}", path=cfg, element="step")
    robots = meta["robots"]
    ok = isinstance(robots, dict) and all(
        isinstance(role, dict) and all(isinstance(k, str) and isinstance(v, (str, type(None))) for k, v in role.items())
        for role in robots.values()
    )
    if not ok:
        raise CheckpointError(
            "robots must map a role (targets, references) to {robot name: skeleton fingerprint}",
            path=cfg,
            element="robots",
            fix="the file was edited or written by other code; restore it from the original checkpoint",
        )
    for key in ("data", "metrics"):
        if not isinstance(meta.get(key, {}), dict):
            raise CheckpointError(f"{key} must be a JSON object", path=cfg, element=key)


def read_meta(path: Path) -> dict:
    cfg = path / CONFIG
    if not cfg.exists() and not cfg.is_symlink():
        raise CheckpointError(
            f"no {CONFIG} in {path}", path=path, fix="pass a checkpoint folder written by `mer train`"
        )
    text = decode_utf8(read_regular_file(cfg, CheckpointError, "MER_MAX_CONFIG_BYTES"), cfg, CheckpointError)
    try:
        meta = json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{CONFIG} is not valid JSON: {exc.msg}", path=cfg, line=exc.lineno) from None
    except (ValueError, RecursionError) as exc:  # NaN/Infinity, or nesting deeper than Python's stack
        raise CheckpointError(
            f"{CONFIG} is not valid JSON: {str(exc)[:100]}", path=cfg, fix="numbers must be finite; restore the file"
        ) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"not a mer checkpoint (format {meta.get('format') if isinstance(meta, dict) else None!r})", path=cfg)
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"checkpoint format version {meta.get('format_version')!r}, this mer reads {FORMAT_VERSION}",
            path=cfg,
            element="format_version",
            fix=f"use mer {meta.get('mer_version', '?')} or convert the checkpoint",
        )
    for key in ("run", "robots", "step"):
        if key not in meta:
            raise CheckpointError(f"{CONFIG} misses the field {key!r}", path=cfg, element=key)
    _check_fields(meta, cfg)
    return meta


def load_weights(model: torch.nn.Module, file: str | Path) -> None:
    """Load a safetensors file into ``model``, strictly (missing/unexpected/shape → CheckpointError)."""
    file = Path(file)
    if not file.is_file():
        raise CheckpointError("the weights file is missing", path=file, fix="the checkpoint folder is incomplete; copy it again")
    try:
        sd = load_file(str(file))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise CheckpointError(f"cannot read the weights: {exc}", path=file, fix="the file is corrupt; download or copy it again") from None
    own = model.state_dict()
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"missing {len(missing)} tensor(s): {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
        if unexpected:
            parts.append(f"unexpected {len(unexpected)} tensor(s): {', '.join(unexpected[:5])}{' ...' if len(unexpected) > 5 else ''}")
        raise CheckpointError(
            "the weights do not match the model: " + "; ".join(parts),
            path=file,
            element=(missing or unexpected)[0],
            fix="the weights and config.json come from different models; use a consistent checkpoint",
        )
    for k, v in own.items():
        if sd[k].shape != v.shape:
            raise CheckpointError(
                f"tensor {k} has shape {tuple(sd[k].shape)}, the model expects {tuple(v.shape)}",
                path=file,
                element=k,
                fix="the weights and config.json come from different models; use a consistent checkpoint",
            )
        if sd[k].is_floating_point() and not bool(torch.isfinite(sd[k]).all()):
            bad = int((~torch.isfinite(sd[k])).sum())
            raise CheckpointError(
                f"tensor {k} holds {bad} NaN/inf value(s) of {sd[k].numel()}: the model would output NaN",
                path=file,
                element=k,
                fix="the training diverged or the file is damaged; use an earlier checkpoint",
            )
    model.load_state_dict({k: sd[k].to(own[k].dtype) for k in own}, strict=True)



def read_run(path: str | Path) -> tuple[dict, RunConfig]:
    """``config.json`` of the checkpoint folder ``path``, checked, and its run configuration."""
    path = Path(path)
    if not is_dir(path):
        raise CheckpointError(f"no checkpoint folder at {path}", path=path, fix="pass the folder `mer train --out` wrote")
    meta = read_meta(path)
    try:
        return meta, from_dict(meta["run"])
    except ConfigError as exc:
        raise ConfigError(
            f"the checkpoint's configuration does not match this version of mer: {exc.message}",
            path=path / CONFIG,
            element=f"run.{exc.element}" if exc.element else "run",
            fix=exc.fix,
        ) from None


def is_dir(p: Path) -> bool:
    """``Path.is_dir`` that answers False for names the file system refuses (too long, bad bytes)."""
    try:
        return p.is_dir()
    except (OSError, ValueError) as exc:
        if isinstance(exc, OSError) and exc.errno not in (errno.ENAMETOOLONG, errno.EACCES, errno.EINVAL):
            raise CheckpointError(f"cannot access {p} ({exc.strerror})", path=p) from None
        return False


