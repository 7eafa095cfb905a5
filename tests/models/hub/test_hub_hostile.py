"""Hub downloads from a server that lies (issue 41): ETags, commit ids and sizes are checked before
they become paths or bytes on disk; every refusal is a ``ModelZooError`` and nothing is written
outside the Hub cache (nor any unverified file inside it).

The server is a loopback HTTP server speaking just the ``resolve`` endpoint the real
huggingface_hub client uses for a file's metadata (``HEAD``) and content (``GET``).
"""

from __future__ import annotations

import hashlib
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from mer_data.base.errors import ModelZooError
from mer_models.hub import client as hub
from mer_models.hub.resolve import resolve

COMMIT = "a" * 40


class LyingHub:
    """Answers every ``/{org}/{name}/resolve/{rev}/{file}`` with ``body`` and the headers it is told."""

    def __init__(self, body: bytes, *, etag: str | None = None, commit: str = COMMIT, size: int | None = None) -> None:
        self.body, self.commit = body, commit
        self.etag = etag if etag is not None else hashlib.sha1(b"blob %d\0" % len(body) + body).hexdigest()
        self.size = len(body) if size is None else size
        self.gets = 0
        owner = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args) -> None:
                pass

            def _reply(self, head: bool) -> None:
                self.send_response(200)
                self.send_header("ETag", f'"{owner.etag}"')
                self.send_header("X-Repo-Commit", owner.commit)
                self.send_header("Content-Length", str(owner.size if head else len(owner.body)))
                self.end_headers()
                if not head:
                    owner.gets += 1
                    self.wfile.write(owner.body)

            def do_HEAD(self) -> None:
                self._reply(True)

            def do_GET(self) -> None:
                self._reply(False)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()

    def __enter__(self) -> "LyingHub":
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    from huggingface_hub import constants

    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    c = tmp_path / "deep" / "er" / "cache"
    c.mkdir(parents=True)
    return c


def _fetch(server: LyingHub, cache: Path, monkeypatch, filename: str = "model.safetensors") -> Path:
    monkeypatch.setattr(hub, "endpoint", lambda: server.url)  # mer's own accessor of HF_ENDPOINT
    with hub.settings(cache_dir=cache):
        return hub.fetch_file("org/model", filename, "main", what="org/model")


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file() or p.is_symlink()}


def test_etag_and_commit_that_are_paths_write_nothing(tmp_path, cache, monkeypatch):
    before = _files(tmp_path)
    for kw in ({"etag": "../../../../escaped"}, {"commit": "../../../../../escaped2"}, {"etag": "ABC" * 20}):
        with LyingHub(b"weights" * 100, **kw) as server:
            with pytest.raises(ModelZooError) as ei:
                _fetch(server, cache, monkeypatch)
        assert "nothing was written" in str(ei.value)
        assert server.gets == 0
    assert not [p for p in _files(tmp_path) - before if "escaped" in str(p) or p.parent.name == "blobs"]


def test_config_size_is_capped_at_download_and_sizes_must_not_lie(tmp_path, cache, monkeypatch):
    monkeypatch.setenv("MER_MAX_CONFIG_BYTES", "1000")
    with LyingHub(b"{}" + b" " * 5000) as server:
        with pytest.raises(ModelZooError, match="MER_MAX_CONFIG_BYTES"):
            _fetch(server, cache, monkeypatch, "config.json")
        assert server.gets == 0  # refused from the announced size: nothing downloaded
    body = b"{}" + b" " * 200_000
    with LyingHub(body, size=100, etag=hashlib.sha1(b"blob 100\0" + body[:100]).hexdigest()) as server:
        with pytest.raises(ModelZooError, match="more than the 100 bytes"):
            _fetch(server, cache, monkeypatch, "config.json")
    assert not [p for p in _files(cache) if p.parent.name in ("blobs", "snapshots") or "snapshots" in p.parts]


def test_a_hash_mismatch_keeps_nothing_and_a_good_file_is_cached(tmp_path, cache, monkeypatch):
    with LyingHub(b"tampered", etag=hashlib.sha256(b"original").hexdigest()) as server:
        with pytest.raises(ModelZooError, match="hashes to"):
            _fetch(server, cache, monkeypatch)
    assert not [p for p in _files(cache) if "blobs" in p.parts or "snapshots" in p.parts]
    with LyingHub(b"good bytes") as server:
        path = _fetch(server, cache, monkeypatch)
    assert path.read_bytes() == b"good bytes" and path.parent.name == COMMIT
    with hub.settings(cache_dir=cache):
        assert hub.cached_file("org/model", "model.safetensors", "main") == path


def test_an_empty_model_name_is_refused():
    for spec in ("", "  "):
        with pytest.raises(ModelZooError, match="empty"):
            resolve(spec)
