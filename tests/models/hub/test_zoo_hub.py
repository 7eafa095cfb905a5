"""The zoo against the real huggingface_hub client and a loopback Hub (tests/hub_server.py).

Every client runs in a fresh interpreter started with HF_ENDPOINT / HF_HUB_CACHE / HF_HUB_OFFLINE
already set (tests/zoo_worker.py), because the client reads them when it is imported: nothing in
huggingface_hub is patched. The server counts requests, so "no network" is asserted, not assumed.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest
from hub_server import HubServer
from zoo_helpers import TOKEN, client_env, make_checkpoint
from zoo_worker import run_worker

from mer_models.hub.card import read_card
from mer_models.hub.registry import write_card

REPO_ID = "lab/tiny-synth"
NAME = "tiny-synth"


def _sha(p: Path) -> str:
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    """One loopback Hub with NAME published twice (v1, then v2), and the client's view of it."""
    tmp = tmp_path_factory.mktemp("zoo_hub")
    v1 = make_checkpoint(tmp / "v1", seed=1)
    v2 = make_checkpoint(tmp / "v2", seed=2, step=8)
    home = tmp / "mer_home"
    with HubServer(token=TOKEN) as hub:
        env = client_env(hub.url, tmp / "publisher", home)
        out = run_worker([
            {"op": "constants"},
            {"op": "publish", "checkpoint": str(v1), "name": NAME, "repo_id": REPO_ID},
            {"op": "publish", "checkpoint": str(v2), "name": NAME, "repo_id": REPO_ID},
            {"op": "list"},
            {"op": "download", "spec": NAME},
            {"op": "list"},
        ], env)
        assert all(o["ok"] for o in out), out
        yield {"hub": hub, "tmp": tmp, "home": home, "v1": v1, "v2": v2, "env": env, "out": out,
               "c1": out[1]["result"]["commit"], "c2": out[2]["result"]["commit"]}


def _fresh_env(published, tmp_path, **extra):
    return client_env(published["hub"].url, tmp_path, published["home"], **extra)


def test_client_takes_its_configuration_from_the_environment(published):
    const = published["out"][0]["result"]
    assert const["endpoint"] == published["hub"].url
    assert const["cache"] == str(published["tmp"] / "publisher" / "hub_cache")
    assert const["offline"] is False and const["disable_xet"] is True


def test_publish_records_commit_and_checksums_in_the_card(published):
    hub, c1, c2 = published["hub"], published["c1"], published["c2"]
    card = read_card(published["home"] / "cards" / "models" / f"{NAME}.md")
    assert card.status == "published" and card.repo_id == REPO_ID and card.revision == c2
    assert [h.revision for h in card.history] == [c1]
    for fname, rec in card.files.items():
        local = published["v2"] / fname
        assert rec.sha256 == _sha(local) and rec.size == local.stat().st_size
    for fname, rec in card.history[0].files.items():
        assert rec.sha256 == _sha(published["v1"] / fname)
    repo = hub.repos[REPO_ID]
    at_c2 = repo.commits[c2].files
    assert set(at_c2) == {".gitattributes", "config.json", "model.safetensors", "README.md"}  # README: v1's card
    assert "optimizer.safetensors" not in at_c2  # optimiser state stays local
    for fname in ("config.json", "model.safetensors"):
        assert at_c2[fname].data == (published["v2"] / fname).read_bytes()
    assert at_c2["model.safetensors"].lfs and not at_c2["config.json"].lfs
    # The card commit follows the weights commit and carries the card itself, bit for bit.
    head = hub.head(REPO_ID)
    assert repo.commits[head].parent == c2
    assert repo.commits[head].files["README.md"].data == card.path.read_bytes()
    assert card.license == "apache-2.0" and "synthetic" in card.license_note


def test_download_by_name_round_trips_bit_for_bit_into_the_hub_cache(published):
    res = published["out"][4]["result"]
    c2, cache = published["c2"], published["tmp"] / "publisher" / "hub_cache"
    folder = Path(res["folder"])
    assert folder == cache / "models--lab--tiny-synth" / "snapshots" / c2  # the client's own layout
    assert res["verified"] == "card" and res["revision"] == c2
    for fname in ("config.json", "model.safetensors"):
        assert (folder / fname).read_bytes() == (published["v2"] / fname).read_bytes()
        assert (folder / fname).is_symlink()
    blob = (folder / "model.safetensors").resolve()
    assert blob.parent.name == "blobs" and blob.name == _sha(published["v2"] / "model.safetensors")
    before = {r["name"]: r for r in published["out"][3]["result"]}
    after = {r["name"]: r for r in published["out"][5]["result"]}
    assert before[NAME] == {"name": NAME, "where": "remote", "source": "user"}
    assert after[NAME] == {"name": NAME, "where": "cached", "source": "user"}
    assert after["mer-paper"]["where"] == "unpublished" and after["mer-paper"]["source"] == "built-in"


def test_pinned_revision_is_respected(published, tmp_path):
    c1, c2 = published["c1"], published["c2"]
    out = run_worker([
        {"op": "download", "spec": NAME, "revision": c1},
        {"op": "download", "spec": NAME},
        {"op": "download", "spec": REPO_ID},
        {"op": "download", "spec": "lab/does-not-exist"},
        {"op": "download", "spec": NAME, "revision": "f" * 40},
    ], _fresh_env(published, tmp_path))
    old, new, plain, missing, badrev = out
    assert old["ok"] and old["result"]["revision"] == c1 and old["result"]["verified"] == "card"  # via the card's history
    assert old["result"]["files"]["model.safetensors"] == _sha(published["v1"] / "model.safetensors")
    assert new["result"]["revision"] == c2
    assert new["result"]["files"]["model.safetensors"] == _sha(published["v2"] / "model.safetensors")
    # A plain Hub id: the branch head (the card commit), checked against the Hub's content ids.
    assert plain["ok"] and plain["result"]["verified"] == "hub" and plain["result"]["revision"] == published["hub"].head(REPO_ID)
    assert not missing["ok"] and "does not exist" in missing["message"]
    assert not badrev["ok"] and "revision" in badrev["message"] and "does not exist" in badrev["message"]

    # A card pinned at the first commit keeps giving the first bytes although main has moved on.
    card = read_card(published["home"] / "cards" / "models" / f"{NAME}.md")
    pinned = card.__class__(**{**card.__dict__, "revision": c1, "files": card.history[0].files, "history": ()})
    home = tmp_path / "pinned_home"
    write_card(pinned, home / "cards" / "models")
    out = run_worker([{"op": "download", "spec": NAME}],
                     client_env(published["hub"].url, tmp_path / "pinned", home))
    assert out[0]["result"]["revision"] == c1
    assert out[0]["result"]["files"]["model.safetensors"] == _sha(published["v1"] / "model.safetensors")


def test_a_cached_model_loads_with_the_network_off(published, tmp_path):
    hub = published["hub"]
    env = _fresh_env(published, tmp_path)
    assert run_worker([{"op": "download", "spec": NAME}], env)[0]["ok"]
    # HF_HUB_OFFLINE=1 with the server up: not a single request reaches it.
    before = len(hub.requests)
    out = run_worker([{"op": "download", "spec": NAME}], {**env, "HF_HUB_OFFLINE": "1"})
    assert out[0]["ok"] and out[0]["result"]["revision"] == published["c2"]
    assert len(hub.requests) == before
    # The server gone (a closed port) and HF_HUB_OFFLINE=1: still served from the cache. A pinned commit
    # that is cached is final, so even without the offline flag nothing is fetched.
    dead = HubServer()
    dead.stop()
    out = run_worker([{"op": "setenv", "name": "HF_HUB_OFFLINE", "value": "1"}, {"op": "download", "spec": NAME},
                      {"op": "setenv", "name": "HF_HUB_OFFLINE", "value": "0"}, {"op": "download", "spec": NAME}],
                     {**env, "HF_ENDPOINT": dead.url})
    assert out[1]["ok"] and out[3]["ok"], out
    assert out[1]["result"]["files"] == out[3]["result"]["files"]


def test_offline_and_not_cached_says_how_to_get_it(published, tmp_path):
    hub = published["hub"]
    before = len(hub.requests)
    out = run_worker([
        {"op": "download", "spec": NAME},
        {"op": "download", "spec": "no-such-model"},
        {"op": "download", "spec": "mer-paper"},
        {"op": "download", "spec": NAME, "revision": "../../../etc"},
        {"op": "download", "spec": REPO_ID},
    ], _fresh_env(published, tmp_path, HF_HUB_OFFLINE="1"))
    offline, unknown, unpublished, traversal, plain = out
    assert offline["error"] == "ModelNotAvailableError"
    assert "HF_HUB_OFFLINE" in offline["message"] and f"mer zoo download {NAME}" in offline["message"]
    assert unknown["error"] == "UnknownModelError" and "mer-paper" in unknown["message"] and NAME in unknown["message"]
    assert unpublished["error"] == "ModelNotAvailableError" and "not yet published" in unpublished["message"]
    assert "mer train" in unpublished["message"]
    assert traversal["error"] == "ModelZooError" and "invalid revision" in traversal["message"]
    assert plain["error"] == "ModelNotAvailableError"
    assert len(hub.requests) == before  # offline: no request at all


@pytest.mark.parametrize("damage", ["altered", "truncated"])
def test_a_tampered_download_fails_its_checksum_and_is_not_kept(published, tmp_path, damage):
    hub = published["hub"]
    good = (published["v2"] / "model.safetensors").read_bytes()
    bad = bytes([good[0] ^ 1]) + good[1:] if damage == "altered" else good[: len(good) // 2]
    hub.tamper(REPO_ID, "model.safetensors", bad)
    try:
        out = run_worker([{"op": "download", "spec": NAME},
                          {"op": "cached", "repo_id": REPO_ID, "filename": "model.safetensors", "revision": published["c2"]}],
                         _fresh_env(published, tmp_path))
    finally:
        hub.tamper(REPO_ID, "model.safetensors", good)
    assert out[0]["error"] == "ChecksumError", out
    assert "not used" in out[0]["message"] or "cut short" in out[0]["message"]
    assert out[1]["result"] is None  # nothing of it is left in the cache
    blobs = tmp_path / "hub_cache" / "models--lab--tiny-synth" / "blobs"
    assert not any(hashlib.sha256(p.read_bytes()).hexdigest() == hashlib.sha256(bad).hexdigest() for p in blobs.iterdir())


def test_a_corrupted_cache_entry_is_removed_and_fetched_again(published, tmp_path):
    env = _fresh_env(published, tmp_path)
    first = run_worker([{"op": "download", "spec": NAME}], env)[0]["result"]
    blob = (Path(first["folder"]) / "model.safetensors").resolve()
    os.chmod(blob, 0o644)
    with open(blob, "r+b") as f:
        f.truncate(100)
    out = run_worker([
        {"op": "setenv", "name": "HF_HUB_OFFLINE", "value": "1"},
        {"op": "download", "spec": NAME},  # offline: refused, and the bad copy removed
        {"op": "cached", "repo_id": REPO_ID, "filename": "model.safetensors", "revision": published["c2"]},
        {"op": "setenv", "name": "HF_HUB_OFFLINE", "value": "0"},
        {"op": "download", "spec": NAME},  # online: fetched again, verified
    ], env)
    assert out[1]["error"] == "ChecksumError" and "removed" in out[1]["message"], out[1]
    assert "mer zoo download" in out[1]["message"]
    assert out[2]["result"] is None and str(blob) in out[1]["message"]  # snapshot entry and blob removed
    assert out[4]["ok"] and out[4]["result"]["files"] == first["files"]
    assert _sha(blob) == _sha(published["v2"] / "model.safetensors")  # the blob is whole again


def test_a_plain_repo_id_is_checked_against_the_hub_content_ids(published, tmp_path):
    env = _fresh_env(published, tmp_path)
    first = run_worker([{"op": "download", "spec": REPO_ID}], env)[0]["result"]
    cfg = Path(first["folder"]) / "config.json"
    blob = cfg.resolve()
    os.chmod(blob, 0o644)
    blob.write_text(blob.read_text().replace('"step": 8', '"step": 9'))
    out = run_worker([{"op": "setenv", "name": "HF_HUB_OFFLINE", "value": "1"},
                      {"op": "download", "spec": REPO_ID, "revision": first["revision"]}], env)
    assert out[1]["error"] == "ChecksumError" and "Hub served it as" in out[1]["message"]
    assert not cfg.exists()
    shutil.rmtree(tmp_path / "hub_cache")
