"""A full disk, for real (issue 41): a tmpfs of a few hundred kB mounted in a private mount namespace
(``unshare -rm``, no root needed where user namespaces are allowed), and ``mer`` run on it.

HDF5 does not survive ``ENOSPC`` (h5py segfaulted, rc 139, closing a piece or the merged file); now
pieces are built in memory and written in one checked write, and the merged shard and the teacher
file claim their room before HDF5 writes into them. Each case must end in one ``error:`` line naming
the path and the space needed, exit 1, nothing under a final name, no temporary file, no lock; and
the same command must finish once there is room (the tmpfs remounted larger).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
BUILD = ["shards", "build", "--synthetic", "2", "--synthetic-seconds", "6", "--robots", "g1", "--targets", "g1", "h1",
         "--augment", "2", "--workers", "1", "--quiet"]  # fmt: skip


def _can_mount(tmp_path: Path) -> str | None:
    """None if ``unshare -rm`` can mount a tmpfs here; else why not."""
    if shutil.which("unshare") is None or not sys.platform.startswith("linux"):
        return "no unshare(1) (util-linux) on this system"
    d = tmp_path / "probe"
    d.mkdir()
    r = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {d}"], capture_output=True, text=True)
    return None if r.returncode == 0 else f"cannot mount a tmpfs in a user namespace here ({r.stderr.strip()[:200]})"


@pytest.fixture
def full_disk(tmp_path):
    """Run a shell script in a mount namespace with ``$FULL`` a tmpfs of the given size (kB)."""
    why = _can_mount(tmp_path)
    if why:
        pytest.skip(why)
    mnt = tmp_path / "full"
    mnt.mkdir()

    def run(size_kb: int, script: str) -> subprocess.CompletedProcess:
        env = {**os.environ, "PYTHONPATH": str(REPO), "MER_HOME": str(tmp_path / "mer_home"), "FULL": str(mnt),
               "PY": sys.executable}  # fmt: skip
        body = f"mount -t tmpfs -o size={size_kb}k tmpfs {mnt} || exit 99\n" + textwrap.dedent(script)
        r = subprocess.run(["unshare", "-rm", "sh", "-c", body], env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode != 99, r.stderr
        return r

    return run


def _one_error_line(stderr: str, *words: str) -> str:
    lines = [x for x in stderr.splitlines() if x.strip()]
    errors = [x for x in lines if x.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in stderr and "Segmentation" not in stderr, stderr[-3000:]
    for w in words:
        assert w in errors[0], errors[0]
    return errors[0]


@pytest.fixture(scope="module")
def piece_bytes(tmp_path_factory) -> int:
    """The size of the largest piece of the build in ``BUILD`` (built on the real disk)."""
    from mer_models.cli import main

    out = tmp_path_factory.mktemp("sizes") / "out"
    assert main([*BUILD, "--out", str(out)]) == 0
    h5 = next(out.glob("*.h5")).stat().st_size
    return max(h5 // 2, 64 * 1024)


def test_a_full_disk_while_writing_pieces_is_one_line_and_recovers(full_disk, piece_bytes):
    size_kb = piece_bytes // 2048  # half a piece: the first piece does not fit
    r = full_disk(
        size_kb,
        f"""
        $PY -m mer_models {" ".join(BUILD)} --out $FULL/out; echo "rc=$?"
        find $FULL/out -name '*.tmp*' -o -name '*.lock' -o -name '*.h5' | sed 's/^/LEFT /'
        mount -o remount,size=8m $FULL
        $PY -m mer_models {" ".join(BUILD)} --out $FULL/out; echo "rc2=$?"
        ls $FULL/out
    """,
    )
    assert "rc=1" in r.stdout and "LEFT" not in r.stdout, r.stdout + r.stderr
    _one_error_line(r.stderr, ".piece", "the disk is full", "needs about", "free there")
    assert "rc2=0" in r.stdout and "g1-train-00000-of-00001.h5" in r.stdout, r.stdout + r.stderr


def test_a_full_disk_at_the_merge_is_one_line_and_keeps_the_pieces(full_disk, piece_bytes):
    size_kb = (2 * piece_bytes + (200 << 10)) // 1024  # the two pieces fit, the merged file (as large) does not
    r = full_disk(
        size_kb,
        f"""
        $PY -m mer_models {" ".join(BUILD)} --out $FULL/out; echo "rc=$?"
        find $FULL/out -name '*.tmp*' -o -name '*.lock' -o -name '*.h5' | sed 's/^/LEFT /'
        ls $FULL/out/.partial/* | grep -c piece | sed 's/^/PIECES /'
    """,
    )
    assert "rc=1" in r.stdout and "LEFT" not in r.stdout, r.stdout + r.stderr
    assert "PIECES 2" in r.stdout, r.stdout  # kept for the next run
    _one_error_line(r.stderr, "g1-train-00000-of-00001.h5", "the disk is full")


def test_a_full_disk_for_the_teacher_file_is_one_line(full_disk, tmp_path):
    from mer_models.cli import main

    shards = tmp_path / "shards"
    assert main([*BUILD, "--out", str(shards)]) == 0
    r = full_disk(
        96,
        f"""
        $PY -m mer_models shards solve {shards} --out $FULL/teacher --gn-iters 1 --no-physics --quiet; echo "rc=$?"
        find $FULL -name '*.h5' | sed 's/^/LEFT /'
    """,
    )
    assert "rc=1" in r.stdout and "LEFT" not in r.stdout, r.stdout + r.stderr
    _one_error_line(r.stderr, "teacher/g1-train-00000-of-00001.h5", "the disk is full")


def test_atomic_writes_on_a_full_disk(full_disk):
    """What dataset retargets, exports, cards and the registry write goes through atomic_write/atomic_dir."""
    r = full_disk(
        64,
        """
        $PY - <<'EOF'
        import os
        from mer_data.base.atomic import atomic_dir, atomic_write
        from mer_data.base.errors import DiskFullError
        full = os.environ["FULL"]
        atomic_write(full + "/small.json", "{}")
        for name, fn in (("file", lambda: atomic_write(full + "/big.csv", b"1" * 200_000)),
                         ("dir", lambda: atomic_dir(full + "/robot", lambda d: (d / "a.urdf").write_bytes(b"1" * 200_000)))):
            try:
                fn()
            except DiskFullError as exc:
                print(name, "REFUSED", str(exc).splitlines()[0])
        print("LEFT", sorted(os.listdir(full)))
        EOF
    """,
    )
    assert "file REFUSED" in r.stdout and "big.csv: the disk is full: writing it needs about 200.0 kB" in r.stdout, (
        r.stdout + r.stderr
    )
    assert "dir REFUSED" in r.stdout, r.stdout + r.stderr
    assert "LEFT ['small.json']" in r.stdout, r.stdout


def test_a_dataset_retarget_on_a_full_disk_is_one_line(full_disk, tmp_path):
    """``mer retarget --input DIR --out OUT``: its outputs go through atomic_write, so it inherits the error."""
    from shard_helpers import make_input

    inp = make_input(tmp_path / "in", robots=("g1",), clips={"walk1_subject1": (2.0, 0.0, 0.0)})
    r = full_disk(
        12,
        f"""
        $PY -m mer_models retarget --input {inp} --source g1 --targets h1 --out $FULL/out --method optimize --quiet
        echo "rc=$?"
        find $FULL -type f | sed 's/^/LEFT /'
    """,
    )
    assert "rc=1" in r.stdout and "LEFT" not in r.stdout, r.stdout + r.stderr
    _one_error_line(r.stderr, "walk1_subject1.csv", "the disk is full")
