"""The default path, as every doc, card and help text names it (issue 52, item 1): ``mer retarget``
without a model option runs the optimiser, not ``mer-base``; a model option that cannot apply to the
input is refused with the reason, never dropped."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from bvh_factory import BANDAI_NAMES, human_definition, smooth_motion, write_bvh
from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)

from mer_models.cli import build_parser, main

REPO = Path(__file__).resolve().parents[3]
# "without --model" / "no --model" said of mer retarget means the optimiser unless --method diffusion is named too
NO_MODEL = re.compile(r"(without|no)\s+`?--model`?", re.IGNORECASE)
# "`mer retarget` ... uses mer-base" / "mer retarget ... the bundled mer-base" in one breath
RETARGET_USES_MODEL = re.compile(r"mer retarget`?[^.\n]{0,60}?(uses?|runs?|:)\s+(it|the bundled\s+(model\s+)?`?mer-base|`?mer-base)")


def _texts() -> dict[str, str]:
    files = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), *sorted((REPO / "cards").rglob("*.md")),
             *sorted((REPO / "mer_models" / "cards").glob("*.md")), *sorted((REPO / "mer_models" / "templates").glob("*"))]
    texts = {str(p.relative_to(REPO)): p.read_text(encoding="utf-8") for p in files if p.is_file()}
    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "retarget" in a.choices)  # each command's own --help
    for name, p in sub.choices.items():
        texts[f"mer {name} --help"] = p.format_help()
    return texts


def _claims(text: str) -> list[str]:
    flat = re.sub(r"\s+", " ", text)
    bad = []
    for m in NO_MODEL.finditer(flat):
        around = flat[max(0, m.start() - 120): m.end() + 40]
        if "mer retarget" in around and "--method diffusion" not in around and "optimi" not in around:
            bad.append(around)
    for m in RETARGET_USES_MODEL.finditer(flat):
        around = flat[max(0, m.start() - 20): m.end() + 60]
        if "--method diffusion" not in around and "--model" not in around:
            bad.append(around)
    return bad


def test_the_grep_finds_the_old_claims():
    """The claims issue 52 found, as they were written: each is caught."""
    for old in ("the bundled default model, `mer-base` (what `mer retarget`\nwithout `--model` and `mer demo` use)",
                "mer retarget walk1_subject1.csv --source g1 --target h1 -o h1.csv    # no --model: the bundled mer-base",
                "mer's default model, bundled with the package: `mer retarget` without `--model` and `mer demo` use it, offline.",
                "`mer retarget` uses mer-base by default"):  # fmt: skip
        assert _claims(old), old
    assert not _claims("`mer demo` and `mer retarget --method diffusion` without `--model` use it")


def test_no_doc_card_or_help_text_says_the_default_path_is_a_model(capsys):
    texts = _texts()
    assert main(["zoo", "info", "mer-base"]) == 0
    texts["mer zoo info mer-base"] = capsys.readouterr().out
    assert "mer retarget --method diffusion" in texts["mer zoo info mer-base"]
    bad = {name: c for name, t in texts.items() if (c := _claims(t))}
    assert not bad, bad
    assert len(texts) > 20  # the docs, the cards and every command's help were read


def _bvh(tmp_path) -> Path:
    rng = np.random.default_rng(0)
    clip = tmp_path / "in" / "bvh" / "walk.bvh"
    clip.parent.mkdir(parents=True)
    clip.write_text(write_bvh(smooth_motion(human_definition(rng, 20, BANDAI_NAMES, angle=10.0, yaw=20.0), rng), six=True))
    return clip


@pytest.mark.parametrize("extra", [["--model", "mer-base"], ["--refine", "5"], ["--method", "diffusion"], ["--bf16"]])
def test_a_model_option_on_a_human_source_is_refused_with_the_reason(tmp_path, capsys, extra):
    clip = _bvh(tmp_path)
    out = tmp_path / "h1.csv"
    assert main(["retarget", str(clip), "--target", "h1", "-o", str(out), "--quiet", *extra]) == 1
    err = capsys.readouterr().err
    assert "a model cannot retarget a human source (BVH" in err and "optimiser" in err and not out.exists()
    assert main(["retarget", "--input", str(clip.parent.parent), "--source", "bvh", "--targets", "h1", "--out", str(tmp_path / "ds"),
                 "--quiet", *extra]) == 1  # fmt: skip
    assert "a model cannot retarget a human source (BVH" in capsys.readouterr().err and not (tmp_path / "ds").exists()


def test_a_model_option_with_the_optimiser_is_refused(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=20)
    for extra in (["--model", "mer-base"], ["--steps", "2"], ["--guidance", "0.1"]):
        assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize", "-o", str(tmp_path / "o.csv"),
                     *extra]) == 1  # fmt: skip
        assert f"{' '.join(extra)}: --method optimize runs no model" in capsys.readouterr().err


def test_a_dataset_run_with_model_runs_the_model(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    """Before issue 52 a dataset run dropped --model without --method and ran the optimiser."""
    synthetic_csv(tmp_path / "in" / "g1" / "walk.csv", frames=30)
    assert main(["retarget", "--input", str(tmp_path / "in"), "--source", "g1", "--targets", "h1", "--out", str(tmp_path / "ds"),
                 "--model", str(micro_checkpoint), "--steps", "1", "--quiet", "--json"]) == 0  # fmt: skip
    assert '"method": "diffusion"' in capsys.readouterr().out
