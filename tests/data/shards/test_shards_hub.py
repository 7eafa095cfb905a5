"""``--input hf://REPO_ID``: the real huggingface_hub client against a loopback Hub, online and offline."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hub_server import FakeHub
from shard_helpers import make_input

from mer_data.shards import open_shard

REPO = Path(__file__).resolve().parents[3]
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


# ---- mer shards push DIR REPO_ID, ShardDataset("hf://datasets/..."), mer_meta.json ---------------------------------

SHARDS_REPO = "lab/synthetic-shards"
_READ_BACK = r'''
import json, sys
from mer_data.shards import ShardDataset
url = sys.argv[1]
ds = ShardDataset(url, split="train", augmented=True)
out = []
for i in (0, len(ds) - 1):
    s = ds[i]
    out.append({"target": s.provenance["target"], "variant": s.provenance["variant"], "file": s.provenance["file"],
                "reference": s.reference.tolist()[0][0], "skeleton": s.target_skeleton.name, "nodes": s.target_skeleton.num_nodes})
print(json.dumps({"len": len(ds), "folder": str(ds.paths[0].parent), "samples": out}))
'''


def _hub_env(hub_url: str, tmp: Path, **extra: str) -> dict:
    from zoo_helpers import TOKEN

    base = {k: v for k, v in os.environ.items() if not k.startswith(("HF_", "HUGGINGFACE_"))}
    return {**base, "PYTHONPATH": str(REPO), "HF_ENDPOINT": hub_url, "HF_HOME": str(tmp / "hf_home"),
            "HF_HUB_CACHE": str(tmp / "hub_cache"), "HF_HUB_DISABLE_XET": "1", "HF_TOKEN": TOKEN,
            "HF_HUB_DISABLE_TELEMETRY": "1", "MER_HOME": str(tmp / "mer"), **extra}  # fmt: skip


@pytest.fixture(scope="module")
def synthetic_shards(tmp_path_factory):
    from mer_models.cli import main

    out = tmp_path_factory.mktemp("synthetic_push")
    assert main(["shards", "build", "--synthetic", "1", "--synthetic-seconds", "4", "--robots", "g1", "--targets", "g1", "atlas",
                 "--augment", "1", "--workers", "1", "--quiet", "--out", str(out)]) == 0  # fmt: skip
    return out


def test_push_then_read_back_through_the_hub_cache_online_and_offline(synthetic_shards, tmp_path):
    from hub_server import HubServer
    from zoo_helpers import TOKEN

    from mer_data.shards import ShardDataset

    local = ShardDataset(synthetic_shards, split="train")
    with HubServer(token=TOKEN) as hub:
        env = _hub_env(hub.url, tmp_path)
        res = _mer(["shards", "push", str(synthetic_shards), SHARDS_REPO], env)
        assert res.returncode == 0, res.stderr
        repo = hub.dataset_repos[SHARDS_REPO]
        head = repo.branches["main"]
        files = repo.commits[head].files
        assert set(files) == {".gitattributes", "README.md", "mer_meta.json", "g1-train-00000-of-00001.h5"}
        assert files["g1-train-00000-of-00001.h5"].data == (synthetic_shards / "g1-train-00000-of-00001.h5").read_bytes()
        assert SHARDS_REPO not in hub.repos  # a dataset repository, not a model
        from hub_server import validate_metadata
        from huggingface_hub import DatasetCard

        card = DatasetCard(files["README.md"].data.decode())  # the client's parser, on what was pushed
        assert card.data.task_categories == ["robotics"] and card.data.license == "apache-2.0"
        assert validate_metadata(card.data.to_dict(), "dataset") == []
        assert json.loads(files["mer_meta.json"].data)["shards"]["g1-train-00000-of-00001.h5"]["targets"] == ["g1", "atlas"]

        url = f"hf://datasets/{SHARDS_REPO}@{head}"
        run = subprocess.run([sys.executable, "-c", _READ_BACK, url], env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        got = json.loads(run.stdout.strip().splitlines()[-1])
        assert got["len"] == len(local)
        assert got["folder"].startswith(str(tmp_path / "hub_cache")) and got["folder"].endswith(head)  # the real cache
        for i, s in zip((0, len(local) - 1), got["samples"]):
            want = local[i]
            assert s["target"] == want.provenance["target"] and s["variant"] == want.provenance["variant"]
            assert s["reference"] == want.reference.tolist()[0][0] and s["nodes"] == want.target_skeleton.num_nodes

        seen = len(hub.requests)
        off = subprocess.run([sys.executable, "-c", _READ_BACK, url], env={**env, "HF_HUB_OFFLINE": "1"},
                             capture_output=True, text=True, timeout=300)
        assert off.returncode == 0, off.stderr
        assert len(hub.requests) == seen and json.loads(off.stdout.strip().splitlines()[-1])["len"] == len(local)

        bad = subprocess.run([sys.executable, "-c", _READ_BACK, f"hf://datasets/{SHARDS_REPO}@v9"], env=env,
                             capture_output=True, text=True, timeout=300)
        assert bad.returncode != 0 and "no revision 'v9'" in bad.stderr


def test_push_refuses_lafan1_derived_shards(tmp_path):
    from shard_helpers import build

    from mer_data.base.errors import ShardError
    from mer_data.shards import push_shards

    out = tmp_path / "out"
    build(make_input(tmp_path / "in", robots=("g1",), clips=CLIPS), out, robots=("g1",), split="all", targets=("g1",), augment=0)
    with pytest.raises(ShardError, match="LAFAN1.*no derivatives"):
        push_shards(out, "lab/nope")  # refused before any network call: no Hub is running


def test_hf_dataset_urls_are_checked():
    from mer_data.base.errors import ShardFormatError
    from mer_data.shards.hub import parse_hf_url

    assert parse_hf_url("hf://datasets/lab/x") == ("lab/x", None)
    assert parse_hf_url("hf://datasets/lab/x@" + "a" * 40) == ("lab/x", "a" * 40)
    for bad in ("hf://lab/x", "hf://datasets/x", "hf://datasets/a/../b", "hf://datasets/lab/x@", "hf://datasets/a/b/c"):
        with pytest.raises(ShardFormatError):
            parse_hf_url(bad)


def test_load_dataset_rows_resolve_target_and_skeleton_through_the_side_file(synthetic_shards, tmp_path):
    """``load_dataset("hdf5")`` drops the HDF5 attributes; ``mer_meta.json`` gives back what sample_target means."""
    datasets = pytest.importorskip("datasets")
    from mer_data.shards import ShardDataset, read_sidecar

    ds = datasets.load_dataset("hdf5", data_files={"train": str(synthetic_shards / "g1-train-*.h5")},
                               cache_dir=str(tmp_path / "hf"))["train"].with_format("numpy")
    assert "targets" not in ds.column_names and not any("skeleton" in c for c in ds.column_names)  # what is lost
    side = read_sidecar(synthetic_shards)
    local = ShardDataset(synthetic_shards, split="train")
    checked = set()
    for row_i in (0, ds.num_rows - 1):
        row = ds[row_i]
        w = local.windows[row_i]
        assert row["clip"] == w.clip and int(row["start_frame"]) == w.start_frame
        for k in range(len(row["sample_target"])):
            info = side.sample_info(row, k, "train")
            want = local._sample(w, k)
            assert info.target == want.provenance["target"] and info.variant == want.provenance["variant"]
            assert info.skeleton.to_json() == want.target_skeleton.to_json()  # link scales applied for variants > 0
            assert info.dropped == want.provenance["dropped"]
            checked.add((info.target, info.variant))
    assert checked == {("g1", 0), ("g1", 1), ("atlas", 0), ("atlas", 1)}
    with pytest.raises(KeyError, match="no shard of robot 'h1'"):
        side.meta("h1", "train")
