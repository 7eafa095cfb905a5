"""Model cards: a Hugging Face ``README.md`` whose YAML front matter is the zoo's record of a model.

The Hub reads the top-level keys (``license``, ``library_name``, ``tags``, ``base_model``); mer reads
the ``mer:`` block::

    mer:
      card_version: 1
      name: mer-base-talos             # the zoo name
      status: published                # published | unpublished | bundled
      summary: one line
      repo_id: ORG/NAME                # where the weights live on the Hub (null: bundled only)
      revision: 40-hex commit          # the pinned revision (null: not published)
      published: YYYY-MM-DD            # when that revision was published
      files: {config.json: {sha256: ..., size: ...}, model.safetensors: {...}}
      history: [{revision, files, published}]   # earlier published revisions, newest first
      base_model: mer-base             # the zoo model it was fine-tuned from (null: trained from scratch)
      base_revision: 40-hex | null
      robots: {targets: [...], references: [...]}
      training: {dataset, robots, split, steps, config, ...}
      metrics: {...}                   # from ``mer evaluate``
      paper_metrics: {...}             # the paper's reported figures (reference only, never ours)
      checkpoint: {format, format_version, mer_version, step, config}
      license_note: text
      reproduce: the command that trains it

The body (markdown) is rendered from this block by :mod:`.render`; a card is never edited by hand.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from mer_data.base.errors import ModelZooError

from .names import is_commit, validate_filename, validate_model_name, validate_repo_id

__all__ = ["CARD_VERSION", "STATUSES", "FileRecord", "PastRevision", "ModelCard", "parse_card", "read_card", "split_front_matter"]

CARD_VERSION = 1
STATUSES = ("published", "unpublished", "bundled")


@dataclass(frozen=True)
class FileRecord:
    """One file of a revision: its sha256 (hex) and size [bytes]."""

    sha256: str
    size: int

    def to_dict(self) -> dict[str, Any]:
        return {"sha256": self.sha256, "size": self.size}


@dataclass(frozen=True)
class PastRevision:
    """An earlier published revision, still loadable with ``revision=`` and still verified."""

    revision: str
    files: dict[str, FileRecord]
    published: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"revision": self.revision, "published": self.published, "files": {k: v.to_dict() for k, v in self.files.items()}}


@dataclass(frozen=True)
class ModelCard:
    """The parsed ``mer:`` block of a card (see the module docstring), plus the Hub licence."""

    name: str
    status: str
    summary: str
    license: str
    repo_id: str | None = None
    revision: str | None = None
    published: str = ""
    files: dict[str, FileRecord] = field(default_factory=dict)
    history: tuple[PastRevision, ...] = ()
    base_model: str | None = None
    base_revision: str | None = None
    base_repo_id: str | None = None
    robots: dict[str, list[str]] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    paper_metrics: dict[str, Any] = field(default_factory=dict)
    checkpoint: dict[str, Any] = field(default_factory=dict)
    license_note: str = ""
    reproduce: str = ""
    path: Path | None = field(default=None, compare=False)

    @property
    def size(self) -> int:
        """Total size [bytes] of the pinned files (0 when unpublished)."""
        return sum(f.size for f in self.files.values())

    @property
    def targets(self) -> list[str]:
        return list(self.robots.get("targets", []))

    def files_for(self, revision: str | None) -> dict[str, FileRecord] | None:
        """The recorded files of ``revision`` (the pinned one or one in ``history``); None if not recorded."""
        if revision is None or revision == self.revision:
            return dict(self.files) if self.files else None
        for past in self.history:
            if past.revision == revision:
                return dict(past.files)
        return None

    def to_meta(self) -> dict[str, Any]:
        """The ``mer:`` block, in a fixed key order (what :func:`parse_card` reads back)."""
        return {
            "card_version": CARD_VERSION,
            "name": self.name,
            "status": self.status,
            "summary": self.summary,
            "repo_id": self.repo_id,
            "revision": self.revision,
            "published": self.published,
            "files": {k: v.to_dict() for k, v in self.files.items()},
            "history": [h.to_dict() for h in self.history],
            "base_model": self.base_model,
            "base_revision": self.base_revision,
            "base_repo_id": self.base_repo_id,
            "robots": {k: list(v) for k, v in self.robots.items()},
            "training": dict(self.training),
            "metrics": dict(self.metrics),
            "paper_metrics": dict(self.paper_metrics),
            "checkpoint": dict(self.checkpoint),
            "license_note": self.license_note,
            "reproduce": self.reproduce,
        }


def split_front_matter(text: str, where: str | Path | None = None) -> tuple[dict, str]:
    """``---\\nYAML\\n---\\nbody`` → (mapping, body). Safe YAML only (no Python objects)."""
    if not text.startswith("---\n"):
        raise ModelZooError("a model card must start with a '---' YAML front matter block", path=where, line=1,
                            fix="regenerate the card with `mer zoo publish` or tools/render_catalogue.py")
    end = text.find("\n---\n", 4)
    if end < 0:
        raise ModelZooError("the YAML front matter is not closed by a '---' line", path=where, fix="regenerate the card")
    try:
        meta = yaml.safe_load(text[4:end])
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise ModelZooError(f"invalid YAML front matter: {getattr(exc, 'problem', exc)}", path=where,
                            line=(mark.line + 2) if mark else None, fix="regenerate the card") from None
    if not isinstance(meta, dict):
        raise ModelZooError("the YAML front matter is not a mapping", path=where, fix="regenerate the card")
    return meta, text[end + 5:]


def _files(raw: Any, where, element: str) -> dict[str, FileRecord]:
    if raw in (None, {}):
        return {}
    if not isinstance(raw, Mapping):
        raise ModelZooError(f"{element} must be a mapping of file name -> {{sha256, size}}", path=where, element=element)
    out = {}
    for name, rec in raw.items():
        validate_filename(name)
        sha, size = (rec or {}).get("sha256"), (rec or {}).get("size")
        if not (isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)):
            raise ModelZooError(f"file {name!r} has no valid sha256 (64 lower-case hex)", path=where, element=f"{element}.{name}.sha256",
                                fix="regenerate the card from the checkpoint with `mer zoo publish`")
        if not (isinstance(size, int) and not isinstance(size, bool) and size >= 0):
            raise ModelZooError(f"file {name!r} has no valid size", path=where, element=f"{element}.{name}.size")
        out[name] = FileRecord(sha, size)
    return out


def parse_card(text: str, where: str | Path | None = None) -> ModelCard:
    """Parse and validate a card's front matter; every name, id, revision and file is checked."""
    top, _body = split_front_matter(text, where)
    m = top.get("mer")
    if not isinstance(m, dict):
        raise ModelZooError("the front matter has no 'mer:' block", path=where, element="mer", fix="regenerate the card")
    if m.get("card_version") != CARD_VERSION:
        raise ModelZooError(f"card_version {m.get('card_version')!r}, this mer reads {CARD_VERSION}", path=where,
                            element="mer.card_version", fix="upgrade mer, or regenerate the card with this version")
    name = validate_model_name(m.get("name"))
    status = m.get("status")
    if status not in STATUSES:
        raise ModelZooError(f"status {status!r} is not one of {', '.join(STATUSES)}", path=where, element="mer.status")
    repo_id = m.get("repo_id")
    if repo_id is not None:
        validate_repo_id(repo_id)
    revision = m.get("revision")
    if revision is not None and not is_commit(revision):
        raise ModelZooError(f"the pinned revision {revision!r} is not a 40-hex commit id", path=where, element="mer.revision",
                            fix="cards pin immutable commits; regenerate the card with `mer zoo publish`")
    files = _files(m.get("files"), where, "mer.files")
    if status == "published" and (repo_id is None or revision is None or not files):
        raise ModelZooError("a published card needs repo_id, revision and files", path=where, element="mer.status")
    if status == "bundled" and not files:
        raise ModelZooError("a bundled card needs its files and checksums", path=where, element="mer.files")
    history = []
    for i, h in enumerate(m.get("history") or []):
        if not isinstance(h, Mapping) or not is_commit(h.get("revision")):
            raise ModelZooError(f"history entry {i} has no 40-hex revision", path=where, element=f"mer.history[{i}]")
        history.append(PastRevision(h["revision"], _files(h.get("files"), where, f"mer.history[{i}].files"), str(h.get("published") or "")))
    base = m.get("base_model")
    if base is not None:
        validate_model_name(base)
    base_rev = m.get("base_revision")
    if base_rev is not None and not is_commit(base_rev):
        raise ModelZooError(f"base_revision {base_rev!r} is not a 40-hex commit id", path=where, element="mer.base_revision")
    base_repo = m.get("base_repo_id")
    if base_repo is not None:
        validate_repo_id(base_repo)
    robots = m.get("robots") or {}
    if not isinstance(robots, Mapping) or not all(isinstance(v, list) for v in robots.values()):
        raise ModelZooError("robots must map 'targets'/'references' to lists of names", path=where, element="mer.robots")
    lic = top.get("license")
    if not isinstance(lic, str) or not lic:
        raise ModelZooError("the card has no licence", path=where, element="license", fix="regenerate the card")
    dicts = {}
    for key in ("training", "metrics", "paper_metrics", "checkpoint"):
        v = m.get(key) or {}
        if not isinstance(v, Mapping):
            raise ModelZooError(f"{key} must be a mapping", path=where, element=f"mer.{key}")
        dicts[key] = dict(v)
    return ModelCard(
        name=name, status=status, summary=str(m.get("summary") or ""), license=lic, repo_id=repo_id, revision=revision,
        published=str(m.get("published") or ""), files=files, history=tuple(history), base_model=base, base_revision=base_rev, base_repo_id=base_repo,
        robots={k: [str(x) for x in v] for k, v in robots.items()}, license_note=str(m.get("license_note") or ""),
        reproduce=str(m.get("reproduce") or ""), path=Path(where) if where else None, **dicts,
    )


def read_card(path: str | Path) -> ModelCard:
    """Read and parse a card file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ModelZooError(f"cannot read the model card: {exc.strerror}", path=path) from None
    card = parse_card(text, path)
    if path.stem != card.name:
        raise ModelZooError(f"the card file is named {path.name!r} but describes {card.name!r}", path=path, element="mer.name",
                            fix=f"rename the file to {card.name}.md")
    return card
