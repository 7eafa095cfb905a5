"""``mer retarget --input DIR --targets ... --out DIR``: whole datasets, batched, resumable, sharded."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hub_server import FakeHub
from hypothesis import given
from hypothesis import strategies as st
from model_helpers import micro_checkpoint, synthetic_csv, synthetic_folder  # noqa: F401 (fixture)

from mer_data.base.atomic import owner_tag
from mer_data.base.errors import MerError
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.robots.registry import get_skeleton
from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features
from mer_models.retarget.dataset import _segments, plan_jobs, retarget_dataset

REPO = Path(__file__).resolve().parents[3]
CLIPS = {"walk1_subject1": 150, "dance1_subject2": 90, "run1_subject2": 40}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return synthetic_folder(tmp_path_factory.mktemp("lafan") / "data", CLIPS)


@given(n=st.integers(1, 2000), segment=st.integers(16, 600), context=st.integers(0, 20))
def test_segments_cover_every_frame_once_with_context(n, segment, context):
    segs = _segments(n, segment, context)
    cores = np.concatenate([np.arange(s, e) for _, _, s, e in segs])
    np.testing.assert_array_equal(cores, np.arange(n))
    for a, b, s, e in segs:
        assert 0 <= a <= s < e <= b <= n and b - a <= segment + 2 * context
        assert s - a >= min(context, s)  # context kept before the core where the clip has it


def test_shards_split_the_pairs_exactly_once(tmp_path):
    clips = {f"c{i}": tmp_path / f"c{i}.csv" for i in range(7)}
    all_jobs = {(j.target, j.clip) for j in plan_jobs(clips, ["h1", "atlas"], tmp_path)}
    parts = [plan_jobs(clips, ["h1", "atlas"], tmp_path, i, 3) for i in range(3)]
    got = [(j.target, j.clip) for p in parts for j in p]
    assert len(got) == len(set(got)) == len(all_jobs) == 14 and set(got) == all_jobs
    with pytest.raises(MerError, match="shard-index"):
        plan_jobs(clips, ["h1"], tmp_path, 3, 3)


def test_a_dataset_retargets_once_and_resumes(dataset, tmp_path):
    out = tmp_path / "out"
    first = retarget_dataset(str(dataset), "g1", ["h1", "tron1"], out, formats=("csv", "npz"), npz_for="beyondmimic", segment=64, context=4,
                             frames_per_batch=300)  # fmt: skip
    assert first["jobs"] == 6 and first["done_now"] == 6 and first["done_before"] == 0
    assert first["frames"] == 2 * sum(CLIPS.values())
    for t in ("h1", "tron1"):
        for clip, n in CLIPS.items():
            rows = np.loadtxt(out / t / f"{clip}.csv", delimiter=",", ndmin=2)
            assert rows.shape == (n, 7 + get_skeleton(t).num_dof) and np.isfinite(rows).all()
            row = json.loads((out / t / f"{clip}.metrics.json").read_text())
            assert row["limit_violation"] == 0 and np.isfinite(row["g_mpbpe"]) and row["frames"] == n
            assert (out / t / f"{clip}.npz").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["rows"]) == 6
    assert not list(out.rglob(".tmp-*"))
    assert read_lafan1_csv(out / "h1" / "walk1_subject1.csv", "h1").num_frames == CLIPS["walk1_subject1"]  # H1's own layout

    (out / "h1" / "walk1_subject1.metrics.json").unlink()  # as if killed before that pair finished
    again = retarget_dataset(str(dataset), "g1", ["h1", "tron1"], out, segment=64, context=4)
    assert again["done_before"] == 5 and again["done_now"] == 1 and len(again["rows"]) == 6


def test_batched_segments_match_the_whole_clip_solution(dataset, tmp_path):
    """Segments solved with context, many at once, are as good as the clip solved in one piece."""
    out = tmp_path / "out"
    retarget_dataset(str(dataset), "g1", ["atlas"], out, segment=48, context=8, frames_per_batch=200)
    g1 = get_skeleton("g1")
    m = read_lafan1_csv(dataset / "g1" / "walk1_subject1.csv", "g1")
    feats = source_features(m.base_pos, m.base_quat, m.node_angles(g1), g1, 30.0)
    whole = sequence_metrics(feats, g1, retarget_features(feats, g1, "atlas", method="optimize").motion)
    row = json.loads((out / "atlas" / "walk1_subject1.metrics.json").read_text())
    assert row["g_mpbpe"] < whole["g_mpbpe"] * 1.15 + 1e-3
    assert row["jerk_frame"] < whole["jerk_frame"] * 1.3 + 2e-3  # no seams at the segment joins


def _env(tmp_path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(REPO), "MER_HOME": str(tmp_path / "mer"), "HF_HOME": str(tmp_path / "hf"),
           "HF_HUB_DISABLE_TELEMETRY": "1"}  # fmt: skip
    env.pop("HF_HUB_OFFLINE", None)
    return env


def test_the_model_retargets_each_clip_to_all_targets_in_one_pass(dataset, tmp_path, micro_checkpoint):  # noqa: F811
    """``method="diffusion"``: clip by clip, every pending target in one pass, the reference encoded
    once per window; each pair's result is what a one-target ``retarget_features`` call gives."""
    from mer_models.retarget.long_horizon import clip_starts
    from mer_models.zoo.checkpoint import resolve_model

    ckpt = resolve_model(str(micro_checkpoint))
    calls: list[int] = []
    hook = ckpt.model.net.encoder.register_forward_hook(lambda mod, args, out: calls.append(out.shape[0]))
    try:
        res = retarget_dataset(str(dataset), "g1", ["h1", "tron1"], tmp_path / "out", method="diffusion", checkpoint=ckpt, steps=1)
    finally:
        hook.remove()
    assert res["done_now"] == 6 and res["frames"] == 2 * sum(CLIPS.values())
    frames, overlap = ckpt.model.cfg.frames, ckpt.run.sampler.overlap
    assert calls == [1] * sum(len(clip_starts(max(n, frames), frames, overlap)) for n in CLIPS.values())
    for clip, n in CLIPS.items():
        m = read_lafan1_csv(dataset / "g1" / f"{clip}.csv", "g1")
        feats = source_features(m.base_pos, m.base_quat, m.node_angles(get_skeleton("g1")), get_skeleton("g1"), 30.0)
        for t in ("h1", "tron1"):
            one = retarget_features(feats, "g1", t, checkpoint=ckpt, steps=1)
            want = sequence_metrics(feats, get_skeleton("g1"), one.motion)
            row = json.loads((tmp_path / "out" / t / f"{clip}.metrics.json").read_text())
            assert row["method"] == "diffusion" and row["frames"] == n
            np.testing.assert_allclose(row["g_mpbpe"], want["g_mpbpe"], rtol=1e-4)
            got = read_lafan1_csv(tmp_path / "out" / t / f"{clip}.csv", t)
            np.testing.assert_allclose(got.base_pos, one.motion.base_pos, atol=1e-4)


def test_a_killed_run_resumes_and_leaves_nothing_half_written(dataset, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mer_models", "retarget", "--input", str(dataset), "--source", "g1",
           "--targets", "h1", "tron1", "atlas", "--out", str(out), "--quiet", "--no-physics"]  # fmt: skip
    # --no-physics: resuming does not depend on the terms (they are test_physics_flag_runs_both_paths...'s); a third of the time
    proc = subprocess.Popen(cmd, env=_env(tmp_path), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    t0 = time.monotonic()
    killed = False
    while time.monotonic() - t0 < 240 and proc.poll() is None:
        if list(out.glob("*/*.metrics.json")):
            os.killpg(proc.pid, signal.SIGKILL)
            killed = True
            break
        time.sleep(0.005)
    proc.wait()
    done_at_kill = len(list(out.glob("*/*.metrics.json")))
    (out / "h1").mkdir(parents=True, exist_ok=True)
    (out / "h1" / f".tmp-x.csv~{owner_tag().split('~')[0]}~{2**22 + 7}~abc").write_text("half")  # a dead writer's leftover
    assert killed and done_at_kill < 9, "the run finished before it could be interrupted"
    res = subprocess.run(cmd + ["--json"], env=_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["done_before"] >= done_at_kill and summary["done_before"] + summary["done_now"] == 9
    assert len(list(out.glob("*/*.metrics.json"))) == 9 and len(list(out.glob("*/*.csv"))) == 9
    assert not list(out.rglob(".tmp-*"))  # nothing half written survives (temp files of the killed run are swept)


def test_hub_dataset_input(tmp_path):
    src = tmp_path / "src"
    synthetic_csv(src / "g1" / "walk1_subject1.csv", "g1", frames=40)
    files = {"g1/walk1_subject1.csv": (src / "g1" / "walk1_subject1.csv").read_bytes(), "h1/other.csv": b"not requested\n"}
    with FakeHub("someone/robot-motions", files) as hub:
        env = {**_env(tmp_path), "HF_ENDPOINT": hub.url}
        cmd = [sys.executable, "-m", "mer_models", "retarget", "--input", "hf://someone/robot-motions", "--source", "g1",
               "--targets", "h1", "--out", str(tmp_path / "out"), "--quiet"]  # fmt: skip
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        assert "walk1_subject1" in res.stdout and (tmp_path / "out" / "h1" / "walk1_subject1.csv").is_file()
        assert not any(r.endswith("other.csv") for r in hub.requests)


def test_dataset_arguments_are_checked(dataset, tmp_path):
    env = _env(tmp_path)
    base = [sys.executable, "-m", "mer_models", "retarget", "--source", "g1"]
    res = subprocess.run(base + ["--input", str(dataset), "--targets", "h1"], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode != 0 and "missing: --out" in res.stderr
    res = subprocess.run(base + ["--input", str(tmp_path / "nope"), "--targets", "h1", "--out", str(tmp_path / "o")],
                         env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert res.returncode != 0 and "does not exist" in res.stderr and "Traceback" not in res.stderr


def test_dataset_and_single_file_runs_give_the_same_output(dataset, tmp_path, micro_checkpoint):  # noqa: F811
    """The same options through ``mer retarget --input DIR`` and ``mer retarget FILE`` write the same
    CSV; ``--refine K`` included (dataset runs once dropped it and wrote the bare model's output)."""
    from mer_models.cli import main

    clip = "dance1_subject2"
    for refine in (0, 3):
        out = tmp_path / f"ds{refine}"
        one = tmp_path / f"one{refine}.csv"
        opts = ["--source", "g1", "--method", "diffusion", "--model", str(micro_checkpoint), "--steps", "1", "--seed", "5",
                "--refine", str(refine)]  # fmt: skip
        assert main(["retarget", "--input", str(dataset), "--targets", "h1", "--out", str(out), "--quiet", *opts]) == 0
        assert main(["retarget", str(dataset / "g1" / f"{clip}.csv"), "--target", "h1", "-o", str(one), *opts]) == 0
        assert (out / "h1" / f"{clip}.csv").read_bytes() == one.read_bytes()
        row = json.loads((out / "h1" / f"{clip}.metrics.json").read_text())
        assert row["method"] == ("diffusion" if refine == 0 else f"diffusion+refine{refine}")
    a = read_lafan1_csv(tmp_path / "one0.csv", "h1").joints
    b = read_lafan1_csv(tmp_path / "one3.csv", "h1").joints
    assert np.abs(a - b).max() > 1e-4  # refinement changed the motion: the comparison above can fail


def test_physics_flag_runs_both_paths_and_reports_artifacts(dataset, tmp_path):
    """The physical terms are on by default in dataset and single-file runs and ``--no-physics``
    turns them off there: a clip sunk 6 cm into the floor comes out above it (terms, then the
    feasibility pass) or under it; the metrics carry the artifact figures."""
    from mer_data.motion.lafan1 import write_lafan1_csv
    from mer_data.robots.registry import load_robot
    from mer_models.cli import main

    g1 = load_robot("g1")
    m = read_lafan1_csv(dataset / "g1" / "walk1_subject1.csv", g1)
    sunk = tmp_path / "data" / "g1" / "sunk.csv"
    sunk.parent.mkdir(parents=True)
    write_lafan1_csv(sunk, m.with_arrays(base_pos=m.base_pos - [0.0, 0.0, 0.06]), robot=g1)
    rows = {}
    for name, flag in (("off", ("--no-physics",)), ("on", ())):
        out = tmp_path / f"ds_{name}"
        assert main(["retarget", "--input", str(tmp_path / "data"), "--source", "g1", "--targets", "h1", "--out", str(out), "--quiet",
                     *flag]) == 0  # fmt: skip
        rows[name] = json.loads((out / "h1" / "sunk.metrics.json").read_text())
        assert {"floor_frames", "skate_median", "selfpen_1cm_frames", "speed_frames"} <= set(rows[name])
        one = tmp_path / f"one_{name}.csv"
        assert main(["retarget", str(sunk), "--source", "g1", "--target", "h1", "--method", "optimize", "-o", str(one), *flag]) == 0
    assert rows["off"]["floor_frames"] > 0.3 and rows["off"]["floor_depth_max"] > 0.04
    assert rows["on"]["floor_frames"] == 0 and rows["on"]["floor_depth_max"] < 1e-3
    import torch

    from mer_data.kinematics.rotations import quat_to_matrix
    from mer_data.robots.collision import collision_model
    from mer_models.retarget.artifacts import motion_artifacts

    h1 = load_robot("h1")
    floor = {}
    for name in ("off", "on"):
        o = read_lafan1_csv(tmp_path / f"one_{name}.csv", h1)
        rot = quat_to_matrix(torch.from_numpy(o.base_quat)).numpy()
        floor[name] = motion_artifacts(o.node_angles(h1.skeleton), o.base_pos, rot, 30.0, h1.skeleton, collision_model(h1))
    assert floor["off"]["floor_frames"] > 0.3
    assert floor["on"]["floor_frames"] == 0 and floor["on"]["floor_depth_max"] < 2e-3  # the single-file run too (CSV rounding)
