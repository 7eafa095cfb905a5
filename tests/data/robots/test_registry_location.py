"""User robots live in the user-data folder; robots of the old cache-folder registry move there once."""

from __future__ import annotations

import logging
import os
import tempfile
from pathlib import Path

import pytest
from urdf_factory import biped

from mer_data.robots import location as registry_location
from mer_data.robots.register import register_robot
from mer_data.robots.registry import get_skeleton, known_names, robots_dir


@pytest.fixture
def platform_dirs(tmp_path, monkeypatch):
    """No MER_HOME: the XDG folders (what platformdirs reads on Linux) point into tmp_path."""
    if os.name != "posix" or os.uname().sysname != "Linux":
        pytest.skip("the folders are set through XDG variables, which platformdirs reads on Linux")
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(registry_location, "_moved", False)
    return tmp_path


def _register_in_old_place(monkeypatch, cache: Path, name: str, urdf: str) -> None:
    monkeypatch.setenv("MER_HOME", str(cache / "mer"))  # the old default: MER_HOME = cache/mer
    register_robot(name, urdf)
    monkeypatch.delenv("MER_HOME")


def test_mer_home_keeps_robots_under_it(mer_home):
    assert robots_dir() == mer_home / "robots"


def test_default_is_the_user_data_folder_not_the_cache(platform_dirs, monkeypatch):
    monkeypatch.delenv("MER_HOME")
    assert robots_dir() == platform_dirs / "data" / "mer" / "robots"
    assert registry_location.legacy_robots_dir() == platform_dirs / "cache" / "mer" / "robots"


def test_old_registry_is_moved_once_with_a_message(platform_dirs, monkeypatch, caplog, tmp_path):
    urdf = biped().write(tmp_path / "b.urdf")
    _register_in_old_place(monkeypatch, platform_dirs / "cache", "oldbot", urdf)
    old = platform_dirs / "cache" / "mer" / "robots"
    assert (old / "oldbot" / "robot.yaml").is_file()
    with caplog.at_level(logging.WARNING):
        assert "oldbot" in known_names()
    new = platform_dirs / "data" / "mer" / "robots"
    assert (new / "oldbot" / "robot.yaml").is_file() and not old.exists()
    assert "moved 1 registered robot(s) (oldbot)" in caplog.text and str(new) in caplog.text
    assert get_skeleton("oldbot").keypoints["left_knee"] >= 0
    caplog.clear()
    monkeypatch.setattr(registry_location, "_moved", False)  # a new process: nothing left to move
    with caplog.at_level(logging.WARNING):
        robots_dir()
    assert "moved" not in caplog.text


def test_a_name_in_both_registries_is_left_and_said(platform_dirs, monkeypatch, caplog, tmp_path):
    urdf = biped().write(tmp_path / "b.urdf")
    _register_in_old_place(monkeypatch, platform_dirs / "cache", "twin", urdf)
    _register_in_old_place(monkeypatch, platform_dirs / "cache", "solo", urdf)
    new = platform_dirs / "data" / "mer" / "robots"
    (new / "twin").mkdir(parents=True)
    (new / "twin" / "marker").write_text("newer")
    with caplog.at_level(logging.WARNING):
        robots_dir()
    assert (new / "solo" / "robot.yaml").is_file() and (new / "twin" / "marker").read_text() == "newer"
    assert (platform_dirs / "cache" / "mer" / "robots" / "twin").is_dir()
    assert "twin" in caplog.text and "not moved" in caplog.text


def test_move_across_file_systems(tmp_path):
    """/dev/shm is another file system than tmp_path: the rename fails with EXDEV and is a copy + rename."""
    shm = Path("/dev/shm")
    if not shm.is_dir() or os.stat(shm).st_dev == os.stat(tmp_path).st_dev:
        pytest.skip("no second file system (/dev/shm) to move across")
    with tempfile.TemporaryDirectory(dir=shm) as d:
        old = Path(d) / "robots"
        (old / "bot").mkdir(parents=True)
        (old / "bot" / "robot.yaml").write_text("name: bot\n")
        moved = registry_location.move_legacy_robots(old, tmp_path / "robots")
        assert moved == ["bot"] and not old.exists()
        assert (tmp_path / "robots" / "bot" / "robot.yaml").read_text() == "name: bot\n"
        assert [p.name for p in (tmp_path / "robots").iterdir()] == ["bot"]  # no temporary folder left
