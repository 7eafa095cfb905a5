"""Shards on the Hugging Face Hub: ``mer shards push DIR REPO_ID`` and ``hf://datasets/REPO_ID[@REV]``.

A pushed shard set is a *dataset* repository holding the shard files, the dataset card
(``README.md``, rendered from the shards' metadata) and ``mer_meta.json`` (:mod:`.sidecar`: the
metadata that ``datasets.load_dataset("hdf5")`` does not read). Reading it back goes through the
client's cache, in its layout, but not through its downloader: a repository may come from anyone,
so :func:`mer_data.base.hub_files.checked_snapshot` checks what the server says (commit id, file
names, sizes, ETags) before it becomes a path, caps every file and verifies its hash before it
enters the cache. Only those files are fetched, and with ``HF_HUB_OFFLINE=1`` the cached snapshot is
used without any network call.

Configuration is huggingface_hub's: ``HF_ENDPOINT``, ``HF_TOKEN``, ``HF_HUB_CACHE``. A Hub-compatible
server without Xet storage needs ``HF_HUB_DISABLE_XET=1`` to upload.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

from mer_data.base.errors import ShardError, ShardFormatError

from .card import LICENSE_ID, write_card
from .humans import human_kind_of
from .reader import SHARD_SUFFIXES, PathsLike, find_shards, open_shard
from .sidecar import META_FILE, write_sidecar

log = logging.getLogger(__name__)

__all__ = ["HF_DATASETS_PREFIX", "PushResult", "parse_hf_url", "resolve_hub_paths", "download_shards", "push_shards"]

HF_DATASETS_PREFIX = "hf://datasets/"
_REPO = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,95}/[A-Za-z0-9][A-Za-z0-9._-]{0,95}$")
#: what a shard repository holds and what is downloaded from it
ALLOW_PATTERNS = [*(f"*{s}" for s in SHARD_SUFFIXES), "README.md", META_FILE]


def parse_hf_url(url: str) -> tuple[str, str | None]:
    """``hf://datasets/OWNER/NAME[@REVISION]`` -> (repo id, revision or None)."""
    if not url.startswith(HF_DATASETS_PREFIX):
        raise ShardFormatError(f"{url!r} is not a Hub dataset URL", fix="write hf://datasets/OWNER/NAME[@REVISION]")
    repo, _, revision = url[len(HF_DATASETS_PREFIX):].partition("@")
    if not _REPO.match(repo) or ".." in repo or repo.endswith(".git"):
        raise ShardFormatError(f"cannot read the Hub dataset id {repo!r} in {url!r}", fix="write hf://datasets/OWNER/NAME[@REVISION]")
    if "@" in url and not revision:
        raise ShardFormatError(f"empty revision in {url!r}", fix="write hf://datasets/OWNER/NAME@REVISION, or leave out '@'")
    return repo, revision or None


def _size_limit(name: str) -> str:
    """The limit on a downloaded file's size: the side file and the card are read whole."""
    if name == META_FILE:
        return "MER_MAX_SIDECAR_BYTES"
    return "MER_MAX_DATASET_CARD_BYTES" if name == "README.md" else "MER_MAX_HUB_FILE_BYTES"


def download_shards(url: str) -> Path:
    """The local snapshot folder of ``hf://datasets/OWNER/NAME[@REV]`` (shards, card, side file only).

    Contained (:func:`mer_data.base.hub_files.checked_snapshot`): the server's commit id, file names,
    sizes and ETags are checked before they become paths; each file is capped (``mer_meta.json``:
    ``MER_MAX_SIDECAR_BYTES``, ``README.md``: ``MER_MAX_DATASET_CARD_BYTES``, shards:
    ``MER_MAX_HUB_FILE_BYTES``) and hashed into a private temporary file before it enters the cache.
    """
    from mer_data.base.hub_files import checked_snapshot

    repo, revision = parse_hf_url(url)
    path = checked_snapshot(repo, revision, repo_type="dataset", patterns=ALLOW_PATTERNS, size_limit=_size_limit,
                            error=ShardError)  # fmt: skip
    log.info("using %s from %s", url, path)
    return path


def resolve_hub_paths(paths: PathsLike) -> PathsLike:
    """``paths`` with every ``hf://datasets/...`` entry replaced by its local snapshot folder."""
    if isinstance(paths, (str, Path)):
        return download_shards(paths) if isinstance(paths, str) and paths.startswith("hf://") else paths
    return [download_shards(p) if isinstance(p, str) and p.startswith("hf://") else p for p in paths]


@dataclass(frozen=True)
class PushResult:
    repo_id: str
    commit: str
    files: list[str]


def push_shards(folder: str | Path, repo_id: str, *, private: bool = False, ignore_license: bool = False,
                message: str | None = None) -> PushResult:
    """Upload the shard folder ``folder`` to the dataset repository ``repo_id`` (created if needed).

    The card (``README.md``) and ``mer_meta.json`` are (re)written from the shards first, so what is
    pushed always describes the shards pushed. Shards of LAFAN1 (CC BY-NC-ND 4.0: no derivatives may
    be distributed) are refused unless ``ignore_license``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ShardError("no shard folder here", path=folder, fix="pass the --out folder of `mer shards build`")
    if not _REPO.match(repo_id) or ".." in repo_id:
        raise ShardError(f"invalid Hub repo id {repo_id!r}", fix="write OWNER/NAME")
    shards = find_shards(folder)
    builds, human = set(), None
    for p in shards:
        f = open_shard(p)
        builds.add((f.meta.build_id, bool(f.meta.config.get("synthetic"))))
        human = human or human_kind_of(f.meta.robot)
        f.close()
    if len(builds) != 1:
        raise ShardFormatError(f"the folder holds shards of {len(builds)} builds", path=folder, fix="push one build per repository")
    synthetic = next(iter(builds))[1]
    if not synthetic and not ignore_license:
        raise ShardError(
            f"these shards are derived from human motion files ({human}) under their own licence (AMASS, Bandai, ... often "
            "forbid redistributing derivatives)" if human else
            f"these shards are derived from LAFAN1 ({LICENSE_ID}: no derivatives may be distributed)", path=folder,
            fix="share the dataset card and the rebuild command instead; pass --ignore-license only if you hold "
            "the rights to distribute them (e.g. to a private repository of your own group)",
        )
    card = write_card(folder)
    side = write_sidecar(folder)
    from huggingface_hub import HfApi
    from huggingface_hub.errors import HfHubHTTPError

    api = HfApi(library_name="mer")
    names = sorted([p.name for p in shards] + [card.name, side.name])
    try:
        api.create_repo(repo_id, repo_type="dataset", exist_ok=True, private=private)
        info = api.upload_folder(folder_path=str(folder), repo_id=repo_id, repo_type="dataset", allow_patterns=names,
                                 commit_message=message or f"mer: {len(shards)} shard file(s)")
    except HfHubHTTPError as exc:
        code = exc.response.status_code if exc.response is not None else "?"
        raise ShardError(f"the Hub refused the upload to {repo_id}: HTTP {code}", fix="check HF_TOKEN (write access) and the repo id") from None
    log.info("pushed %d file(s) to %s@%s", len(names), repo_id, info.oid)
    return PushResult(repo_id, info.oid, names)
