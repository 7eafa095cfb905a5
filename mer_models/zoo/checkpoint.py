"""A checkpoint loaded: the model (the diffusion model :class:`~mer_models.diffusion.model.RetargetModel` or
the warm start :class:`~mer_models.warm.model.WarmModel`, as ``run.kind`` says) and its metadata.

The folder format itself (``config.json`` + ``model.safetensors``, written atomically, read
strictly) is :mod:`mer_models.hub.checkpoint_files`; this module builds the network from it, by
folder (:func:`load_checkpoint`), by zoo name or folder (:func:`resolve_model`, :func:`load`).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mer_data.base.errors import UnseenRobotError
from mer_models.config import RunConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.hub.checkpoint_files import is_dir, read_run
from mer_models.hub.registry import Registry
from mer_models.hub.resolve import download, resolve
from mer_models.warm.model import WarmModel

log = logging.getLogger(__name__)

__all__ = ["Checkpoint", "load_checkpoint", "resolve_model", "check_robot", "load"]


@dataclass
class Checkpoint:
    """A loaded checkpoint: the model (eval mode) and its metadata."""

    path: Path
    run: RunConfig
    model: RetargetModel | WarmModel
    robots: dict[str, dict[str, str]] = field(default_factory=dict)
    data: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    step: int = 0

    @property
    def targets(self) -> list[str]:
        return sorted(self.robots.get("targets", {}))

    @property
    def references(self) -> list[str]:
        return sorted(self.robots.get("references", {}))



def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> Checkpoint:
    """Build the model from ``config.json`` and load ``model.safetensors`` strictly."""
    path = Path(path)
    meta, run = read_run(path)
    model = (WarmModel if run.kind == "warm" else RetargetModel).from_folder(path, device, run=run)
    return Checkpoint(path, run, model, meta["robots"], meta.get("data", {}), meta.get("metrics", {}), int(meta["step"]))


def load(spec: str | Path, revision: str | None = None, device: Any = "cpu", registry: Registry | None = None) -> Checkpoint:
    """Build the model from ``config.json`` and load ``model.safetensors`` strictly (see :func:`~mer_models.hub.resolve.resolve`)."""
    return load_checkpoint(resolve(spec, revision, registry).folder, device=device)


def resolve_model(spec: str | Path, device: str | torch.device = "cpu") -> Checkpoint:
    """A checkpoint folder, or a model name from the zoo."""
    p = Path(spec).expanduser()
    if is_dir(p) or os.sep in str(spec) or str(spec).startswith("."):
        return load_checkpoint(p, device)
    return load_checkpoint(download(str(spec)), device)


def check_robot(ckpt: Checkpoint, robot: str, role: str = "targets", fingerprint: str | None = None) -> None:
    """Refuse a robot the checkpoint was not trained on (role ``targets`` or ``references``)."""
    seen = ckpt.robots.get(role, {})
    if robot not in seen:
        what = "target" if role == "targets" else "reference (source)"
        raise UnseenRobotError(
            f"the model {ckpt.path} was never trained with {robot!r} as a {what} robot "
            f"(it saw: {', '.join(sorted(seen)) or 'none'})",
            element=robot,
            fix=f"retarget zero-shot with --allow-unseen (mer retarget; expect lower accuracy), fine-tune it for {robot!r} "
                f"with `mer finetune --robot {robot} ...`, or use the optimiser (`--method optimize` in mer retarget, "
                "`--methods optimize` in mer evaluate)",
        )
    if fingerprint is not None and seen[robot] and seen[robot] != fingerprint:
        log.warning(
            "robot %r differs from the skeleton the model was trained on (fingerprint %s… vs %s…)",
            robot,
            fingerprint[:12],
            seen[robot][:12],
        )
