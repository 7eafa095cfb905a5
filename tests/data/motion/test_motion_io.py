"""Reading and writing LAFAN1 motion CSVs: exact values, every kind of bad input, real clips."""

from __future__ import annotations

import gzip
import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mer_data.base.errors import MotionFormatError, UnknownRobotError
from mer_data.motion.csv_numeric import parse_numeric_csv
from mer_data.motion.lafan1 import QUAT_TOLERANCE, lafan1_columns, parse_lafan1, read_lafan1_csv, write_lafan1_csv
from mer_data.robots.registry import load_robot
from mer_data.synthesis.walking import walking_motion

G1_COLS = 36


def _g1_rows(n: int = 5) -> list[list[float]]:
    m = walking_motion("g1", (n - 1) / 30)
    q = m.base_quat
    table = np.column_stack([m.base_pos, q[:, 1:4], q[:, :1], m.joints])
    return table.tolist()


def _csv(rows) -> bytes:
    return ("\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n").encode()


def _err(data: bytes, robot="g1", path="clip.csv") -> MotionFormatError:
    with pytest.raises(MotionFormatError) as exc:
        parse_lafan1(data, load_robot(robot), path=path)
    return exc.value


# ---- exact values -------------------------------------------------------------------------------
def test_layouts_of_the_builtin_robots():
    assert len(lafan1_columns(load_robot("g1"))) == 29 and len(lafan1_columns(load_robot("h1"))) == 19 and len(lafan1_columns(load_robot("h1_2"))) == 27


@pytest.mark.parametrize("robot", ["g1", "h1", "h1_2"])
@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
def test_write_read_round_trip(tmp_path, robot, suffix):
    m = walking_motion(robot, 1.0)
    p = write_lafan1_csv(tmp_path / f"clip{suffix}", m)
    back = read_lafan1_csv(p, robot)
    assert back.num_frames == m.num_frames and back.columns == lafan1_columns(load_robot(robot))
    np.testing.assert_allclose(back.base_pos, m.base_pos, atol=5e-7)
    np.testing.assert_allclose(back.joints, m.joints, atol=5e-7)
    np.testing.assert_allclose(np.abs((back.base_quat * m.base_quat).sum(1)), 1.0, atol=1e-6)  # wxyz inside
    if suffix == ".csv.gz":
        assert gzip.decompress(p.read_bytes()).count(b"\n") == m.num_frames


def test_quaternion_is_converted_to_wxyz():
    rows = _g1_rows(2)
    rows[0][3:7] = [0.0, 0.0, 0.6, 0.8]  # x y z w
    m = parse_lafan1(_csv(rows), load_robot("g1"))
    np.testing.assert_array_equal(m.base_quat[0], [0.8, 0.0, 0.0, 0.6])


def test_fast_parser_is_bit_identical_to_loadtxt_on_varied_formats():
    rng = np.random.default_rng(1)
    a = rng.normal(scale=3, size=(50, 7))
    a[3, 2] = -0.0
    a[4, 1] = 0.0
    for fmt in ("%.6f", "%.3f", "%.9g", "%.4e"):
        text = ("\n".join(",".join(fmt % v for v in r) for r in a) + "\n").encode()
        got = parse_numeric_csv(text, 7)
        ref = np.loadtxt(io.BytesIO(text), delimiter=",")
        assert got.tobytes() == ref.tobytes(), fmt
    neg = parse_numeric_csv(b"-0.000000,1.000000\n", 2)
    assert np.signbit(neg[0, 0])
    # unusual but valid spellings go through the exact line-by-line route
    odd = parse_numeric_csv(b" 1.5,+2,3e-1\n4, 5 ,-6.25\n", 3)
    assert odd.tolist() == [[1.5, 2.0, 0.3], [4.0, 5.0, -6.25]]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=3, max_size=3), min_size=1, max_size=20),
    st.integers(1, 9),
)
def test_fast_parser_matches_python_float_property(rows, decimals):
    text = "\n".join(",".join(f"{v:.{decimals}f}" for v in r) for r in rows)
    got = parse_numeric_csv(text.encode(), 3)
    ref = [[float(c) for c in line.split(",")] for line in text.split("\n")]
    assert got.tobytes() == np.array(ref, np.float64).tobytes()


def test_tolerated_variants():
    rows = _g1_rows(3)
    base = parse_lafan1(_csv(rows), load_robot("g1"))
    no_final_newline = parse_lafan1(_csv(rows).rstrip(b"\n"), load_robot("g1"))
    crlf = parse_lafan1(_csv(rows).replace(b"\n", b"\r\n"), load_robot("g1"))
    trailing_blank = parse_lafan1(_csv(rows) + b"\n\n", load_robot("g1"))
    for m in (no_final_newline, crlf, trailing_blank):
        assert np.array_equal(m.joints, base.joints) and np.array_equal(m.base_quat, base.base_quat)


def test_non_unit_quaternion_within_tolerance_is_renormalized():
    rows = _g1_rows(3)
    rows[1][3:7] = [v * (1 + 0.5 * QUAT_TOLERANCE) for v in rows[1][3:7]]
    m = parse_lafan1(_csv(rows), load_robot("g1"))
    assert abs(np.linalg.norm(m.base_quat[1]) - 1) < 1e-12


# ---- bad input: each names the file and the line ------------------------------------------------
def test_wrong_column_count():
    rows = _g1_rows(4)
    rows[2] = rows[2][:-1]
    e = _err(_csv(rows))
    assert e.path == "clip.csv" and e.line == 3 and "35 values" in str(e) and "expected 36" in str(e) and "g1" in str(e)


def test_h1_file_read_as_g1_is_refused_at_line_1():
    h1 = walking_motion("h1", 0.2)
    q = h1.base_quat
    data = _csv(np.column_stack([h1.base_pos, q[:, 1:], q[:, :1], h1.joints]).tolist())
    e = _err(data, "g1")
    assert e.line == 1 and "26 values" in str(e) and "expected 36" in str(e)


@pytest.mark.parametrize("cell", ["abc", "1.0x", "", "--1"])
def test_non_numeric_cell(cell):
    rows = [[f"{v:.6f}" for v in r] for r in _g1_rows(4)]
    rows[1][10] = cell
    e = _err(("\n".join(",".join(r) for r in rows) + "\n").encode())
    assert e.line == 2 and e.element == "column 11" and "non-numeric" in str(e)


def test_header_line_is_a_non_numeric_cell_at_line_1():
    header = ",".join(["root_pos_x"] * G1_COLS) + "\n"
    e = _err(header.encode() + _csv(_g1_rows(2)))
    assert e.line == 1 and "root_pos_x" in str(e)


@pytest.mark.parametrize("cell", ["nan", "inf", "-inf", "NaN"])
def test_non_finite_values(cell):
    rows = [[f"{v:.6f}" for v in r] for r in _g1_rows(4)]
    rows[3][20] = cell
    e = _err(("\n".join(",".join(r) for r in rows) + "\n").encode())
    assert e.line == 4 and e.element == "column 21" and "non-finite" in str(e)


def test_truncated_last_row():
    data = _csv(_g1_rows(5))
    cut = data[: data.rstrip(b"\n").rfind(b",", 0, len(data) - 40)]  # the file stops mid-row
    e = _err(cut)
    assert e.line == 5 and "truncated last row" in str(e)


def test_short_last_row_that_ends_its_line_is_a_layout_error():
    rows = _g1_rows(3)
    rows[2] = rows[2][:20]
    e = _err(_csv(rows))
    assert e.line == 3 and "20 values on this line, expected 36" in str(e)


@pytest.mark.parametrize("data", [b"", b"\n\n", b"   \n"])
def test_empty_file(data):
    e = _err(data)
    assert "empty" in str(e) and e.path == "clip.csv"


def test_blank_line_inside_the_data():
    data = _csv(_g1_rows(2)) + b"\n" + _csv(_g1_rows(2))
    e = _err(data)
    assert e.line == 3 and "blank line" in str(e)


def test_non_unit_quaternion_is_refused():
    rows = _g1_rows(6)
    rows[4][3:7] = [0.1, 0.2, 0.3, 0.5]
    e = _err(_csv(rows))
    assert e.line == 5 and e.element == "root quaternion" and "norm" in str(e) and "x, y, z, w" in e.fix


def test_corrupt_gzip(tmp_path):
    p = tmp_path / "clip.csv.gz"
    p.write_bytes(b"not gzip at all")
    with pytest.raises(MotionFormatError, match="gzip"):
        read_lafan1_csv(p, "g1")


def test_unknown_robot_and_robot_without_a_lafan1_layout(tmp_path):
    """A robot without LAFAN1 data reads mer's own layout (its joints in node order, what
    ``mer retarget -o`` writes), so every built-in robot can be a source; a G1 file is not it."""
    p = write_lafan1_csv(tmp_path / "c.csv", walking_motion("g1", 0.2))
    with pytest.raises(UnknownRobotError, match="unknown robot 'nope'.*g1"):
        read_lafan1_csv(p, "nope")
    atlas = load_robot("atlas")
    assert atlas.card.lafan1_columns is None and lafan1_columns(atlas) == tuple(atlas.skeleton.joint_names)
    with pytest.raises(MotionFormatError, match="expected 37 .atlas: root xyz, root quaternion xyzw, 30 joint angles"):
        read_lafan1_csv(p, "atlas")


def test_errors_name_the_file(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_bytes(b"1,2,3\n")
    with pytest.raises(MotionFormatError) as exc:
        read_lafan1_csv(p, "g1")
    assert str(exc.value).startswith(f"{p}:1:")


# ---- real clips ------------------------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["g1", "h1"])
def test_real_clip_matches_loadtxt_bit_for_bit(lafan1_dir, robot):
    path = lafan1_dir / robot / "fight1_subject2.csv"
    m = read_lafan1_csv(path, robot)
    ref = np.loadtxt(path, delimiter=",")
    assert m.joints.tobytes() == np.ascontiguousarray(ref[:, 7:]).tobytes()
    assert m.base_pos.tobytes() == np.ascontiguousarray(ref[:, :3]).tobytes()
    assert np.allclose(m.base_quat[:, 0], ref[:, 6] / np.linalg.norm(ref[:, 3:7], axis=1))
    # design notes: read as w-first, the feet would float; read correctly, the root is ~0.7-1 m up
    assert 0.5 < np.median(m.base_pos[:, 2]) < 1.2


def test_a_csv_of_another_robot_names_that_robot():
    """A G1 file read as H1's: the column count is G1's layout, and the error says so (and the fix)."""
    with pytest.raises(MotionFormatError) as e:
        parse_lafan1(_csv(_g1_rows(3)), load_robot("h1"), path="walk.csv")
    assert e.value.line == 1 and "36 columns is the layout of g1, not h1" in str(e.value) and "--source g1" in str(e.value)
    rows = _g1_rows(3)
    rows[0] = rows[0][:20]  # a count no robot has: the plain message
    with pytest.raises(MotionFormatError, match="20 values on this line, expected 36") as e:
        parse_lafan1(_csv(rows), load_robot("g1"))
    assert "layout of" not in str(e.value)
