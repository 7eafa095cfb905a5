"""Model cards: parsing, rendering, the committed catalogue, and the validation of names and paths."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml
from zoo_helpers import make_checkpoint

from mer_data.base.errors import ModelZooError, PublishError
from mer_models.hub.card import FileRecord, ModelCard, PastRevision, parse_card, read_card
from mer_models.hub.catalogue import CATALOGUE, planned_card
from mer_models.hub.fromckpt import card_from_checkpoint, infer_dataset
from mer_models.hub.names import validate_filename, validate_model_name, validate_repo_id, validate_revision
from mer_models.hub.registry import packaged_cards_dir, source_cards_dir
from mer_models.hub.render import render_card

REPO = Path(__file__).resolve().parents[3]
C1, C2 = "a" * 40, "0123456789abcdef0123456789abcdef01234567"


def _card(**kw) -> ModelCard:
    base = dict(name="my-model", status="published", summary="s", license="apache-2.0", repo_id="lab/my-model",
                revision=C2, published="2026-01-02", files={"config.json": FileRecord("1" * 64, 10), "model.safetensors": FileRecord("2" * 64, 20)},
                history=(PastRevision(C1, {"config.json": FileRecord("3" * 64, 9), "model.safetensors": FileRecord("4" * 64, 19)}, "2026-01-01"),),
                robots={"targets": ["g1", "h1"], "references": ["g1"]}, training={"dataset": "synthetic", "steps": 4},
                metrics={"eval": {"split": "held-out", "per_robot": {"g1": {"E_g-mpbpe [m]": 0.01}, "h1": {"E_g-mpbpe [m]": 0.02}}}},
                reproduce="mer train --config tiny\nmer zoo publish X")
    base.update(kw)
    return ModelCard(**base)


def test_render_then_parse_is_the_identity_and_rendering_is_a_fixed_point():
    card = _card()
    text = render_card(card)
    back = parse_card(text)
    assert dataclasses.replace(back, path=None) == card
    assert render_card(back) == text
    assert back.files_for(C1)["model.safetensors"].sha256 == "4" * 64
    assert back.files_for(None) == back.files_for(C2) == card.files
    assert back.files_for("b" * 40) is None
    assert "| g1 | 0.01 |" in text and "`" + C2 + "`" in text


def test_committed_cards_are_exactly_what_the_code_renders():
    """No card is edited by hand: each committed card equals its own re-rendering, and every
    unpublished catalogue card equals the catalogue's rendering."""
    src = source_cards_dir()
    assert src == REPO / "cards" / "models"
    planned = {p.name: p for p in CATALOGUE}
    for path in sorted(src.glob("*.md")):
        card = read_card(path)
        assert render_card(card) == path.read_text(encoding="utf-8"), f"{path} differs from its rendering"
        if card.status == "unpublished":
            assert render_card(planned_card(planned[card.name])) == path.read_text(encoding="utf-8")
    assert set(planned) <= {p.stem for p in src.glob("*.md")}


def test_packaged_cards_equal_the_repository_cards():
    src = sorted(p.name for p in (REPO / "cards" / "models").glob("*.md"))
    pkg = sorted(p.name for p in packaged_cards_dir().glob("*.md"))
    assert src == pkg, "run `python tools/render_catalogue.py --sync`"
    for name in src:
        assert (REPO / "cards" / "models" / name).read_bytes() == (packaged_cards_dir() / name).read_bytes(), \
            f"{name}: run `python tools/render_catalogue.py --sync`"


def test_catalogue_cards_say_the_weights_are_not_published_and_are_non_commercial():
    names = {p.name for p in CATALOGUE}
    assert {"mer-paper", "mer-paper-talos", "mer-paper-valkyrie"} <= names
    for p in CATALOGUE:
        card = read_card(REPO / "cards" / "models" / f"{p.name}.md")
        text = card.path.read_text()
        if card.status == "unpublished":
            assert "Weights not yet published" in text and card.revision is None and not card.files
        assert card.license == "cc-by-nc-nd-4.0" and "non-commercial" in card.license_note
        assert card.training["dataset"] == "lafan1"
    base = read_card(REPO / "cards" / "models" / "mer-paper.md")
    assert base.targets == ["g1", "h1", "atlas", "oli", "tron1"] and base.robots["references"] == ["g1", "h1"]
    for robot in ("talos", "valkyrie"):
        ft = read_card(REPO / "cards" / "models" / f"mer-paper-{robot}.md")
        assert ft.base_model == "mer-paper" and robot in ft.targets and robot not in base.targets
        assert f"mer finetune --base mer-paper --robot {robot}" in ft.reproduce


@pytest.mark.parametrize("edit, message", [
    (lambda m: m["mer"].update(revision="main"), "40-hex"),
    (lambda m: m["mer"]["files"].update({"../../evil.json": {"sha256": "1" * 64, "size": 1}}), "invalid file name"),
    (lambda m: m["mer"]["files"].update({"model.bin": {"sha256": "1" * 64, "size": 1}}), "only data files"),
    (lambda m: m["mer"]["files"]["config.json"].update(sha256="XYZ"), "sha256"),
    (lambda m: m["mer"].update(name="../x"), "invalid model name"),
    (lambda m: m["mer"].update(repo_id="a/../b"), "invalid Hub repo id"),
    (lambda m: m["mer"].update(status="maybe"), "status"),
    (lambda m: m["mer"].update(card_version=99), "card_version"),
    (lambda m: m.pop("license"), "licence"),
    (lambda m: m["mer"].update(files={}), "published card needs"),
])
def test_a_bad_card_is_refused_with_the_element_named(edit, message):
    text = render_card(_card())
    meta = yaml.safe_load(text.split("---\n")[1])
    edit(meta)
    bad = "---\n" + yaml.safe_dump(meta, sort_keys=False) + "---\n# body\n"
    with pytest.raises(ModelZooError, match=message.replace("(", r"\(")):
        parse_card(bad, "bad.md")


def test_a_card_cannot_smuggle_python_objects():
    text = "---\nlicense: mit\nmer: !!python/object/apply:os.system ['echo pwned']\n---\n"
    with pytest.raises(ModelZooError, match="invalid YAML"):
        parse_card(text)


@pytest.mark.parametrize("name", ["mer-paper", "a", "x1.2_b-c", "m" * 64])
def test_valid_names(name):
    assert validate_model_name(name) == name


@pytest.mark.parametrize("name", ["", "..", "../x", "a/b", "A", "-a", "a.", "a..b", ".hidden", "m" * 65, "a b", "a\\b"])
def test_invalid_names(name):
    with pytest.raises(ModelZooError):
        validate_model_name(name)


@pytest.mark.parametrize("rev", ["main", "v1.0", "refs/pr/1", "release/2026-01", C2])
def test_valid_revisions(rev):
    assert validate_revision(rev) == rev


@pytest.mark.parametrize("rev", ["", "../x", "a/../b", "/abs", "a//b", "x.lock", ".hidden", "a/", C2.upper(), "a b", "a\\b",
                                 "refs/heads/..", "~", "r" * 200])
def test_invalid_revisions_cannot_leave_the_cache(rev):
    with pytest.raises(ModelZooError, match="revision"):
        validate_revision(rev)


@pytest.mark.parametrize("repo", ["lab/x", "Lab-1/x.y_z", "a/b"])
def test_valid_repo_ids(repo):
    assert validate_repo_id(repo) == repo


@pytest.mark.parametrize("repo", ["x", "a/b/c", "../b", "a/..", "a--b/c", "a/b.git", "/b", "a/", "a/b c"])
def test_invalid_repo_ids(repo):
    with pytest.raises(ModelZooError):
        validate_repo_id(repo)


@pytest.mark.parametrize("fname", ["model.bin", "pytorch_model.pt", "x.pkl", "code.py", "model.ckpt", "/etc/passwd.json",
                                   "../config.json", "a/../config.json", "a\\b.json"])
def test_only_plain_data_files_are_ever_fetched(fname):
    with pytest.raises(ModelZooError):
        validate_filename(fname)


def test_licence_follows_the_training_data(tmp_path):
    assert infer_dataset({"shards": ["/data/lafan1/train-00.h5"], "note": "synthetic warmup"}) == "lafan1"
    assert infer_dataset({"dataset": "synthetic"}) == "synthetic"
    assert infer_dataset({"shards": ["/data/mocap.h5"]}) is None
    nc = card_from_checkpoint(make_checkpoint(tmp_path / "a", dataset="lafan1 g1+h1"), name="a", status="unpublished")
    assert nc.license == "cc-by-nc-nd-4.0" and "non-commercial" in nc.license_note
    ok = card_from_checkpoint(make_checkpoint(tmp_path / "b"), name="b", status="unpublished")
    assert ok.license == "apache-2.0"
    unknown = make_checkpoint(tmp_path / "c", dataset="my own mocap")
    with pytest.raises(PublishError, match="--license"):
        card_from_checkpoint(unknown, name="c", status="unpublished")
    assert card_from_checkpoint(unknown, name="c", status="unpublished", license="cc-by-4.0").license == "cc-by-4.0"


def test_card_from_checkpoint_records_its_metadata(tmp_path):
    ck = make_checkpoint(tmp_path / "ck", targets=("h1", "g1", "talos"), step=12)
    base = _card(name="base-model")
    card = card_from_checkpoint(ck, name="ft", status="unpublished", base=base)
    assert card.robots == {"targets": ["g1", "h1", "talos"], "references": ["g1"]}
    assert card.checkpoint == {"format": "mer-checkpoint", "format_version": 1, "mer_version": "0.1.0", "step": 12, "config": "tiny"}
    assert card.training["steps"] == 12 and card.training["dataset"] == "synthetic"
    assert card.base_model == "base-model" and card.base_revision == C2 and card.base_repo_id == "lab/my-model"
    assert "talos" in card.summary
    assert card.files["model.safetensors"].size == (ck / "model.safetensors").stat().st_size
    assert "optimizer.safetensors" not in card.files


# ---- Hub conventions: the metadata as huggingface_hub and the Hub read it ----------------------------------------

def test_card_metadata_parses_with_huggingface_hubs_own_parser_and_passes_the_hub_checks():
    from hub_server import validate_metadata
    from huggingface_hub import ModelCard as HubModelCard
    from huggingface_hub.repocard import metadata_load

    from mer_data.shards.sources import LAFAN1_REPO

    for path in sorted((REPO / "cards" / "models").glob("*.md")):
        meta = metadata_load(path)
        card = read_card(path)
        assert meta["pipeline_tag"] == "robotics" and meta["library_name"] == "mer" and meta["license"] == card.license
        assert meta["tags"][0] == "robotics" and meta["mer"] == card.to_meta()  # mer's own block kept whole
        assert meta.get("datasets") == ([LAFAN1_REPO] if card.training.get("dataset") == "lafan1" else None)
        assert validate_metadata(meta, "model") == [], path
        hub_card = HubModelCard.load(path)
        assert hub_card.data.pipeline_tag == "robotics"
        assert str(hub_card) == path.read_text(encoding="utf-8")  # the client rewrites it unchanged
    for robot in ("talos", "valkyrie"):  # fine-tunes name their base the Hub's way: a top-level repo id
        meta = metadata_load(REPO / "cards" / "models" / f"mer-paper-{robot}.md")
        assert meta["base_model"] == "mer-robotics/mer-paper" and meta["mer"]["base_model"] == "mer-paper"
    assert "base_model" not in metadata_load(REPO / "cards" / "models" / "mer-paper.md")


def test_the_hub_checks_can_fail():
    from hub_server import validate_metadata

    meta = dict(yaml.safe_load(render_card(_card()).split("---\n")[1]))
    assert validate_metadata(meta, "model") == []
    assert validate_metadata({**meta, "license": "cc-by-nc-nd"}, "model")
    assert validate_metadata({**meta, "pipeline_tag": "retargeting"}, "model")
    assert validate_metadata({**meta, "base_model": "mer-paper"}, "model")  # a zoo name is not a repo id
    assert validate_metadata({**meta, "tags": "robotics"}, "model")


def test_dataset_cards_parse_with_huggingface_hubs_own_parser_and_pass_the_hub_checks():
    from hub_server import validate_metadata
    from huggingface_hub import DatasetCard

    for path in sorted((REPO / "cards" / "datasets").glob("*.md")):
        card = DatasetCard.load(path)
        data = card.data.to_dict()
        assert data["task_categories"] == ["robotics"] and data["license"] == "cc-by-nc-nd-4.0" and "mer" in data["tags"]
        assert all(c["config_name"].endswith(("_train", "_eval")) for c in data["configs"])
        assert validate_metadata(data, "dataset") == [], path
        assert str(card) == path.read_text(encoding="utf-8")
