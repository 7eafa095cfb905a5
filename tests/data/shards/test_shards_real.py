"""A reduced real-data build (LAFAN1 G1 + H1, a few clips): windows, features, pairing, datasets."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.kinematics.scaling import body_part_scales
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.motion.windows import window_starts
from mer_data.robots.registry import get_skeleton
from mer_data.shards import BuildConfig, ShardDataset, build_shards, open_shard

CLIPS = ("dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2", "walk1_subject1")


@pytest.fixture(scope="module")
def real(lafan1_dir, tmp_path_factory):
    inp = tmp_path_factory.mktemp("lafan1")
    for robot in ("g1", "h1"):
        (inp / robot).mkdir()
        for c in CLIPS:
            (inp / robot / f"{c}.csv").symlink_to(lafan1_dir / robot / f"{c}.csv")
    out = tmp_path_factory.mktemp("shards")  # never inside the repository: LAFAN1 is CC BY-NC-ND
    report = build_shards(BuildConfig(input=str(inp), robots=("g1", "h1"), augment=1), out, workers=2)
    return inp, out, report


@pytest.mark.slow
def test_reduced_real_build(real, lafan1_dir):
    inp, out, report = real
    frames = {c: sum(1 for _ in open(lafan1_dir / "g1" / f"{c}.csv")) for c in CLIPS}
    assert report.frames == 2 * sum(frames.values()) and not report.failed and not report.short
    assert report.windows == 2 * sum(len(window_starts(f, 60, 60)) for f in frames.values())
    for name, clips in (("g1-train-00000-of-00001.h5", 3), ("g1-eval-00000-of-00001.h5", 1)):
        m = open_shard(out / name).meta
        assert m.counts()["clips"] == clips
    manifest = dict(line.split()[::-1] for line in (lafan1_dir / "MANIFEST.sha256").read_text().splitlines())
    ds = ShardDataset(out)
    for w in ds.windows[::40]:
        assert w.source_sha256 == manifest[f"{w.robot}/{w.clip}.csv"]


@pytest.mark.slow
def test_real_windows_match_fk_and_g1_h1_pair_up(real, lafan1_dir):
    inp, out, _ = real
    ds = ShardDataset(out)
    for robot, clip in (("g1", "walk1_subject1"), ("h1", "fight1_subject2")):
        m = read_lafan1_csv(lafan1_dir / robot / f"{clip}.csv", robot)
        skel = get_skeleton(robot)
        st = skeleton_tensors(skel, torch.float64)
        for w in ds.clips(robot)[(robot, clip)][::9]:
            sel = np.arange(w.start_frame, w.start_frame + 60)
            pos, _ = fk_skeleton(st, torch.from_numpy(m.node_angles(skel)[sel]), torch.from_numpy(m.base_pos[sel]),
                                 base_quat=torch.from_numpy(m.base_quat[sel]))  # fmt: skip
            pos = pos.numpy()
            pos[..., :2] -= m.base_pos[w.start_frame, :2]
            f = ds.window_features(w)
            np.testing.assert_allclose(f[:, 1:, 1:4], pos[:, 1:], atol=2e-6)
            np.testing.assert_allclose(f[:, 0, 3:6], pos[:, 0], atol=2e-6)
    # G1 and H1 share clips and frame counts: every unaugmented G1 -> H1 sample has a ground truth
    g1_to_h1 = [ds.sample(w, "h1") for w in ds.windows if w.robot == "g1"]
    assert all(s.target is not None and s.target.shape == (60, 24, 9) for s in g1_to_h1)


@pytest.mark.slow
def test_g1_travels_about_0_74_of_h1(lafan1_dir):
    """Design notes: root paths are scaled per robot, G1 ~0.74x H1. mer's alpha_root (feet kept on the
    ground, mer_data.kinematics.scaling) is an independent estimate of the same ratio from the two URDFs alone."""
    num = den = 0.0
    for clip in ("walk1_subject1", "run1_subject2"):
        g = read_lafan1_csv(lafan1_dir / "g1" / f"{clip}.csv", "g1").base_pos[:, :2]
        h = read_lafan1_csv(lafan1_dir / "h1" / f"{clip}.csv", "h1").base_pos[:, :2]
        g, h = g - g[0], h - h[0]
        num += float((g * h).sum())
        den += float((h * h).sum())
    ratio = num / den
    assert ratio == pytest.approx(0.74, abs=0.01)
    assert body_part_scales(get_skeleton("h1"), get_skeleton("g1"))["root"] == pytest.approx(ratio, abs=0.015)


def _expected(lafan1_dir):
    rows = [line.split("\t") for line in (lafan1_dir / "MANIFEST.tsv").read_text().splitlines()[1:]]
    frames = {r[0]: int(r[1]) for r in rows}
    windows = sum(len(window_starts(f, 60, 60)) for f in frames.values())
    return frames, windows


@pytest.mark.slow
@pytest.mark.parametrize("split", ["paper", "all"])
def test_full_g1_h1_build(lafan1_dir, tmp_path, split):
    """The whole data: 80 clips, 529,410 frames (about 10 s per build on 2 cores)."""
    frames, windows = _expected(lafan1_dir)
    report = build_shards(BuildConfig(input=str(lafan1_dir), robots=("g1", "h1"), split=split), tmp_path, workers=2)
    assert report.clips == 80 and report.frames == sum(frames.values()) == 529_410 and report.windows == windows
    assert not report.failed and not report.short
    names = sorted(p.name for p in tmp_path.glob("*.h5"))
    if split == "paper":
        assert names == ["g1-eval-00000-of-00001.h5", "g1-train-00000-of-00001.h5", "h1-eval-00000-of-00001.h5",
                         "h1-train-00000-of-00001.h5"]  # fmt: skip
        train = open_shard(tmp_path / "g1-train-00000-of-00001.h5").meta
        assert sorted(s["clip"] for s in train.sources) == ["dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2"]
        assert open_shard(tmp_path / "h1-eval-00000-of-00001.h5").meta.counts()["clips"] == 37
    else:
        assert names == ["g1-train-00000-of-00001.h5", "h1-train-00000-of-00001.h5"]
    ds = ShardDataset(tmp_path, augmented=False)
    assert len(ds.windows) == windows and len(ds.clips()) == 80
    ds.close()
    shutil.rmtree(tmp_path, ignore_errors=True)  # ~0.2 GB built from CC BY-NC-ND data: do not keep it around
