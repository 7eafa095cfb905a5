"""A loopback Hugging Face Hub: enough of the Hub's HTTP protocol that the *real* huggingface_hub
client (2.x) downloads, caches and uploads against it through ``HF_ENDPOINT``.

What it speaks (model and dataset repositories; a dataset's paths carry the Hub's ``datasets/``
prefix: ``/datasets/{org}/{name}/resolve/...``, ``/api/datasets/...``, ``/datasets/{org}/{name}.git/...``),
as huggingface_hub 2.4 calls it:

* ``HEAD``/``GET /{org}/{name}/resolve/{revision}/{path}``: ``X-Repo-Commit``, ``ETag`` (git blob
  sha1), ``Content-Length``, ``Accept-Ranges``; ``Range: bytes=N-`` gives 206. An LFS file answers
  ``302`` to the "CDN" (a second loopback port, i.e. another origin, as on the real Hub) with
  ``X-Linked-Etag`` (its sha256) and ``X-Linked-Size``. Errors carry the Hub's ``X-Error-Code``
  (``RepoNotFound``, ``RevisionNotFound``, ``EntryNotFound``) and ``X-Error-Message``.
* ``GET /api/models/{repo}[/revision/{rev}]`` (model info with siblings), ``.../tree/{rev}[/{path}]``,
  ``.../refs``; ``GET /api/agent-harnesses`` (the client asks for it once; an empty registry).
* Uploads: ``POST /api/repos/create``, ``POST /api/validate-yaml`` (the Hub's metadata checks for the
  keys mer writes, see :func:`validate_metadata`), ``POST .../preupload/{rev}``,
  the git-LFS batch API ``POST /{repo}.git/info/lfs/objects/batch`` with basic ``PUT`` transfer and
  ``verify``, and ``POST .../commit/{rev}`` (ndjson: header, file, lfsFile, deletedFile,
  deletedFolder; ``parentCommit`` checked). Xet storage is not spoken: clients must run with
  ``HF_HUB_DISABLE_XET=1`` to upload (the client then takes the plain LFS path); downloads never
  offer Xet (no ``X-Xet-Hash`` header), so they take the plain HTTP path anyway.

Every commit gets a 40-hex id (sha1 over its tree, parent, message and a counter), so pinned
revisions behave as on the Hub. Writes need ``Authorization: Bearer <token>`` when ``token`` is set.

``FakeHub`` (below) is a smaller stand-in for one *dataset* repository (info, tree, file
downloads), used by the shard tooling's tests.

Bounded: binds 127.0.0.1 on ephemeral ports, counts every request (``requests``), answers 503
after ``max_requests``, refuses bodies over ``max_body`` bytes, and stops itself after
``lifetime_s`` seconds. Test hooks: :meth:`tamper` (serve other bytes under the same metadata, as a
compromised mirror would), :meth:`lie` (a server that lies in its metadata: commit ids, ETags,
listed sizes, extra listed files), :meth:`put` (commit files directly) and :meth:`stop`.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import threading
import time
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, unquote, urlparse, urlsplit

import yaml

__all__ = ["HubServer", "FakeHub", "validate_metadata"]

GITATTRIBUTES = b"*.safetensors filter=lfs diff=lfs merge=lfs -text\n*.bin filter=lfs diff=lfs merge=lfs -text\n"
LFS_SUFFIXES = (".safetensors", ".bin", ".pt", ".pth", ".ckpt", ".h5", ".npz", ".onnx", ".msgpack")
LFS_MIN_SIZE = 10 * 1024 * 1024


def git_oid(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def lfs_pointer(sha256: str, size: int) -> bytes:
    return f"version https://git-lfs.github.com/spec/v1\noid sha256:{sha256}\nsize {size}\n".encode()


@dataclass
class Blob:
    data: bytes
    lfs: bool
    sha256: str = ""
    oid: str = ""  # git object id: of the data (regular) or of the LFS pointer (LFS), as git stores it

    def __post_init__(self) -> None:
        self.sha256 = hashlib.sha256(self.data).hexdigest()
        self.oid = git_oid(lfs_pointer(self.sha256, len(self.data)) if self.lfs else self.data)

    @property
    def etag(self) -> str:
        return self.sha256 if self.lfs else git_oid(self.data)


@dataclass
class Commit:
    oid: str
    parent: str | None
    message: str
    files: dict[str, Blob]
    date: str


@dataclass
class Repo:
    repo_id: str
    private: bool
    commits: dict[str, Commit] = field(default_factory=dict)
    branches: dict[str, str] = field(default_factory=dict)

    def resolve(self, rev: str) -> Commit | None:
        oid = self.branches.get(rev) or (rev if re.fullmatch(r"[0-9a-f]{40}", rev) else None)
        return self.commits.get(oid) if oid else None


#: A subset of the Hub's licence identifiers (https://huggingface.co/docs/hub/repositories-licenses).
HUB_LICENSES = {"apache-2.0", "mit", "bsd-3-clause", "cc-by-4.0", "cc-by-sa-4.0", "cc-by-nc-4.0", "cc-by-nc-sa-4.0",
                "cc-by-nc-nd-4.0", "cc-by-nd-4.0", "cc0-1.0", "openrail", "other", "unknown"}
#: A subset of the Hub's task ids (pipeline tags / dataset task categories); "robotics" is LeRobot's.
HUB_TASKS = {"robotics", "reinforcement-learning", "time-series-forecasting", "image-classification", "text-generation",
             "video-classification", "tabular-regression", "other"}
_HUB_REPO_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*/[A-Za-z0-9][A-Za-z0-9._-]*$")


def validate_metadata(meta: dict, repo_type: str) -> list[str]:
    """The Hub's card metadata checks for the keys mer writes; a list of error messages (empty: accepted).

    Types as the Hub's schema has them: ``license`` a known id (or a list of them), ``tags`` a list
    of strings, ``library_name`` a string; models: ``pipeline_tag`` a known task, ``base_model`` and
    ``datasets`` repo ids; datasets: ``task_categories`` known tasks, ``configs`` a list of
    ``{config_name, data_files}``."""
    errors = []

    def strings(key):
        v = meta.get(key)
        if v is not None and not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
            errors.append(f'"{key}" must be an array of strings')
            return []
        return v or []

    lic = meta.get("license")
    for x in ([lic] if isinstance(lic, str) else lic if isinstance(lic, list) else [] if lic is None else [None]):
        if x not in HUB_LICENSES:
            errors.append(f'"license" must be one of the Hub\'s licence ids, not {x!r}')
    strings("tags")
    if meta.get("library_name") is not None and not isinstance(meta["library_name"], str):
        errors.append('"library_name" must be a string')
    if repo_type == "model":
        if meta.get("pipeline_tag") is not None and meta["pipeline_tag"] not in HUB_TASKS:
            errors.append(f'"pipeline_tag" must be a known task, not {meta["pipeline_tag"]!r}')
        base = meta.get("base_model")
        for x in ([base] if isinstance(base, str) else base if isinstance(base, list) else [] if base is None else [None]):
            if not (isinstance(x, str) and _HUB_REPO_ID.match(x)):
                errors.append(f'"base_model" must be a model repo id (OWNER/NAME), not {x!r}')
        for x in strings("datasets"):
            if not _HUB_REPO_ID.match(x) and "/" in x:
                errors.append(f'"datasets" must hold dataset ids, not {x!r}')
    elif repo_type == "dataset":
        for x in strings("task_categories"):
            if x not in HUB_TASKS:
                errors.append(f'"task_categories" must hold known tasks, not {x!r}')
        configs = meta.get("configs")
        if configs is not None:
            if not isinstance(configs, list) or not all(isinstance(c, dict) and isinstance(c.get("config_name"), str)
                                                         and "data_files" in c for c in configs):
                errors.append('"configs" must be a list of {config_name, data_files}')
    return errors


class _Reply(Exception):
    def __init__(self, status: int, body: bytes | dict | list = b"", headers: dict | None = None, error: str | None = None):
        self.status, self.body, self.headers = status, body, dict(headers or {})
        if error:
            self.headers.setdefault("X-Error-Code", error)
        if isinstance(body, dict) and "error" in body:
            self.headers.setdefault("X-Error-Message", str(body["error"]))


class HubServer:
    """The loopback Hub (see module docstring). Use as a context manager or call :meth:`stop`."""

    def __init__(self, *, token: str | None = None, max_requests: int = 5000, max_body: int = 256 << 20,
                 lifetime_s: float = 300.0) -> None:
        self.token, self.max_requests, self.max_body = token, max_requests, max_body
        self.repos: dict[str, Repo] = {}  # model repositories
        self.dataset_repos: dict[str, Repo] = {}
        self.lfs_store: dict[str, bytes] = {}
        self._tampered: dict[tuple[str, str], bytes] = {}
        self.lies: dict = {}
        self._log: list[tuple[str, str]] = []
        self._lock = threading.RLock()
        self._counter = 0
        self._hub = ThreadingHTTPServer(("127.0.0.1", 0), self._handler(cdn=False))
        self._cdn = ThreadingHTTPServer(("127.0.0.1", 0), self._handler(cdn=True))
        self.url = f"http://127.0.0.1:{self._hub.server_address[1]}"
        self.cdn_url = f"http://127.0.0.1:{self._cdn.server_address[1]}"
        self._threads = [threading.Thread(target=s.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
                         for s in (self._hub, self._cdn)]
        for t in self._threads:
            t.start()
        self._timer = threading.Timer(lifetime_s, self.stop)
        self._timer.daemon = True
        self._timer.start()
        self._stopped = False

    # -- lifecycle and inspection -------------------------------------------------------------
    def stop(self) -> None:
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        self._timer.cancel()
        for s in (self._hub, self._cdn):
            s.shutdown()
            s.server_close()

    def __enter__(self) -> "HubServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def requests(self) -> list[tuple[str, str]]:
        """Every request seen so far, as (method, path)."""
        with self._lock:
            return list(self._log)

    def head(self, repo_id: str, branch: str = "main") -> str:
        return self.repos[repo_id].branches[branch]

    def tamper(self, repo_id: str, path: str, data: bytes) -> None:
        """Serve ``data`` for ``path`` at every revision, with the original headers (a compromised mirror)."""
        self._tampered[(repo_id, path)] = data

    def lie(self, *, sha: str | None = None, commit: str | None = None, etag: dict[str, str] | None = None,
            size: dict[str, int] | None = None, extra: list[dict] | None = None) -> None:
        """Lie from now on: ``sha`` in repository info, ``commit`` in ``X-Repo-Commit``, ``etag`` (path -> value)
        in ``ETag``/``X-Linked-Etag``, ``size`` (path -> bytes) in listings, ``extra`` entries appended to
        every tree listing (e.g. ``{"type": "file", "path": "../../x.h5", "size": 1, "oid": "0" * 40}``)."""
        for key, value in (("sha", sha), ("commit", commit), ("etag", etag), ("size", size), ("extra", extra)):
            if value is not None:
                self.lies[key] = value

    def put(self, repo_id: str, files: dict[str, bytes], *, kind: str = "dataset", lfs: bool | None = None) -> str:
        """Commit ``files`` (path -> bytes) on ``main`` of ``repo_id`` (created if missing); returns the commit id.
        LFS: as the Hub decides (suffix or size) unless ``lfs`` says."""
        with self._lock:
            repo = self._kind(kind).get(repo_id) or self.create_repo(repo_id, kind=kind)
            head = repo.branches["main"]
            new = dict(repo.commits[head].files)
            for path, data in files.items():
                big = path.endswith(LFS_SUFFIXES) or len(data) >= LFS_MIN_SIZE
                blob = Blob(data, big if lfs is None else lfs)
                if blob.lfs:
                    self.lfs_store[blob.sha256] = data
                new[path] = blob
            return self._commit(repo, head, "put", new)

    # -- repository model --------------------------------------------------------------------
    def _kind(self, kind: str) -> dict[str, Repo]:
        return self.dataset_repos if kind == "dataset" else self.repos

    def create_repo(self, repo_id: str, private: bool = False, kind: str = "model") -> Repo:
        with self._lock:
            repo = Repo(repo_id, private)
            self._kind(kind)[repo_id] = repo
            self._commit(repo, None, "initial commit", {".gitattributes": Blob(GITATTRIBUTES, False)})
            return repo

    def _commit(self, repo: Repo, parent: str | None, message: str, files: dict[str, Blob], branch: str = "main") -> str:
        self._counter += 1
        tree = hashlib.sha1("".join(f"{p}\0{b.oid}\n" for p, b in sorted(files.items())).encode()).hexdigest()
        oid = hashlib.sha1(f"tree {tree}\nparent {parent}\ncounter {self._counter}\n\n{message}".encode()).hexdigest()
        repo.commits[oid] = Commit(oid, parent, message, dict(files), time.strftime("%Y-%m-%dT%H:%M:%S.000Z", time.gmtime()))
        repo.branches[branch] = oid
        return oid

    def _served(self, repo_id: str, path: str, blob: Blob) -> bytes:
        return self._tampered.get((repo_id, path), blob.data)

    # -- HTTP -------------------------------------------------------------------------------
    def _handler(self, cdn: bool):
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args) -> None:  # quiet
                pass

            def _body(self) -> bytes:
                if self.headers.get("Transfer-Encoding", "").lower() == "chunked":
                    out = bytearray()
                    while True:
                        size = int(self.rfile.readline().split(b";")[0].strip() or b"0", 16)
                        if size == 0:
                            self.rfile.readline()
                            return bytes(out)
                        if len(out) + size > server.max_body:
                            raise _Reply(413, {"error": "body too large"})
                        out += self.rfile.read(size)
                        self.rfile.readline()
                n = int(self.headers.get("Content-Length") or 0)
                if n > server.max_body:
                    raise _Reply(413, {"error": "body too large"})
                return self.rfile.read(n) if n else b""

            def _send(self, status: int, body: bytes | dict | list = b"", headers: dict | None = None) -> None:
                data = json.dumps(body).encode() if isinstance(body, (dict, list)) else body
                self.send_response(status)
                hdrs = {"Content-Type": "application/json" if isinstance(body, (dict, list)) else "application/octet-stream",
                        **(headers or {})}
                hdrs.setdefault("Content-Length", str(len(data)))
                for k, v in hdrs.items():
                    self.send_header(k, v)
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(data)

            def _dispatch(self) -> None:
                with server._lock:
                    server._log.append((self.command, self.path))
                    too_many = len(server._log) > server.max_requests
                try:
                    if too_many:
                        raise _Reply(503, {"error": "request budget of the test server exhausted"})
                    body = self._body() if self.command in ("POST", "PUT") else b""
                    status, payload, headers = (server._cdn_route if cdn else server._route)(self, body)
                except _Reply as r:
                    status, payload, headers = r.status, r.body, r.headers
                except Exception as exc:  # a bug in the test server: say so, do not hang the client
                    status, payload, headers = 500, {"error": f"test hub: {type(exc).__name__}: {exc}"}, {}
                self._send(status, payload, headers)

            do_GET = do_HEAD = do_POST = do_PUT = _dispatch

        return Handler

    def _auth(self, h) -> None:
        if self.token and h.headers.get("Authorization") != f"Bearer {self.token}":
            raise _Reply(401, {"error": "Invalid credentials in Authorization header"})

    def _repo(self, repo_id: str, h, kind: str = "model") -> Repo:
        repo = self._kind(kind).get(repo_id)
        if repo is None or (repo.private and h.headers.get("Authorization") != f"Bearer {self.token}"):
            raise _Reply(404, {"error": "Repository not found"}, error="RepoNotFound")
        return repo

    def _at(self, repo: Repo, rev: str) -> Commit:
        commit = repo.resolve(rev)
        if commit is None:
            raise _Reply(404, {"error": f"Invalid rev id: {rev}"}, error="RevisionNotFound")
        return commit

    def _cdn_route(self, h, body: bytes):
        m = re.fullmatch(r"/lfs/([0-9a-f]{64})/(\S+)", urlsplit(h.path).path)
        if h.command not in ("GET", "HEAD") or not m or m.group(1) not in self.lfs_store:
            raise _Reply(404, {"error": "not found"})
        repo_id, _, path = unquote(m.group(2)).partition("::")
        data = self._tampered.get((repo_id, path), self.lfs_store[m.group(1)])
        return self._ranged(h, data, {"ETag": f'"{m.group(1)}"'})

    def _ranged(self, h, data: bytes, headers: dict):
        headers = {**headers, "Accept-Ranges": "bytes"}
        rng = re.fullmatch(r"bytes=(\d+)-", h.headers.get("Range", ""))
        if rng and int(rng.group(1)) < len(data):
            start = int(rng.group(1))
            headers["Content-Range"] = f"bytes {start}-{len(data) - 1}/{len(data)}"
            return 206, data[start:], headers
        return 200, data, headers

    def _route(self, h, body: bytes):
        url = urlsplit(h.path)
        parts = url.path.split("/")[1:]
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        kind = "model"
        if parts and parts[0] == "datasets":  # /datasets/{org}/{name}/resolve/..., /datasets/{org}/{name}.git/...
            kind, parts = "dataset", parts[1:]
        elif parts[:2] == ["api", "datasets"]:
            kind, parts = "dataset", ["api", "models", *parts[2:]]
        if url.path == "/api/agent-harnesses":
            return 200, {"standardEnvVars": [], "harnesses": {}}, {}
        if url.path == "/api/repos/create" and h.command == "POST":
            return self._create(h, json.loads(body or b"{}"))
        if url.path == "/api/validate-yaml" and h.command == "POST":
            return self._validate_yaml(json.loads(body or b"{}"))
        if url.path == "/lfs-verify" and h.command == "POST":
            req = json.loads(body)
            return (200, {}, {}) if req.get("oid") in self.lfs_store else (404, {"error": "object not uploaded"}, {})
        if len(parts) == 2 and parts[0] == "lfs-upload" and h.command == "PUT":
            return self._lfs_put(h, parts[1], body)
        if len(parts) >= 5 and parts[2] == "resolve" and h.command in ("GET", "HEAD"):
            return self._resolve(h, f"{parts[0]}/{parts[1]}", unquote(parts[3]), unquote("/".join(parts[4:])), kind)
        if len(parts) == 6 and parts[1].endswith(".git") and parts[2:] == ["info", "lfs", "objects", "batch"]:
            return self._lfs_batch(h, f"{parts[0]}/{parts[1][:-4]}", json.loads(body), kind)
        if len(parts) >= 4 and parts[:2] == ["api", "models"]:
            repo = self._repo(f"{parts[2]}/{parts[3]}", h, kind)
            rest = parts[4:]
            if h.command == "GET" and (not rest or rest[0] == "revision"):
                return self._info(repo, self._at(repo, unquote(rest[1]) if rest else "main"))
            if h.command == "GET" and rest and rest[0] == "tree":
                return self._tree(repo, self._at(repo, unquote(rest[1])), unquote("/".join(rest[2:])), query.get("recursive") in ("True", "true", "1"))
            if h.command == "GET" and rest == ["refs"]:
                return 200, {"branches": [{"name": b, "ref": f"refs/heads/{b}", "targetCommit": o} for b, o in repo.branches.items()],
                             "converts": [], "tags": []}, {}
            if h.command == "POST" and len(rest) == 2 and rest[0] == "preupload":
                self._auth(h)
                return self._preupload(repo, unquote(rest[1]), json.loads(body))
            if h.command == "POST" and len(rest) == 2 and rest[0] == "commit":
                self._auth(h)
                return self._commit_api(repo, unquote(rest[1]), body)
        raise _Reply(404, {"error": f"test hub: no route for {h.command} {url.path}"})

    # -- endpoints ------------------------------------------------------------------------------
    def _resolve(self, h, repo_id: str, rev: str, path: str, kind: str = "model"):
        repo = self._repo(repo_id, h, kind)
        commit = self._at(repo, rev)
        blob = commit.files.get(path)
        base = {"X-Repo-Commit": self.lies.get("commit", commit.oid)}
        if blob is None:
            raise _Reply(404, {"error": "Entry not found"}, base, error="EntryNotFound")
        etag = self.lies.get("etag", {}).get(path, blob.etag)
        if blob.lfs:
            loc = f"{self.cdn_url}/lfs/{blob.sha256}/{repo_id}::{path}"
            return 302, b"", {**base, "Location": loc, "ETag": f'"{blob.oid}"', "X-Linked-Etag": f'"{etag}"',
                              "X-Linked-Size": str(len(blob.data))}
        return self._ranged(h, self._served(repo_id, path, blob), {**base, "ETag": f'"{etag}"'})

    def _info(self, repo: Repo, commit: Commit):
        siblings = [{"rfilename": p, "size": len(b.data), "blobId": b.oid,
                     **({"lfs": {"sha256": b.sha256, "size": len(b.data), "pointerSize": len(lfs_pointer(b.sha256, len(b.data)))}} if b.lfs else {})}
                    for p, b in sorted(commit.files.items())]
        return 200, {"_id": repo.repo_id, "id": repo.repo_id, "modelId": repo.repo_id, "sha": self.lies.get("sha", commit.oid),
                     "private": repo.private,
                     "disabled": False, "gated": False, "lastModified": commit.date, "tags": [], "siblings": siblings}, {}

    def _tree(self, repo: Repo, commit: Commit, prefix: str, recursive: bool):
        out, dirs = [], set()
        for p, b in sorted(commit.files.items()):
            if prefix and not p.startswith(prefix.rstrip("/") + "/"):
                continue
            rel = p[len(prefix.rstrip("/")) + 1:] if prefix else p
            if "/" in rel and not recursive:
                dirs.add((prefix.rstrip("/") + "/" if prefix else "") + rel.split("/")[0])
                continue
            size = self.lies.get("size", {}).get(p, len(b.data))
            entry = {"type": "file", "oid": b.oid, "size": size, "path": p}
            if b.lfs:
                entry["lfs"] = {"oid": b.sha256, "size": size, "pointerSize": len(lfs_pointer(b.sha256, len(b.data)))}
            out.append(entry)
        out += [{"type": "directory", "oid": hashlib.sha1(d.encode()).hexdigest(), "size": 0, "path": d} for d in sorted(dirs)]
        return 200, out + list(self.lies.get("extra", [])), {}

    def _create(self, h, req: dict):
        self._auth(h)
        kind = req.get("type") or "model"
        if kind not in ("model", "dataset"):
            raise _Reply(400, {"error": "test hub: model and dataset repositories only"})
        repo_id = f"{req.get('organization')}/{req['name']}" if req.get("organization") else f"user/{req['name']}"
        url = f"{self.url}/{'datasets/' if kind == 'dataset' else ''}{repo_id}"
        if repo_id in self._kind(kind):
            raise _Reply(409, {"error": f"You already created this {kind} repo", "url": url})
        self.create_repo(repo_id, private=req.get("visibility") == "private" or bool(req.get("private")), kind=kind)
        return 200, {"url": url, "name": repo_id, "id": repo_id}, {}

    def _validate_yaml(self, req: dict):
        text = req.get("content", "")
        if text.startswith("---\n"):
            try:
                meta = yaml.safe_load(text[4:text.index("\n---\n", 4)])
            except (yaml.YAMLError, ValueError) as exc:
                raise _Reply(400, {"errors": [{"message": f"invalid YAML: {exc}"}], "warnings": []})
            if meta is not None and not isinstance(meta, dict):
                raise _Reply(400, {"errors": [{"message": "metadata must be a mapping"}], "warnings": []})
            errors = validate_metadata(meta or {}, req.get("repoType") or "model")
            if errors:
                raise _Reply(400, {"errors": [{"message": e} for e in errors], "warnings": []})
        return 200, {"errors": [], "warnings": []}, {}

    def _preupload(self, repo: Repo, rev: str, req: dict):
        commit = self._at(repo, rev)
        files = []
        for f in req.get("files", []):
            sample = base64.b64decode(f.get("sample", ""))
            lfs = f["path"].endswith(LFS_SUFFIXES) or f.get("size", 0) >= LFS_MIN_SIZE or b"\0" in sample
            old = commit.files.get(f["path"])
            oid = (old.sha256 if old.lfs else git_oid(old.data)) if old is not None else None
            files.append({"path": f["path"], "uploadMode": "lfs" if lfs else "regular", "shouldIgnore": False, "oid": oid})
        return 200, {"files": files, "commitOid": commit.oid}, {}

    def _lfs_batch(self, h, repo_id: str, req: dict, kind: str = "model"):
        self._auth(h)
        self._repo(repo_id, h, kind)
        objects = []
        for o in req.get("objects", []):
            entry = {"oid": o["oid"], "size": o["size"], "authenticated": True}
            if o["oid"] not in self.lfs_store:
                entry["actions"] = {"upload": {"href": f"{self.url}/lfs-upload/{o['oid']}", "header": {}},
                                    "verify": {"href": f"{self.url}/lfs-verify", "header": {}}}
            objects.append(entry)
        return 200, {"transfer": "basic", "objects": objects}, {"Content-Type": "application/vnd.git-lfs+json"}

    def _lfs_put(self, h, oid: str, body: bytes):
        if hashlib.sha256(body).hexdigest() != oid:
            raise _Reply(400, {"error": "sha256 of the uploaded content does not match the object id"})
        with self._lock:
            self.lfs_store[oid] = body
        return 200, b"", {}

    def _commit_api(self, repo: Repo, branch: str, body: bytes):
        if branch not in repo.branches:
            raise _Reply(404, {"error": f"Invalid rev id: {branch}"}, error="RevisionNotFound")
        lines = [json.loads(x) for x in body.decode().splitlines() if x.strip()]
        if not lines or lines[0].get("key") != "header":
            raise _Reply(400, {"error": "the first line of a commit must be its header"})
        header = lines[0]["value"]
        with self._lock:
            head = repo.branches[branch]
            parent = header.get("parentCommit")
            if parent and not head.startswith(parent):
                raise _Reply(412, {"error": "A commit has happened since. Please refresh and try again."})
            files = dict(repo.commits[head].files)
            for line in lines[1:]:
                key, v = line["key"], line["value"]
                if key == "file":
                    files[v["path"]] = Blob(base64.b64decode(v["content"]), False)
                elif key == "lfsFile":
                    data = self.lfs_store.get(v["oid"])
                    if data is None:
                        raise _Reply(422, {"error": f"LFS object {v['oid']} of {v['path']} was never uploaded"})
                    files[v["path"]] = Blob(data, True)
                elif key == "deletedFile":
                    if files.pop(v["path"], None) is None:
                        raise _Reply(404, {"error": f"{v['path']} does not exist"}, error="EntryNotFound")
                elif key == "deletedFolder":
                    files = {p: b for p, b in files.items() if not p.startswith(v["path"].rstrip("/") + "/")}
                else:
                    raise _Reply(400, {"error": f"unknown commit operation {key!r}"})
            oid = self._commit(repo, head, header.get("summary", ""), files, branch)
        return 200, {"commitUrl": f"{self.url}/{repo.repo_id}/commit/{oid}", "commitOid": oid, "success": True,
                     "commitMessage": header.get("summary", ""), "pullRequestUrl": None}, {}


# --- A minimal dataset-repository stand-in (shard tooling tests) -------------------------------


class FakeHub:
    def __init__(self, repo_id: str, files: dict[str, bytes], commit: str = "c0ffee" * 6 + "abcd") -> None:
        self.repo_id, self.files, self.commit = repo_id, files, commit
        self.requests: list[str] = []
        hub = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def _send(self, code: int, body: bytes = b"", headers: dict | None = None, head: bool = False):
                self.send_response(code)
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if not head:
                    self.wfile.write(body)

            def _json(self, obj, code=200):
                self._send(code, json.dumps(obj).encode(), {"Content-Type": "application/json"})

            def _route(self, head: bool):
                path = unquote(urlparse(self.path).path)
                hub.requests.append(f"{self.command} {path}")
                api = f"/api/datasets/{hub.repo_id}"
                resolve = f"/datasets/{hub.repo_id}/resolve/"
                if path.startswith(f"{api}/revision/"):
                    rev = path[len(f"{api}/revision/") :]
                    if rev not in ("main", hub.commit):
                        return self._send(404, b'{"error":"Revision Not Found"}', {"X-Error-Code": "RevisionNotFound"})
                    return self._json({"id": hub.repo_id, "sha": hub.commit, "private": False,
                                       "siblings": [{"rfilename": p} for p in sorted(hub.files)]})  # fmt: skip
                if path.startswith(f"{api}/tree/"):
                    entries, dirs = [], set()
                    for p, data in sorted(hub.files.items()):
                        parts = p.split("/")
                        for i in range(1, len(parts)):
                            dirs.add("/".join(parts[:i]))
                        entries.append({"type": "file", "path": p, "size": len(data), "oid": git_oid(data)})
                    entries += [{"type": "directory", "path": d, "oid": "0" * 40, "size": 0} for d in sorted(dirs)]
                    return self._json(entries)
                if path.startswith(resolve):
                    rev, _, name = path[len(resolve) :].partition("/")
                    if name not in hub.files or rev not in ("main", hub.commit):
                        return self._send(404, b'{"error":"Entry not found"}', {"X-Error-Code": "EntryNotFound"}, head)
                    data = hub.files[name]
                    etag = '"' + git_oid(data) + '"'
                    return self._send(200, data, {"ETag": etag, "X-Repo-Commit": hub.commit,
                                                  "Content-Type": "application/octet-stream"}, head)  # fmt: skip
                if path.startswith("/api/datasets/"):
                    return self._send(404, b'{"error":"Repository not found"}', {"X-Error-Code": "RepoNotFound"}, head)
                return self._send(404, b"not found", head=head)

            def do_GET(self):
                self._route(head=False)

            def do_HEAD(self):
                self._route(head=True)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> "FakeHub":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
