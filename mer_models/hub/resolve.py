"""Loading by name: ``list_models``, ``model_info``, ``resolve``, ``download``, ``load``.

A spec resolves, in this order, to:

1. an existing local folder: used as is (no network; nothing to verify it against);
2. a zoo name: its card gives the Hub repo, the pinned commit and each file's sha256 and size;
   bundled models load from the package, others from the Hub cache, downloading what is missing
   (:func:`.client.fetch_file`: checked metadata, private temporary file); every file is verified before use;
3. a plain Hub id ``ORG/NAME`` with no card: ``config.json`` and ``model.safetensors`` at the
   given revision (default ``main``) are fetched and checked against the Hub's own content ids;
   no independent checksum exists, so the resolved commit is reported for pinning.

Nothing but ``config.json`` and ``model.safetensors`` is ever read from a repository (no code, no
pickles). With ``HF_HUB_OFFLINE`` on, no network call is made at all.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from mer_data.base.errors import ChecksumError, ModelNotAvailableError, ModelZooError

from . import client as hub
from .card import FileRecord, ModelCard
from .integrity import verify_hub_blob, verify_record
from .names import is_commit, looks_like_repo_id, validate_model_name, validate_revision
from .registry import ModelEntry, Registry, source_cards_dir

log = logging.getLogger(__name__)

__all__ = ["Resolved", "list_models", "model_info", "where", "resolve", "download", "DEFAULT_MODEL", "REQUIRED_FILES"]

DEFAULT_MODEL = "mer-base"  # bundled: trained on synthetic motion only, every built-in robot as source and target
# Published cards whose repository is on no public Hub yet: published to the loopback Hub of mer's tests only
# (its commit pinned in the card), their weights committed in the source repository at cards/weights/NAME/; a
# maintainer's `tools/finetune_warm.py --publish-only --hub-url https://huggingface.co` puts one on the Hub
# (then remove it here). docs/zoo.md, The catalogue.
NOT_ON_PUBLIC_HUB = frozenset({"mer-warm-romeo"})
PUBLIC_HUB = "https://huggingface.co"
REQUIRED_FILES = ("config.json", "model.safetensors")


@dataclass(frozen=True)
class Resolved:
    """Where a model's files are, and how they were checked.

    Attributes:
        folder: holds ``config.json`` and ``model.safetensors``.
        source: ``bundled``, ``hub`` or ``local``.
        verified: ``card`` (size + sha256 against the card), ``hub`` (against the Hub's content ids)
            or ``none`` (a local folder).
    """

    folder: Path
    source: str
    verified: str
    name: str | None = None
    repo_id: str | None = None
    revision: str | None = None
    card: ModelCard | None = None


def _registry(registry: Registry | None) -> Registry:
    return registry if registry is not None else Registry()


def list_models(registry: Registry | None = None) -> list[ModelEntry]:
    """Every model in the registry (built-in catalogue, then the user's), sorted by name."""
    entries = _registry(registry).entries()
    return [entries[n] for n in sorted(entries)]


def model_info(name: str, registry: Registry | None = None) -> ModelEntry:
    """The registry entry (card and source) of a zoo name; unknown names list the known ones."""
    return _registry(registry).get(name)


def _cached(card: ModelCard) -> bool:
    return bool(card.repo_id and card.revision and all(hub.cached_file(card.repo_id, f, card.revision) for f in card.files))


def _off_public_hub(card: ModelCard) -> bool:
    """The card's repository is on no public Hub (:data:`NOT_ON_PUBLIC_HUB`) and the client asks the public one."""
    return card.name in NOT_ON_PUBLIC_HUB and hub.endpoint().rstrip("/") == PUBLIC_HUB


def where(entry: ModelEntry, registry: Registry | None = None) -> str:
    """``bundled``, ``cached``, ``remote`` (on the Hub the client asks), ``not on Hub`` (published to no
    public Hub yet: :data:`NOT_ON_PUBLIC_HUB`) or ``unpublished`` - from the filesystem only, no network."""
    card = entry.card
    if card.status == "unpublished":
        return "unpublished"
    if card.status == "bundled" and _registry(registry).bundled_folder(card.name).is_dir():
        return "bundled"
    if _cached(card):
        return "cached"
    if _off_public_hub(card):
        return "not on Hub"
    return "remote" if card.repo_id and card.revision else "unpublished"


def _not_on_hub(card: ModelCard) -> ModelNotAvailableError:
    cards = source_cards_dir()
    weights = cards.parent / "weights" / card.name if cards is not None else None
    here = (f"load its committed weights by folder: --model {weights}" if weights is not None and weights.is_dir()
            else f"in a source checkout of mer (git clone), load its committed weights by folder: --model cards/weights/{card.name}")
    return ModelNotAvailableError(
        f"{card.name!r} is on no public Hub yet: its repository {card.repo_id} was published to mer's test Hub only, "
        f"not to {PUBLIC_HUB} (docs/zoo.md)",
        element=card.name,
        fix=f"{here}; or set HF_ENDPOINT to a Hub that holds {card.repo_id}",
    )


def _not_published(card: ModelCard) -> ModelNotAvailableError:
    steps = "".join(f"\n      {line}" for line in card.reproduce.splitlines())
    how = f"train it yourself:{steps}\n    and load the output folder" if steps else "train it yourself and load the output folder"
    return ModelNotAvailableError(
        f"the weights of {card.name!r} are not yet published (its card says so; `mer zoo info {card.name}`)",
        element=card.name,
        fix=f"{how}, or use the bundled default model {DEFAULT_MODEL!r}",
    )


def _fetch_verified(repo_id: str, filename: str, revision: str, record: FileRecord | None, label: str) -> Path:
    """Cached copy (verified) or a fresh download (verified); a bad cached copy is removed and re-fetched online."""
    fix = f"run `mer zoo download {label}` while online to fetch a fresh copy"
    # A commit is immutable: a cached copy is final. A branch is asked to the Hub unless offline.
    path = hub.cached_file(repo_id, filename, revision) if (is_commit(revision) or hub.offline()) else None
    if path is not None:
        try:
            if record is not None:
                verify_record(path, record, name=filename, fix=fix)
            else:
                verify_hub_blob(path, name=filename, fix=fix)
            return path
        except ChecksumError as exc:
            if hub.offline():
                raise
            log.warning("%s; downloading it again", exc.message)
    path = hub.fetch_file(repo_id, filename, revision, what=label)
    fix = (f"the Hub serves a {filename} that differs from the card of {label}: the repository was changed or the "
           "transfer was corrupted; check HF_ENDPOINT, then report it to the model's publisher")
    if record is not None:
        verify_record(path, record, name=filename, fix=fix)
    else:
        verify_hub_blob(path, name=filename, fix=f"run `mer zoo download {label}` again")
    return path


def _from_hub(repo_id: str, revision: str, files: dict[str, FileRecord] | None, label: str) -> tuple[Path, str]:
    names = list(files) if files else list(REQUIRED_FILES)
    for req in REQUIRED_FILES:
        if req not in names:
            raise ModelZooError(f"{label}: the card lists no {req}", element=req, fix="regenerate the card with `mer zoo publish`")
    paths = [_fetch_verified(repo_id, n, revision, (files or {}).get(n), label) for n in names]
    folder = paths[0].parent
    commit = folder.name
    if any(p.parent != folder for p in paths) or not is_commit(commit):
        raise ModelZooError(f"{label}: the files of {repo_id}@{revision} resolved to different commits", element=revision,
                            fix="the branch moved during the download; pin a commit with --revision")
    return folder, commit


def _resolve_card(entry: ModelEntry, revision: str | None, registry: Registry) -> Resolved:
    card = entry.card
    if revision is None and card.status == "bundled":
        folder = registry.bundled_folder(card.name)
        if not folder.is_dir():
            raise ModelNotAvailableError(f"the bundled model {card.name!r} is missing from {folder}", path=folder,
                                         fix="reinstall mer (pip install --force-reinstall mer)")
        for fname, rec in card.files.items():
            p = folder / fname
            if not p.is_file():
                raise ModelNotAvailableError(f"the bundled model {card.name!r} has no {fname}", path=p, fix="reinstall mer")
            verify_record(p, rec, name=fname, cached=False, fix="the installed package is damaged: reinstall mer")
        return Resolved(folder, "bundled", "card", card.name, card.repo_id, card.revision, card)
    if card.status == "unpublished" or not card.repo_id or not card.revision:
        raise _not_published(card)
    if _off_public_hub(card) and not _cached(card):  # said before any request, not as a network error
        raise _not_on_hub(card)
    rev = validate_revision(revision) if revision is not None else card.revision
    files = card.files_for(rev)
    if files is None:
        log.warning("revision %s of %r is not recorded in its card: its files are checked against the Hub's content ids "
                    "only, not against recorded checksums", rev, card.name)
    folder, commit = _from_hub(card.repo_id, rev, files, card.name)
    return Resolved(folder, "hub", "card" if files else "hub", card.name, card.repo_id, commit, card)


def resolve(spec: str | Path, revision: str | None = None, registry: Registry | None = None) -> Resolved:
    """Resolve a local folder, a zoo name or a Hub id to verified local files (see module docstring)."""
    reg = _registry(registry)
    text = str(spec)
    if not text.strip():
        raise ModelZooError("empty model name or path (it would mean the current folder)", element="name",
                            fix="pass a zoo name (e.g. mer-base), a checkpoint folder or ORG/NAME")  # fmt: skip
    p = Path(text).expanduser()
    try:
        local = p.is_dir()
    except (OSError, ValueError):  # a name the file system refuses (e.g. over 255 bytes): not a folder
        local = False
    if local:
        if revision is not None:
            raise ModelZooError(f"{text} is a local folder; --revision applies to zoo names and Hub ids only", element="revision")
        return Resolved(p, "local", "none")
    try:
        validate_model_name(text)
        is_name = True
    except ModelZooError:
        is_name = False
    if is_name:
        return _resolve_card(reg.get(text), revision, reg)
    if looks_like_repo_id(text):
        rev = validate_revision(revision) if revision is not None else "main"
        folder, commit = _from_hub(text, rev, None, text)
        if not is_commit(rev):
            log.warning("%s has no card: files were checked against the Hub's content ids only; pin revision=%s "
                        "for a reproducible load", text, commit)
        return Resolved(folder, "hub", "hub", None, text, commit, None)
    if "/" in text or "\\" in text or text.startswith((".", "~")):
        raise ModelZooError(f"no checkpoint folder at {text}", path=text, fix="pass an existing folder, a zoo name or ORG/NAME")
    reg.get(text)  # raises UnknownModelError with the known names
    raise AssertionError("unreachable")  # pragma: no cover


def download(spec: str | Path, revision: str | None = None, registry: Registry | None = None) -> Path:
    """The verified local folder of a model (see :func:`resolve`); downloads what the cache lacks."""
    return resolve(spec, revision, registry).folder
