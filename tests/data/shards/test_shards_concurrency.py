"""Two `mer shards build` into one --out: the second is refused cleanly, never crashes the first."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
from pathlib import Path

import pytest
from shard_helpers import make_input

from mer_data.base.atomic import owner_tag
from mer_data.shards import BuildConfig, build_shards, open_shard
from mer_models.cli import main

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork and pids: Linux")
FORK = multiprocessing.get_context("fork")
CLIPS = {"dance1_subject1": (2.1, 0.0, 0.1), "walk1_subject1": (2.1, 0.5, 0.0)}
REPO = Path(__file__).resolve().parents[3]
LOCK = ".g1-train-00000-of-00001.h5.lock"


@pytest.fixture(scope="module")
def inp(tmp_path_factory):
    return make_input(tmp_path_factory.mktemp("in"), robots=("g1",), clips=CLIPS)


def _config(inp) -> BuildConfig:
    return BuildConfig(input=str(inp), robots=("g1",), targets=("g1",), split="all", augment=0)


def test_a_live_build_holding_the_files_is_refused_with_its_owner(inp, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK).write_text(owner_tag() + "\n")  # this (live) process holds it
    code = main(["shards", "build", "--input", str(inp), "--robots", "g1", "--targets", "g1", "--split", "all",
                 "--augment", "0", "--out", str(out), "--workers", "1", "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert f"process {os.getpid()}" in err and "is writing g1-train-00000-of-00001.h5" in err and LOCK in err
    assert not list(out.glob("*.h5"))


def test_a_lock_left_by_a_dead_build_is_taken_over(inp, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    child = FORK.Process(target=os._exit, args=(0,))
    child.start()
    child.join()
    (out / LOCK).write_text(f"{owner_tag().split('~')[0]}~{child.pid}\n")
    report = build_shards(_config(inp), out)
    assert report.files and not list(out.glob(".*.lock"))


def test_two_concurrent_builds_into_one_out(inp, tmp_path):
    """Two real processes (the command line; a forked torch would deadlock): each either builds or is
    refused with the lock message; neither crashes, and the result is one complete build."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mer_models.cli", "shards", "build", "--input", str(inp), "--robots", "g1",
           "--targets", "g1", "--split", "all", "--augment", "0", "--out", str(out), "--workers", "1", "--quiet"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    procs = [subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [p.communicate(timeout=300) + (p.returncode,) for p in procs]
    for _out, err, code in results:
        assert "Traceback" not in err, err
        assert code == 0 or (code == 1 and "is writing" in err), err
    assert any(code == 0 for *_, code in results)
    shard = open_shard(out / "g1-train-00000-of-00001.h5")
    assert shard.num_rows > 0 and not list(out.glob(".*.lock")) and not list(out.glob(".*.tmp-*"))
