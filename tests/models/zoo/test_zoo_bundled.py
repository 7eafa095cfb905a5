"""The bundled default model (mer-base): present, verified, rendered from its own metadata, trained
for every built-in robot as source and target, loads offline and retargets with no --model."""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np
import pytest
from conftest import REPO
from model_helpers import synthetic_csv
from zoo_helpers import make_checkpoint

from mer_data.robots.registry import BUILTIN_ROBOTS, get_skeleton
from mer_models import zoo
from mer_models.cli import main
from mer_models.config import from_dict, preset
from mer_models.hub.fromckpt import card_from_checkpoint
from mer_models.hub.registry import Registry, bundled_dir


def _train_base():
    """tools/train_base.py as a module (the maintainer script that bundles mer-base)."""
    spec = importlib.util.spec_from_file_location("train_base", REPO / "tools" / "train_base.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_default_model_is_mer_base_bundled_and_described_by_its_card():
    name = zoo.DEFAULT_MODEL
    assert name == "mer-base"
    entry = zoo.model_info(name)
    card = entry.card
    assert entry.source == "built-in" and card.status == "bundled" and zoo.where(entry) == "bundled"
    folder = bundled_dir() / name
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "model.safetensors"]  # no optimiser state
    assert (folder / "model.safetensors").stat().st_size < 6_000_000  # base with a feed-forward of 768, float32: ~4.6 MB
    # trained on synthetic motion only: a permissive licence, said plainly
    assert card.license == "apache-2.0" and card.training["dataset"] == "synthetic" and card.checkpoint["config"] == "base"
    assert "synthetic motion" in card.summary and "default" in card.summary and "teacher is the optimiser" in card.summary
    assert "lafan" not in json.dumps(card.training).lower()
    assert "tools/train_base.py" in card.reproduce and "--bundle-only" in card.reproduce
    # evaluated on LAFAN1 (every built-in robot as target, G1 and H1 as sources), or said not to be
    ev = card.metrics.get("evaluation (mer evaluate)")
    if ev is None:
        assert "has not been evaluated" in card.summary
    else:
        assert "is in this card's metrics" in card.summary
        for src in ("g1", "h1"):
            assert set(ev[f"source {src}, {_train_base()._METHOD['model']}"]) == set(BUILTIN_ROBOTS)


def test_the_bundled_checkpoint_covers_exactly_every_builtin_robot_as_source_and_target():
    """8 x 8 retargets would take minutes: the recorded robots (names and skeleton fingerprints) are checked instead."""
    meta = json.loads((bundled_dir() / zoo.DEFAULT_MODEL / "config.json").read_text())
    expected = {r: get_skeleton(r).fingerprint for r in BUILTIN_ROBOTS}
    assert meta["robots"]["targets"] == expected and meta["robots"]["references"] == expected
    card = zoo.model_info(zoo.DEFAULT_MODEL).card
    assert card.targets == sorted(BUILTIN_ROBOTS) and card.robots["references"] == sorted(BUILTIN_ROBOTS)
    # what ships: the preset's sampler (fields added since the bundle load with their legacy values)
    assert meta["run"]["name"] == "base" and from_dict(meta["run"]).sampler == preset("base").sampler
    assert _train_base().sampler_text(meta["run"]["sampler"]) in card.summary  # the sampler as the checkpoint has it


def test_the_card_names_the_network_size_and_where_it_differs_from_the_preset():
    run = json.loads((bundled_dir() / zoo.DEFAULT_MODEL / "config.json").read_text())["run"]
    text = _train_base().architecture_text(run)
    assert text.startswith(f"the `base` preset (H = 96, 2 layers per decoder, feed-forward {run['model']['ffn']}")
    wide = dict(run, model=dict(run["model"], ffn=768))
    assert "feed-forward 768 (the preset: feed-forward 256)" in _train_base().architecture_text(wide)
    same = dict(run, model=dict(run["model"], ffn=256))
    assert "the preset:" not in _train_base().architecture_text(same)


def test_the_bundled_card_is_rendered_from_the_checkpoint_metadata():
    card = zoo.model_info(zoo.DEFAULT_MODEL).card
    folder = bundled_dir() / zoo.DEFAULT_MODEL
    again = card_from_checkpoint(folder, name=card.name, status="bundled", summary=card.summary,
                                 license_note=card.license_note, reproduce=card.reproduce)  # fmt: skip
    assert again.files == card.files  # sha256 and size of the files as they are
    assert (again.robots, again.training, again.metrics, again.checkpoint) == (card.robots, card.training, card.metrics, card.checkpoint)
    meta = json.loads((folder / "config.json").read_text())
    assert card.checkpoint["step"] == meta["step"] and card.training["steps"] == meta["step"]
    assert f"trained for {meta['step']} steps" in card.summary and f"this checkpoint: step {meta['step']}" in card.reproduce


def test_load_by_name_offline_with_no_hub_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    res = zoo.resolve(zoo.DEFAULT_MODEL)
    assert res.source == "bundled" and res.verified == "card" and res.folder == bundled_dir() / zoo.DEFAULT_MODEL
    ckpt = zoo.load(zoo.DEFAULT_MODEL)
    assert set(ckpt.targets) == set(BUILTIN_ROBOTS) and set(ckpt.references) == set(BUILTIN_ROBOTS)
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
    assert f"no --model: using the bundled model {zoo.DEFAULT_MODEL!r}" in err
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == (45, 7 + get_skeleton("tron1").num_dof) and np.array_equal(a, b)  # same model, same seed


@pytest.mark.parametrize("source, target", [("h1", "valkyrie"), ("h1_2", "tron1"), ("g1", "talos")])
def test_retarget_with_no_model_offline_between_builtin_robots(tmp_path, capsys, monkeypatch, source, target):
    """--method diffusion, no --model and no --allow-unseen: the default model saw every built-in robot (tron1: a biped
    with point feet). The command line reads CSVs of the robots with a LAFAN1 column layout (g1, h1,
    h1_2); the other sources are checked through the library below."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    src = synthetic_csv(tmp_path / f"{source}.csv", source, frames=40, seed=2)
    out = tmp_path / f"{target}.csv"
    assert main(["retarget", str(src), "--source", source, "--target", target, "-o", str(out), "--method", "diffusion"]) == 0, (
        capsys.readouterr().err)  # fmt: skip
    err = capsys.readouterr().err
    assert f"using the bundled model {zoo.DEFAULT_MODEL!r}" in err and "never trained" not in err
    a = np.loadtxt(out, delimiter=",")
    assert a.shape == (40, 7 + get_skeleton(target).num_dof) and np.isfinite(a).all()
    assert not (tmp_path / "empty-cache").exists()


@pytest.mark.parametrize("source, target", [("talos", "tron1"), ("tron1", "atlas"), ("valkyrie", "h1_2"), ("oli", "g1")])
def test_the_default_model_retargets_from_robots_without_a_csv_layout(monkeypatch, source, target):
    """Sources the command line cannot read from a CSV: their motion as features, through the library."""
    from mer_models.retarget.clip import retarget_features, source_features
    from mer_models.training.synthetic import synthetic_motion

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    ckpt = zoo.load(zoo.DEFAULT_MODEL)
    skel = get_skeleton(source)
    m = synthetic_motion(skel, 40, seed=4)
    feats = source_features(m["base_pos"], m["base_quat"], m["q"], skel, 30.0)
    res = retarget_features(feats, source, target, checkpoint=ckpt)  # no allow_unseen: both robots are the model's
    assert res.method == "diffusion" and res.motion.q.shape == (40, get_skeleton(target).num_nodes)
    assert np.isfinite(res.motion.q).all() and np.isfinite(res.motion.base_pos).all()


def test_the_library_still_needs_a_model_for_diffusion(tmp_path):
    """Only the command line falls back to the bundled model (and says so); the library never picks one."""
    from mer_data.base.errors import MerError
    from mer_models.retarget.clip import retarget_file

    with pytest.raises(MerError, match="--method optimize"):
        retarget_file(synthetic_csv(tmp_path / "w.csv", frames=10, seed=5), "g1", "h1", out_csv=tmp_path / "o.csv")
    assert not (tmp_path / "o.csv").exists()


def test_bundling_refuses_a_checkpoint_that_is_not_for_every_builtin_robot(tmp_path):
    """tools/train_base.py bundles only a checkpoint with all eight robots as targets and references,
    and touches nothing in the package when it refuses."""
    from mer_data.base.errors import PublishError

    tb = _train_base()
    before = {p.name: p.read_bytes() for p in (bundled_dir() / zoo.DEFAULT_MODEL).iterdir()}
    with pytest.raises(PublishError, match="not a mer-base checkpoint"):
        tb.bundle_step(make_checkpoint(tmp_path / "ck", targets=("g1", "h1"), references=("g1",)), None)
    with pytest.raises(PublishError, match="no checkpoint"):
        tb.bundle_step(tmp_path / "missing", None)
    every = tuple(BUILTIN_ROBOTS)  # every robot, but skeletons other than this checkout's (fingerprints "fp-<robot>")
    with pytest.raises(PublishError, match="other skeletons"):
        tb.bundle_step(make_checkpoint(tmp_path / "ck8", targets=every, references=every), None)
    assert {p.name: p.read_bytes() for p in (bundled_dir() / zoo.DEFAULT_MODEL).iterdir()} == before
    assert not any(p.name.startswith(".tmp-") for p in bundled_dir().iterdir())


def test_bundle_only_refuses_the_evaluation_of_another_run(tmp_path, monkeypatch):
    tb = _train_base()
    (tmp_path / tb.EVALUATION_FILE).write_text(json.dumps({"g1": {"model": str(tmp_path / "other-run"), "rows": []}}))
    monkeypatch.setattr(sys, "argv", ["train_base.py", "--work", str(tmp_path), "--bundle-only", "--run", str(tmp_path / "run")])
    with pytest.raises(SystemExit, match="not .*run: bundle that run"):
        tb.main()


def test_bundling_refuses_weights_not_trained_on_synthetic_motion(tmp_path):
    """A run for every built-in robot whose shards were built from motion files (LAFAN1's layout,
    here generated in code) is refused: only weights trained on synthetic motion may ship; so is a
    run whose shards cannot be opened to check. The package is left untouched."""
    from shard_helpers import build, make_input

    from mer_data.base.errors import PublishError

    tb = _train_base()
    before = {p.name: p.read_bytes() for p in (bundled_dir() / zoo.DEFAULT_MODEL).iterdir()}
    build(make_input(tmp_path / "in", robots=("g1",)), tmp_path / "shards", robots=("g1",), targets=("g1",), augment=0)
    every = tuple(BUILTIN_ROBOTS)
    ck = make_checkpoint(tmp_path / "ck", targets=every, references=every)
    meta = json.loads((ck / "config.json").read_text())
    for side in ("targets", "references"):
        meta["robots"][side] = {r: get_skeleton(r).fingerprint for r in every}
    meta["data"] = {"shards": [str(p) for p in sorted((tmp_path / "shards").glob("*.h5"))], "motion": "synthetic (a false claim)"}
    (ck / "config.json").write_text(json.dumps(meta))
    with pytest.raises(PublishError, match="not synthetic motion: its weights must not ship"):
        tb.bundle_step(ck, None)
    meta["data"]["shards"] = [str(tmp_path / "gone.h5")]
    (ck / "config.json").write_text(json.dumps(meta))
    with pytest.raises(PublishError, match="not readable"):
        tb.bundle_step(ck, None)
    assert {p.name: p.read_bytes() for p in (bundled_dir() / zoo.DEFAULT_MODEL).iterdir()} == before
