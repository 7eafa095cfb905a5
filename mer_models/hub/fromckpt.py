"""Build a card from a checkpoint folder's own metadata (``config.json``), and decide its licence.

Only JSON is read here (no torch, no weights): the format and its version, the run configuration's
name, the robots the model was trained on, the data description, the metrics and the step.

Licence: weights inherit the terms of the motion data they were trained on. The data description
is searched for the dataset's name; LAFAN1 (CC BY-NC-ND 4.0) wins over everything else, so
weights that saw any LAFAN1 motion are marked non-commercial. When no known dataset is named, the
publisher must say which licence applies (``--license``): mer never guesses a permissive one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

from mer_data.base.errors import PublishError

from .card import FileRecord, ModelCard, PastRevision
from .integrity import file_record

__all__ = [
    "CHECKPOINT_FORMAT",
    "PUBLISH_FILES",
    "DATASETS",
    "DatasetLicence",
    "read_checkpoint_meta",
    "infer_dataset",
    "checkpoint_files",
    "card_from_checkpoint",
]

CHECKPOINT_FORMAT = "mer-checkpoint"
# What a published model holds: the configuration and the weights. Optimiser state stays local.
PUBLISH_FILES = ("config.json", "model.safetensors")


@dataclass(frozen=True)
class DatasetLicence:
    """The licence weights inherit from a dataset, and the sentence the card says about it."""

    license: str
    note: str
    hub_id: str | None = None  # the dataset's Hub repository (the card's ``datasets:``), if it has one


DATASETS: dict[str, DatasetLicence] = {
    "lafan1": DatasetLicence(
        "cc-by-nc-nd-4.0",
        "The weights are trained on LAFAN1 motion (Ubisoft La Forge) retargeted to robots, which is "
        "licensed CC BY-NC-ND 4.0: the weights are derived from non-commercial data. Use them for "
        "non-commercial research only, credit LAFAN1, and read the dataset's licence before any other use.",
        "lvhaidong/LAFAN1_Retargeting_Dataset",
    ),
    "synthetic": DatasetLicence(
        "apache-2.0",
        "The weights are trained only on synthetic motion that mer generates in code (no third-party "
        "motion data), so they carry the package's own licence, Apache-2.0.",
    ),
}


def read_checkpoint_meta(folder: str | Path) -> dict[str, Any]:
    """``config.json`` of a checkpoint folder, checked to be a mer checkpoint with the publish files."""
    folder = Path(folder)
    cfg = folder / "config.json"
    if not folder.is_dir() or not cfg.is_file():
        raise PublishError(f"no checkpoint at {folder} (config.json is missing)", path=folder,
                           fix="pass the folder written by `mer train --out` or `mer finetune --out`")
    try:
        meta = json.loads(cfg.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PublishError(f"config.json is not valid JSON: {exc}", path=cfg) from None
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        raise PublishError(f"not a mer checkpoint (format {meta.get('format') if isinstance(meta, dict) else None!r})",
                           path=cfg, element="format")
    if not isinstance(meta.get("format_version"), int):
        raise PublishError("config.json has no integer format_version", path=cfg, element="format_version")
    for name in PUBLISH_FILES:
        if not (folder / name).is_file():
            raise PublishError(f"the checkpoint has no {name}", path=folder / name,
                               fix="the folder is incomplete; train or copy it again")
    return meta


def _strings(x: Any) -> Iterable[str]:
    if isinstance(x, str):
        yield x
    elif isinstance(x, Mapping):
        for k, v in x.items():
            yield str(k)
            yield from _strings(v)
    elif isinstance(x, (list, tuple)):
        for v in x:
            yield from _strings(v)


def infer_dataset(data: Mapping[str, Any]) -> str | None:
    """The dataset named in a checkpoint's data description: ``lafan1`` wins, then ``synthetic``."""
    text = " ".join(_strings(data)).lower()
    if "lafan" in text:
        return "lafan1"
    if "synthetic" in text:
        return "synthetic"
    return None


def checkpoint_files(folder: str | Path) -> dict[str, FileRecord]:
    """sha256 and size of the files a published model holds."""
    return {name: file_record(Path(folder) / name) for name in PUBLISH_FILES}


def _scalars(data: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, (str, int, float, bool)) or v is None:
            out[str(k)] = v
        elif isinstance(v, (list, tuple)) and all(isinstance(x, (str, int, float)) for x in v):
            out[str(k)] = list(v)
        else:
            out[str(k)] = json.dumps(v, sort_keys=True)
    return out


def _recorded_base(data: Mapping[str, Any]) -> tuple[str | None, str | None, str | None] | None:
    """(zoo name, commit, Hub repo id) of the base ``mer finetune`` recorded; None when not a fine-tune.

    Values that are not a valid name, commit or repo id are dropped (a card must validate)."""
    from mer_data.base.errors import ModelZooError

    from .names import is_commit, validate_model_name, validate_repo_id

    if not any(k in data for k in ("base_model", "base_repo_id", "base_checkpoint")):
        return None
    name, rev, repo = data.get("base_model"), data.get("base_revision"), data.get("base_repo_id")
    try:
        name = validate_model_name(name) if isinstance(name, str) else None
    except ModelZooError:
        name = None
    try:
        repo = validate_repo_id(repo) if isinstance(repo, str) else None
    except ModelZooError:
        repo = None
    return name, (rev if isinstance(rev, str) and is_commit(rev) else None), repo


def card_from_checkpoint(
    folder: str | Path,
    *,
    name: str,
    status: str,
    repo_id: str | None = None,
    revision: str | None = None,
    published: str = "",
    files: Mapping[str, FileRecord] | None = None,
    history: Iterable[PastRevision] = (),
    base: ModelCard | None = None,
    license: str | None = None,
    license_note: str | None = None,
    summary: str | None = None,
    reproduce: str | None = None,
) -> ModelCard:
    """A card whose robots, training, metrics and checkpoint fields come from ``folder/config.json``.

    ``base`` is the card of the model it was fine-tuned from; without it, the base that ``mer
    finetune`` recorded in the checkpoint's ``data`` (``base_model``, ``base_revision``,
    ``base_repo_id``) is used.
    """
    meta = read_checkpoint_meta(folder)
    kind = str((meta.get("run") or {}).get("kind", "diffusion"))
    what_kind = "warm-start" if kind == "warm" else "guided-diffusion"
    robots = meta.get("robots") or {}
    targets = sorted(robots.get("targets", {}))
    references = sorted(robots.get("references", {}))
    data = dict(meta.get("data") or {})
    dataset = infer_dataset(data)
    if license is None:
        if dataset is None:
            raise PublishError(
                "the checkpoint's data description names no known dataset, so the weights' licence is unknown",
                path=Path(folder) / "config.json", element="data",
                fix=f"pass --license (the licence of the training data; known datasets: {', '.join(DATASETS)})",
            )
        license = DATASETS[dataset].license
        license_note = license_note if license_note is not None else DATASETS[dataset].note
    recorded = _recorded_base(data) if base is None else None
    run = meta.get("run") or {}
    run_name = run.get("name", "?") if isinstance(run, Mapping) else "?"
    step = int(meta.get("step") or 0)
    training = {"dataset": dataset or "unknown", "config": run_name, "steps": step, **_scalars(data)}
    if summary is None:
        if base is not None:
            new = sorted(set(targets) - set(base.targets))
            summary = f"`{base.name}` fine-tuned for {', '.join(new) or 'its targets'} (mer {what_kind} retargeting)."
        elif recorded is not None:
            what = recorded[0] or recorded[2] or "a checkpoint"
            summary = f"`{what}` fine-tuned for {data.get('finetune_robot') or 'its targets'} (mer {what_kind} retargeting)."
        else:
            summary = f"mer {what_kind} retargeting model ({run_name} configuration) for {', '.join(targets) or 'no target'}."
    if reproduce is None:
        reproduce = str(meta.get("command") or "")
    return ModelCard(
        name=name,
        status=status,
        summary=summary,
        license=license,
        repo_id=repo_id,
        revision=revision,
        published=published,
        files=dict(files) if files is not None else checkpoint_files(folder),
        history=tuple(history),
        base_model=base.name if base is not None else (recorded[0] if recorded else None),
        base_revision=base.revision if base is not None else (recorded[1] if recorded else None),
        base_repo_id=(base.repo_id if base.status == "published" else None) if base is not None else (recorded[2] if recorded else None),
        robots={"targets": targets, "references": references},
        training=training,
        metrics=dict(meta.get("metrics") or {}),
        checkpoint={
            "format": meta["format"],
            "format_version": meta["format_version"],
            "mer_version": meta.get("mer_version"),
            "step": step,
            "config": run_name,
            **({"kind": kind} if kind != "diffusion" else {}),  # diffusion cards stay as they were written
        },
        license_note=license_note or "",
        reproduce=reproduce,
    )
