"""``--input hf://REPO_ID``: the real huggingface_hub client against a loopback Hub, online and offline."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hub_server import FakeHub
from shard_helpers import make_input

from mer_data.shards import open_shard

REPO = Path(__file__).resolve().parents[1]
CLIPS = {"dance1_subject1": (2.5, 0.0, 0.1), "walk1_subject1": (2.2, 1.0, 0.0)}


def _mer(args: list[str], env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mer_models", *args], env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture()
def hub(tmp_path):
    inp = make_input(tmp_path / "src", robots=("g1",), clips=CLIPS)
    files = {str(p.relative_to(inp)): p.read_bytes() for p in inp.rglob("*.csv")}
    files["h1_2/other.csv"] = b"not requested\n"
    files["README.md"] = b"# LAFAN1 robots\n"
    with FakeHub("someone/lafan1-robots", files) as h:
        yield h


def test_hf_input_downloads_then_works_offline(hub, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO), "HF_ENDPOINT": hub.url, "HF_HOME": str(tmp_path / "hf"),
           "HF_HUB_DISABLE_TELEMETRY": "1", "MER_HOME": str(tmp_path / "mer")}  # fmt: skip
    env.pop("HF_HUB_OFFLINE", None)
    args = ["shards", "build", "--input", "hf://someone/lafan1-robots", "--robots", "g1", "--split", "all",
            "--targets", "g1", "h1", "--augment", "0", "--quiet", "--workers", "1"]  # fmt: skip
    res = _mer([*args, "--out", str(tmp_path / "a")], env)
    assert res.returncode == 0, res.stderr
    downloads = [r for r in hub.requests if r.startswith("GET /datasets/")]
    assert sorted(r.rsplit("/", 1)[1] for r in downloads) == ["dance1_subject1.csv", "walk1_subject1.csv"]  # allow_patterns
    meta = open_shard(tmp_path / "a" / "g1-train-00000-of-00001.h5").meta
    assert meta.config["input"] == "hf://someone/lafan1-robots" and meta.counts()["clips"] == 2

    hub.requests.clear()
    res = _mer([*args, "--out", str(tmp_path / "b")], {**env, "HF_HUB_OFFLINE": "1"})
    assert res.returncode == 0, res.stderr
    assert hub.requests == []  # offline means offline
    assert open_shard(tmp_path / "b" / "g1-train-00000-of-00001.h5").meta.build_id == meta.build_id

    res = _mer([*args, "--out", str(tmp_path / "c")], {**env, "HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp_path / "empty")})
    assert res.returncode == 1 and "not in the local cache" in res.stderr and "HF_HUB_OFFLINE" in res.stderr

    res = _mer([*args[:3], "hf://someone/missing", *args[4:], "--out", str(tmp_path / "d")], env)
    assert res.returncode == 1 and "no dataset 'someone/missing'" in res.stderr
    res = _mer([*args[:3], "hf://someone/lafan1-robots@v9", *args[4:], "--out", str(tmp_path / "d")], env)
    assert res.returncode == 1 and "no revision 'v9'" in res.stderr
