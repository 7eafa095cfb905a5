"""The short card (``mer zoo info`` without --verbose, ``mer demo``) and model-name suggestions (issue 40, items 6, 8)."""

from __future__ import annotations

import pytest

from mer_data.base.errors import ModelZooError, UnknownModelError
from mer_models.hub.brief import brief_lines, first_sentence, headline_accuracy
from mer_models.hub.card import FileRecord, ModelCard
from mer_models.hub.registry import Registry
from mer_models.hub.resolve import resolve

C = "0123456789abcdef0123456789abcdef01234567"


def _card(**kw) -> ModelCard:
    base = dict(name="my-model", status="published", summary="A small model. Trained for a long time, with a history.",
                license="apache-2.0", repo_id="lab/my-model", revision=C, files={"config.json": FileRecord("1" * 64, 10)},
                robots={"targets": ["g1", "h1"], "references": ["g1"]}, training={"history": "run K " * 200})  # fmt: skip
    base.update(kw)
    return ModelCard(**base)


def test_first_sentence_stops_at_the_first_full_stop_and_at_a_word():
    assert first_sentence("A model. Trained on X.") == "A model."
    assert first_sentence("Uses `mer retarget`, offline. `mer demo` too.") == "Uses `mer retarget`, offline."
    long = first_sentence("word " * 100, limit=40)
    assert len(long) <= 42 and long.endswith(" …") and "  " not in long


def test_headline_accuracy_pools_sources_and_puts_the_best_method_first():
    metrics = {"evaluation (mer evaluate)": {
        "data": "LAFAN1, every clip",
        "source g1, model alone": {"g1": {"E_g-mpbpe [m]": "0.04"}, "h1": {"E_g-mpbpe [m]": "0.06"}},
        "source h1, model alone": {"g1": {"E_g-mpbpe [m]": "0.05"}},
        "source g1, optimiser": {"g1": {"E_g-mpbpe [m]": 0.01, "frames/s": 500}},
        "windows per robot": 32,
    }, "train": {"loss": 0.4}}  # fmt: skip
    rows = headline_accuracy(metrics)
    assert [m for m, _ in rows] == ["optimiser", "model alone"]
    assert rows[1][1] == "median 0.05 m (0.04-0.06 m, 3 source-target pairs)"
    assert rows[0][1] == "median 0.01 m (1 source-target pair)"
    paper = headline_accuracy({"paper, Table II": {"in-domain": {"g1": {"E_g-mpbpe [m]": "0.0071 ± 0.0038"}}}})
    assert paper == [("in-domain", "median 0.0071 m (1 robot)")]


def test_brief_is_a_few_lines_without_history_or_empty_repo():
    lines = brief_lines(_card())
    text = "\n".join(lines)
    assert lines[0] == "A small model." and "run K" not in text and "history" not in text
    assert "robots:   from g1 to g1, h1" in text and "Hub:      lab/my-model @ 0123456789ab" in text
    assert "accuracy: not measured yet" in text
    unpublished = "\n".join(brief_lines(_card(status="unpublished", repo_id="lab/x", revision=None, files={})))
    assert "@" not in unpublished and "not published yet" in unpublished and "--verbose" in unpublished


@pytest.mark.parametrize("name", ["mer-base", "mer-paper", "mer-paper-talos"])
def test_catalogue_cards_are_short(name):
    card = Registry().get(name).card
    text = "\n".join(brief_lines(card))
    assert len(text) < 700 and len(brief_lines(card)) <= 8, text
    assert "accuracy:" in text and "E_g-mpbpe" in text and "function-preservingly" not in text and "issue 11" not in text


def test_the_bundled_model_says_its_measured_accuracy():
    text = "\n".join(brief_lines(Registry().get("mer-base").card))
    assert "model alone" in text and "model + 5 optimiser iterations" in text and "16 source-target pairs" in text
    assert text.index("model + 5 optimiser iterations") < text.index("model alone")  # best first


def test_an_unknown_model_name_suggests_the_closest():
    with pytest.raises(UnknownModelError) as info:
        resolve("mer-bse")
    assert "did you mean 'mer-base'?" in str(info.value) and "known models: mer-base" in str(info.value)
    with pytest.raises(ModelZooError, match="did you mean 'mer-base'"):
        resolve("Mer-Base")  # names are lower-case
    with pytest.raises(UnknownModelError) as info:
        resolve("no-such-model")
    assert "did you mean" not in str(info.value) and "known models:" in str(info.value)
