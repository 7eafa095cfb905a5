"""Untrusted motion files: BOM, non-regular files, size limits, gzip bombs and plausibility, through
the library and both commands that read them (`mer shards build`, `mer retarget`)."""

from __future__ import annotations

import gzip
import os
import threading

import numpy as np
import pytest
from shard_helpers import make_input

from mer_data.base.errors import MotionFormatError
from mer_data.motion.lafan1 import parse_lafan1, read_lafan1_csv
from mer_data.motion.plausibility import check_motion_arrays
from mer_data.robots.registry import get_skeleton, load_robot
from mer_models.cli import main

CLIPS = {"dance1_subject1": (2.1, 0.0, 0.1), "walk1_subject1": (2.1, 0.5, 0.0)}


@pytest.fixture(scope="module")
def inp(tmp_path_factory):
    return make_input(tmp_path_factory.mktemp("in"), robots=("g1",), clips=CLIPS)


def _shards(inp, out):
    return main(["shards", "build", "--input", str(inp), "--robots", "g1", "--out", str(out), "--augment", "0",
                 "--targets", "g1", "--split", "all", "--workers", "1", "--quiet"])  # fmt: skip


def _retarget(src, out):
    return main(["retarget", str(src), "--source", "g1", "--target", "tron1", "--method", "optimize", "-o", str(out)])


def _rows(path):
    return path.read_text().splitlines()


def _with_cell(inp, tmp_path, line: int, column: int, value: str):
    """A copy of the input whose clip ``walk1_subject1`` has ``value`` at (line, column), 1-based."""
    dst = tmp_path / "in"
    (dst / "g1").mkdir(parents=True)
    for f in (inp / "g1").iterdir():
        rows = _rows(f)
        if f.stem == "walk1_subject1":
            cells = rows[line - 1].split(",")
            cells[column - 1] = value
            rows[line - 1] = ",".join(cells)
        (dst / "g1" / f.name).write_text("\n".join(rows) + "\n")
    return dst, dst / "g1" / "walk1_subject1.csv"


@pytest.mark.parametrize("column", [1, 3, 8, 20], ids=["root-x", "root-z", "joint-1", "joint-13"])
def test_a_1e30_cell_is_refused_by_both_commands_with_file_line_and_column(inp, tmp_path, capsys, column):
    dst, clip = _with_cell(inp, tmp_path, 17, column, "1e30")
    assert _shards(dst, tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert f"{clip}:17" in err and f"column {column}" in err and "1e+30" in err
    assert not list((tmp_path / "out").glob("*.h5"))
    assert _retarget(clip, tmp_path / "t.csv") == 1
    err = capsys.readouterr().err
    assert f"{clip}:17" in err and f"column {column}" in err and "Traceback" not in err
    assert not (tmp_path / "t.csv").exists()


def test_a_utf8_byte_order_mark_is_read(inp, tmp_path):
    src = inp / "g1" / "walk1_subject1.csv"
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + src.read_bytes())
    a, b = read_lafan1_csv(src, "g1"), read_lafan1_csv(bom, "g1")
    assert np.array_equal(a.base_pos, b.base_pos) and np.array_equal(a.joints, b.joints)
    crlf = tmp_path / "bom_crlf.csv"  # the BOM also goes through the exact (line-by-line) route
    crlf.write_bytes(b"\xef\xbb\xbf" + src.read_bytes().replace(b"\n", b"\r\n").replace(b",", b", ", 1))
    assert np.array_equal(read_lafan1_csv(crlf, "g1").joints, a.joints)


def test_utf16_csv_is_refused_clearly(inp, tmp_path):
    f = tmp_path / "wide.csv"
    f.write_bytes((inp / "g1" / "walk1_subject1.csv").read_text().encode("utf-16"))
    with pytest.raises(MotionFormatError, match="UTF-16"):
        read_lafan1_csv(f, "g1")


def _message(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err.split("error: ", 1)[1].split("\n")[0]


def _fifo_guard(fifo):
    """If a reader blocks on the FIFO, open its write end after 10 s so the test fails instead of hanging."""

    def unblock():
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
        except OSError:
            pass

    t = threading.Timer(10.0, unblock)
    t.start()
    return t


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_named_csv_is_refused_up_front_by_both_commands(inp, tmp_path, capsys):
    dst = tmp_path / "in"
    (dst / "g1").mkdir(parents=True)
    for f in (inp / "g1").iterdir():
        (dst / "g1" / f.name).write_bytes(f.read_bytes())
    fifo = dst / "g1" / "x.csv"
    os.mkfifo(fifo)
    guard = _fifo_guard(fifo)
    try:
        assert _shards(dst, tmp_path / "out") == 1
        m1 = _message(capsys)
        assert _retarget(fifo, tmp_path / "t.csv") == 1
        m2 = _message(capsys)
    finally:
        guard.cancel()
    assert str(fifo) in m1 and "named pipe (FIFO), not a regular file" in m1
    assert str(fifo) in m2 and "named pipe (FIFO), not a regular file" in m2


@pytest.mark.parametrize("kind", ["directory", "dangling", "loop"])
def test_non_regular_csv_entries_get_one_message_in_both_commands(inp, tmp_path, capsys, kind):
    dst = tmp_path / "in"
    (dst / "g1").mkdir(parents=True)
    (dst / "g1" / "a.csv").write_bytes((inp / "g1" / "walk1_subject1.csv").read_bytes())
    bad = dst / "g1" / "b.csv"
    if kind == "directory":
        bad.mkdir()
        expect = "is a directory, not a regular file"
    elif kind == "dangling":
        bad.symlink_to(dst / "nowhere.csv")
        expect = "dangling symbolic link"
    else:
        bad.symlink_to(bad)
        expect = "symbolic link loop"
    assert _shards(dst, tmp_path / "out") == 1
    m1 = _message(capsys)
    assert _retarget(bad, tmp_path / "t.csv") == 1
    m2 = _message(capsys)
    assert expect in m1 and expect in m2 and str(bad) in m1 and str(bad) in m2


def test_gzip_bomb_is_refused_without_expanding_it(inp, tmp_path, monkeypatch):
    monkeypatch.setenv("MER_MAX_MOTION_BYTES", str(2**20))
    f = tmp_path / "bomb.csv.gz"
    f.write_bytes(gzip.compress(b"0" * (64 * 2**20), compresslevel=9))  # 64 MiB of zeros in ~64 KB
    assert f.stat().st_size < 2**20
    with pytest.raises(MotionFormatError, match="after gunzip") as e:
        read_lafan1_csv(f, "g1")
    assert "MER_MAX_MOTION_BYTES" in str(e.value) and "1,048,576" in str(e.value)


def test_oversized_file_and_long_line_are_refused_with_the_limit(inp, tmp_path, monkeypatch):
    src = inp / "g1" / "walk1_subject1.csv"
    monkeypatch.setenv("MER_MAX_MOTION_BYTES", "1000")
    with pytest.raises(MotionFormatError, match="MER_MAX_MOTION_BYTES"):
        read_lafan1_csv(src, "g1")
    monkeypatch.delenv("MER_MAX_MOTION_BYTES")
    long = tmp_path / "long.csv"
    long.write_bytes(src.read_bytes() + b"1" * 70_000 + b"\n")
    with pytest.raises(MotionFormatError, match="MER_MAX_CSV_LINE_BYTES") as e:
        read_lafan1_csv(long, "g1")
    assert e.value.line == len(_rows(src)) + 1


def _motion(inp):
    m = read_lafan1_csv(inp / "g1" / "walk1_subject1.csv", "g1")
    return m.base_pos.copy(), m.base_quat.copy(), m.joints.copy(), m.columns


def test_plausibility_refuses_the_impossible_and_warns_on_the_unusual(inp):
    skel = get_skeleton("g1")
    pos, quat, q, cols = _motion(inp)
    assert check_motion_arrays(pos, quat, q, cols, skel, 30.0, path="w.csv") == []
    j = cols.index("left_knee_joint")

    bad = q.copy()
    bad[5, j] = skel.upper[skel.node_index("left_knee_joint")] + 4.0  # degrees-like: far past the stop
    with pytest.raises(MotionFormatError, match="far outside its limits") as e:
        check_motion_arrays(pos, quat, bad, cols, skel, 30.0, path="w.csv")
    assert e.value.line == 6 and e.value.element == f"column {j + 8}"

    odd = q.copy()
    odd[5:, j] = skel.upper[skel.node_index("left_knee_joint")] + 0.6
    w = check_motion_arrays(pos, quat, odd, cols, skel, 30.0, path="w.csv")
    assert any("w.csv:6:" in x and "outside its limits" in x for x in w)

    jump = pos.copy()
    jump[10:, 0] += 50.0  # 50 m in one frame: 1500 m/s
    with pytest.raises(MotionFormatError, match="physically possible") as e:
        check_motion_arrays(jump, quat, q, cols, skel, 30.0, path="w.csv")
    assert e.value.line == 11

    skip = pos.copy()
    skip[10:, 0] += 1.0  # 30 m/s: a glitch, not impossible
    w = check_motion_arrays(skip, quat, q, cols, skel, 30.0, path="w.csv")
    assert len(w) == 1 and "w.csv:11:" in w[0] and "m/s" in w[0]

    mm = pos * 1000.0  # millimetres: 1 m of height reads as 1000 m
    w = check_motion_arrays(mm, quat, q, cols, skel, 30.0, path="w.csv")
    assert any("root height" in x for x in w)


def test_warnings_reach_the_motion_and_the_log(inp, caplog):
    data = (inp / "g1" / "walk1_subject1.csv").read_bytes()
    rows = data.decode().splitlines()
    cells = rows[3].split(",")
    cells[0] = str(float(cells[0]) + 1.0)  # a 1 m root glitch on line 4
    rows[3] = ",".join(cells)
    with caplog.at_level("WARNING"):
        m = parse_lafan1("\n".join(rows).encode() + b"\n", load_robot("g1"), path="g.csv")
    assert len(m.warnings) == 1 and "g.csv:4:" in m.warnings[0]
    assert "unusual motion" in caplog.text


def test_real_lafan1_clips_pass_the_plausibility_checks(lafan1_dir):
    """No real clip is refused; the one warning is a real 0.94 m root jump in one frame."""
    warnings = []
    for robot in ("g1", "h1"):
        files = sorted((lafan1_dir / robot).glob("*.csv"))
        assert len(files) == 40
        for f in files:
            warnings += read_lafan1_csv(f, robot).warnings
    assert len(warnings) <= 1, warnings
