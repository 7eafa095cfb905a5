"""The model registry: zoo name → model card (→ Hub repo, pinned revision, checksums).

Where cards come from, in order:

1. **Built-in cards**, the catalogue mer ships. Their source is ``cards/models/<name>.md`` in the
   repository; a copy is packaged as ``mer_models/cards/<name>.md`` (package data, so an installed
   wheel lists them). From a source checkout the zoo reads ``cards/models`` itself; installed, it
   reads the packaged copy. The copies are kept identical by :func:`write_card` (which writes
   both when it writes into the source folder) and a test that fails on any difference.
2. **User cards** in ``$MER_HOME/cards/models/<name>.md``, written by ``mer zoo publish`` for
   models that are not part of the catalogue. A user card cannot take a built-in name.

Bundled weights live in ``mer_models/bundled/<name>/`` (``config.json`` + ``model.safetensors``)
and are described by a built-in card whose status is ``bundled``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import ModelZooError, UnknownModelError
from mer_data.base.suggest import close_matches, did_you_mean
from mer_data.robots.registry import mer_home

from .card import ModelCard, read_card
from .names import validate_model_name
from .render import render_card

log = logging.getLogger(__name__)

__all__ = [
    "PACKAGE_DIR",
    "source_cards_dir",
    "packaged_cards_dir",
    "builtin_cards_dir",
    "user_cards_dir",
    "bundled_dir",
    "ModelEntry",
    "Registry",
    "write_card",
]

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # mer_models/


def source_cards_dir() -> Path | None:
    """``<repo>/cards/models`` when mer runs from a source checkout, else None."""
    repo = PACKAGE_DIR.parent
    d = repo / "cards" / "models"
    return d if d.is_dir() and (repo / "pyproject.toml").is_file() else None


def packaged_cards_dir() -> Path:
    """``mer_models/cards``: the packaged copy of the catalogue."""
    return PACKAGE_DIR / "cards"


def builtin_cards_dir() -> Path:
    """The catalogue the zoo reads: the source folder in a checkout, else the packaged copy."""
    return source_cards_dir() or packaged_cards_dir()


def user_cards_dir() -> Path:
    """``$MER_HOME/cards/models``: cards of models a user published."""
    return mer_home() / "cards" / "models"


def bundled_dir() -> Path:
    """``mer_models/bundled``: weights shipped inside the package."""
    return PACKAGE_DIR / "bundled"


@dataclass(frozen=True)
class ModelEntry:
    """A card and where it came from (``built-in`` or ``user``)."""

    card: ModelCard
    source: str

    @property
    def name(self) -> str:
        return self.card.name


class Registry:
    """Cards found in ``builtin`` then ``user`` folders; ``bundled`` holds packaged weights.

    Arguments default to the package's folders and ``$MER_HOME`` (read when the registry is made).
    """

    def __init__(self, builtin: Path | None = None, user: Path | None = None, bundled: Path | None = None) -> None:
        self.builtin = Path(builtin) if builtin is not None else builtin_cards_dir()
        self.user = Path(user) if user is not None else user_cards_dir()
        self.bundled = Path(bundled) if bundled is not None else bundled_dir()

    def _scan(self, folder: Path, source: str, out: dict[str, ModelEntry], strict: bool) -> None:
        if not folder.is_dir():
            return
        for path in sorted(folder.glob("*.md")):
            try:
                card = read_card(path)
            except ModelZooError as exc:
                if strict:
                    raise
                log.warning("skipping a broken model card: %s", exc)
                continue
            if card.name in out:
                log.warning("%s: the name %r is taken by a built-in model; this card is ignored", path, card.name)
                continue
            out[card.name] = ModelEntry(card, source)

    def entries(self) -> dict[str, ModelEntry]:
        """All models by name (built-in first). A broken built-in card raises; a broken user card is skipped."""
        out: dict[str, ModelEntry] = {}
        self._scan(self.builtin, "built-in", out, strict=True)
        self._scan(self.user, "user", out, strict=False)
        return out

    def names(self) -> list[str]:
        return sorted(self.entries())

    def get(self, name: str) -> ModelEntry:
        """The entry for ``name``; an unknown name raises :class:`UnknownModelError` with the closest known
        names ("did you mean 'mer-base'?") and the list of all of them."""
        try:
            validate_model_name(name)
        except ModelZooError as exc:
            hint = did_you_mean(name, self.names()) if isinstance(name, str) else ""
            if not hint:
                raise
            raise ModelZooError(f"{exc.message}; {hint}", element=exc.element, fix=exc.fix) from None
        entries = self.entries()
        if name in entries:
            return entries[name]
        user_path = self.user / f"{name}.md"
        if user_path.is_file():  # present but broken: say why
            read_card(user_path)
        known = ", ".join(sorted(entries)) or "none"
        hint = did_you_mean(name, sorted(entries))
        fix = "pick one of the known names (`mer zoo list`), pass a checkpoint folder, or a Hub id ORG/NAME"
        raise UnknownModelError(
            f"unknown model {name!r}; " + (f"{hint} (known models: {known})" if hint else f"known models: {known}"),
            element=name,
            fix=f"use {near[0]!r}, or {fix}" if (near := close_matches(name, sorted(entries))) else fix,
        )

    def is_builtin(self, name: str) -> bool:
        return (self.builtin / f"{validate_model_name(name)}.md").is_file()

    def bundled_folder(self, name: str) -> Path:
        return self.bundled / validate_model_name(name)


def write_card(card: ModelCard, folder: Path) -> Path:
    """Render ``card`` into ``folder/<name>.md`` atomically; writing into the repository's source
    catalogue also refreshes the packaged copy. Returns the path written."""
    text = render_card(card)
    path = Path(folder) / f"{validate_model_name(card.name)}.md"
    atomic_write(path, text)
    src = source_cards_dir()
    if src is not None and Path(folder).resolve() == src.resolve():
        atomic_write(packaged_cards_dir() / path.name, text)
    log.info("wrote the model card %s", path)
    return path
