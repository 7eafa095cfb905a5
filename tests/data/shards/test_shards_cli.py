"""``mer shards build|inspect|card`` and ``mer demo`` from the command line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from shard_helpers import make_input

from mer_data.shards import open_shard
from mer_models.cli import main

CLIPS = {"dance1_subject1": (2.5, 0.0, 0.1), "fallAndGetUp1_subject1": (2.2, 1.0, -0.2), "fight1_subject2": (2.1, 2.0, 0.3),
         "walk1_subject1": (2.4, 0.5, 0.0)}  # fmt: skip


@pytest.fixture(scope="module")
def inp(tmp_path_factory):
    return make_input(tmp_path_factory.mktemp("in"), clips=CLIPS)


def _build(inp, out, *extra):
    return main(["shards", "build", "--input", str(inp), "--robots", "g1", "h1", "--out", str(out), "--augment", "1",
                 "--workers", "1", "--split", "paper", *extra])  # fmt: skip


def test_build_and_inspect(inp, tmp_path, capsys):
    out = tmp_path / "out"
    assert _build(inp, out) == 0
    cap = capsys.readouterr()
    assert "4 shard file(s)" in cap.out and "dataset card:" in cap.out and "clip" in cap.err  # tqdm bar on stderr
    assert main(["shards", "inspect", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["robots"] == ["g1", "h1"] and info["format_versions"] == [1]
    assert set(info["totals"]) == {"g1/train", "g1/eval", "h1/train", "h1/eval"}
    f = info["files"][0]
    assert {"format", "format_version", "bytes", "windows", "samples", "clips", "frames", "targets"} <= set(f)
    assert next(iter(info["configs"].values()))["window"] == 60
    assert main(["shards", "inspect", str(out / "g1-eval-00000-of-00001.h5")]) == 0
    text = capsys.readouterr().out
    assert "hdf5 v1, g1 eval" in text and "MB" in text and "build " in text
    dest = tmp_path / "card.md"
    assert main(["shards", "card", str(out), "--out", str(dest), "--input-label", "hf://x/y"]) == 0
    assert "--input hf://x/y" in dest.read_text()


def test_exit_status_on_bad_input(inp, tmp_path, capsys):
    bad = tmp_path / "in"
    shutil.copytree(inp, bad)
    (bad / "g1" / "walk1_subject1.csv").write_text("1,2,3\n")
    assert _build(bad, tmp_path / "a", "--quiet") == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "walk1_subject1.csv:1" in err and "expected 36" in err
    assert _build(bad, tmp_path / "b", "--quiet", "--keep-going") == 1  # built, but reports the failure
    out = capsys.readouterr().out
    assert "FAILED g1/walk1_subject1" in out and open_shard(tmp_path / "b" / "h1-eval-00000-of-00001.h5").meta.num_rows > 0
    assert _build(inp, tmp_path / "c", "--stride", "0") == 2
    assert _build(inp, tmp_path / "d", "--robots", "nobody") == 1
    assert "unknown robot 'nobody'" in capsys.readouterr().err
    assert main(["shards", "inspect", str(tmp_path / "nothing")]) == 1


def test_mcap_format_from_the_command_line(inp, tmp_path):
    assert _build(inp, tmp_path / "m", "--format", "mcap", "--quiet", "--split", "all", "--window", "30", "--stride", "15") == 0
    m = open_shard(tmp_path / "m" / "h1-train-00000-of-00001.mcap").meta
    assert m.window == 30 and m.config["stride"] == 15 and m.split == "train"


@pytest.mark.slow
def test_demo(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "robots in the registry" in out and "valkyrie" in out  # the registry part stays
    assert "one training batch: reference" in out and "MCAP for Foxglove" in out and "docs/shards.md" in out
    assert sorted(p.name for p in (tmp_path / "demo" / "shards").glob("*.h5")) == [
        "g1-train-00000-of-00001.h5", "h1-train-00000-of-00001.h5", "h1_2-train-00000-of-00001.h5"]  # fmt: skip
    assert len(list((tmp_path / "demo" / "mcap").glob("*.mcap"))) == 3
    # the walk goes on: a robot registered from a URDF, the default model by name, every robot retargeted
    assert "register a robot from its URDF" in out and "registered 'mer_demo_humanoid'" in out
    assert "model 'mer-base': bundled (every file checked against the sha256 of its card)" in out
    assert "mer-base is trained on synthetic motion only" in out
    robots = ["g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie", "mer_demo_humanoid"]
    rows = {w[0]: line for line in out.splitlines() if len(w := line.split()) > 7 and w[0] in robots and w[1] in ("yes", "no:")}
    assert set(robots) <= set(rows), out
    assert "no: zero-shot" in rows["mer_demo_humanoid"] and "zero-shot (as `mer retarget --allow-unseen`): mer_demo_humanoid" in out
    ret = tmp_path / "demo" / "retarget"
    from mer_data.robots.registry import get_skeleton

    for robot in robots:
        a = np.loadtxt(ret / f"{robot}.csv", delimiter=",")
        assert a.shape == (241, 7 + get_skeleton(robot).num_dof) and np.isfinite(a).all(), robot
    assert [p.name for p in ret.glob("*.mcap")] == ["h1.mcap"] and [p.name for p in ret.glob("*.png")] == ["h1.png"]
    from PIL import Image

    with Image.open(ret / "h1.gif") as gif:  # the scaled reference | the retarget, 241 frames shown at 15 Hz
        assert gif.n_frames == 121 and gif.size == (800, 400)
    assert "GIF (scaled reference | retarget):" in out
    for line in (rows[r] for r in robots):  # five finite metrics per robot
        vals = [float(x) for x in line.split()[-6:]]
        assert np.isfinite(vals).all(), line
