"""``ShardDataset``: the samples, their targets and augmentations, filters, metadata, DataLoader."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from shard_helpers import CLIPS, build, make_input

from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import collate
from mer_data.motion.windows import window_starts
from mer_data.robots.registry import get_skeleton
from mer_data.shards import ShardDataset, open_shard
from mer_data.skeleton import KEYPOINTS


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    inp = make_input(tmp_path_factory.mktemp("in"))
    o = tmp_path_factory.mktemp("out")
    build(inp, o, augment=3, seed=5)
    return o


def test_sample_count_and_layout(out):
    ds = ShardDataset(out)
    n = 0
    for p in sorted(out.glob("*.h5")):
        m = open_shard(p).meta
        n += m.num_rows * len(m.targets) * m.variants
    assert len(ds) == n
    assert ds.robots == ["g1", "h1"] and ds.targets == sorted(["g1", "h1", "oli", "tron1", "atlas", "talos", "valkyrie"])
    s = ds[len(ds) - 1]
    assert s.reference.shape == (60, s.reference_skeleton.num_nodes, 9) and s.reference.dtype == np.float32
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_targets_are_filled_from_the_other_robots_windows(out):
    ds = ShardDataset(out)
    for w in ds.windows[::5]:
        other = "h1" if w.robot == "g1" else "g1"
        s = ds.sample(w, other)
        tw = ds.find_window(other, w.clip, w.start_frame)
        assert s.target is not None and s.target.tobytes() == ds.window_features(tw).tobytes()
        assert ds.sample(w, w.robot).target.tobytes() == s.reference.tobytes()  # self-retargeting: the window itself
        assert ds.sample(w, "oli").target is None  # no Oli data
        if w.split == "train":
            assert ds.sample(w, other, 1).target is None  # augmented: no ground truth


def test_evaluation_samples_use_the_urdf_skeletons(out):
    ev = ShardDataset(out, split="eval")
    assert len(ev) == sum(len(w) for (r, c), w in ev.clips(split="eval").items()) * 7
    for i in range(0, len(ev), 17):
        s = ev[i]
        assert s.provenance["split"] == "eval" and s.provenance["variant"] == 0
        assert s.target_skeleton == get_skeleton(s.target_skeleton.name)
        assert np.array_equal(s.joint_map, joint_map(s.target_skeleton, s.reference_skeleton))


def test_augmented_samples_carry_their_stored_scales_and_drops(out):
    ds = ShardDataset(out, split="train")
    drops = 0
    for i in range(len(ds)):
        w, k = ds.locate(i)
        s = ds[i]
        urdf = get_skeleton(s.provenance["target"])
        if s.provenance["variant"] == 0:
            assert s.target_skeleton == urdf
            continue
        ratio = np.linalg.norm(s.target_skeleton.offsets, axis=1)[1:] / np.maximum(urdf.link_lengths[1:], 1e-12)
        ratio = ratio[urdf.link_lengths[1:] > 1e-6]
        assert ratio.min() >= 0.5 - 1e-6 and ratio.max() <= 2.0 + 1e-6 and not np.allclose(ratio, 1)
        full = joint_map(s.target_skeleton, s.reference_skeleton)
        removed = full.sum() - s.joint_map.sum()
        assert removed == len(s.provenance["dropped"]) - sum(
            urdf.keypoints[k] < 0 or s.reference_skeleton.keypoints[k] < 0 for k in s.provenance["dropped"]
        )
        assert not {"left_hand", "right_hand", "left_toe", "right_toe"} & set(s.provenance["dropped"])
        drops += len(s.provenance["dropped"])
        assert set(s.provenance["dropped"]) <= set(KEYPOINTS)
    assert drops > 0


def test_filters(out):
    full = ShardDataset(out)
    only_h1 = ShardDataset(out, targets=["h1"])
    plain = ShardDataset(out, augmented=False)
    train = ShardDataset(out, split="train", augmented=False)
    assert {only_h1[i].target_skeleton.name for i in range(0, len(only_h1), 7)} == {"h1"}
    assert len(plain) == len(full.windows) * 7
    assert all(train[i].provenance["variant"] == 0 for i in range(len(train)))
    assert len(only_h1) == sum(4 if w.split == "train" else 1 for w in full.windows)


def test_clip_metadata_for_evaluation_loops(out):
    ds = ShardDataset(out)
    clips = ds.clips()
    assert len(clips) == 2 * len(CLIPS)
    for (robot, clip), ws in clips.items():
        frames = int(round(CLIPS[clip][0] * 30)) + 1
        assert [w.start_frame for w in ws] == window_starts(frames, 60, 60).tolist()
        assert {w.robot for w in ws} == {robot}
    assert ds.config["window"] == 60 and ds.window_length == 60 and ds.fps == 30.0
    assert ds.skeleton("valkyrie") == get_skeleton("valkyrie")


def test_dataloader_with_workers(out):
    ds = ShardDataset(out)
    loader = torch.utils.data.DataLoader(ds, batch_size=16, shuffle=True, num_workers=2, collate_fn=collate,
                                         generator=torch.Generator().manual_seed(0))  # fmt: skip
    seen = 0
    for b, batch in enumerate(loader):
        B = batch["reference"].shape[0]
        assert batch["reference"].shape[1] == 60 and batch["reference"].shape[2] == batch["ref_mask"].shape[1] <= 34
        assert batch["target"].shape[2] == batch["tgt_mask"].shape[1] <= 36  # Oli has the most nodes (36)
        assert batch["joint_map"].shape[0] == B and batch["has_target"].dtype == torch.bool
        seen += B
        if b == 5:
            break
    assert seen == 6 * 16
    # a worker sees exactly what the main process sees
    i = 123
    one = next(iter(torch.utils.data.DataLoader(torch.utils.data.Subset(ds, [i]), num_workers=1, collate_fn=list)))[0]
    assert one.reference.tobytes() == ds[i].reference.tobytes()


def test_same_seed_same_augmentation(out, tmp_path):
    inp = make_input(tmp_path / "in", clips={"dance1_subject1": CLIPS["dance1_subject1"]})
    a = build(inp, tmp_path / "a", augment=3, seed=5, split="all")
    b = build(inp, tmp_path / "b", augment=3, seed=6, split="all")
    assert a.windows == b.windows
    x = open_shard(tmp_path / "a" / "g1-train-00000-of-00001.h5").column("link_scales")
    y = open_shard(tmp_path / "b" / "g1-train-00000-of-00001.h5").column("link_scales")
    z = open_shard(out / "g1-train-00000-of-00001.h5")  # seed 5 as well, same clip: same draws
    rows = [i for i, c in enumerate(z.column("clip")) if c == "dance1_subject1"]
    assert np.array_equal(x, z.column("link_scales")[rows]) and not np.array_equal(x, y)
