"""``datasets.load_dataset("hdf5", ...)`` reads our HDF5 shards (documented in docs/shards.md)."""

from __future__ import annotations

import numpy as np
import pytest
from shard_helpers import build, make_input

from mer_data.shards import open_shard

datasets = pytest.importorskip("datasets")

CLIPS = {"dance1_subject1": (3.0, 0.0, 0.1), "fallAndGetUp1_subject1": (2.5, 1.0, -0.2), "fight1_subject2": (2.2, 2.0, 0.3),
         "walk1_subject1": (4.0, 0.5, 0.0)}  # fmt: skip


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    o = tmp_path_factory.mktemp("out")
    build(make_input(tmp_path_factory.mktemp("in"), clips=CLIPS), o)
    return o


@pytest.mark.parametrize("split", ["train", "eval"])
def test_load_dataset_hdf5_gives_one_row_per_window(out, tmp_path, split):
    ds = datasets.load_dataset("hdf5", data_files={split: str(out / f"g1-{split}-*.h5")}, cache_dir=str(tmp_path / "hf"))[split]
    shard = open_shard(next(out.glob(f"g1-{split}-*.h5")))
    assert ds.num_rows == shard.num_rows > 0
    assert set(ds.column_names) == {"pos", "q", "base_rotvec", "origin_xy", "robot", "clip", "start_frame", "source_sha256",
                                    "sample_target", "sample_variant", "link_scales", "dropped"}  # fmt: skip
    rows = ds.with_format("numpy")
    for i in (0, shard.num_rows - 1):
        r = rows[i]
        assert r["pos"].tobytes() == shard.row("pos", i).tobytes()
        assert r["q"].tobytes() == shard.row("q", i).tobytes()
        assert r["clip"] == shard.row("clip", i) and int(r["start_frame"]) == int(shard.row("start_frame", i))
        assert np.array_equal(r["link_scales"], shard.row("link_scales", i))
    assert ds.features["pos"].shape == (60, 34, 3)


def test_card_declares_a_config_per_robot_and_split(out, tmp_path):
    from huggingface_hub import DatasetCard

    data = DatasetCard.load(out / "README.md").data  # the client's own parser
    assert {"config_name": "h1_eval", "data_files": [{"split": "eval", "path": "h1-eval-*.h5"}]} in data.configs
    assert data.task_categories == ["robotics"] and data.license == "cc-by-nc-nd-4.0" and "mer" in data.tags
    ds = datasets.load_dataset(str(out), "h1_eval", cache_dir=str(tmp_path / "hf"))
    assert ds["eval"].num_rows == open_shard(next(out.glob("h1-eval-*.h5"))).num_rows
