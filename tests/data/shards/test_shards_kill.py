"""An interrupted build (kill -9) re-run with the same arguments finishes cleanly."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from shard_helpers import assert_same_arrays, build, make_input, shard_arrays

from mer_data.shards import open_shard

REPO = Path(__file__).resolve().parents[3]
CLIPS = {f"walk{i}_subject{i % 5 + 1}": (5.0, 0.3 * i, 0.05 * (i % 3 - 1)) for i in range(1, 9)}


def _cmd(inp: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "mer_models", "shards", "build", "--input", str(inp), "--robots", "g1", "h1",
            "--out", str(out), "--split", "all", "--num-shards", "2", "--augment", "1", "--workers", "1", "--quiet"]  # fmt: skip


def _run_until(cmd: list[str], env: dict, ready, timeout: float = 120.0) -> bool:
    """Start the build, SIGKILL it (whole process group) as soon as ``ready()``; True if it was killed mid-build."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < timeout:
            if proc.poll() is not None:
                return False
            if ready():
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                return True
            time.sleep(0.005)
        raise AssertionError("the build never reached the point to interrupt")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.mark.slow
def test_kill_minus_9_then_rerun(tmp_path):
    inp = make_input(tmp_path / "in", clips=CLIPS)
    ref = tmp_path / "ref"
    build(inp, ref, split="all", num_shards=2, augment=1)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = tmp_path / "out"
    cmd = _cmd(inp, out)

    # 1. killed while the first shard file's pieces are being made
    assert _run_until(cmd, env, lambda: any((out / ".partial").glob("*/*.piece")))
    assert not list(out.glob("*.h5"))  # no shard file yet, and certainly no partial one
    # 2. re-run, killed again once a shard file is complete (others still missing)
    assert _run_until(cmd, env, lambda: len(list(out.glob("*.h5"))) >= 1)
    done = sorted(out.glob("*.h5"))
    assert 1 <= len(done) < 4
    for p in done:
        assert open_shard(p).meta.num_rows > 0
    # leftovers of a crash at any moment: a temporary shard and a temporary piece
    (out / ".g1-train-00001-of-00002.h5.tmp-999999").write_bytes(b"half a shard")
    (out / ".partial" / "h1-train-00001-of-00002").mkdir(parents=True, exist_ok=True)
    (out / ".partial" / "h1-train-00001-of-00002" / "walk2_subject3.piece.tmp-999999").write_bytes(b"half a piece")
    # 3. the same command again finishes cleanly
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "up to date" in res.stdout
    assert sorted(p.name for p in out.glob("*.h5")) == sorted(p.name for p in ref.glob("*.h5"))
    assert not [p for p in out.rglob("*") if ".tmp-" in p.name] and not (out / ".partial").exists()
    for p in ref.glob("*.h5"):
        assert_same_arrays(shard_arrays(p), shard_arrays(out / p.name))
