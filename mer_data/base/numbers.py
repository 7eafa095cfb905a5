"""One strict reader of the numbers file formats write: ASCII decimal, nothing Python adds.

Python's ``float`` and ``int`` accept more than any robot or motion format: ``1_0`` (= 10), full-width
and other Unicode digits (``１０``), ``nan``, ``inf``, ``infinity`` and surrounding Unicode spaces. A
URDF limit ``-1_0`` would silently become -10 rad. Every reader of numbers in text (URDF attributes,
motion CSV cells, BVH values, numbers mer reads from an MJCF) goes through :func:`parse_number` or
:func:`strict_float`, which accept exactly ``[+-]digits[.digits][e[+-]digits]`` (ASCII digits) and
``.5`` / ``5.`` forms, as C's ``strtod`` reads them in the formats' own readers.
"""

from __future__ import annotations

import math
import re

from .errors import MerError

__all__ = ["DECIMAL", "COUNT", "parse_number", "parse_count", "strict_float", "strict_count"]

#: A decimal number as the file formats write it (ASCII only: no ``_``, no Unicode digits, no inf/nan).
DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
#: A whole non-negative count (at most 12 digits).
COUNT = re.compile(r"[+]?[0-9]{1,12}\Z")


def parse_number(text: str | bytes) -> float | None:
    """The value of one decimal number (surrounding ASCII blanks allowed), or None if it is not one
    (``1_0``, ``１０``, ``nan``, ``inf``, ``0x10``, empty). The result is always finite or None."""
    if isinstance(text, bytes):
        try:
            text = text.decode("ascii")
        except UnicodeDecodeError:
            return None
    text = text.strip(" \t\r\n")
    if not DECIMAL.match(text):
        return None
    v = float(text)
    return v if math.isfinite(v) else None  # 1e999 overflows to inf


def parse_count(text: str | bytes) -> int | None:
    """A whole non-negative number written in ASCII digits (``10``, ``+3``), or None."""
    if isinstance(text, bytes):
        try:
            text = text.decode("ascii")
        except UnicodeDecodeError:
            return None
    text = text.strip(" \t\r\n")
    return int(text) if COUNT.match(text) else None


def strict_float(text: str | bytes | None, *, what: str, error: type[MerError] = MerError, path=None, line: int | None = None,
                 element: str | None = None) -> float:  # fmt: skip
    """:func:`parse_number` or ``error`` saying which text is not a number, where, and how to write it."""
    v = None if text is None else parse_number(text)
    if v is None:
        shown = repr(text[:40] if isinstance(text, (str, bytes)) else text)
        raise error(f"{what}: {shown} is not a decimal number", path=path, line=line, element=element,
                    fix="write plain decimal numbers (1.5, -2, 3e-4): no digit separators (1_0), no non-ASCII "
                        "digits, no nan/inf")  # fmt: skip
    return v


def strict_count(text: str | bytes | None, *, what: str, error: type[MerError] = MerError, path=None, line: int | None = None,
                 element: str | None = None) -> int:  # fmt: skip
    """:func:`parse_count` or ``error`` (as :func:`strict_float`)."""
    v = None if text is None else parse_count(text)
    if v is None:
        shown = repr(text[:40] if isinstance(text, (str, bytes)) else text)
        raise error(f"{what}: {shown} is not a whole number", path=path, line=line, element=element,
                    fix="write a whole number in ASCII digits (e.g. 10)")
    return v
