"""Downloads from a Hugging Face Hub endpoint that may lie: checked before anything becomes a path.

huggingface_hub turns what a server says into cache paths unchecked: an ETag of ``../../x`` makes it
write ``blobs/../../x`` outside the cache, a file name or commit id with ``..`` raises a raw
``ValueError`` (or worse), and nothing caps what it downloads. Every mer download from the Hub goes
through this module instead, in the client's own cache layout (so ``try_to_load_from_cache`` and
``HF_HUB_OFFLINE`` work as usual):

* **What the server says is checked first**: commit ids (40 hex digits), content ids (ETags: a git
  blob sha1 or an LFS sha256), file names (relative paths of plain components, no ``..``), sizes
  (announced, within the file's limit and the total; the listing and the file's own headers must
  agree); JSON answers are size-capped (``MER_MAX_HUB_JSON_BYTES``) and never paginated off-site.
* **Bytes go to a private temporary file** (created exclusively in ``blobs/``), capped at the
  announced size and hashed on the fly; only a file that hashes to its content id is moved into the
  cache and linked from its snapshot. A refusal keeps nothing.
* **Offline** (``HF_HUB_OFFLINE``): the cache alone, no network call at all.
* **One attempt, one message**: no retries with back-off; a transport error is one ``MerError``.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import logging
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, urlsplit

from .atomic import atomic_write, create_new, disk_full, disk_full_as_error, free_bytes, owner_tag, real_folder
from .errors import MerError
from .limits import limit, too_big

log = logging.getLogger(__name__)

__all__ = [
    "RemoteFile",
    "hub_offline",
    "check_commit",
    "check_content_id",
    "check_repo_path",
    "check_ref",
    "check_repo_id",
    "COMMIT_RE",
    "is_repo_id",
    "is_ref",
    "storage_folder",
    "download_blob",
    "install_blob",
    "checked_snapshot",
]

#: a full commit id: 40 lower-case hex digits
COMMIT_RE = _COMMIT = re.compile(r"^[0-9a-f]{40}$")
_CONTENT_ID = re.compile(r"^(?:[0-9a-f]{40}|[0-9a-f]{64})$")
_COMPONENT = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._+=@ -]{0,254}$")
_REF_COMPONENT = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$")
# the Hub's rule for each half of ``org/name``: no "--" or "..", no leading/trailing "-" or "."
_REPO_PART = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9_]|[-.](?![-.])){0,94}[A-Za-z0-9_]$|^[A-Za-z0-9]$")
_TRUE = {"1", "on", "yes", "true"}
#: timeout of one request [s] (connect, read)
TIMEOUT_S = 60.0
SERVER_FIX = "check HF_ENDPOINT: the server does not behave as the Hub does"


@dataclass(frozen=True)
class RemoteFile:
    """One file of a repository at a commit, as the listing announced it (checked)."""

    path: str
    size: int
    content_id: str  # git blob sha1 (40 hex) or the LFS sha256 (64 hex): the ETag and the blob's name


def hub_offline() -> bool:
    """``HF_HUB_OFFLINE`` (or ``TRANSFORMERS_OFFLINE``) in the environment now, or as the client read it."""
    if any((os.environ.get(v) or "").strip().lower() in _TRUE for v in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE")):
        return True
    from huggingface_hub import constants

    return bool(constants.HF_HUB_OFFLINE)


def _shown(value: object) -> str:
    return repr(str(value)[:80])


def check_commit(value: object, error: type[MerError], what: str) -> str:
    """A commit id the server gave: 40 lower-case hex digits (it becomes a folder name); else ``error``."""
    if not isinstance(value, str) or not _COMMIT.match(value):
        raise error(f"{what}: the server gave the commit id {_shown(value)}, not 40 hex digits; nothing was written",
                    fix=SERVER_FIX)  # fmt: skip
    return value


def check_content_id(value: object, filename: str, error: type[MerError], what: str) -> str:
    """A content id (ETag) the server gave: a git sha1 or an LFS sha256 (it becomes a file name)."""
    if not isinstance(value, str) or not _CONTENT_ID.match(value):
        raise error(f"{what}: the server gave {filename} the ETag {_shown(value)}, which is not a content id (40 or 64 "
                    "hex digits); nothing was written", element=filename, fix=SERVER_FIX)  # fmt: skip
    return value


def check_repo_path(name: object, error: type[MerError], what: str) -> str:
    """A file name the server gave: a relative path of plain components (no ``..``, no absolute path,
    no backslash, no control characters), at most 1024 characters; it becomes a path in the cache."""
    comps = name.split("/") if isinstance(name, str) else [""]
    if not (isinstance(name, str) and len(name) <= 1024 and "\\" not in name
            and all(_COMPONENT.match(c) and ".." not in c for c in comps)):  # fmt: skip
        raise error(f"{what}: the server lists a file named {_shown(name)}, which is not a plain relative path (no '..', "
                    "no absolute path); nothing was written", fix=SERVER_FIX)  # fmt: skip
    return name


def is_repo_id(repo_id: object) -> bool:
    """``ORG/NAME`` by the Hub's character rules for each half (no "--" or "..", no leading or
    trailing "-" or ".", at most 96 characters), not ending in ``.git``."""
    parts = repo_id.split("/") if isinstance(repo_id, str) else []
    return len(parts) == 2 and all(_REPO_PART.match(p) for p in parts) and not str(repo_id).endswith(".git")


def is_ref(revision: object) -> bool:
    """A git ref name, restricted: components of ``[A-Za-z0-9._-]`` separated by single "/", none
    starting with "." or ending with ".lock", no "..", at most 128 characters (a commit id is one too)."""
    comps = revision.split("/") if isinstance(revision, str) else [""]
    return (isinstance(revision, str) and len(revision) <= 128 and all(_REF_COMPONENT.match(c) for c in comps)
            and not any(".." in c or c.endswith(".lock") for c in comps))  # fmt: skip


def check_repo_id(repo_id: object, error: type[MerError]) -> str:
    """A repository id ``ORG/NAME`` (:func:`is_repo_id`): it becomes a URL and a cache folder."""
    if not is_repo_id(repo_id):
        raise error(f"invalid Hub repository id {_shown(repo_id)}", fix="write OWNER/NAME of letters, digits, '-', '_' and '.'")
    return str(repo_id)


def check_ref(revision: str, error: type[MerError], what: str) -> str:
    """A revision (a commit id or a branch/tag name of plain components): it becomes ``refs/<revision>``."""
    if not is_ref(revision):
        raise error(
            f"{what}: invalid revision {_shown(revision)}",
            fix="pass a 40-hex commit id or a branch/tag name of letters, digits, '.', '_', '-' and single '/'",
        )
    return revision


def storage_folder(cache: Path, repo_id: str, repo_type: str) -> Path:
    """``<cache>/<models|datasets>--ORG--NAME`` (the client's layout)."""
    return Path(cache) / f"{repo_type}s--{repo_id.replace('/', '--')}"


def download_blob(url: str, dest_dir: Path, content_id: str, size: int, headers: dict[str, str], *,
                  error: type[MerError], what: str, filename: str) -> Path:  # fmt: skip
    """Stream ``url`` into a private temporary file in ``dest_dir``: at most ``size`` bytes, hashed on the
    fly and checked against ``content_id`` (sha256 for LFS files, the git blob sha1 otherwise). Returns it."""
    from huggingface_hub.utils import get_session, hf_raise_for_status

    h = hashlib.sha256() if len(content_id) == 64 else hashlib.sha1(f"blob {size}\0".encode())
    tmp = dest_dir / f".tmp-{content_id}~{owner_tag()}~{os.urandom(4).hex()}"
    got = 0
    with disk_full_as_error(tmp, size):
        fd = create_new(tmp, 0o644)
        try:
            with os.fdopen(fd, "wb") as fh:
                with get_session().stream("GET", url, headers=headers, follow_redirects=True, timeout=TIMEOUT_S) as r:
                    hf_raise_for_status(r)
                    for chunk in r.iter_bytes(1 << 20):
                        got += len(chunk)
                        if got > size:
                            raise error(f"{what}: the server sent more than the {size:,} bytes it announced for {filename}; "
                                        "nothing was kept", element=filename, fix=SERVER_FIX)  # fmt: skip
                        h.update(chunk)
                        fh.write(chunk)
                fh.flush()
                os.fsync(fh.fileno())
            if got != size:
                raise error(f"{what}: the download of {filename} was cut short ({got:,} of {size:,} bytes); nothing was kept",
                            element=filename, fix="run the command again")  # fmt: skip
            if h.hexdigest() != content_id:
                raise error(f"{what}: {filename} hashes to {h.hexdigest()}, but the Hub served it as {content_id}; the "
                            "file was not used and nothing was kept", element=filename,
                            fix="check HF_ENDPOINT, then run the command again")  # fmt: skip
            return tmp
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise


def install_blob(storage: Path, tmp_blob: Path, content_id: str, commit: str, filename: str, revision: str) -> Path:
    """Move a verified blob into the cache (huggingface_hub's layout) and link its snapshot entry.

    Every name is one the caller checked (:func:`check_content_id`, :func:`check_commit`,
    :func:`check_repo_path`, :func:`check_ref`); the folders below ``storage`` must be real folders."""
    blob = storage / "blobs" / content_id
    os.replace(tmp_blob, blob)
    pointer = storage / "snapshots" / commit / filename
    real_folder(pointer.parent, storage)
    link = pointer.parent / f".tmp-{pointer.name}~{owner_tag()}~{os.urandom(4).hex()}"
    os.symlink(os.path.relpath(blob, pointer.parent), link)
    os.replace(link, pointer)  # replaces the name, never what a link there points to
    if revision != commit:
        atomic_write(storage / "refs" / revision, commit, below=storage)
    return pointer


def _get_json(url: str, headers: dict[str, str], *, error: type[MerError], what: str) -> tuple[object, str | None]:
    """(parsed JSON, URL of the next page or None) of one GET, its body capped (``MER_MAX_HUB_JSON_BYTES``)."""
    from huggingface_hub.utils import get_session, hf_raise_for_status

    cap = limit("MER_MAX_HUB_JSON_BYTES")
    body = bytearray()
    with get_session().stream("GET", url, headers=headers, follow_redirects=False, timeout=TIMEOUT_S) as r:
        hf_raise_for_status(r)
        for chunk in r.iter_bytes(1 << 20):
            body += chunk
            if len(body) > cap:
                msg, fix = too_big("MER_MAX_HUB_JSON_BYTES", f"over {cap:,}")
                raise error(f"{what}: the server's answer to {urlsplit(url).path} {msg}", fix=fix)
        nxt = r.links.get("next", {}).get("url") if r.headers.get("link") else None
    try:
        return json.loads(body), nxt
    except (ValueError, RecursionError):
        raise error(f"{what}: the server's answer to {urlsplit(url).path} is not JSON", fix=SERVER_FIX) from None


def _listing(endpoint: str, repo_id: str, repo_type: str, commit: str, headers: dict[str, str], *,
             error: type[MerError], what: str) -> list[dict]:  # fmt: skip
    """Every entry of the repository's tree at ``commit`` (pages followed on the same origin and path only)."""
    base = f"{endpoint.rstrip('/')}/api/{repo_type}s/{repo_id}/tree/{commit}"
    url: str | None = base + "?recursive=true"
    entries: list[dict] = []
    cap = limit("MER_MAX_HUB_FILES")
    for _ in range(1 + cap // 100):
        if url is None:
            return entries
        page, url = _get_json(url, headers, error=error, what=what)
        if not isinstance(page, list) or not all(isinstance(e, dict) for e in page):
            raise error(f"{what}: the server's file listing is not a list of entries", fix=SERVER_FIX)
        entries += page
        if len(entries) > cap:
            msg, fix = too_big("MER_MAX_HUB_FILES", f"over {cap:,}")
            raise error(f"{what}: the repository's file listing {msg}", fix=fix)
        if url is not None and not url.startswith(base):
            raise error(f"{what}: the server's listing continues at another address ({url[:120]!r})", fix=SERVER_FIX)
    raise error(f"{what}: the server's file listing does not end", fix=SERVER_FIX)


def _remote_file(entry: dict, error: type[MerError], what: str) -> RemoteFile:
    """A checked :class:`RemoteFile` from one listing entry of type ``file``."""
    name = check_repo_path(entry.get("path"), error, what)
    lfs = entry.get("lfs")
    size = entry.get("size")
    cid = entry.get("oid")
    if isinstance(lfs, dict):  # the content is the LFS object: its sha256 and size
        cid = lfs.get("oid") or lfs.get("sha256")
        if size is not None and lfs.get("size") != size:
            raise error(f"{what}: the server lists {name} with two sizes ({_shown(size)}, {_shown(lfs.get('size'))}); "
                        "nothing was written", element=name, fix=SERVER_FIX)  # fmt: skip
        size = lfs.get("size")
    if not isinstance(size, int) or isinstance(size, bool) or size < 0:
        raise error(f"{what}: the server gives {name} no valid size ({_shown(size)}); nothing was written", element=name,
                    fix=SERVER_FIX)  # fmt: skip
    return RemoteFile(name, size, check_content_id(cid, name, error, what))


def _cached(storage: Path, commit: str, f: RemoteFile) -> bool:
    """Whether the snapshot of ``commit`` holds ``f`` (a link to its blob, of its size)."""
    pointer = storage / "snapshots" / commit / f.path
    blob = storage / "blobs" / f.content_id
    try:
        return os.path.samefile(pointer, blob) and blob.stat().st_size == f.size
    except OSError:
        return False


def _head(endpoint: str, repo_id: str, repo_type: str, commit: str, f: RemoteFile, token: str | bool | None, *,
          error: type[MerError], what: str) -> str:  # fmt: skip
    """The download address of ``f`` at ``commit``, after its headers (ETag, size, commit) are checked
    against the listing."""
    from huggingface_hub import get_hf_file_metadata

    prefix = "" if repo_type == "model" else f"{repo_type}s/"
    url = f"{endpoint}/{prefix}{repo_id}/resolve/{commit}/{quote(f.path)}"
    meta = get_hf_file_metadata(url, token=token, library_name="mer", endpoint=endpoint)
    etag = check_content_id(meta.etag, f.path, error, what)
    if etag != f.content_id or meta.size != f.size:
        raise error(f"{what}: the server's headers for {f.path} (ETag {etag[:12]}, {meta.size} bytes) contradict its "
                    f"listing ({f.content_id[:12]}, {f.size} bytes); nothing was written", element=f.path,
                    fix=SERVER_FIX)  # fmt: skip
    if check_commit(meta.commit_hash, error, what) != commit:
        raise error(f"{what}: the server served {f.path} from commit {meta.commit_hash[:12]}, not {commit[:12]}; nothing "
                    "was written", element=f.path, fix=SERVER_FIX)  # fmt: skip
    return meta.location


def _fetch(location: str, endpoint: str, commit: str, revision: str, f: RemoteFile, storage: Path,
           token: str | bool | None, *, error: type[MerError], what: str) -> Path:  # fmt: skip
    """Download ``f`` from ``location`` (hashed and capped) and install it."""
    from huggingface_hub.utils import build_hf_headers

    same_origin = location.startswith(endpoint.rstrip("/") + "/")
    headers = build_hf_headers(token=token if same_origin else False, library_name="mer")
    headers["Accept-Encoding"] = "identity"  # bytes as stored: no decompression bomb on the way
    tmp = download_blob(location, storage / "blobs", f.content_id, f.size, headers, error=error, what=what,
                        filename=f.path)  # fmt: skip
    with disk_full_as_error(storage / "snapshots" / commit / f.path):
        return install_blob(storage, tmp, f.content_id, commit, f.path, revision)


def _offline_snapshot(storage: Path, revision: str, *, error: type[MerError], what: str, offline_fix: str) -> Path:
    commit = revision
    if not _COMMIT.match(revision):
        try:
            commit = (storage / "refs" / revision).read_text()[:41].strip()
        except OSError:
            commit = ""
    folder = storage / "snapshots" / commit
    if not _COMMIT.match(commit) or not folder.is_dir() or folder.is_symlink():
        raise error(f"{what} is not in the local cache and cannot be downloaded (HF_HUB_OFFLINE is set)", fix=offline_fix)
    return folder


def checked_snapshot(
    repo_id: str,
    revision: str | None,
    *,
    repo_type: str,
    patterns: Sequence[str],
    size_limit: Callable[[str], str],
    error: type[MerError],
    cache: Path | None = None,
    endpoint: str | None = None,
    token: str | bool | None = None,
    offline: bool | None = None,
    offline_fix: str = "connect to the network (and unset HF_HUB_OFFLINE) once to download it",
) -> Path:
    """The snapshot folder of ``repo_id`` at ``revision`` holding the files that match ``patterns``.

    Online, the commit, the listing, each file's name, size (``size_limit(name)``: the name of its
    limit; all files together ``MER_MAX_HUB_DOWNLOAD_BYTES``) and content id are checked before
    anything is downloaded; files missing from the cache are fetched by :func:`_fetch`. Offline, the
    cached snapshot is used (no network call). Refusals and Hub errors are ``error``; a full disk is a
    ``DiskFullError``.
    """
    import httpx2
    from huggingface_hub import constants
    from huggingface_hub.errors import HfHubHTTPError, RepositoryNotFoundError, RevisionNotFoundError
    from huggingface_hub.utils import build_hf_headers

    what = f"the {repo_type} {check_repo_id(repo_id, error)!r}"
    rev = check_ref(revision or "main", error, what)
    cache = Path(cache if cache is not None else constants.HF_HUB_CACHE).expanduser()
    storage = storage_folder(cache, repo_id, repo_type)
    if hub_offline() if offline is None else offline:
        return _offline_snapshot(storage, rev, error=error, what=what, offline_fix=offline_fix)
    endpoint = (endpoint or constants.ENDPOINT).rstrip("/")
    headers = build_hf_headers(token=token, library_name="mer")
    try:
        info, _ = _get_json(f"{endpoint}/api/{repo_type}s/{repo_id}/revision/{quote(rev, safe='')}", headers, error=error,
                            what=what)  # fmt: skip
        commit = check_commit(info.get("sha") if isinstance(info, dict) else None, error, what)
        files: dict[str, RemoteFile] = {}
        for entry in _listing(endpoint, repo_id, repo_type, commit, headers, error=error, what=what):
            if entry.get("type") != "file" or not any(fnmatch.fnmatch(str(entry.get("path")), p) for p in patterns):
                continue
            f = _remote_file(entry, error, what)
            if f.path in files:
                raise error(f"{what}: the server lists {f.path} twice", fix=SERVER_FIX)
            name = size_limit(f.path)
            if f.size > limit(name):
                msg, fix = too_big(name, f.size)
                raise error(f"{what}: {f.path} is announced with {f.size:,} bytes: {msg}; nothing was downloaded",
                            element=f.path, fix=fix)  # fmt: skip
            files[f.path] = f
        todo = [f for f in files.values() if not _cached(storage, commit, f)]
        total = sum(f.size for f in todo)
        if total > limit("MER_MAX_HUB_DOWNLOAD_BYTES"):
            msg, fix = too_big("MER_MAX_HUB_DOWNLOAD_BYTES", total)
            raise error(f"{what}: the files to download {msg}; nothing was downloaded", fix=fix)
        with disk_full_as_error(storage, total):
            real_folder(storage / "blobs", cache)
        free = free_bytes(storage / "blobs" / "x")
        if free is not None and total > free:
            raise disk_full(storage / "blobs" / "x", total)
        where = [_head(endpoint, repo_id, repo_type, commit, f, token, error=error, what=what) for f in todo]
        for f, location in zip(todo, where):  # every file's headers checked before the first byte is fetched
            _fetch(location, endpoint, commit, rev, f, storage, token, error=error, what=what)
        if not files:
            real_folder(storage / "snapshots" / commit, storage)
        elif rev != commit:
            atomic_write(storage / "refs" / rev, commit, below=storage)
    except RevisionNotFoundError:
        raise error(f"{what} has no revision {rev!r}", fix="check the @REVISION part") from None
    except RepositoryNotFoundError:
        raise error(f"no {repo_type} {repo_id!r} on the Hub (or it is private and no token was given)",
                    fix="check the id, or log in with `hf auth login` (HF_TOKEN)") from None  # fmt: skip
    except HfHubHTTPError as exc:
        code = exc.response.status_code if exc.response is not None else "?"
        raise error(
            f"downloading {what} failed: the Hub answered HTTP {code}", fix="retry; check HF_ENDPOINT and HF_TOKEN"
        ) from None
    except (httpx2.TransportError, httpx2.InvalidURL) as exc:
        raise error(f"{what} is not in the local cache and cannot be downloaded ({type(exc).__name__}: {exc})",
                    fix=offline_fix) from None  # fmt: skip
    log.info("%s: %d file(s) at %s, %d downloaded", what, len(files), commit, len(todo))
    return storage / "snapshots" / commit
