"""tools/train_device.sh: the accelerator's one prepared command, dry-run on CPU (2 training steps)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_dry_run_writes_weights_log_and_teacher(tmp_path):
    out, work = tmp_path / "out", tmp_path / "work"
    env = {**os.environ, "OUT": str(out), "WORK": str(work), "PYTHON": sys.executable, "OMP_NUM_THREADS": "1"}
    bundled = REPO / "mer_models" / "bundled" / "mer-base"
    cmd = ["bash", str(REPO / "tools" / "train_device.sh"), "--dry-run", "--ref-group", "2", "--init", str(bundled),
           "--lr", "1e-5", "--warmup", "1", "--lr-decay-steps", "10", "--lr-min-ratio", "0.05", "--ffn", "1024"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    for name in ("config.json", "model.safetensors", "train_log.jsonl", "run.learning_curve.jsonl", "teacher.json", "log.txt"):
        assert (out / name).is_file(), name
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["step"] == 2 and cfg["run"]["name"] == "base" and cfg["run"]["train"]["ref_group"] == 2
    teacher = json.loads((out / "teacher.json").read_text())
    assert len(teacher) == 2 and all(t["status"] == "solved" and t["frames_per_s"] > 0 for t in teacher)
    assert cfg["data"]["teacher"] is True
    train = cfg["run"]["train"]
    assert (train["lr"], train["warmup"], train["lr_decay_steps"], train["lr_min_ratio"]) == (1e-5, 1, 10, 0.05)
    assert cfg["run"]["model"]["ffn"] == 1024  # --ffn: the bundled feed-forward (768) widened
    # --init: two small steps from the bundled weights stay next to them (from scratch they would not);
    # the widened tensors hold the bundled ones in their first rows and columns
    from safetensors.torch import load_file

    start, now = load_file(str(bundled / "model.safetensors")), load_file(str(out / "model.safetensors"))
    assert start.keys() == now.keys()
    assert now["net.denoiser.layers.0.ffn.0.weight"].shape[0] == 1024
    old = {k: now[k][tuple(slice(0, n) for n in start[k].shape)] for k in start}
    assert max(float((old[k] - start[k]).abs().max()) for k in start) < 1e-3


def test_unknown_option_is_refused(tmp_path):
    r = subprocess.run(["bash", str(REPO / "tools" / "train_device.sh"), "--bogus"], env={**os.environ, "OUT": str(tmp_path)},
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "unknown option --bogus" in r.stderr
