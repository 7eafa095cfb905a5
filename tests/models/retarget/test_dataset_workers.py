"""``mer retarget --input DIR --workers N``: processes write what one process writes; a resumed run
says how many pairs it skipped."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from model_helpers import synthetic_folder

from mer_models.cli import main
from mer_models.retarget.dataset import _chunks, plan_jobs, retarget_dataset
from mer_models.retarget.workers import available_cores

CLIPS = {"walk1_subject1": 150, "dance1_subject2": 90, "run1_subject2": 40, "jumps1_subject1": 60}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return synthetic_folder(tmp_path_factory.mktemp("lafan") / "data", CLIPS)


def _outputs(out: Path) -> dict[str, bytes | dict]:
    files: dict[str, bytes | dict] = {}
    for p in sorted(out.glob("*/*")):
        key = f"{p.parent.name}/{p.name}"
        if p.name.endswith(".metrics.json"):
            row = json.loads(p.read_text())
            row.pop("seconds")  # wall time, the one thing that differs
            files[key] = row
        else:
            files[key] = p.read_bytes()
    return files


def test_two_workers_write_the_files_one_worker_writes(dataset, tmp_path):
    kw = {"formats": ("csv", "npz"), "npz_for": "mjlab", "segment": 48, "context": 4, "frames_per_batch": 100}
    one = retarget_dataset(str(dataset), "g1", ["h1", "tron1"], tmp_path / "one", workers=1, **kw)
    two = retarget_dataset(str(dataset), "g1", ["h1", "tron1"], tmp_path / "two", workers=2, **kw)
    assert one["workers"] == 1 and two["workers"] == 2  # two processes really ran
    assert one["done_now"] == two["done_now"] == 8 and one["frames"] == two["frames"] == 2 * sum(CLIPS.values())
    a, b = _outputs(tmp_path / "one"), _outputs(tmp_path / "two")
    assert len(a) == 3 * 8 and a.keys() == b.keys()
    for k in a:
        assert a[k] == b[k], k


def test_chunks_cover_every_pair_once_and_do_not_depend_on_the_workers(dataset, tmp_path):
    clips = {c: dataset / "g1" / f"{c}.csv" for c in CLIPS}
    jobs = plan_jobs(clips, ["h1", "atlas"], tmp_path)
    chunks = _chunks(jobs, 100, 30.0)
    got = [(j.target, j.clip) for c in chunks for j in c]
    assert sorted(got) == sorted((j.target, j.clip) for j in jobs) and len(got) == len(set(got))
    assert all(len({j.target for j in c}) == 1 for c in chunks)  # one target per chunk
    # clips in name order (dance1 90, jumps1 60, run1 40, walk1 150 frames), a chunk closed at >= 100 frames
    assert [[j.clip for j in c] for c in chunks[:2]] == [["run1_subject2", "walk1_subject1"]] * 2  # the largest first
    assert [[j.clip for j in c] for c in chunks[2:]] == [["dance1_subject2", "jumps1_subject1"]] * 2


def test_a_resumed_run_prints_its_skipped_pairs(dataset, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["retarget", "--input", str(dataset), "--source", "g1", "--targets", "tron1", "--out", str(out), "--quiet",
            "--no-physics", "--workers", "1"]  # fmt: skip
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "4 (target, clip) pairs to do, 1 process" in err and "skipped;" not in err
    (out / "tron1" / "run1_subject2.metrics.json").unlink()  # as if killed before that pair finished
    assert main(argv) == 0
    o = capsys.readouterr()
    assert f"3 of 4 pairs already done in {out}, skipped; 1 (target, clip) pairs to do" in o.err
    assert "4 pairs in this shard: 3 skipped (done before), 1 now" in o.out


def test_workers_are_checked_and_default_to_the_cores(dataset, tmp_path, capsys):
    assert available_cores() >= 1
    argv = [
        "retarget",
        "--input",
        str(dataset),
        "--source",
        "g1",
        "--targets",
        "tron1",
        "--out",
        str(tmp_path / "o"),
        "--workers",
        "0",
    ]
    assert main(argv) == 1
    assert "--workers must be >= 1" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_a_planted_target_folder_link_is_refused(dataset, tmp_path):
    """``OUT/h1 -> elsewhere``: refused before anything is read or written, nothing lands elsewhere."""
    from mer_data.base.errors import MerError

    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "h1").symlink_to(elsewhere)
    with pytest.raises(MerError, match="symbolic link"):
        retarget_dataset(str(dataset), "g1", ["h1"], out, workers=1, segment=48, context=4)
    assert list(elsewhere.iterdir()) == []
