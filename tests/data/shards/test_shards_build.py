"""``build_shards`` on synthetic inputs: layout, counts, resume, sharding, workers, bad input."""

from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest
from shard_helpers import CLIPS, assert_same_arrays, build, make_input, shard_arrays

from mer_data.base.errors import ShardBuildError, UnknownRobotError
from mer_data.motion.windows import window_starts
from mer_data.shards import ShardDataset, inspect_shards, open_shard

PARTS = ["g1-eval-00000-of-00001.h5", "g1-train-00000-of-00001.h5", "h1-eval-00000-of-00001.h5", "h1-train-00000-of-00001.h5"]


@pytest.fixture(scope="module")
def syn_input(tmp_path_factory):
    return make_input(tmp_path_factory.mktemp("input"))


@pytest.fixture(scope="module")
def built(syn_input, tmp_path_factory):
    out = tmp_path_factory.mktemp("shards")
    report = build(syn_input, out)
    return out, report


def _windows(seconds: float) -> int:
    return len(window_starts(int(round(seconds * 30)) + 1, 60, 60))


def test_files_counts_and_card(built):
    out, report = built
    assert sorted(p.name for p in out.glob("*.h5")) == PARTS
    assert not list(out.glob(".*tmp*")) and not (out / ".partial").exists()
    per_robot = sum(_windows(s) for s, _, _ in CLIPS.values())
    assert report.windows == 2 * per_robot and report.clips == 10
    train = {"dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2"}
    for name in PARTS:
        m = open_shard(out / name).meta
        clips = {s["clip"] for s in m.sources}
        assert clips == (train if m.split == "train" else set(CLIPS) - train)
        assert m.variants == (3 if m.split == "train" else 1) and len(m.targets) == 7
        assert m.num_rows == sum(_windows(CLIPS[c][0]) for c in clips)
        assert set(m.skeletons) == {m.robot, *m.targets}
        assert m.config["split"] == "paper" and m.config["resolved"]["splits"]["g1"]["walk1_subject1"] == "eval"
    card = (out / "README.md").read_text()
    assert "license: cc-by-nc-nd-4.0" in card and "sha256" in card and "mer shards build" in card
    assert json.loads((out / "build-report.json").read_text())["windows"] == report.windows


def test_rerun_keeps_finished_shards(built, syn_input):
    out, _ = built
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}
    report = build(syn_input, out)
    assert {f["status"] for f in report.files} == {"up to date"}
    assert before == {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}


def test_changed_input_rebuilds_only_its_shard(syn_input, tmp_path):
    inp = tmp_path / "in"
    shutil.copytree(syn_input, inp)
    out = tmp_path / "out"
    build(inp, out)
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.h5")}
    (inp / "h1" / "walk2_subject3.csv").write_bytes((inp / "h1" / "walk1_subject1.csv").read_bytes())
    report = build(inp, out)
    status = {f["name"]: f["status"] for f in report.files}
    assert status.pop("h1-eval-00000-of-00001.h5") == "built" and set(status.values()) == {"up to date"}
    assert before["g1-eval-00000-of-00001.h5"] == (out / "g1-eval-00000-of-00001.h5").stat().st_mtime_ns


def test_another_build_in_the_same_folder_is_refused(built, syn_input):
    out, _ = built
    with pytest.raises(ShardBuildError, match="another build") as exc:
        build(syn_input, out, seed=1)
    assert "new --out" in exc.value.fix


def test_workers_and_sharding_give_identical_content(built, syn_input, tmp_path):
    out, _ = built
    par = tmp_path / "par"
    build(syn_input, par, workers=2)
    for name in PARTS:
        assert_same_arrays(shard_arrays(out / name), shard_arrays(par / name))
    # 3 shards built one index at a time (as separate machines would) hold the same windows
    sharded = tmp_path / "sharded"
    for i in range(3):
        build(syn_input, sharded, num_shards=3, shard_index=i)
    files = sorted(sharded.glob("*.h5"))
    clips_by_file = [{s["clip"] for s in open_shard(f).meta.sources} for f in files]
    for robot in ("g1", "h1"):
        per = [c for f, c in zip(files, clips_by_file) if f.name.startswith(robot + "-")]
        assert sum(len(c) for c in per) == len(CLIPS) and set().union(*per) == set(CLIPS)
    a, b = ShardDataset(out), ShardDataset(sharded)
    assert len(a) == len(b)
    for w in a.windows:
        v = b.find_window(w.robot, w.clip, w.start_frame)
        assert a.window_features(w).tobytes() == b.window_features(v).tobytes()
        sa, sb = a.sample(w, "oli", 1 if w.split == "train" else 0), b.sample(v, "oli", 1 if v.split == "train" else 0)
        assert sa.target_skeleton == sb.target_skeleton and np.array_equal(sa.joint_map, sb.joint_map)
    with pytest.raises(ShardBuildError, match="outside 0..2"):
        build(syn_input, sharded, num_shards=3, shard_index=3)


def _broken_input(syn_input, tmp_path):
    inp = tmp_path / "in"
    shutil.copytree(syn_input, inp)
    bad = inp / "h1" / "walk1_subject1.csv"
    lines = bad.read_text().splitlines()
    lines[41] = lines[41].replace(",", ",x", 1)
    bad.write_text("\n".join(lines) + "\n")
    return inp, bad


def test_a_failing_clip_stops_the_build_and_leaves_no_partial_shard(syn_input, tmp_path):
    inp, bad = _broken_input(syn_input, tmp_path)
    out = tmp_path / "out"
    with pytest.raises(ShardBuildError) as exc:
        build(inp, out)
    assert f"{bad}:42" in str(exc.value) and "non-numeric" in str(exc.value) and "--keep-going" in str(exc.value)
    assert not (out / "h1-eval-00000-of-00001.h5").exists()
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name]
    for p in out.glob("*.h5"):  # whatever was finished is complete
        assert open_shard(p).meta.num_rows > 0


def test_keep_going_records_the_failure_and_builds_the_rest(syn_input, tmp_path):
    inp, bad = _broken_input(syn_input, tmp_path)
    out = tmp_path / "out"
    report = build(inp, out, keep_going=True)
    assert sorted(p.name for p in out.glob("*.h5")) == PARTS
    assert [(f["robot"], f["clip"]) for f in report.failed] == [("h1", "walk1_subject1")]
    assert f"{bad}:42" in report.failed[0]["error"]
    info = inspect_shards(out)
    h1_eval = next(f for f in info["files"] if f["path"].endswith("h1-eval-00000-of-00001.h5"))
    assert h1_eval["failed_clips"] == 1 and h1_eval["clips"] == 1
    assert "FAILED h1/walk1_subject1" in report.summary()


def test_short_clips_are_skipped_counted_and_reported(syn_input, tmp_path, caplog):
    inp = make_input(tmp_path / "in", clips={**CLIPS, "walk3_subject1": (1.5, 0.0, 0.0)})
    with caplog.at_level(logging.WARNING):
        report = build(inp, tmp_path / "out", split="all")
    assert sorted((s["robot"], s["clip"]) for s in report.short) == [("g1", "walk3_subject1"), ("h1", "walk3_subject1")]
    assert "walk3_subject1" in caplog.text and "shorter than a window" in report.summary()
    meta = open_shard(tmp_path / "out" / "g1-train-00000-of-00001.h5").meta
    assert meta.counts()["short_clips"] == 1 and meta.counts()["clips"] == len(CLIPS)


def test_gz_input_and_other_frame_rates(tmp_path):
    clips = {"walk1_subject1": (4.0, 0.0, 0.1)}
    a = make_input(tmp_path / "a", clips=clips)
    b = make_input(tmp_path / "b", clips=clips, gz=True)
    build(a, tmp_path / "oa", split="all")
    build(b, tmp_path / "ob", split="all")
    x, y = shard_arrays(tmp_path / "oa" / "g1-train-00000-of-00001.h5"), shard_arrays(tmp_path / "ob" / "g1-train-00000-of-00001.h5")
    assert x["pos"].tobytes() == y["pos"].tobytes() and list(x["source_sha256"]) != list(y["source_sha256"])
    # the same clip at 60 Hz, read with --fps 60, gives windows of the same 30 Hz frames
    from mer_data.motion.lafan1 import write_lafan1_csv
    from mer_data.synthesis.walking import walking_motion

    m60 = walking_motion("g1", 4.0, fps=60.0, turn_rate=0.1)
    write_lafan1_csv(tmp_path / "c" / "g1" / "walk1_subject1.csv", m60)
    rep = build(tmp_path / "c", tmp_path / "oc", split="all", robots=("g1",), fps=60.0)
    z = shard_arrays(tmp_path / "oc" / "g1-train-00000-of-00001.h5")
    assert rep.frames == 121 and z["pos"].tobytes() == x["pos"].tobytes()  # every other frame, exactly


def test_bad_requests(syn_input, tmp_path):
    with pytest.raises(UnknownRobotError, match="unknown robot 'r2d2'"):
        build(syn_input, tmp_path / "o", robots=("g1", "r2d2"))
    with pytest.raises(UnknownRobotError):
        build(syn_input, tmp_path / "o", targets=("g1", "r2d2"))
    with pytest.raises(ShardBuildError, match="no folder for robot 'atlas'"):
        build(syn_input, tmp_path / "o", robots=("atlas",))  # any robot can be a source; this input has no atlas/
    with pytest.raises(ShardBuildError, match="does not exist"):
        build(tmp_path / "nowhere", tmp_path / "o")
    with pytest.raises(ShardBuildError, match="no folder for robot 'h1_2'"):
        build(syn_input, tmp_path / "o", robots=("g1", "h1_2"))
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").glob("*.h5"))
