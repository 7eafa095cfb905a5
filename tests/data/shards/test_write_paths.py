"""Write paths that cannot be redirected (issue 41): a folder of shards may come from anyone, with
symbolic links planted where mer writes (``teacher/``, ``.partial/``, a piece, an output file). Each
is refused (``OutputPathError``) or replaced by name, never written through; the link's target is
never touched."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import MerError, OutputPathError
from mer_data.shards import BuildConfig, build_shards

CFG = BuildConfig(input="", robots=("g1",), targets=("g1",), synthetic=1, synthetic_seconds=2.5, augment=0, split="all")


@pytest.fixture(scope="module")
def shard(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wp") / "shards"
    build_shards(CFG, out)
    return next(out.glob("*.h5"))


def _victim(tmp_path: Path) -> Path:
    """A folder outside the output with one precious file (and one named like mer's temporaries)."""
    v = tmp_path / "victim"
    v.mkdir()
    (v / "precious.txt").write_text("precious\n")
    (v / "x.piece.tmp-1-abc").write_text("not mer's\n")
    return v


def _untouched(v: Path) -> None:
    assert sorted(p.name for p in v.iterdir()) == ["precious.txt", "x.piece.tmp-1-abc"]
    assert (v / "precious.txt").read_text() == "precious\n"


def test_a_symlinked_teacher_folder_is_refused(shard, tmp_path):
    from mer_models.training.teacher import SolverConfig, solve_shards

    folder = tmp_path / "s"
    folder.mkdir()
    p = Path(shutil.copy(shard, folder))
    v = _victim(tmp_path)
    (folder / "teacher").symlink_to(v, target_is_directory=True)
    with pytest.raises(OutputPathError, match="symbolic link") as ei:
        solve_shards(p, solver=SolverConfig(gn_iters=1, physics=None))
    assert "teacher" in str(ei.value)
    _untouched(v)


def test_a_symlinked_teacher_file_is_refused_before_solving(shard, tmp_path):
    from mer_models.training.teacher import SolverConfig, solve_shards

    folder = tmp_path / "s"
    (folder / "teacher").mkdir(parents=True)
    p = Path(shutil.copy(shard, folder))
    v = _victim(tmp_path)
    (folder / "teacher" / p.with_suffix(".h5").name).symlink_to(v / "precious.txt")
    with pytest.raises(OutputPathError, match="symbolic link"):
        solve_shards(p, solver=SolverConfig(gn_iters=1, physics=None))
    _untouched(v)


@pytest.mark.parametrize("where", [".partial", ".partial/g1-train-00000-of-00001"])
def test_symlinked_partial_folders_are_refused(tmp_path, where):
    out = tmp_path / "out"
    v = _victim(tmp_path)
    link = out / where
    link.parent.mkdir(parents=True)
    link.symlink_to(v, target_is_directory=True)
    with pytest.raises(OutputPathError, match="symbolic link"):
        build_shards(CFG, out)
    _untouched(v)  # neither written into nor cleaned (clean-up deletes *.tmp-* files there)
    assert not list(out.glob("*.h5"))


def test_a_planted_piece_link_is_neither_read_nor_written_through(tmp_path):
    out = tmp_path / "out"
    v = _victim(tmp_path)
    piece = out / ".partial" / "g1-train-00000-of-00001" / "synthetic-g1-00000.piece"
    piece.parent.mkdir(parents=True)
    piece.symlink_to(v / "precious.txt")
    build_shards(CFG, out)
    _untouched(v)
    assert list(out.glob("*.h5"))


def test_atomic_write_replaces_a_link_by_name_and_refuses_linked_folders(tmp_path):
    v = _victim(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").symlink_to(v / "precious.txt")
    atomic_write(out / "summary.json", "{}\n")
    assert not (out / "summary.json").is_symlink() and (out / "summary.json").read_text() == "{}\n"
    (out / "h1").symlink_to(v, target_is_directory=True)
    with pytest.raises(OutputPathError, match="symbolic link"):
        atomic_write(out / "h1" / "clip.csv", "1,2\n", below=out)
    with pytest.raises(OutputPathError, match="not a regular file"):
        atomic_write(out, "x")  # a folder under the name is not replaced
    os.mkfifo(out / "fifo")
    with pytest.raises(MerError, match="not a regular file"):
        atomic_write(out / "fifo", "x")
    _untouched(v)
    assert sorted(p.name for p in out.iterdir()) == ["fifo", "h1", "summary.json"]  # no temporary left


def test_a_symlinked_hub_cache_folder_is_refused(tmp_path, monkeypatch):
    """``blobs/`` of a dataset in the Hub cache: a link planted there would take the downloads elsewhere."""
    from hub_server import HubServer
    from huggingface_hub import constants

    from mer_data.shards.hub import download_shards

    v = _victim(tmp_path)
    storage = tmp_path / "cache" / "datasets--lab--s"
    storage.mkdir(parents=True)
    (storage / "blobs").symlink_to(v, target_is_directory=True)
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setattr(constants, "HF_HUB_OFFLINE", False)
    with HubServer() as hub:
        hub.put("lab/s", {"README.md": b"# shards\n"})
        monkeypatch.setattr(constants, "ENDPOINT", hub.url)
        monkeypatch.setattr(constants, "HF_HUB_CACHE", str(tmp_path / "cache"))
        with pytest.raises(OutputPathError, match="symbolic link"):
            download_shards("hf://datasets/lab/s")
    _untouched(v)
