"""Shards from human motion capture: a folder of BVH files becomes windows whose reference is the
dataset's one human skeleton, read back by ShardDataset with joint maps to every target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bvh_factory import BANDAI_NAMES, human_definition, smooth_motion, write_bvh

from mer_data.base.errors import MerError
from mer_data.shards import BuildConfig, ShardDataset, build_shards


def _folder(tmp_path: Path, clips: int = 2, frames: int = 80) -> Path:
    d = tmp_path / "in" / "bvh"
    d.mkdir(parents=True)
    for k in range(clips):
        rng = np.random.default_rng(k)
        (d / f"clip{k}.bvh").write_text(write_bvh(smooth_motion(human_definition(rng, frames, BANDAI_NAMES, angle=10.0), rng),
                                                  six=True))  # fmt: skip
    return tmp_path / "in"


def test_a_bvh_folder_builds_shards_with_the_human_as_reference(tmp_path):
    report = build_shards(BuildConfig(input=str(_folder(tmp_path)), robots=("bvh",), targets=("g1", "h1"), split="all", augment=1),
                          tmp_path / "out")  # fmt: skip
    assert report.windows >= 2  # 60-frame windows of both 80-frame clips
    ds = ShardDataset(tmp_path / "out")
    samples = [ds[i] for i in range(len(ds))]
    assert {s.reference_skeleton.name for s in samples} == {"bvh"}
    assert {s.target_skeleton.name for s in samples} == {"g1", "h1"}
    human = samples[0].reference_skeleton
    assert set(human.keypoints) >= {"left_hip", "right_ankle", "left_hand"} and all(v >= 0 for v in human.keypoints.values())
    for s in samples:
        assert s.reference.shape == (60, human.num_nodes, 9) and np.isfinite(s.reference).all()
        if not s.provenance["augmented"]:  # augmented variants drop some correspondences on purpose
            assert s.joint_map.sum() >= 12  # hips, knees, ankles, toes, shoulders, elbows, hands (+ base)


def test_bvh_is_built_alone_and_from_a_folder(tmp_path):
    with pytest.raises(MerError, match="--robots bvh alone"):
        build_shards(BuildConfig(input=str(_folder(tmp_path)), robots=("bvh", "g1"), targets=("g1",), split="all"), tmp_path / "o")
    with pytest.raises(MerError, match="no BVH files"):
        build_shards(BuildConfig(input=str(tmp_path), robots=("bvh",), targets=("g1",), split="all"), tmp_path / "o2")


def test_the_bandai_folder_builds(bandai, tmp_path):
    src = bandai[0].parent
    d = tmp_path / "in"
    d.mkdir()
    for name in ("dataset-1_walk_normal_001", "dataset-1_kick_normal_001"):
        (d / f"{name}.bvh").symlink_to(src / f"{name}.bvh")
    with pytest.raises(MerError, match="no BVH files"):  # links are not followed
        build_shards(BuildConfig(input=str(d), robots=("bvh",), targets=("g1",), split="all"), tmp_path / "o0")
    for p in list(d.iterdir()):
        target = p.resolve()
        p.unlink()
        p.write_bytes(target.read_bytes())
    build_shards(BuildConfig(input=str(d), robots=("bvh",), targets=("g1", "h1"), split="all", augment=0), tmp_path / "out")
    ds = ShardDataset(tmp_path / "out")
    assert len(ds) > 0 and ds[0].reference_skeleton.name == "bvh" and np.isfinite(ds[0].reference).all()
