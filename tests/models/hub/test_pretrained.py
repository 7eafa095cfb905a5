"""``RetargetModel.from_pretrained`` / ``push_to_hub`` against the real huggingface_hub client and the loopback Hub.

Clients run in fresh interpreters (tests/zoo_worker.py) so that the client reads HF_ENDPOINT and the
cache folders from the environment, as in a user's process; the server counts requests.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hub_server import HubServer
from model_helpers import MICRO, micro_run
from safetensors.torch import load, load_file, save_file
from zoo_helpers import TOKEN, client_env
from zoo_worker import model_outputs, run_worker

from mer_data.base.errors import CheckpointError, ModelZooError
from mer_models import RetargetModel
from mer_models.hub.checkpoint_files import save_checkpoint
from mer_models.zoo.checkpoint import load_checkpoint

REPO_ID = "lab/mer-micro"


@pytest.fixture(scope="module")
def micro(tmp_path_factory):
    """A micro model's checkpoint folder (random weights; no training needed to move and load bytes)."""
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("pretrained") / "micro"
    save_checkpoint(folder, RetargetModel(MICRO), micro_run(), robots={"targets": {"g1": "", "h1": ""}, "references": {"g1": ""}},
                    data={"dataset": "synthetic", "windows": 16}, step=3)
    return folder


def test_from_pretrained_takes_a_zoo_name_and_a_local_folder(micro):
    bundled = RetargetModel.from_pretrained("mer-base")  # the bundled default model, by name
    assert bundled.pretrained_info.source == "bundled" and not bundled.training
    local = RetargetModel.from_pretrained(micro)
    assert local.pretrained_info.source == "local" and local.pretrained_info.step == 3
    assert np.array_equal(model_outputs(local), model_outputs(load_checkpoint(micro).model))


def test_save_pretrained_round_trips_and_a_model_built_in_code_needs_its_metadata(micro, tmp_path):
    m = RetargetModel.from_pretrained(micro)
    out = m.save_pretrained(tmp_path / "again")
    assert {p.name for p in out.iterdir()} == {"config.json", "model.safetensors"}
    assert np.array_equal(model_outputs(RetargetModel.from_pretrained(out)), model_outputs(m))
    with pytest.raises(CheckpointError, match="no checkpoint metadata"):
        RetargetModel(MICRO).save_pretrained(tmp_path / "bare")
    RetargetModel(MICRO).save_pretrained(tmp_path / "bare", run=micro_run(), robots={"targets": {"g1": ""}, "references": {"g1": ""}})
    assert load_checkpoint(tmp_path / "bare").targets == ["g1"]


def test_push_to_hub_then_from_pretrained_gives_identical_outputs_online_and_offline(micro, tmp_path):
    want = model_outputs(load_checkpoint(micro).model)
    with HubServer(token=TOKEN) as hub:
        pub = run_worker([{"op": "push_to_hub", "spec": str(micro), "repo_id": REPO_ID},
                          {"op": "hub_card", "repo_id": REPO_ID}], client_env(hub.url, tmp_path / "pub", tmp_path / "home"))
        assert all(o["ok"] for o in pub), pub
        commit = pub[0]["result"]["commit"]
        files = hub.repos[REPO_ID].commits[commit].files
        pushed, local = load(files["model.safetensors"].data), load_file(str(micro / "model.safetensors"))
        assert pushed.keys() == local.keys() and all(torch.equal(pushed[k], local[k]) for k in local)
        assert "optimizer.safetensors" not in files
        meta = pub[1]["result"]  # parsed by huggingface_hub and accepted by the Hub's metadata validation
        assert meta["pipeline_tag"] == "robotics" and meta["library_name"] == "mer" and meta["license"] == "apache-2.0"
        assert meta["mer"]["revision"] == commit and meta["mer"]["repo_id"] == REPO_ID

        user = client_env(hub.url, tmp_path / "user", tmp_path / "home")
        mine = tmp_path / "my_cache"
        out = run_worker([
            {"op": "from_pretrained", "spec": REPO_ID, "cache_dir": str(mine), "save": str(tmp_path / "main.npy")},
            {"op": "from_pretrained", "spec": REPO_ID, "revision": commit, "cache_dir": str(mine), "save": str(tmp_path / "pinned.npy")},
        ], user)
        assert all(o["ok"] for o in out), out
        assert out[0]["result"]["revision"] == hub.head(REPO_ID) != commit  # main: the card's commit, same weights
        assert out[1]["result"]["revision"] == commit and out[1]["result"]["source"] == "hub"
        assert out[0]["result"]["folder"].startswith(str(mine))  # cache_dir=, not HF_HUB_CACHE
        assert not (tmp_path / "user" / "hub_cache").exists()
        assert np.array_equal(np.load(tmp_path / "main.npy"), want) and np.array_equal(np.load(tmp_path / "pinned.npy"), want)

        seen = len(hub.requests)
        off = run_worker([
            {"op": "from_pretrained", "spec": REPO_ID, "cache_dir": str(mine), "local_files_only": True, "save": str(tmp_path / "off.npy")},
            {"op": "from_pretrained", "spec": REPO_ID, "cache_dir": str(tmp_path / "empty"), "local_files_only": True},
        ], user)
        assert len(hub.requests) == seen  # local_files_only: not one request
        assert off[0]["ok"], off and np.array_equal(np.load(tmp_path / "off.npy"), want)
        assert not off[1]["ok"] and "ModelNotAvailableError" in off[1]["mro"] and "local_files_only" in off[1]["message"]


def _partial(src: Path, dst: Path, edit) -> Path:
    shutil.copytree(src, dst)
    (dst / "optimizer.safetensors").unlink(missing_ok=True)
    edit(dst / "model.safetensors")
    return dst


def _drop_key(path: Path) -> None:
    sd = load_file(str(path))
    sd.pop(sorted(sd)[-1])
    save_file(sd, str(path), metadata={"format": "mer-checkpoint", "format_version": "1"})


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_a_partial_or_corrupted_push_is_refused_on_load_naming_the_missing_keys(micro, tmp_path):
    missing = sorted(load_file(str(micro / "model.safetensors")))[-1]
    dropped = _partial(micro, tmp_path / "dropped", _drop_key)
    truncated = _partial(micro, tmp_path / "truncated", _truncate)
    with HubServer(token=TOKEN) as hub:
        env = client_env(hub.url, tmp_path / "c", tmp_path / "home")
        out = run_worker([
            {"op": "upload_folder", "folder": str(dropped), "repo_id": "lab/dropped"},
            {"op": "upload_folder", "folder": str(truncated), "repo_id": "lab/truncated"},
            {"op": "from_pretrained", "spec": "lab/dropped"},
            {"op": "from_pretrained", "spec": "lab/truncated"},
            {"op": "from_pretrained", "spec": "lab/nothing-here"},
        ], env)
    assert out[0]["ok"] and out[1]["ok"], out
    assert out[2]["error"] == "CheckpointError" and "missing 1 tensor(s)" in out[2]["message"] and missing in out[2]["message"]
    assert out[3]["error"] == "CheckpointError" and "cannot read the weights" in out[3]["message"]
    assert not out[4]["ok"] and "ModelZooError" in out[4]["mro"] and "does not exist" in out[4]["message"]
    # and locally, the same refusals (no silently initialised weights)
    with pytest.raises(CheckpointError, match=missing.replace(".", r"\.")):
        RetargetModel.from_pretrained(dropped)


def test_push_to_hub_refuses_offline_and_bad_repo_ids(micro, monkeypatch):
    m = RetargetModel.from_pretrained(micro)
    with pytest.raises(ModelZooError, match="invalid Hub repo id"):
        m.push_to_hub("not-a-repo-id")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(ModelZooError, match="offline"):
        m.push_to_hub(REPO_ID)
