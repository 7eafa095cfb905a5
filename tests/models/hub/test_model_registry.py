"""The model registry, bundled models, local folders and publishing refusals (no network involved)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from zoo_helpers import make_checkpoint

from mer_data.base.errors import ChecksumError, ModelNotAvailableError, ModelZooError, PublishError, UnknownModelError
from mer_models import zoo
from mer_models.hub.fromckpt import card_from_checkpoint
from mer_models.hub.registry import Registry, write_card

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture
def bundled_registry(tmp_path):
    """A catalogue folder with one bundled model whose weights sit in a bundled folder."""
    bundled = tmp_path / "bundled"
    ck = make_checkpoint(bundled / "tiny-default", seed=3)
    (ck / "optimizer.safetensors").unlink()
    cards = tmp_path / "cards"
    write_card(card_from_checkpoint(ck, name="tiny-default", status="bundled"), cards)
    return Registry(builtin=cards, user=tmp_path / "user", bundled=bundled)


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(UnknownModelError) as exc:
        zoo.resolve("mer-bsae")
    text = str(exc.value)
    assert "unknown model 'mer-bsae'" in text and "mer-paper, mer-paper-talos, mer-paper-valkyrie" in text
    assert "mer zoo list" in text


def test_the_catalogue_is_listed_and_unpublished_models_refuse_to_load():
    entries = {e.name: e for e in zoo.list_models()}
    assert {"mer-paper", "mer-paper-talos", "mer-paper-valkyrie"} <= set(entries)
    assert zoo.where(entries["mer-paper"]) == "unpublished"
    with pytest.raises(ModelNotAvailableError, match="not yet published") as exc:
        zoo.load("mer-paper-valkyrie")
    assert "mer finetune --base mer-paper --robot valkyrie" in str(exc.value)


def test_a_bundled_model_resolves_offline_and_is_verified(bundled_registry, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    entry = zoo.model_info("tiny-default", bundled_registry)
    assert zoo.where(entry, bundled_registry) == "bundled"
    res = zoo.resolve("tiny-default", registry=bundled_registry)
    assert res.source == "bundled" and res.verified == "card"
    assert res.folder == bundled_registry.bundled / "tiny-default"


def test_a_damaged_bundled_file_is_refused_but_never_deleted(bundled_registry):
    weights = bundled_registry.bundled / "tiny-default" / "model.safetensors"
    data = weights.read_bytes()
    weights.write_bytes(data[:-1] + bytes([data[-1] ^ 0xFF]))
    with pytest.raises(ChecksumError, match="sha256") as exc:
        zoo.resolve("tiny-default", registry=bundled_registry)
    assert "reinstall mer" in str(exc.value)
    assert weights.exists()  # package files are reported, not removed


def test_a_user_card_cannot_shadow_a_builtin_name(tmp_path, caplog):
    reg = Registry(user=tmp_path / "user")
    src = REPO / "cards" / "models" / "mer-paper.md"
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "mer-paper.md").write_text(src.read_text())
    assert reg.get("mer-paper").source == "built-in"
    assert "taken by a built-in model" in caplog.text


def test_a_broken_user_card_is_skipped_in_the_list_but_explained_by_name(tmp_path):
    user = tmp_path / "user"
    user.mkdir()
    (user / "mine.md").write_text("---\nmer: [1, 2\n---\n")
    reg = Registry(user=user)
    assert "mine" not in reg.names()
    with pytest.raises(ModelZooError, match="invalid YAML"):
        reg.get("mine")


def test_a_local_folder_is_used_as_is(tmp_path):
    ck = make_checkpoint(tmp_path / "ck")
    res = zoo.resolve(str(ck))
    assert res.source == "local" and res.folder == ck and res.verified == "none"
    with pytest.raises(ModelZooError, match="local folder"):
        zoo.resolve(str(ck), revision="main")
    with pytest.raises(ModelZooError, match="no checkpoint folder"):
        zoo.resolve(str(tmp_path / "missing" / "ckpt"))


def test_publish_refuses_before_touching_the_network(tmp_path, monkeypatch):
    ck = make_checkpoint(tmp_path / "ck")
    with pytest.raises(PublishError, match="built-in model"):
        zoo.publish(ck, name="mer-paper", repo_id="lab/x", cards_dir=tmp_path / "cards")
    with pytest.raises(PublishError, match="--license"):
        zoo.publish(make_checkpoint(tmp_path / "unk", dataset="studio mocap"), name="x", repo_id="lab/x",
                    cards_dir=tmp_path / "cards")
    (ck / "model.safetensors").unlink()
    with pytest.raises(PublishError, match="no model.safetensors"):
        zoo.publish(ck, name="x", repo_id="lab/x", cards_dir=tmp_path / "cards")
    with pytest.raises(ModelZooError, match="invalid Hub repo id"):
        zoo.publish(ck, name="x", repo_id="../x", cards_dir=tmp_path / "cards")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(PublishError, match="HF_HUB_OFFLINE"):
        zoo.publish(make_checkpoint(tmp_path / "ok"), name="x", repo_id="lab/x", cards_dir=tmp_path / "cards")
    assert not (tmp_path / "cards").exists()


_FORBIDDEN = [
    (re.compile(r"^\s*(import pickle|from pickle|import cPickle|import dill|import joblib)", re.M), "pickle"),
    (re.compile(r"\bpickle\.loads?\("), "pickle.load"),
    (re.compile(r"torch\.load\((?![^)]*weights_only\s*=\s*True)"), "torch.load without weights_only=True"),
    (re.compile(r"allow_pickle\s*=\s*True"), "numpy allow_pickle"),
    (re.compile(r"trust_remote_code\s*=\s*True"), "remote code"),
    (re.compile(r"yaml\.load\((?![^)]*Loader\s*=\s*(yaml\.SafeLoader|_NoAliasLoader)\b)"), "unsafe yaml.load"),
]


def test_no_pickle_and_no_remote_code_anywhere_in_the_package():
    import yaml

    from mer_data.base import safe_io

    assert issubclass(safe_io._NoAliasLoader, yaml.SafeLoader)  # the one other loader allowed
    offenders = []
    for pkg in ("mer_data", "mer_models", "tools"):
        for path in sorted((REPO / pkg).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            for pattern, what in _FORBIDDEN:
                for m in pattern.finditer(text):
                    offenders.append(f"{path.relative_to(REPO)}:{text[:m.start()].count(chr(10)) + 1}: {what}")
    assert not offenders, "\n".join(offenders)
