"""Shards from human motion (BVH, SMPL-family parameters, joint positions): a folder becomes windows
whose reference is the human body of each clip (one reference per body: a folder mixing skeletons,
performers or genders is built per body, never refused), read through the same source reader as
``mer retarget``, and read back by ShardDataset with joint maps to every target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from body_model_files import build_body_model, random_poses
from bvh_factory import BANDAI_NAMES, human_definition, smooth_motion, write_bvh

from mer_data.base.errors import MerError
from mer_data.motion.body_model import BODY_MODEL_ENV
from mer_data.motion.features import split_features
from mer_data.motion.sources import HumanOptions, read_source
from mer_data.shards import BuildConfig, ShardDataset, build_shards


@pytest.fixture(autouse=True)
def _no_user_models(monkeypatch, tmp_path):
    monkeypatch.delenv(BODY_MODEL_ENV, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))


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
    assert {s.reference_skeleton.name for s in samples} == {"bvh", "bvh-2"}  # two performers: two bodies, one per clip
    assert {s.target_skeleton.name for s in samples} == {"g1", "h1"}
    assert {s.provenance["clip"] for s in samples if s.reference_skeleton.name == "bvh-2"} == {"clip1"}
    for s in samples:
        human = s.reference_skeleton
        assert set(human.keypoints) >= {"left_hip", "right_ankle", "left_hand"} and all(v >= 0 for v in human.keypoints.values())
        assert s.reference.shape == (60, human.num_nodes, 9) and np.isfinite(s.reference).all()
        if not s.provenance["augmented"]:  # augmented variants drop some correspondences on purpose
            assert s.joint_map.sum() >= 12  # hips, knees, ankles, toes, shoulders, elbows, hands (+ base)


def test_bvh_is_built_alone_and_from_a_folder(tmp_path):
    with pytest.raises(MerError, match="--robots bvh alone"):
        build_shards(BuildConfig(input=str(_folder(tmp_path)), robots=("bvh", "g1"), targets=("g1",), split="all"), tmp_path / "o")
    with pytest.raises(MerError, match="no BVH files"):
        build_shards(BuildConfig(input=str(tmp_path), robots=("bvh",), targets=("g1",), split="all"), tmp_path / "o2")
    for folder in (tmp_path / "in", tmp_path / "in" / "bvh"):  # a BVH folder given as a robot's: the fix says --robots bvh
        with pytest.raises(MerError, match="fix: for human motion give --robots bvh"):
            build_shards(BuildConfig(input=str(folder), robots=("g1",), targets=("h1",), split="all"), tmp_path / "o3")


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


def _same_as_retarget(ds, folder, kind: str, opts: HumanOptions) -> None:
    """Each clip's first window is the first 60 frames of what `mer retarget` reads (read_source)."""
    first = {}
    for i in range(len(ds)):
        s = ds[i]
        if s.provenance["start_frame"] == 0 and not s.provenance["augmented"]:
            first[s.provenance["clip"]] = s
    assert first
    for clip, s in first.items():
        src = read_source(next(folder.glob(f"{clip}.*")), kind, bvh=opts)
        assert src.skeleton.num_nodes == s.reference_skeleton.num_nodes
        got = split_features(torch.from_numpy(np.asarray(s.reference, np.float64)))["pos"].numpy()
        want = split_features(torch.from_numpy(src.features()[:60]))["pos"].numpy()
        want[..., :2] -= np.asarray(s.provenance["origin_xy"])  # windows start at their origin
        np.testing.assert_allclose(got, want, atol=2e-4)  # float32 shards


def test_an_smpl_folder_mixing_genders_builds_one_reference_per_body(tmp_path):
    models = tmp_path / "models"
    build_body_model(models / "smplh" / "SMPLH_FEMALE.npz", "smplh", seed=1)
    build_body_model(models / "smplh" / "SMPLH_MALE.npz", "smplh", seed=2)
    d = tmp_path / "in"
    d.mkdir()
    for k, gender in enumerate(("female", "male", "female")):
        np.savez(d / f"c{k}.npz", poses=random_poses(70, 52, seed=k)[:, :156], trans=np.zeros((70, 3)), betas=np.zeros(16),
                 gender=np.array(gender), mocap_framerate=np.array(30.0))  # fmt: skip
    cfg = BuildConfig(input=str(d), robots=("smpl",), targets=("g1",), split="all", augment=0, body_model=str(models))
    report = build_shards(cfg, tmp_path / "out")
    assert report.windows == 6 and not report.failed  # two windows of 60 frames per 70-frame clip
    ds = ShardDataset(tmp_path / "out")
    names = {ds[i].provenance["clip"]: ds[i].reference_skeleton.name for i in range(len(ds))}
    assert names == {"c0": "smpl", "c1": "smpl-2", "c2": "smpl"}  # the female clips share a body, the male one has its own
    _same_as_retarget(ds, d, "smpl", cfg.human_options())
    card = (tmp_path / "out" / "README.md").read_text()
    assert "license: other" in card and "human motion (smpl, smpl-2)" in card and "LAFAN1" not in card
    assert str(models) not in card  # a local path stays local
    with pytest.raises(MerError, match="body model"):  # no model: refused naming what to give, nothing built
        build_shards(BuildConfig(input=str(d), robots=("smpl",), targets=("g1",), split="all"), tmp_path / "none")
    assert not (tmp_path / "none").exists() or not any((tmp_path / "none").glob("*.h5"))


def test_a_joint_position_folder_mixing_layouts_builds(tmp_path):
    from body_model_files import TPOSE22

    d = tmp_path / "in" / "joints"
    d.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k, J in enumerate((22, 22, 24)):
        rest = np.concatenate([TPOSE22, TPOSE22[[20, 21]] + [[0.08, 0, 0], [-0.08, 0, 0]]])[:J]
        wave = 0.02 * np.sin(np.linspace(0, 6, 70))[:, None, None] * rng.normal(size=(1, J, 3))
        np.save(d / f"m{k}.npy", (rest + [0, 0.93, 0] + wave).astype(np.float32))  # y up, standing on the floor
    cfg = BuildConfig(input=str(tmp_path / "in"), robots=("joints",), targets=("h1",), split="all", augment=0, human_fps=30.0)
    build_shards(cfg, tmp_path / "out")
    ds = ShardDataset(tmp_path / "out")
    names = {ds[i].provenance["clip"]: ds[i].reference_skeleton for i in range(len(ds))}
    assert {c: s.name for c, s in names.items()} == {"m0": "joints", "m1": "joints", "m2": "joints-2"}
    assert names["m2"].num_nodes > names["m0"].num_nodes  # the 24-joint layout keeps its hands
    _same_as_retarget(ds, d, "joints", cfg.human_options())
    (d / "m3.npy").write_bytes(b"\x93NUMPY garbage")  # a clip that cannot be read: named, or recorded with keep_going
    with pytest.raises(MerError, match="m3.npy"):
        build_shards(cfg, tmp_path / "out2")
    report = build_shards(cfg, tmp_path / "out3", keep_going=True)
    assert [f["clip"] for f in report.failed] == ["m3"] and report.windows == 6


def test_retarget_and_evaluate_take_a_folder_mixing_genders_per_clip(tmp_path, capsys):
    """`mer retarget --input DIR --source smpl --workers 2` and `mer evaluate` on a folder of a female
    and a male clip: each clip on its own body (the body model of its gender), none refused."""
    import json

    from mer_models.cli import main

    models = tmp_path / "models"
    build_body_model(models / "smplh" / "SMPLH_FEMALE.npz", "smplh", seed=1)
    build_body_model(models / "smplh" / "SMPLH_MALE.npz", "smplh", seed=2)
    d = tmp_path / "in"
    d.mkdir()
    for k, gender in enumerate(("female", "male")):
        trans = np.zeros((62, 3))
        trans[:, 2] = 0.9
        np.savez(d / f"c{k}.npz", poses=random_poses(62, 52, seed=k, scale=0.15)[:, :156], trans=trans, betas=np.zeros(16),
                 gender=np.array(gender), mocap_framerate=np.array(30.0))  # fmt: skip
    bm = ["--body-model", str(models), "--no-physics"]
    capsys.readouterr()
    assert main(["retarget", "--input", str(d), "--source", "smpl", "--targets", "g1", "--out", str(tmp_path / "m"), "--refine", "1",
                 *bm]) == 1  # a model option is refused up front for any human kind, nothing written  # fmt: skip
    assert "a model cannot retarget a human source" in capsys.readouterr().err and not (tmp_path / "m").exists()
    assert main(["retarget", "--input", str(d), "--source", "smpl", "--targets", "g1", "--out", str(tmp_path / "ds"),
                 "--workers", "2", "--quiet", *bm]) == 0  # fmt: skip
    for k in range(2):
        assert json.loads((tmp_path / "ds" / "g1" / f"c{k}.metrics.json").read_text())["frames"] == 62
    assert main(["evaluate", "--input", str(d), "--source", "smpl", "--targets", "g1", "--split", "all", "--stride", "30",
                 "--save", str(tmp_path / "eval.json"), *bm]) == 0  # fmt: skip
    assert json.loads((tmp_path / "eval.json").read_text())
