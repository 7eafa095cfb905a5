"""``mer zoo publish``: upload a checkpoint to the Hub and record the commit and checksums in its card.

Two commits, so the card can name the commit that holds the weights:

1. ``HfApi.upload_folder`` uploads ``config.json`` + ``model.safetensors`` (optimiser state stays
   local): the resulting commit is the one the card pins;
2. the card, rendered from the checkpoint's metadata with that commit and the files' sha256 and
   size, is uploaded as ``README.md`` and written to the cards folder (atomically).

Publishing a name again keeps the previous pinned revision in the card's ``history``, so it stays
loadable (``revision=``) and verified. Authentication is the client's (``HF_TOKEN`` or
``hf auth login``); the endpoint is ``HF_ENDPOINT``. A Hub-compatible server without Xet storage
needs ``HF_HUB_DISABLE_XET=1`` (the client then uses the plain LFS upload).
"""

from __future__ import annotations

import datetime as _dt
import logging
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from mer_data.base.errors import PublishError

from . import client as hub
from .card import ModelCard, PastRevision, read_card
from .fromckpt import PUBLISH_FILES, card_from_checkpoint, checkpoint_files, read_checkpoint_meta
from .names import validate_model_name, validate_repo_id
from .registry import Registry, source_cards_dir, user_cards_dir, write_card
from .render import render_card

log = logging.getLogger(__name__)

__all__ = ["PublishResult", "publish", "upload_checkpoint", "default_cards_dir"]


@dataclass(frozen=True)
class PublishResult:
    card: ModelCard
    card_path: Path
    commit: str
    card_commit: str


def default_cards_dir(name: str, registry: Registry) -> Path:
    """The repository's catalogue for a built-in name in a source checkout, else ``$MER_HOME/cards/models``."""
    src = source_cards_dir()
    if src is not None and registry.is_builtin(name) and registry.builtin.resolve() == src.resolve():
        return src
    return user_cards_dir()


def _previous(name: str, folder: Path, repo_id: str) -> ModelCard | None:
    path = folder / f"{name}.md"
    if not path.is_file():
        return None
    old = read_card(path)
    if old.repo_id and old.repo_id != repo_id and old.status == "published":
        raise PublishError(f"{name!r} is already published as {old.repo_id}, not {repo_id}", path=path, element="repo_id",
                           fix=f"publish to --repo-id {old.repo_id}, or choose another --name")
    return old


def publish(
    checkpoint_dir: str | Path,
    *,
    name: str,
    repo_id: str,
    base: str | None = None,
    cards_dir: str | Path | None = None,
    license: str | None = None,
    summary: str | None = None,
    private: bool = False,
    registry: Registry | None = None,
) -> PublishResult:
    """Upload ``checkpoint_dir`` to ``repo_id`` and write the card ``<cards_dir>/<name>.md``."""
    validate_model_name(name)
    validate_repo_id(repo_id)
    reg = registry if registry is not None else Registry()
    folder = Path(cards_dir) if cards_dir is not None else default_cards_dir(name, reg)
    if reg.is_builtin(name) and folder.resolve() != reg.builtin.resolve():
        raise PublishError(f"{name!r} is a built-in model of the catalogue", element=name,
                           fix="choose another --name for your model (built-in cards are updated from a source checkout)")
    if hub.offline():
        raise PublishError("HF_HUB_OFFLINE is set: publishing needs the network", fix="unset HF_HUB_OFFLINE")
    ckpt = Path(checkpoint_dir)
    meta = read_checkpoint_meta(ckpt)
    base_card = reg.get(base).card if base is not None else None
    recorded = (meta.get("data") or {}).get("base_model") if isinstance(meta.get("data"), dict) else None
    if recorded and base and recorded != base:
        raise PublishError(f"the checkpoint was fine-tuned from {recorded!r}, not {base!r}", path=ckpt / "config.json",
                           element="data.base_model", fix=f"pass --base {recorded}")
    if recorded and base_card is None:
        base_card = reg.get(recorded).card
    old = _previous(name, folder, repo_id)
    history = list(old.history) if old is not None else []
    if old is not None and old.revision:
        history.insert(0, PastRevision(old.revision, dict(old.files), old.published))
    card, commit, card_commit = upload_checkpoint(ckpt, repo_id, name=name, base=base_card, license=license, summary=summary,
                                                  private=private, history=history, step=meta.get("step", 0))
    path = write_card(card, folder)
    log.info("published %s as %s@%s", name, repo_id, commit)
    return PublishResult(card, path, commit, card_commit)


def upload_checkpoint(
    ckpt: Path,
    repo_id: str,
    *,
    name: str,
    base: ModelCard | None = None,
    license: str | None = None,
    summary: str | None = None,
    private: bool = False,
    history: list[PastRevision] | None = None,
    step: int = 0,
    token: str | None = None,
) -> tuple[ModelCard, str, str]:
    """The two commits of a publication (module docstring): the weights, then the card pinning them.

    Returns (card, weights commit, card commit). Nothing is written locally."""
    from huggingface_hub import HfApi
    from huggingface_hub.errors import HfHubHTTPError

    files = checkpoint_files(ckpt)
    # Render once before uploading anything: a checkpoint that cannot be carded is refused up front.
    card_from_checkpoint(ckpt, name=name, status="unpublished", base=base, license=license, summary=summary)
    api = HfApi(token=token, library_name="mer")
    try:
        api.create_repo(repo_id, repo_type="model", exist_ok=True, private=private)
        with tempfile.TemporaryDirectory(prefix="mer-publish-") as tmp:
            stage = Path(tmp)
            for fname in PUBLISH_FILES:
                shutil.copy2(ckpt / fname, stage / fname)
            info = api.upload_folder(folder_path=str(stage), repo_id=repo_id, repo_type="model",
                                     commit_message=f"mer: weights of {name} (step {step})")
            commit = info.oid
            past = [h for h in (history or []) if h.revision != commit]
            card = card_from_checkpoint(ckpt, name=name, status="published", repo_id=repo_id, revision=commit,
                                        files=files, history=past, base=base, license=license, summary=summary,
                                        published=_dt.date.today().isoformat())
            readme = stage / "README.md"
            readme.write_text(render_card(card), encoding="utf-8")
            card_info = api.upload_file(path_or_fileobj=str(readme), path_in_repo="README.md", repo_id=repo_id,
                                        repo_type="model", commit_message=f"mer: card of {name} (weights at {commit[:12]})")
    except HfHubHTTPError as exc:
        code = exc.response.status_code if exc.response is not None else "?"
        raise PublishError(f"the Hub ({hub.endpoint()}) refused the upload to {repo_id}: HTTP {code}", element=repo_id,
                           fix="check HF_TOKEN (a token with write access) and the repo id") from None
    except (OSError, ValueError) as exc:
        raise PublishError(f"upload to {repo_id} failed: {exc}", element=repo_id, fix="check the network and retry") from None
    return card, commit, card_info.oid
