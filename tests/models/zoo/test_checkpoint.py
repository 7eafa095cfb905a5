"""Checkpoints: round trip, strict safetensors loading, config mismatches, unseen robots, no pickle."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import torch
from model_helpers import MICRO, micro_checkpoint, micro_run  # noqa: F401 (fixture)
from safetensors.torch import load_file, save_file

from mer_data.base.errors import CheckpointError, ConfigError, UnseenRobotError
from mer_models.diffusion.model import RetargetModel
from mer_models.hub.checkpoint_files import save_checkpoint
from mer_models.zoo.checkpoint import check_robot, load_checkpoint, resolve_model

PACKAGE = Path(__file__).resolve().parents[3] / "mer_models"


@pytest.fixture
def ckpt(tmp_path, micro_checkpoint):  # noqa: F811
    dst = tmp_path / "ckpt"
    shutil.copytree(micro_checkpoint, dst)
    return dst


def test_round_trip_is_bit_exact(tmp_path):
    torch.manual_seed(0)
    m = RetargetModel(MICRO)
    save_checkpoint(tmp_path / "c", m, micro_run(), robots={"targets": {"h1": ""}, "references": {"g1": ""}}, step=7)
    ck = load_checkpoint(tmp_path / "c")
    assert ck.step == 7 and ck.targets == ["h1"] and ck.references == ["g1"]
    for (k, a), (k2, b) in zip(m.state_dict().items(), ck.model.state_dict().items()):
        assert k == k2 and torch.equal(a, b)
    meta = json.loads((tmp_path / "c" / "config.json").read_text())
    assert meta["format"] == "mer-checkpoint" and meta["format_version"] == 1
    assert set(meta) >= {"run", "robots", "data", "metrics", "step", "mer_version"}


def test_training_checkpoint_has_resume_state(micro_checkpoint):  # noqa: F811
    names = {p.name for p in micro_checkpoint.iterdir()}
    assert {"config.json", "model.safetensors", "optimizer.safetensors", "trainer_state.json", "train_log.jsonl"} <= names
    ck = load_checkpoint(micro_checkpoint)
    assert ck.targets == ["g1", "h1", "tron1"]
    assert ck.data == {} or isinstance(ck.data, dict)


def _rewrite_weights(path, fn):
    sd = load_file(str(path / "model.safetensors"))
    fn(sd)
    save_file(sd, str(path / "model.safetensors"))


def test_missing_tensor_is_named(ckpt):
    _rewrite_weights(ckpt, lambda sd: sd.pop("net.base_head.weight"))
    with pytest.raises(CheckpointError, match=r"missing 1 tensor\(s\): net.base_head.weight"):
        load_checkpoint(ckpt)


def test_unexpected_tensor_is_named(ckpt):
    _rewrite_weights(ckpt, lambda sd: sd.__setitem__("net.extra", torch.zeros(2)))
    with pytest.raises(CheckpointError, match="unexpected 1 tensor.*net.extra"):
        load_checkpoint(ckpt)


def test_shape_mismatch_is_named(ckpt):
    _rewrite_weights(ckpt, lambda sd: sd.__setitem__("net.base_head.bias", torch.zeros(3)))
    with pytest.raises(CheckpointError, match=r"net.base_head.bias has shape \(3,\)"):
        load_checkpoint(ckpt)


def test_corrupt_weights_file(ckpt):
    (ckpt / "model.safetensors").write_bytes(b"\x00" * 40)
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(ckpt)


def test_config_that_does_not_match_the_code_names_the_field(ckpt):
    meta = json.loads((ckpt / "config.json").read_text())
    meta["run"]["model"]["relative_bias"] = True
    (ckpt / "config.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError) as e:
        load_checkpoint(ckpt)
    assert "model.relative_bias" in str(e.value) and "config.json" in str(e.value)


def test_config_whose_model_differs_from_the_weights(ckpt):
    meta = json.loads((ckpt / "config.json").read_text())
    meta["run"]["model"]["hidden"] = 32
    (ckpt / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="has shape"):
        load_checkpoint(ckpt)


def test_format_version_mismatch(ckpt):
    meta = json.loads((ckpt / "config.json").read_text())
    meta["format_version"] = 99
    (ckpt / "config.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="format version 99"):
        load_checkpoint(ckpt)


def test_not_a_checkpoint(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint folder"):
        resolve_model(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match="no config.json"):
        load_checkpoint(tmp_path / "empty")


def test_unseen_robot_points_to_finetune(micro_checkpoint):  # noqa: F811
    ck = load_checkpoint(micro_checkpoint)
    check_robot(ck, "h1")
    with pytest.raises(UnseenRobotError) as e:
        check_robot(ck, "valkyrie")
    assert "mer finetune" in str(e.value) and "valkyrie" in str(e.value)


def test_no_pickle_anywhere_in_the_model_package():
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text()
        assert not re.search(r"torch\.load\(|import pickle|pickle\.load", text), path


def test_save_is_atomic(tmp_path, monkeypatch):
    m = RetargetModel(MICRO)
    save_checkpoint(tmp_path / "c", m, micro_run(), robots={"targets": {}, "references": {}}, step=1)
    import mer_models.hub.checkpoint_files as cp

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(cp, "save_file", boom)
    with pytest.raises(OSError):
        save_checkpoint(tmp_path / "c", m, micro_run(), robots={"targets": {}, "references": {}}, step=2)
    assert load_checkpoint(tmp_path / "c").step == 1  # the old checkpoint is intact
    assert [p.name for p in tmp_path.iterdir()] == ["c"]  # no temporary left behind
