"""The zoo's only door to the Hugging Face Hub: cache look-ups (no network) and per-file downloads.

Configuration is huggingface_hub's own: ``HF_ENDPOINT``, ``HF_HUB_CACHE`` / ``HF_HOME`` and
``HF_TOKEN`` as the client resolved them (the first three when ``huggingface_hub`` was imported,
so set them before starting Python). Offline mode is honoured more strictly than by the client:
``HF_HUB_OFFLINE`` is read both as the client read it at import *and* from the environment at call
time, and when it is on, the zoo calls no client function that can reach the network at all; it
only looks files up in the cache (``try_to_load_from_cache``, pure filesystem). A file that is
cached at a pinned commit is likewise never re-fetched or re-validated over the network.

Downloads (:func:`fetch_file`) do not go through ``hf_hub_download``: the client turns the server's
ETag into a cache path unchecked (``blobs/<etag>``; ``../..`` in it writes outside the cache), so mer
asks for the metadata, checks it, downloads into a private temporary file, verifies the bytes and
only then moves them into the cache, in the client's own layout (:mod:`mer_data.base.hub_files`,
which shard datasets, ``hf://datasets/...``, share).
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import logging
import os
import re
from pathlib import Path
from typing import Any, Iterator

from mer_data.base.errors import ChecksumError, DiskFullError, ModelNotAvailableError, ModelZooError
from mer_data.base.hub_files import download_blob, install_blob
from mer_data.base.limits import limit, too_big

from .names import is_commit, validate_filename, validate_repo_id, validate_revision

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


_CONTENT_ID = re.compile(r"^(?:[0-9a-f]{40}|[0-9a-f]{64})$")
#: files whose size is capped at download (they are read whole): name -> limit
_SIZE_LIMITS = {"config.json": "MER_MAX_CONFIG_BYTES"}


def _refuse(what: str, filename: str, message: str, fix: str = "check HF_ENDPOINT: the server does not behave as the Hub does"):
    return ModelZooError(f"{what}: {message}; nothing was written", element=filename, fix=fix)


def _download_blob(url: str, dest_dir: Path, etag: str, size: int, headers: dict[str, str], what: str, filename: str) -> Path:
    """Stream ``url`` into a private temporary file in ``dest_dir`` (capped, hashed, checked against ``etag``)."""
    return download_blob(url, dest_dir, etag, size, headers, error=ChecksumError, what=what, filename=filename)


def _install(storage: Path, tmp_blob: Path, etag: str, commit: str, filename: str, revision: str) -> Path:
    """Move a verified blob into the cache (huggingface_hub's layout) and link its snapshot entry."""
    return install_blob(storage, tmp_blob, etag, commit, filename, revision)


def fetch_file(repo_id: str, filename: str, revision: str, *, what: str) -> Path:
    """Download one file into the Hub cache (huggingface_hub's layout); returns the snapshot path.

    What the server says is checked before it becomes a path or a byte on disk: the ETag must be a
    content id (40 or 64 hex digits), the commit a 40-hex id, the size within the file's limit
    (``config.json``: ``MER_MAX_CONFIG_BYTES``). The bytes go to a private temporary file, capped at
    the announced size and hashed on the fly; only a file that hashes to its ETag is moved into the
    cache. Refuses in offline mode (callers look in the cache first). Client errors become
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
    import httpx2
    from huggingface_hub import get_hf_file_metadata, hf_hub_url
    from huggingface_hub.errors import (
        HfHubHTTPError,
        RemoteEntryNotFoundError,
        RepositoryNotFoundError,
        RevisionNotFoundError,
    )
    from huggingface_hub.utils import build_hf_headers

    where = f"{repo_id}@{revision} on {endpoint()}"
    token = _SETTINGS.get().get("token")
    size: int | None = None
    try:
        url = hf_hub_url(repo_id, filename, revision=revision, endpoint=endpoint())
        meta = get_hf_file_metadata(url, token=token, library_name="mer", endpoint=endpoint())
        etag, commit, size = meta.etag, meta.commit_hash, meta.size
        if not isinstance(etag, str) or not _CONTENT_ID.match(etag):
            raise _refuse(what, filename, f"the server gave {filename} the ETag {str(etag)[:80]!r}, which is not a content id "
                          "(40 or 64 hex digits)")  # fmt: skip
        if not is_commit(commit):
            raise _refuse(what, filename, f"the server gave the commit id {str(commit)[:80]!r}, not 40 hex digits")
        if not isinstance(size, int) or size < 0:
            raise _refuse(what, filename, f"the server gave {filename} no valid size ({size!r})")
        name = filename.rsplit("/", 1)[-1]
        if name in _SIZE_LIMITS and size > limit(_SIZE_LIMITS[name]):
            msg, fix = too_big(_SIZE_LIMITS[name], size)
            raise _refuse(what, filename, f"{filename} is announced with {size:,} bytes: {msg}", fix)
        storage = repo_cache_folder(repo_id)
        (storage / "blobs").mkdir(parents=True, exist_ok=True)
        same_origin = meta.location.startswith(endpoint().rstrip("/") + "/")
        headers = build_hf_headers(token=token if same_origin else False, library_name="mer")
        headers["Accept-Encoding"] = "identity"  # bytes as stored: no decompression bomb on the way
        tmp = _download_blob(meta.location, storage / "blobs", etag, size, headers, what, filename)
        path = _install(storage, tmp, etag, commit, filename, revision)
    except RepositoryNotFoundError:
        raise ModelZooError(f"{what}: the repository {repo_id} does not exist on {endpoint()} (or it is private)",
                            element=repo_id, fix="check the repo id; for a private repository set HF_TOKEN") from None
    except RevisionNotFoundError:
        raise ModelZooError(f"{what}: revision {revision} does not exist in {repo_id} on {endpoint()}", element=revision,
                            fix="pass a commit or branch that exists (`mer zoo info NAME` lists the recorded ones)") from None
    except RemoteEntryNotFoundError:
        raise ModelZooError(f"{what}: {filename} is missing from {where}", element=filename,
                            fix="the repository does not hold a mer checkpoint at that revision") from None
    except HfHubHTTPError as exc:
        code = exc.response.status_code if exc.response is not None else "?"
        raise ModelZooError(f"{what}: the Hub answered HTTP {code} for {filename} ({where})", element=filename,
                            fix="retry later; for a private repository set HF_TOKEN") from None
    except (httpx2.TransportError, httpx2.InvalidURL, ValueError) as exc:
        raise ModelNotAvailableError(
            f"{what}: cannot download {filename} from {endpoint()} ({type(exc).__name__}: {exc})",
            element=filename,
            fix=f"check the network (and HF_ENDPOINT), then run `mer zoo download {what}`",
        ) from None
    except DiskFullError:
        raise
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            raise ModelZooError(f"{what}: the disk is full: cannot store {filename} ({size or 0:,} bytes) in {cache_dir()}",
                                path=cache_dir(), element=filename, fix="free space, or point HF_HUB_CACHE elsewhere") from None
        raise ModelZooError(f"{what}: cannot download {filename}: {exc}", element=filename) from None
    return path
