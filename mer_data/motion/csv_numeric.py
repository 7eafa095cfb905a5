"""Fast, strict parsing of headerless numeric CSV (comma separated, one row per line).

The fast path does all work in C loops over the bytes: numpy counts and locates the separators
(checking that every row has ``ncols`` cells), ``bytes.translate`` drops the decimal points, and
``np.fromstring`` parses the digits. Files written with a fixed number of decimals (LAFAN1:
``%.6f``) take this *fixed-point* route: the digits are parsed as int64 and divided by
``10**decimals`` -- one correctly rounded IEEE division of two exact numbers, hence bit-identical to
``strtod``/``np.loadtxt``. Other plain files take numpy's float parser.

Whenever the fast path sees anything unexpected (another byte between the numbers, a row with the
wrong number of cells, a cell it cannot parse, a non-finite value) it hands over to
:func:`exact_parse`, a line-by-line scan in Python that either parses the file (unusual but valid
spellings such as ``" 1.5"`` or ``"+2"``) or raises :class:`MotionFormatError` naming the file, the
line, the column and the cell. That slow scan runs only for such files.

Why not ``np.loadtxt(delimiter=",")`` (numpy 2.4.6, real LAFAN1 G1 clips, wall time best of 9, a
loaded 2-core machine): it is 2.5-4x slower -- walk1_subject1 (2.7 MB, 7840 rows) 12 ms here vs
46 ms, sprint1_subject2 (2.8 MB) 14 vs 56 ms, dance1_subject1 (1.3 MB) 11 vs 27 ms; 174 vs 57 MB/s
of CPU time over 12 clips -- with bit-identical values, and it is less strict: it accepts
``nan``, blank lines and ``#`` comments, its errors name no file, and it numbers rows
inconsistently (a bad cell on the 2nd line is "row 1", a short 2nd line "row 2").
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from mer_data.base.errors import MotionFormatError
from mer_data.base.limits import check_motion_size, limit, too_big
from mer_data.base.numbers import parse_number

__all__ = ["parse_numeric_csv", "exact_parse"]

_COMMA, _NL, _DOT, _MINUS = 44, 10, 46, 45
_MAX_EXACT = 2**53
_DROP_DOTS = bytes.maketrans(b"\n", b",")
_BOM = b"\xef\xbb\xbf"
_WIDE_BOMS = (b"\xff\xfe", b"\xfe\xff")


def parse_numeric_csv(data: bytes, ncols: int, *, path: str = "<bytes>", what: str | None = None) -> np.ndarray:
    """Parse ``data`` into a ``(rows, ncols)`` float64 array, or raise :class:`MotionFormatError`.

    Args:
        data: the file's bytes (already decompressed).
        ncols: the number of cells every row must have.
        path: shown in error messages.
        what: description of the expected layout, shown when a row has the wrong number of cells.

    A missing newline after the last row is accepted when the row is complete; blank lines at the
    very end are ignored; Windows line ends and a UTF-8 byte-order mark are accepted. A line longer
    than ``MER_MAX_CSV_LINE_BYTES`` (:mod:`mer_data.base.limits`) is refused with its number.
    """
    check_motion_size(data.count(b"\n") + 1, ncols, what="the CSV's table (rows x columns)", error=MotionFormatError,
                      path=path)  # fmt: skip
    if data.startswith(_BOM):  # spreadsheet programs and Windows editors write one
        data = data[len(_BOM) :]
    elif data.startswith(_WIDE_BOMS) or b"\0" in data[:64]:
        raise MotionFormatError(
            "the file is UTF-16 text or binary, not a plain-text CSV",
            path=path,
            line=1,
            fix="save it as UTF-8 (or ASCII) comma-separated text",
        )
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n")
    cut_short = not data.endswith(b"\n")  # a file cut mid-row has no final line end
    data = data.rstrip(b"\n\r \t")
    if not data:
        raise MotionFormatError("the file is empty (no rows)", path=path, fix="re-export or re-download the clip")
    data += b"\n"
    _check_line_length(data, path)
    values = _fast(data, ncols)
    if values is None:  # something is off: find out exactly what and where
        values = exact_parse(data, ncols, path=path, what=what, cut_short=cut_short)
    return values


def _check_line_length(data: bytes, path: str) -> None:
    """Every line within ``MER_MAX_CSV_LINE_BYTES`` (one vectorized pass; ``data`` ends with a newline)."""
    ends = np.flatnonzero(np.frombuffer(data, np.uint8) == _NL)
    lengths = np.diff(ends, prepend=-1) - 1
    i = int(np.argmax(lengths))
    if lengths[i] > limit("MER_MAX_CSV_LINE_BYTES"):
        msg, fix = too_big("MER_MAX_CSV_LINE_BYTES", int(lengths[i]))
        raise MotionFormatError(msg, path=path, line=i + 1, fix=fix)


def _fast(data: bytes, ncols: int) -> np.ndarray | None:
    buf = np.frombuffer(data, np.uint8)
    nrows = int(np.count_nonzero(buf == _NL))
    nfields = nrows * ncols
    if int(np.count_nonzero(buf == _COMMA)) != nrows * (ncols - 1):
        return None
    seps = np.flatnonzero(buf <= _COMMA)  # ',' and '\n' -- and any other low byte, which fails below
    # only commas and newlines, and every ncols-th separator a newline: every row has ncols cells
    if len(seps) != nfields or not (buf[seps[ncols - 1 :: ncols]] == _NL).all():
        return None
    values = _fixed_point(data, buf, seps, nfields)
    if values is None:
        values = _fromstring(data.replace(b"\n", b","), np.float64)
        if values is None or len(values) != nfields:
            return None
    if not np.isfinite(values).all():
        return None
    return values.reshape(nrows, ncols)


def _fromstring(text: bytes, dtype) -> np.ndarray | None:
    """numpy's C parser; None where it stops early (numpy warns or raises, depending on the version)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(text, dtype=dtype, sep=",")
        except (ValueError, DeprecationWarning):
            return None


def _fixed_point(data: bytes, buf: np.ndarray, seps: np.ndarray, nfields: int) -> np.ndarray | None:
    """Every cell ``[-]digits.digits`` with the same number of decimals -> exact int64 route."""
    first_dot = np.flatnonzero(buf[: seps[0]] == _DOT)
    if len(first_dot) != 1:
        return None
    k = int(seps[0]) - int(first_dot[0])  # separator minus dot position = decimals + 1
    decimals = k - 1
    # one dot per cell, each exactly `decimals` before the cell's end
    if decimals < 1 or int(np.count_nonzero(buf == _DOT)) != nfields or not (buf[seps - k] == _DOT).all():
        return None
    ints = _fromstring(data.translate(_DROP_DOTS, b"."), np.int64)
    if ints is None or len(ints) != nfields or (np.abs(ints) >= _MAX_EXACT).any():
        return None  # (numpy saturates int64 overflow, which the bound catches)
    values = ints / float(10**decimals)
    zeros = np.flatnonzero(ints == 0)
    if len(zeros):  # "-0.000000" is -0.0, as strtod reads it
        starts = np.concatenate([[0], seps[:-1] + 1])[zeros]
        values[zeros[buf[starts] == _MINUS]] = -0.0
    return values


def exact_parse(
    data: bytes, ncols: int, *, path: str, what: str | None = None, cut_short: bool = False
) -> np.ndarray:
    """Line-by-line parse with Python's ``float``: the values, or :class:`MotionFormatError` at the
    first bad line and cell.

    ``cut_short``: the file did not end with a line end; a short last row is then reported as a
    truncated file rather than a wrong layout.
    """
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    layout = f" ({what})" if what else ""
    last = len(lines)
    out = np.empty((last, ncols))
    for i, raw in enumerate(lines, start=1):
        line = raw.rstrip(b"\r")
        if not line.strip():
            raise MotionFormatError("blank line inside the data", path=path, line=i, fix="remove the blank line")
        cells = line.split(b",")
        if len(cells) != ncols:
            if i == last and i > 1 and cut_short and len(cells) < ncols:
                raise MotionFormatError(
                    f"truncated last row: {len(cells)} of {ncols} values{layout}; the file ends mid-row",
                    path=path,
                    line=i,
                    fix="the file was cut short (interrupted download or copy?): fetch it again, or delete the last line",
                )
            raise MotionFormatError(
                f"{len(cells)} values on this line, expected {ncols}{layout}",
                path=path,
                line=i,
                fix="check that the file belongs to this robot (each robot has its own column layout)",
            )
        for j, cell in enumerate(cells, start=1):
            text = cell.decode("utf-8", "replace").strip()
            v = parse_number(text)  # strict: Python's float would read 1_0 and full-width digits
            if v is None and text.lower().lstrip("+-") in ("nan", "inf", "infinity"):
                v = math.nan
            if v is None:
                raise MotionFormatError(
                    f"non-numeric cell {text!r} in column {j}",
                    path=path,
                    line=i,
                    element=f"column {j}",
                    fix="the file must be headerless decimal numbers only (no 1_0, no non-ASCII digits); "
                    "remove headers or stray text",
                )
            if not math.isfinite(v):
                raise MotionFormatError(
                    f"non-finite value {text!r} in column {j}",
                    path=path,
                    line=i,
                    element=f"column {j}",
                    fix="repair or drop the frames with NaN/inf (the source motion has gaps)",
                )
            out[i - 1, j - 1] = v
    return out
