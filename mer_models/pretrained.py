"""``RetargetModel.from_pretrained`` / ``save_pretrained`` / ``push_to_hub``, the way LeRobot policies load.

Thin wrappers over mer's own checkpoint folder (:mod:`.checkpoint`: ``config.json`` +
``model.safetensors``) and the zoo's Hub access (:mod:`.zoo`), rather than huggingface_hub's
``PyTorchModelHubMixin``: the mixin writes its own ``config.json`` (the ``__init__`` arguments) and
loads safetensors non-strictly by default, while a mer checkpoint's ``config.json`` holds the whole
run configuration, the robots (with skeleton fingerprints) and the data description, and its
weights load strictly. So ``from_pretrained`` reads exactly what ``mer`` writes and what
``zoo.load`` reads, and a missing, partial or mismatched weights file is a
:class:`~mer_data.errors.CheckpointError` naming the missing / unexpected keys; weights are never
silently initialised.

``from_pretrained(spec)`` takes a zoo name (``mer-base``, bundled), a local checkpoint
folder or a Hub repo id ``ORG/NAME`` (``revision=`` a branch, tag or commit); ``local_files_only``
looks in the Hub cache only (no network call at all), ``cache_dir`` replaces ``HF_HUB_CACHE``.

The loaded model keeps its checkpoint's metadata as ``model.pretrained_info``, so
``model.push_to_hub(repo_id)`` re-publishes it with its configuration. A model built in code needs
``run=`` and ``robots=`` to be saved or pushed.

:class:`~mer_models.model.RetargetModel` exposes them as ``RetargetModel.from_pretrained``,
``model.save_pretrained`` and ``model.push_to_hub`` (which import this module on use).
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import torch

from mer_data.errors import CheckpointError, PublishError

from .checkpoint import load_checkpoint, save_checkpoint
from .config import RunConfig
from .model import RetargetModel

log = logging.getLogger(__name__)

__all__ = ["PretrainedInfo", "from_pretrained", "push_to_hub", "save_pretrained"]


@dataclass
class PretrainedInfo:
    """What a loaded model came with: its run configuration, robots, data, metrics and origin."""

    run: RunConfig
    robots: dict[str, dict[str, str]]
    data: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    step: int = 0
    folder: Path | None = None
    source: str = "local"  # bundled | hub | local
    repo_id: str | None = None
    revision: str | None = None


def from_pretrained(
    spec: str | Path,
    *,
    revision: str | None = None,
    local_files_only: bool = False,
    cache_dir: str | Path | None = None,
    token: str | None = None,
    device: str | torch.device = "cpu",
) -> RetargetModel:
    """Load a model (eval mode) from a zoo name, a local checkpoint folder or a Hub repo id.

    Files are verified (card checksums for zoo names, the Hub's content ids for repo ids) and the
    weights load strictly (see the module docstring).
    """
    from . import zoo
    from .zoo import hub

    with hub.settings(cache_dir=cache_dir, local_files_only=local_files_only, token=token):
        res = zoo.resolve(spec, revision)
    ckpt = load_checkpoint(res.folder, device=device)
    model = ckpt.model
    model.pretrained_info = PretrainedInfo(ckpt.run, dict(ckpt.robots), dict(ckpt.data), dict(ckpt.metrics), ckpt.step,
                                           res.folder, res.source, res.repo_id, res.revision)
    log.info("loaded %s (%s%s)", spec, res.source, f" {res.repo_id}@{res.revision}" if res.repo_id else "")
    return model


def _info(model: torch.nn.Module, run: RunConfig | None, robots: Mapping[str, Mapping[str, str]] | None) -> PretrainedInfo:
    info: PretrainedInfo | None = getattr(model, "pretrained_info", None)
    if run is None and info is None or robots is None and info is None:
        raise CheckpointError(
            "this model has no checkpoint metadata (it was not loaded with from_pretrained)",
            element="run" if run is None else "robots",
            fix="pass run= (the RunConfig it was trained with) and robots= ({'targets': {name: fingerprint}, "
            "'references': {...}}), or load it with RetargetModel.from_pretrained",
        )
    if info is None:
        return PretrainedInfo(run, {k: dict(v) for k, v in robots.items()})
    return PretrainedInfo(run or info.run, {k: dict(v) for k, v in (robots or info.robots).items()}, info.data, info.metrics,
                          info.step, info.folder, info.source, info.repo_id, info.revision)


def save_pretrained(
    model: RetargetModel,
    save_directory: str | Path,
    *,
    run: RunConfig | None = None,
    robots: Mapping[str, Mapping[str, str]] | None = None,
    data: Mapping[str, Any] | None = None,
    metrics: Mapping[str, Any] | None = None,
    step: int | None = None,
) -> Path:
    """Write ``save_directory`` as a mer checkpoint (``config.json`` + ``model.safetensors``), atomically."""
    info = _info(model, run, robots)
    if run is not None and run.model != model.cfg:
        raise CheckpointError("run.model does not describe this network", element="run.model",
                              fix="pass the RunConfig the model was built from")
    return save_checkpoint(save_directory, model, info.run, robots=info.robots, data=data if data is not None else info.data,
                           metrics=metrics if metrics is not None else info.metrics, step=info.step if step is None else step)


def push_to_hub(
    model: RetargetModel,
    repo_id: str,
    *,
    private: bool = False,
    token: str | None = None,
    name: str | None = None,
    license: str | None = None,
    summary: str | None = None,
    run: RunConfig | None = None,
    robots: Mapping[str, Mapping[str, str]] | None = None,
    data: Mapping[str, Any] | None = None,
) -> str:
    """Upload the model to the Hub model repository ``repo_id``; returns the commit holding the weights.

    As ``mer zoo publish`` does (two commits: ``config.json`` + ``model.safetensors``, then the card
    ``README.md`` pinning that commit with the files' sha256), without writing a local zoo card.
    ``name`` is the card's model name (default: the repo's name, lower-cased); ``license`` is
    needed when the checkpoint's data description names no known dataset.
    """
    from .zoo import hub
    from .zoo.names import validate_model_name, validate_repo_id
    from .zoo.publish import upload_checkpoint

    validate_repo_id(repo_id)
    card_name = validate_model_name(name or repo_id.split("/")[1].lower())
    if hub.offline():
        raise PublishError("offline mode (HF_HUB_OFFLINE) is on: pushing needs the network", fix="unset HF_HUB_OFFLINE")
    with tempfile.TemporaryDirectory(prefix="mer-push-") as tmp:
        folder = save_pretrained(model, Path(tmp) / "ckpt", run=run, robots=robots, data=data)
        card, commit, _ = upload_checkpoint(folder, repo_id, name=card_name, license=license, summary=summary,
                                            private=private, step=model.pretrained_info.step if hasattr(model, "pretrained_info") else 0,
                                            token=token)
    log.info("pushed %s to %s@%s", card.name, repo_id, commit)
    return commit
