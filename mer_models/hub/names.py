"""Validation of everything that becomes a path or a URL: model names, repo ids, revisions, files.

A model name becomes a card file name (``cards/models/<name>.md``), a revision becomes a file under
the Hub cache (``refs/<revision>``) and a URL segment, a file name becomes a path inside a snapshot
folder. Each is checked against a strict pattern before use, so no value read from a card, the
command line or a caller can reach outside the cache or the registry.
"""

from __future__ import annotations

import re

from mer_data.base.errors import ModelZooError
from mer_data.base.hub_files import COMMIT_RE, is_ref, is_repo_id

__all__ = [
    "COMMIT_RE",
    "validate_model_name",
    "validate_repo_id",
    "validate_revision",
    "validate_filename",
    "is_commit",
    "looks_like_repo_id",
    "SAFE_SUFFIXES",
]

# Lower-case, starts with a letter or digit; dots only inside (never "..").
_NAME = re.compile(r"^[a-z0-9](?:[a-z0-9_-]|\.(?!\.)){0,62}[a-z0-9]$|^[a-z0-9]$")
_FILE_COMPONENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,127}$")
# File types the zoo will ever download: data only, never code or pickles.
SAFE_SUFFIXES = (".json", ".safetensors", ".md", ".jsonl")


def validate_model_name(name: str) -> str:
    """A zoo name: ``[a-z0-9]`` then ``[a-z0-9._-]``, at most 64 characters, no ``..``."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise ModelZooError(
            f"invalid model name {name!r}",
            element="name",
            fix="use lower-case letters, digits, '-', '_' and single '.', at most 64 characters "
            "(e.g. mer-base-talos)",
        )
    return name


def validate_repo_id(repo_id: str) -> str:
    """A Hub model repo id ``org/name`` (the Hub's own character rules, no ``..`` or ``--``)."""
    if not is_repo_id(repo_id):
        raise ModelZooError(
            f"invalid Hub repo id {repo_id!r}",
            element="repo_id",
            fix="use ORG/NAME with letters, digits, '-', '_' and '.', e.g. my-lab/mer-base-talos",
        )
    return repo_id


def is_commit(revision: str | None) -> bool:
    """True for a full 40-hex commit id (the only revision that is immutable)."""
    return isinstance(revision, str) and bool(COMMIT_RE.match(revision))


def validate_revision(revision: str) -> str:
    """A 40-hex commit id, or a branch/tag name without ``..``, leading ``/`` or odd characters."""
    if not isinstance(revision, str) or not revision:
        raise ModelZooError("empty revision", element="revision", fix="pass a 40-hex commit id or a branch/tag name")
    if is_commit(revision):
        return revision
    if not is_ref(revision) or re.fullmatch(r"[0-9a-fA-F]{40}", revision):  # an upper-case "commit" is neither
        raise ModelZooError(
            f"invalid revision {revision!r}",
            element="revision",
            fix="pass a full 40-hex lower-case commit id (recommended: it is immutable) or a branch/tag name "
            "made of letters, digits, '.', '_', '-' and single '/'",
        )
    return revision


def validate_filename(filename: str) -> str:
    """A relative POSIX path of safe components whose suffix is a data format (never code/pickle)."""
    comps = filename.split("/") if isinstance(filename, str) else [""]
    if not all(_FILE_COMPONENT.match(c) and ".." not in c for c in comps) or "\\" in filename:
        raise ModelZooError(
            f"invalid file name {filename!r} in a model card",
            element=filename if isinstance(filename, str) else None,
            fix="file names are relative paths of letters, digits, '.', '_' and '-' (no '..', no absolute paths)",
        )
    if not filename.endswith(SAFE_SUFFIXES):
        raise ModelZooError(
            f"refusing to fetch {filename!r}: only data files ({', '.join(SAFE_SUFFIXES)}) are ever downloaded "
            "(no pickles, no code)",
            element=filename,
            fix="publish weights as model.safetensors and the configuration as config.json",
        )
    return filename


def looks_like_repo_id(spec: str) -> bool:
    """True for ``org/name`` (one slash, valid halves) - the form a plain Hub id takes."""
    try:
        validate_repo_id(spec)
    except ModelZooError:
        return False
    return True
