"""``ShardDataset("hf://datasets/...")`` and ``--input hf://...`` against a Hub that lies (issue 41).

The real huggingface_hub client code paths mer uses (metadata, streaming) against the loopback Hub
(``tests/hub_server.py``), told to lie about commit ids, ETags, file names and sizes, or to serve
an oversized ``mer_meta.json``. Each lie is a ``MerError`` naming what the server said; nothing is
written outside the Hub cache, and no unverified byte is kept inside it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from hub_server import HubServer

from mer_data.base.errors import MerError, ShardBuildError, ShardError

REPO_ID = "lab/shards"


@pytest.fixture(scope="module")
def shard_files(tmp_path_factory) -> dict[str, bytes]:
    """One small synthetic HDF5 shard folder: {name: bytes} of the shard, card and mer_meta.json."""
    from mer_data.shards import BuildConfig, build_shards

    out = tmp_path_factory.mktemp("hub_shards") / "out"
    cfg = BuildConfig(input="", robots=("g1",), targets=("g1",), synthetic=1, synthetic_seconds=2.5, augment=0, split="all")
    build_shards(cfg, out)
    return {p.name: p.read_bytes() for p in out.iterdir() if p.suffix in (".h5", ".json", ".md") and "report" not in p.name}


@pytest.fixture
def hub(tmp_path, monkeypatch, shard_files):
    """A loopback Hub holding the shards in ``lab/shards``; the client pointed at it, cache in tmp_path."""
    from huggingface_hub import constants

    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    with HubServer() as server:
        server.put(REPO_ID, shard_files)
        monkeypatch.setattr(constants, "ENDPOINT", server.url)
        monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "cache"))
        yield server


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file() or p.is_symlink()}


def _refused(tmp_path: Path, url: str, *words: str) -> MerError:
    """``ShardDataset(url)`` is a ShardError with every word; nothing new outside the cache, no blob kept."""
    from mer_data.shards import ShardDataset

    before = _files(tmp_path)
    with pytest.raises(ShardError) as ei:
        ShardDataset(url)
    for w in words:
        assert w in str(ei.value), str(ei.value)
    new = _files(tmp_path) - before
    assert not [p for p in new if "cache" not in p.relative_to(tmp_path).parts[:1]], new  # nothing outside the cache
    for p in new:  # no unverified byte kept: every blob hashes to its name
        if p.parent.name == "blobs":
            data = p.read_bytes()
            assert p.name in (hashlib.sha256(data).hexdigest(), hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()), p
    return ei.value


def test_a_truthful_hub_is_read_through_the_cache(hub, tmp_path):
    from mer_data.shards import ShardDataset

    ds = ShardDataset(f"hf://datasets/{REPO_ID}")
    assert len(ds) > 0 and ds.paths[0].parent.parent.parent == tmp_path / "cache" / "datasets--lab--shards"
    assert ds.paths[0].resolve().parent.name == "blobs"
    ShardDataset(f"hf://datasets/{REPO_ID}")  # again: cached, nothing downloaded twice
    assert sum(1 for m, p in hub.requests if m == "GET" and p.startswith("/lfs/")) == 1  # the shard (LFS), once


def test_a_commit_id_that_is_a_path_is_refused(hub, tmp_path):
    hub.lie(sha="../../../../escaped")
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "commit id", "not 40 hex digits")


def test_an_etag_that_is_a_path_writes_nothing(hub, tmp_path):
    name = next(
        n for n in hub.dataset_repos[REPO_ID].commits[hub.dataset_repos[REPO_ID].branches["main"]].files if n.endswith(".h5")
    )
    hub.lie(etag={name: "../../../../escaped"})
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "ETag", "nothing was written")
    assert not any("escaped" in str(p) or p.parent.name == "blobs" for p in _files(tmp_path))  # all headers first


def test_file_names_with_dot_dot_are_refused(hub, tmp_path):
    hub.lie(extra=[{"type": "file", "path": "../../../escaped.h5", "size": 10, "oid": "0" * 40}])
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "'../../../escaped.h5'", "not a plain relative path")


def test_sizes_must_agree_and_mer_meta_json_is_capped_at_download(hub, tmp_path, monkeypatch, shard_files):
    hub.lie(size={"mer_meta.json": 10})  # the listing says 10 bytes, the file's headers the truth
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "contradict")
    hub.lies.clear()
    big = shard_files["mer_meta.json"] + b" " * 3_000_000  # a 3 MB side file: refused from its announced size
    hub.put(REPO_ID, {"mer_meta.json": big}, lfs=False)
    monkeypatch.setenv("MER_MAX_SIDECAR_BYTES", "1000000")
    seen = len(hub.requests)
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "MER_MAX_SIDECAR_BYTES", "mer_meta.json")
    assert not [p for m, p in hub.requests[seen:] if m == "GET" and ("/resolve/" in p or p.startswith("/lfs/"))]


def test_a_served_commit_or_content_that_differs_is_refused(hub, tmp_path, shard_files):
    hub.lie(commit="b" * 40)
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "not " + hub.dataset_repos[REPO_ID].branches["main"][:12])
    hub.lies.clear()
    name = next(n for n in shard_files if n.endswith(".h5"))
    hub.tamper(REPO_ID, name, shard_files[name][:-1] + bytes([shard_files[name][-1] ^ 0xFF]))  # same headers, other bytes
    _refused(tmp_path, f"hf://datasets/{REPO_ID}", "hashes to", "nothing was kept")


def test_revisions_that_are_paths_are_refused(hub, tmp_path):
    for rev in ("../../escaped", "main/../x", "a..b"):
        _refused(tmp_path, f"hf://datasets/{REPO_ID}@{rev}", "invalid revision")


def test_motion_input_from_a_lying_hub_is_refused(hub, tmp_path, monkeypatch):
    """``mer shards build --input hf://...``: the same checks; the CSVs capped at MER_MAX_MOTION_BYTES."""
    from mer_data.shards.sources import resolve_input

    hub.put("lab/motions", {"g1/walk.csv": b"0,0,0.8,0,0,0,1" + b",0" * 29 + b"\n"})
    hub.lie(extra=[{"type": "file", "path": "g1/../../escaped.csv", "size": 10, "oid": "0" * 40}])
    with pytest.raises(ShardBuildError, match="not a plain relative path"):
        resolve_input("hf://lab/motions", ["g1"])
    hub.lies.clear()
    monkeypatch.setenv("MER_MAX_MOTION_BYTES", "10")
    with pytest.raises(ShardBuildError, match="MER_MAX_MOTION_BYTES"):
        resolve_input("hf://lab/motions", ["g1"])
    monkeypatch.delenv("MER_MAX_MOTION_BYTES")
    root = resolve_input("hf://lab/motions", ["g1"])
    assert (root / "g1" / "walk.csv").read_bytes().startswith(b"0,0,0.8")
    assert not any("escaped" in str(p) for p in _files(tmp_path))
