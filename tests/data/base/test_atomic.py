"""mer_data.base.atomic: nothing half-written under the final name; permissions as open()/mkdir give."""

from __future__ import annotations

import os
import stat
import time

import pytest

from mer_data.base.atomic import atomic_dir, atomic_write


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_atomic_write_text_and_bytes(tmp_path):
    p = atomic_write(tmp_path / "sub" / "a.txt", "héllo\n")
    assert p.read_bytes() == "héllo\n".encode()
    atomic_write(p, b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    assert sorted(x.name for x in p.parent.iterdir()) == ["a.txt"]


def test_atomic_write_mode_follows_umask(tmp_path, umask_022):
    p = atomic_write(tmp_path / "card.md", "x")
    assert stat.S_IMODE(p.stat().st_mode) == 0o644  # mkstemp alone would leave 0600


def test_atomic_write_failure_keeps_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    p = atomic_write(tmp_path / "a.txt", "old")

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        atomic_write(p, "new")
    assert p.read_text() == "old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


def test_atomic_dir_replaces_folder_with_umask_mode(tmp_path, umask_022):
    final = tmp_path / "robot"
    atomic_dir(final, lambda d: (d / "one.txt").write_text("1"))
    assert stat.S_IMODE(final.stat().st_mode) == 0o755  # mkdtemp alone would leave 0700
    atomic_dir(final, lambda d: (d / "two.txt").write_text("2"))
    assert sorted(x.name for x in final.iterdir()) == ["two.txt"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["robot"]


def test_atomic_dir_failure_keeps_old_folder(tmp_path):
    final = tmp_path / "robot"
    atomic_dir(final, lambda d: (d / "one.txt").write_text("1"))

    def half(d):
        (d / "partial.txt").write_text("half")
        raise ValueError("bad URDF")

    with pytest.raises(ValueError, match="bad URDF"):
        atomic_dir(final, half)
    assert sorted(x.name for x in final.iterdir()) == ["one.txt"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["robot"]


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux /proc to see a process's state")
def test_an_exited_writer_not_yet_reaped_is_not_alive():
    """A killed writer whose parent died with it stays a zombie until init reaps it: its temporary
    files are abandoned all the same (a resumed run sweeps them)."""
    from mer_data.base.atomic import owner_alive, owner_tag

    host = owner_tag().split("~")[0]
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    try:
        for _ in range(500):  # until the child has exited (a zombie: not reaped yet)
            with open(f"/proc/{pid}/stat") as fh:
                if fh.read().rsplit(")", 1)[1].split()[0] == "Z":
                    break
            time.sleep(0.01)
        assert not owner_alive(host, pid)
        assert owner_alive(host, os.getppid())  # a running process is alive
    finally:
        os.waitpid(pid, 0)
    assert not owner_alive(host, pid)  # reaped: gone
