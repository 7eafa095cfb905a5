"""``from_pretrained`` / ``save_pretrained`` / ``push_to_hub`` for any model class, the way LeRobot policies load.

Thin wrappers over mer's own checkpoint folder (:mod:`.checkpoint_files`: ``config.json`` +
``model.safetensors``) and the zoo's Hub access (:mod:`.resolve`, :mod:`.publish`), rather than huggingface_hub's
``PyTorchModelHubMixin``: the mixin writes its own ``config.json`` (the ``__init__`` arguments) and
loads safetensors non-strictly by default, while a mer checkpoint's ``config.json`` holds the whole
run configuration, the robots (with skeleton fingerprints) and the data description, and its
weights load strictly. So ``from_pretrained`` reads exactly what ``mer`` writes and what
``zoo.load`` reads, and a missing, partial or mismatched weights file is a
:class:`~mer_data.base.errors.CheckpointError` naming the missing / unexpected keys; weights are never
silently initialised.

``from_pretrained(spec)`` takes a zoo name (``mer-base``, bundled), a local checkpoint
folder or a Hub repo id ``ORG/NAME`` (``revision=`` a branch, tag or commit); ``local_files_only``
looks in the Hub cache only (no network call at all), ``cache_dir`` replaces ``HF_HUB_CACHE``.

The loaded model keeps its checkpoint's metadata as ``model.pretrained_info``, so
``model.push_to_hub(repo_id)`` re-publishes it with its configuration. A model built in code needs
``run=`` and ``robots=`` to be saved or pushed.

:class:`PretrainedMixin` gives a model class (``cls(run.model)`` builds it) these three; its subclass
:class:`~mer_models.diffusion.model.RetargetModel` is what ``RetargetModel.from_pretrained`` loads. The
mixin knows files, not networks, so the model module stands on it and nothing here imports the model.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, TypeVar

import torch

from mer_data.base.errors import CheckpointError, PublishError
from mer_models.config import RunConfig

from . import client as hub
from .checkpoint_files import WEIGHTS, load_weights, read_run, save_checkpoint
from .names import validate_model_name, validate_repo_id
from .publish import upload_checkpoint
from .resolve import resolve

log = logging.getLogger(__name__)

__all__ = ["PretrainedInfo", "PretrainedMixin"]

M = TypeVar("M", bound="PretrainedMixin")


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


class PretrainedMixin:
    """Hub conventions for a ``torch.nn.Module`` built as ``cls(cls.config_of(run))`` from a checkpoint's
    configuration; ``kind`` is the :data:`~mer_models.config.KINDS` entry its checkpoints carry."""

    kind = "diffusion"

    @staticmethod
    def config_of(run: RunConfig) -> Any:
        """The section of ``run`` that builds this model class (``run.model`` for the diffusion model)."""
        return run.model

    @classmethod
    def from_folder(cls: type[M], folder: str | Path, device: str | torch.device = "cpu", *, run: RunConfig | None = None) -> M:
        """Build the model from a checkpoint folder's ``config.json`` and load its weights strictly (eval mode)."""
        folder = Path(folder)
        if run is None:
            _, run = read_run(folder)
        if run.kind != cls.kind:
            raise CheckpointError(f"{folder} holds a {run.kind!r} model, not a {cls.kind!r} one", path=folder, element="run.kind",
                                  fix="load it with mer_models.zoo.load (it builds either kind)")  # fmt: skip
        model = cls(cls.config_of(run))  # type: ignore[call-arg]
        load_weights(model, folder / WEIGHTS)  # type: ignore[arg-type]
        model.to(device).eval()  # type: ignore[attr-defined]
        return model

    @classmethod
    def from_pretrained(cls: type[M], pretrained_model_name_or_path: str | Path, *, revision: str | None = None,
                        local_files_only: bool = False, cache_dir: str | Path | None = None, token: str | None = None,
                        device: str | torch.device = "cpu") -> M:  # fmt: skip
        """Load a model (eval mode) from a zoo name, a local checkpoint folder or a Hub repo id.

        Files are verified (card checksums for zoo names, the Hub's content ids for repo ids) and the
        weights load strictly (see the module docstring).
        """
        spec = pretrained_model_name_or_path
        with hub.settings(cache_dir=cache_dir, local_files_only=local_files_only, token=token):
            res = resolve(spec, revision)
        meta, run = read_run(res.folder)
        model = cls.from_folder(res.folder, device, run=run)
        model.pretrained_info = PretrainedInfo(run, dict(meta["robots"]), dict(meta.get("data", {})),  # type: ignore[attr-defined]
                                               dict(meta.get("metrics", {})), int(meta["step"]), res.folder, res.source,
                                               res.repo_id, res.revision)  # fmt: skip
        log.info("loaded %s (%s%s)", spec, res.source, f" {res.repo_id}@{res.revision}" if res.repo_id else "")
        return model

    def save_pretrained(
        self,
        save_directory: str | Path,
        *,
        run: RunConfig | None = None,
        robots: Mapping[str, Mapping[str, str]] | None = None,
        data: Mapping[str, Any] | None = None,
        metrics: Mapping[str, Any] | None = None,
        step: int | None = None,
    ) -> Path:
        """Write ``save_directory`` as a mer checkpoint (``config.json`` + ``model.safetensors``), atomically."""
        info = _info(self, run, robots)
        if run is not None and (run.kind != self.kind or self.config_of(run) != self.cfg):  # type: ignore[attr-defined]
            raise CheckpointError(f"the run configuration does not describe this {self.kind} network", element="run",
                                  fix="pass the RunConfig the model was built from")
        return save_checkpoint(save_directory, self, info.run, robots=info.robots, data=data if data is not None else info.data,
                               metrics=metrics if metrics is not None else info.metrics, step=info.step if step is None else step)

    def push_to_hub(
        self,
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
        validate_repo_id(repo_id)
        card_name = validate_model_name(name or repo_id.split("/")[1].lower())
        if hub.offline():
            raise PublishError("offline mode (HF_HUB_OFFLINE) is on: pushing needs the network", fix="unset HF_HUB_OFFLINE")
        with tempfile.TemporaryDirectory(prefix="mer-push-") as tmp:
            folder = self.save_pretrained(Path(tmp) / "ckpt", run=run, robots=robots, data=data)
            card, commit, _ = upload_checkpoint(folder, repo_id, name=card_name, license=license, summary=summary,
                                                private=private, step=self.pretrained_info.step if hasattr(self, "pretrained_info") else 0,
                                                token=token)
        log.info("pushed %s to %s@%s", card.name, repo_id, commit)
        return commit
