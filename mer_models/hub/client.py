"""The zoo's only door to the Hugging Face Hub: cache look-ups (no network) and per-file downloads.

Configuration is huggingface_hub's own: ``HF_ENDPOINT``, ``HF_HUB_CACHE`` / ``HF_HOME`` and
``HF_TOKEN`` as the client resolved them (the first three when ``huggingface_hub`` was imported,
so set them before starting Python). Offline mode is honoured more strictly than by the client:
``HF_HUB_OFFLINE`` is read both as the client read it at import *and* from the environment at call
time, and when it is on, the zoo calls no client function that can reach the network at all; it
only looks files up in the cache (``try_to_load_from_cache``, pure filesystem). A file that is
cached at a pinned commit is likewise never re-fetched or re-validated over the network.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
from pathlib import Path
from typing import Any, Iterator

from mer_data.base.errors import ChecksumError, ModelNotAvailableError, ModelZooError

from .names import validate_filename, validate_repo_id, validate_revision

log = logging.getLogger(__name__)

__all__ = ["offline", "cache_dir", "endpoint", "cached_file", "fetch_file", "repo_cache_folder", "settings"]

_TRUE = {"1", "on", "yes", "true"}
#: per-call settings of :func:`settings` (``from_pretrained(cache_dir=, local_files_only=, token=)``)
_SETTINGS: contextvars.ContextVar[dict[str, Any]] = contextvars.ContextVar("mer_hub_settings", default={})


@contextlib.contextmanager
def settings(*, cache_dir: str | Path | None = None, local_files_only: bool = False, token: str | None = None) -> Iterator[None]:
    """Within the block: another Hub cache folder, cache-only look-ups (``local_files_only``: as
    ``HF_HUB_OFFLINE``, no network call at all), and the token for downloads. Nested blocks add up."""
    new = dict(_SETTINGS.get())
    if cache_dir is not None:
        new["cache_dir"] = Path(cache_dir).expanduser()
    if local_files_only:
        new["local_files_only"] = True
    if token is not None:
        new["token"] = token
    reset = _SETTINGS.set(new)
    try:
        yield
    finally:
        _SETTINGS.reset(reset)


def _offline_reason() -> str:
    return "local_files_only=True was given" if _SETTINGS.get().get("local_files_only") else "HF_HUB_OFFLINE is set"


def offline() -> bool:
    """``local_files_only`` (:func:`settings`), or ``HF_HUB_OFFLINE`` (or ``TRANSFORMERS_OFFLINE``) from the
    environment now or as the client read it."""
    if _SETTINGS.get().get("local_files_only"):
        return True
    if any((os.environ.get(v) or "").strip().lower() in _TRUE for v in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE")):
        return True
    from huggingface_hub import constants

    return bool(constants.HF_HUB_OFFLINE)


def cache_dir() -> Path:
    """The Hub cache folder: :func:`settings`' ``cache_dir``, else the client's (``HF_HUB_CACHE``, default
    ``~/.cache/huggingface/hub``)."""
    if "cache_dir" in _SETTINGS.get():
        return _SETTINGS.get()["cache_dir"]
    from huggingface_hub import constants

    return Path(constants.HF_HUB_CACHE).expanduser()


def endpoint() -> str:
    """The Hub endpoint the client uses (``HF_ENDPOINT``, default ``https://huggingface.co``)."""
    from huggingface_hub import constants

    return constants.ENDPOINT


def repo_cache_folder(repo_id: str) -> Path:
    """``<cache>/models--ORG--NAME`` (the client's layout)."""
    validate_repo_id(repo_id)
    return cache_dir() / ("models--" + repo_id.replace("/", "--"))


def cached_file(repo_id: str, filename: str, revision: str) -> Path | None:
    """The cached copy of ``filename`` at ``revision`` (commit, or a branch the cache has a ref for), else None.

    Pure filesystem: never touches the network, whatever the mode.
    """
    from huggingface_hub import try_to_load_from_cache

    validate_repo_id(repo_id)
    validate_filename(filename)
    validate_revision(revision)
    found = try_to_load_from_cache(repo_id, filename, cache_dir=str(cache_dir()), revision=revision)
    return Path(found) if isinstance(found, str) else None


def fetch_file(repo_id: str, filename: str, revision: str, *, what: str) -> Path:
    """Download one file through ``hf_hub_download`` into the Hub cache; returns the snapshot path.

    Refuses in offline mode (callers look in the cache first). Client errors become
    :class:`~mer_data.base.errors.ModelZooError` subclasses that say what to do.
    """
    validate_repo_id(repo_id)
    validate_filename(filename)
    validate_revision(revision)
    if offline():
        raise ModelNotAvailableError(
            f"{what}: {filename} is not in the Hub cache ({cache_dir()}) and {_offline_reason()}, so it cannot be downloaded",
            element=filename,
            fix=f"run `mer zoo download {what}` once while online (unset HF_HUB_OFFLINE), or point HF_HUB_CACHE at a "
            "cache that has it",
        )
    from huggingface_hub import hf_hub_download
    from huggingface_hub.errors import (
        HfHubHTTPError,
        LocalEntryNotFoundError,
        RemoteEntryNotFoundError,
        RepositoryNotFoundError,
        RevisionNotFoundError,
    )

    where = f"{repo_id}@{revision} on {endpoint()}"
    try:
        path = hf_hub_download(repo_id, filename, revision=revision, cache_dir=str(cache_dir()), library_name="mer",
                               token=_SETTINGS.get().get("token"))
    except RepositoryNotFoundError:
        raise ModelZooError(f"{what}: the repository {repo_id} does not exist on {endpoint()} (or it is private)",
                            element=repo_id, fix="check the repo id; for a private repository set HF_TOKEN") from None
    except RevisionNotFoundError:
        raise ModelZooError(f"{what}: revision {revision} does not exist in {repo_id} on {endpoint()}", element=revision,
                            fix="pass a commit or branch that exists (`mer zoo info NAME` lists the recorded ones)") from None
    except RemoteEntryNotFoundError:
        raise ModelZooError(f"{what}: {filename} is missing from {where}", element=filename,
                            fix="the repository does not hold a mer checkpoint at that revision") from None
    except LocalEntryNotFoundError as exc:
        raise ModelNotAvailableError(
            f"{what}: cannot reach {endpoint()} to download {filename} and it is not cached ({type(exc.__cause__ or exc).__name__})",
            element=filename,
            fix=f"check the network (and HF_ENDPOINT), then run `mer zoo download {what}`",
        ) from None
    except HfHubHTTPError as exc:
        code = exc.response.status_code if exc.response is not None else "?"
        raise ModelZooError(f"{what}: the Hub answered HTTP {code} for {filename} ({where})", element=filename,
                            fix="retry later; for a private repository set HF_TOKEN") from None
    except OSError as exc:  # the client's size consistency check, disk errors
        if "Consistency check failed" in str(exc):
            raise ChecksumError(f"{what}: the download of {filename} was cut short ({where})", element=filename,
                                fix="run the command again; nothing was kept") from None
        raise ModelZooError(f"{what}: cannot download {filename}: {exc}", element=filename) from None
    return Path(path)
