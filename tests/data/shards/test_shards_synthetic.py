"""``mer shards build --synthetic N``: shards of synthetic motion, for robots with or without a LAFAN1 layout."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mer_data.shards import BuildConfig, ShardDataset, open_shard
from mer_models.cli import main


def _build(out, *extra):
    return main(["shards", "build", "--synthetic", "2", "--synthetic-seconds", "4", "--robots", "g1", "atlas",
                 "--targets", "g1", "atlas", "--augment", "1", "--workers", "1", "--quiet", "--out", str(out), *extra])  # fmt: skip


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("synthetic")
    assert _build(out) == 0
    return out


def test_synthetic_shards_load_with_shard_dataset(built, capsys):
    ds = ShardDataset(built, split="train")
    assert {w.robot for w in ds.windows} == {"g1", "atlas"}  # atlas has no LAFAN1 layout: shards hold it anyway
    assert {w.clip for w in ds.windows} == {"synthetic-g1-00000", "synthetic-g1-00001", "synthetic-atlas-00000", "synthetic-atlas-00001"}
    clips = ds.clips()
    assert all(len(ws) == 3 for ws in clips.values())  # 121 frames: windows at 0, 60 and 61
    s = ds.sample(next(w for w in ds.windows if w.robot == "atlas"), "g1")
    assert s.reference.shape == (60, 33, 9) and np.all(np.isfinite(s.reference))
    assert s.target is None  # another robot's synthetic clip of the same name would be another motion
    shard = open_shard(built / "atlas-train-00000-of-00001.h5")
    cfg = shard.meta.config
    assert cfg["synthetic"] == 2 and cfg["synthetic_seconds"] == 4 and cfg["split"] == "all"
    assert all(src["status"] == "ok" and src["file"].startswith("synthetic:atlas/") for src in shard.meta.sources)
    card = (built / "README.md").read_text()
    assert "license: apache-2.0" in card and "--synthetic 2 --synthetic-seconds 4" in card and "LAFAN1 (Ubisoft" not in card


def test_rebuild_is_up_to_date_and_same_seed_same_sources(built, tmp_path, capsys):
    assert _build(built) == 0
    assert "0 built, 2 up to date" in capsys.readouterr().out
    other = tmp_path / "again"
    assert _build(other) == 0
    sha = lambda d: [s["sha256"] for s in open_shard(d / "g1-train-00000-of-00001.h5").meta.sources]  # noqa: E731
    assert sha(built) == sha(other)
    assert _build(tmp_path / "seed1", "--synthetic-seed", "1") == 0
    assert sha(tmp_path / "seed1") != sha(built)


def test_input_and_synthetic_are_exclusive_and_file_builds_keep_their_config(tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["shards", "build", "--input", str(tmp_path), "--synthetic", "2", "--robots", "g1", "--out", str(tmp_path / "o")])
    assert e.value.code == 2
    assert main(["shards", "build", "--synthetic", "0", "--robots", "g1", "--out", str(tmp_path / "o")]) == 2
    d = BuildConfig(input="x", robots=("g1",)).to_dict()
    assert not any(k.startswith("synthetic") for k in d)  # build ids of LAFAN1 builds are unchanged
    assert json.loads(json.dumps(BuildConfig(input="synthetic", robots=("g1",), synthetic=3).to_dict()))["synthetic"] == 3
