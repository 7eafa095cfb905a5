"""The bundled default model: present, verified, rendered from its own metadata, loads offline, retargets."""

from __future__ import annotations

import json

import numpy as np

from mer_data.registry import get_skeleton
from mer_models import zoo
from mer_models.cli import main
from mer_models.zoo.fromckpt import card_from_checkpoint
from mer_models.zoo.registry import Registry, bundled_dir

from conftest import REPO
from model_helpers import synthetic_csv

DEMO_TARGETS = {"g1", "h1", "h1_2", "atlas", "oli", "tron1"}


def test_the_default_model_is_bundled_small_and_described_by_its_card():
    name = zoo.DEFAULT_MODEL
    entry = zoo.model_info(name)
    card = entry.card
    assert entry.source == "built-in" and card.status == "bundled" and zoo.where(entry) == "bundled"
    folder = bundled_dir() / name
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "model.safetensors"]  # no optimiser state
    assert (folder / "model.safetensors").stat().st_size < 2_000_000
    # trained on synthetic motion only: a permissive licence, said plainly; and evaluated
    assert card.license == "apache-2.0" and card.training["dataset"] == "synthetic"
    assert "not for real use" in card.summary and "synthetic" in card.summary
    assert DEMO_TARGETS <= set(card.targets) and card.robots["references"] == ["g1"]
    ev = card.metrics["evaluation (mer evaluate)"]
    for table in ("model, in-domain", "model, out-of-domain", "optimisation baseline, out-of-domain"):
        assert DEMO_TARGETS <= set(ev[table]), table
    assert "tools/train_bundled.py" in card.reproduce and "mer train --config tiny --synthetic" in card.reproduce


def test_the_bundled_card_is_rendered_from_the_checkpoint_metadata():
    card = zoo.model_info(zoo.DEFAULT_MODEL).card
    folder = bundled_dir() / zoo.DEFAULT_MODEL
    again = card_from_checkpoint(folder, name=card.name, status="bundled", summary=card.summary,
                                 license_note=card.license_note, reproduce=card.reproduce)  # fmt: skip
    assert again.files == card.files  # sha256 and size of the files as they are
    assert (again.robots, again.training, again.metrics, again.checkpoint) == (card.robots, card.training, card.metrics, card.checkpoint)
    meta = json.loads((folder / "config.json").read_text())
    assert card.checkpoint["step"] == meta["step"] and card.training["steps"] == meta["step"]
    assert f"trained for {meta['step']} steps" in card.summary


def test_load_by_name_offline_with_no_hub_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    res = zoo.resolve(zoo.DEFAULT_MODEL)
    assert res.source == "bundled" and res.verified == "card" and res.folder == bundled_dir() / zoo.DEFAULT_MODEL
    ckpt = zoo.load(zoo.DEFAULT_MODEL)
    assert DEMO_TARGETS <= set(ckpt.targets) and ckpt.references == ["g1"]
    assert not ckpt.model.training
    assert not (tmp_path / "empty-cache").exists()


def test_a_source_checkout_and_an_install_read_the_same_card():
    src = Registry().get(zoo.DEFAULT_MODEL).card
    pkg = Registry(builtin=REPO / "mer_models" / "cards").get(zoo.DEFAULT_MODEL).card
    assert src.files == pkg.files and src.metrics == pkg.metrics




def test_retarget_by_name_and_by_default_offline(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    src = synthetic_csv(tmp_path / "walk.csv", frames=45, seed=5)
    assert main(["retarget", str(src), "--source", "g1", "--target", "tron1", "--model", zoo.DEFAULT_MODEL,
                 "-o", str(tmp_path / "a.csv"), "--steps", "2"]) == 0  # fmt: skip
    assert main(["retarget", str(src), "--source", "g1", "--target", "tron1", "-o", str(tmp_path / "b.csv"), "--steps", "2"]) == 0
    err = capsys.readouterr().err
    assert f"using the bundled demo model {zoo.DEFAULT_MODEL!r}" in err
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == (45, 7 + get_skeleton("tron1").num_dof) and np.array_equal(a, b)  # same model, same seed


def test_the_library_still_needs_a_model_for_diffusion(tmp_path):
    """Only the command line falls back to the bundled model (and says so); the library never picks one."""
    import pytest

    from mer_data.errors import MerError
    from mer_models.retarget import retarget_file

    with pytest.raises(MerError, match="--method optimize"):
        retarget_file(synthetic_csv(tmp_path / "w.csv", frames=10, seed=5), "g1", "h1", out_csv=tmp_path / "o.csv")
    assert not (tmp_path / "o.csv").exists()
