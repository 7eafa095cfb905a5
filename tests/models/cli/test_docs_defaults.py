"""Defaults the docs state, as a fresh install runs them (issue 40, item 9): ``mer shards build``
trains on every clip unless ``--split paper``; ``ShardDataset(split=...)`` counts its own split;
``--allow-unseen`` says the result is zero-shot."""

from __future__ import annotations

from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)
from shard_helpers import make_input

from mer_data.shards import ShardDataset, open_shard
from mer_models.cli import main

CLIPS = {"dance1_subject1": (2.5, 0.0, 0.1), "fallAndGetUp1_subject1": (2.2, 1.0, -0.2), "fight1_subject2": (2.1, 2.0, 0.3),
         "walk1_subject1": (2.4, 0.5, 0.0)}  # fmt: skip


def _build(inp, out, *extra):
    return main(["shards", "build", "--input", str(inp), "--robots", "g1", "--targets", "g1", "h1", "--out", str(out), "--augment", "0",
                 "--workers", "1", "--quiet", *extra])  # fmt: skip


def test_shards_build_trains_on_every_clip_unless_the_paper_split_is_asked_for(tmp_path, capsys):
    inp = make_input(tmp_path / "in", robots=("g1",), clips=CLIPS)
    assert _build(inp, tmp_path / "all") == 0
    assert "split all: every clip trains (--split paper:" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "all").glob("*.h5")) == ["g1-train-00000-of-00001.h5"]
    assert {s["clip"] for s in open_shard(tmp_path / "all" / "g1-train-00000-of-00001.h5").meta.sources} == set(CLIPS)
    assert _build(inp, tmp_path / "paper", "--split", "paper") == 0
    assert "split paper: the paper's 3 training clips per robot" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "paper").glob("*.h5")) == [f"g1-{s}-00000-of-00001.h5" for s in ("eval", "train")]

    train, every = ShardDataset(tmp_path / "paper", split="train"), ShardDataset(tmp_path / "paper")
    rows = {s: open_shard(tmp_path / "paper" / f"g1-{s}-00000-of-00001.h5").num_rows for s in ("train", "eval")}
    assert rows["train"] > 0 and rows["eval"] > 0
    assert f"1 of 2 files, {rows['train']} train windows, {len(train)} samples" in repr(train)
    assert f"2 of 2 files, {rows['train'] + rows['eval']} windows, {len(every)} samples" in repr(every)


def test_allow_unseen_on_one_file_says_the_result_is_zero_shot(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    src = synthetic_csv(tmp_path / "walk.csv", frames=40)
    argv = ["retarget", str(src), "--source", "g1", "--target", "atlas", "--model", str(micro_checkpoint), "--steps", "1",
            "-o", str(tmp_path / "atlas.csv")]  # fmt: skip
    assert main(argv) == 1  # the micro model never saw atlas: refused ...
    err = capsys.readouterr().err
    assert "never trained with 'atlas'" in err and "retarget zero-shot with --allow-unseen" in err  # the fix names the flag
    assert main([*argv, "--allow-unseen"]) == 0  # ... and retargeted zero-shot when asked, with a notice
    err = capsys.readouterr().err
    assert "zero-shot: the model never saw 'atlas' as a target" in err and "--method optimize" in err
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(micro_checkpoint), "--steps", "1",
                 "-o", str(tmp_path / "h1.csv"), "--allow-unseen"]) == 0  # fmt: skip
    assert "zero-shot" not in capsys.readouterr().err  # a robot it saw: no notice
