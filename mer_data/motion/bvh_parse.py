"""The grammar of a BVH file: the HIERARCHY (joints, offsets, channels) and the MOTION table.

:func:`parse_sections` turns the text into joints and the (F, C) channel values, strictly (every
problem a :class:`~mer_data.base.errors.BVHError` with the line); :mod:`.bvh` adds units, up axis,
facing and the kinematics. Sizes are bounded while reading: the file (``MER_MAX_BVH_BYTES``), a
line, the joints, the declared frames, and the table it produces (:func:`~mer_data.base.limits.check_motion_size`).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass

import numpy as np

from mer_data.base.errors import BVHError
from mer_data.base.limits import check_motion_size, limit, too_big
from mer_data.base.numbers import DECIMAL

__all__ = ["BvhJoint", "parse_sections", "MAX_BVH_NUMBER"]

#: Largest magnitude accepted for any number of the file (keeps every computed value finite).
MAX_BVH_NUMBER = 1e9
_CHANNELS = {f"{a}{k}".upper(): f"{a}{k}" for k in ("position", "rotation") for a in "XYZ"}
_NUMBER = DECIMAL
_COUNT = re.compile(r"[0-9]{1,9}\Z")
_NOT_NUMERIC = re.compile(r"[^0-9eE+\-.\s]")
_FILE_FIX = "re-export the BVH from your motion capture tool"
_BLOCK = 4096  # frame lines split at a time


@dataclass(frozen=True)
class BvhJoint:
    """One joint (or End Site) of the hierarchy, in file order (parents first).

    Attributes:
        name: the joint's name (End Sites: ``<parent>_End``).
        parent: index of the parent joint, -1 for the ROOT.
        offset: (3,) OFFSET in file units and axes.
        channels: channel names as written (``"Zrotation"``...), canonical capitalisation.
        column: column of the first channel in the frame table.
        line: 1-based line of the ROOT / JOINT / End Site keyword.
        end_site: True for End Sites.
    """

    name: str
    parent: int
    offset: tuple[float, float, float]
    channels: tuple[str, ...]
    column: int
    line: int
    end_site: bool = False

    @property
    def rotation_channels(self) -> tuple[tuple[int, str], ...]:
        """(column, axis ``"x"|"y"|"z"``) of each rotation channel, in the order written."""
        return tuple((self.column + i, c[0].lower()) for i, c in enumerate(self.channels) if c.endswith("rotation"))

    @property
    def position_channels(self) -> tuple[tuple[int, int], ...]:
        """(column, component 0-2) of each position channel."""
        return tuple((self.column + i, "XYZ".index(c[0])) for i, c in enumerate(self.channels) if c.endswith("position"))


def parse_sections(text: str, path: str) -> tuple[list[BvhJoint], np.ndarray, float, int]:
    """The hierarchy, the (F, C) channel values, the Frame Time [s] and the 1-based line of the
    first frame of BVH text; :class:`BVHError` at the first problem (module :mod:`.bvh`'s docstring)."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    _check_line_lengths(lines, path)
    motion_at = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    last = len(lines)  # the last line that is not blank
    while last > 1 and not lines[last - 1].strip():
        last -= 1
    header = lines if motion_at is None else lines[:motion_at]
    joints = _Hierarchy(header, path, last if motion_at is None else motion_at + 1).parse(motion_at)
    if motion_at is None:
        raise BVHError("there is no MOTION section (the file ends after the hierarchy)", path=path, line=last,
                       fix="the file was cut short or is a hierarchy only: " + _FILE_FIX)  # fmt: skip
    C = sum(len(j.channels) for j in joints)
    if C == 0:
        raise BVHError("the hierarchy has no CHANNELS: there is no motion to read", path=path, line=joints[0].line,
                       fix="give the ROOT at least its CHANNELS (e.g. CHANNELS 6 Xposition ... Yrotation)")  # fmt: skip
    frames, frame_time, first = _motion_header(lines, motion_at, path)
    values = _parse_frames(lines, first, frames, joints, path, cut_short=not text.endswith(("\n", "\r")))
    return joints, values, frame_time, first + 2


def _check_line_lengths(lines: list[str], path: str) -> None:
    """Every line within ``MER_MAX_BVH_LINE_BYTES`` (UTF-8 bytes; only lines that could be over are encoded)."""
    cap = limit("MER_MAX_BVH_LINE_BYTES")
    for i, line in enumerate(lines):
        if len(line) * 4 > cap and (n := len(line.encode("utf-8"))) > cap:
            msg, fix = too_big("MER_MAX_BVH_LINE_BYTES", n)
            raise BVHError(msg, path=path, line=i + 1, fix=fix)


class _Hierarchy:
    """Parser of the HIERARCHY section: tokens with their lines; ROOT/JOINT names are the rest of
    their line (they may contain spaces). Iterative (a deep hierarchy cannot exhaust the stack)."""

    def __init__(self, lines: list[str], path: str, end_line: int) -> None:
        self.path = path
        self.end_line = end_line  # the MOTION line, or the last line of the file
        self.toks: list[tuple[str, int]] = []  # (text, 1-based line)
        for i, raw in enumerate(lines, start=1):
            words = raw.split()
            if words and words[0].upper() in ("ROOT", "JOINT"):
                name = raw.strip()[len(words[0]) :].strip()
                brace = name.endswith("{")
                name = name[:-1].strip() if brace else name
                self.toks += [(words[0], i), (name, i)] + ([("{", i)] if brace else [])
            else:
                self.toks += [(w, i) for w in words]
        self.pos = 0
        self.joints: list[dict] = []
        self.lines_of: dict[str, int] = {}
        self.column = 0

    # -- token access --
    def _peek(self) -> tuple[str, int] | None:
        return self.toks[self.pos] if self.pos < len(self.toks) else None

    def _take(self, expected: str, where: str) -> tuple[str, int]:
        tok = self._peek()
        if tok is None:
            self._fail(f"the hierarchy ends where {expected} was expected ({where})", self.end_line,
                       "complete the hierarchy (every '{' needs its '}', and MOTION follows the ROOT's '}')")  # fmt: skip
        self.pos += 1
        return tok

    def _expect(self, word: str, where: str) -> int:
        tok = self._take(f"'{word}'", where)
        if tok[0].upper() != word.upper():
            self._fail(f"expected '{word}' ({where}), found {tok[0]!r}", tok[1], _FILE_FIX)
        return tok[1]

    def _fail(self, message: str, line: int, fix: str, element: str | None = None):
        raise BVHError(message, path=self.path, line=line, element=element, fix=fix)

    # -- grammar --
    def parse(self, motion_at: int | None) -> list[BvhJoint]:
        tok = self._peek()
        if tok is None or tok[0].upper() != "HIERARCHY":
            found = "an empty file" if tok is None else repr(tok[0][:40])
            self._fail(f"not a BVH file: it must start with HIERARCHY, found {found}", tok[1] if tok else 1,
                       "pass a BVH motion capture file (text starting with HIERARCHY)")  # fmt: skip
        self.pos += 1
        tok = self._take("ROOT", "after HIERARCHY")
        if tok[0].upper() != "ROOT":
            self._fail(f"expected ROOT after HIERARCHY, found {tok[0]!r}", tok[1], _FILE_FIX)
        stack = [self._joint_header(-1, tok[1])]  # open joints: (index, line of its '{')
        while stack:
            tok = self._peek()
            parent, opened = stack[-1]
            pname = self.joints[parent]["name"]
            if tok is None:
                where = "MOTION starts" if motion_at is not None else "the file ends"
                self._fail(f"unbalanced braces: {where} inside joint {pname!r}, whose '{{' on line {opened} is never "
                           "closed", self.end_line, "add the missing '}' (one per ROOT, JOINT and End Site)")  # fmt: skip
            self.pos += 1
            word = tok[0].upper()
            if word == "JOINT":
                stack.append(self._joint_header(parent, tok[1]))
            elif word == "END":
                self._end_site(parent, tok[1])
            elif word == "}":
                stack.pop()
            elif word == "ROOT":
                self._fail(f"ROOT inside joint {pname!r}: a ROOT's '}}' is missing, or the file has several ROOTs",
                           tok[1], "balance the braces; mer reads one skeleton (one ROOT) per file")  # fmt: skip
            elif word in ("OFFSET", "CHANNELS"):
                self._fail(f"{tok[0]} out of place in joint {pname!r}: OFFSET then CHANNELS come once, right after "
                           "the joint's '{'", tok[1], _FILE_FIX)  # fmt: skip
            else:
                self._fail(f"unexpected {tok[0][:40]!r} in joint {pname!r} (expected JOINT, End Site or '}}')", tok[1],
                           _FILE_FIX)  # fmt: skip
        tok = self._peek()
        if tok is not None:
            if tok[0] == "}":
                self._fail("unbalanced braces: a '}' closes nothing (the ROOT is already closed)", tok[1],
                           "remove the extra '}'")  # fmt: skip
            if tok[0].upper() == "ROOT":
                self._fail("a second ROOT: several skeletons in one file are not supported", tok[1],
                           "export one skeleton per file")  # fmt: skip
            self._fail(f"unexpected {tok[0][:40]!r} after the hierarchy (expected MOTION)", tok[1], _FILE_FIX)
        return self._joints()

    def _add(self, **kw) -> int:
        if len(self.joints) >= limit("MER_MAX_BVH_JOINTS"):
            msg, fix = too_big("MER_MAX_BVH_JOINTS", f"over {len(self.joints):,}")
            raise BVHError(msg, path=self.path, line=kw["line"], fix=fix)
        self.joints.append(kw)
        return len(self.joints) - 1

    def _joint_header(self, parent: int, line: int) -> tuple[int, int]:
        kind = "ROOT" if parent < 0 else "JOINT"
        name_tok = self._take("a joint name", f"after {kind}")
        name = name_tok[0]
        if not name or name in ("{", "}"):
            self._fail(f"{kind} without a name", line, f"give every joint a name: {kind} NAME")
        if name in self.lines_of:
            self._fail(f"duplicate joint name {name!r} (also on line {self.lines_of[name]})", line,
                       "give every joint a unique name", element=f"joint {name!r}")  # fmt: skip
        self.lines_of[name] = line
        opened = self._expect("{", f"after {kind} {name}")
        offset = self._offset(name)
        channels = self._channels(name) if (self._peek() or ("",))[0].upper() == "CHANNELS" else ()
        index = self._add(name=name, parent=parent, offset=offset, channels=channels, column=self.column, line=line)
        self.column += len(channels)
        return index, opened

    def _end_site(self, parent: int, line: int) -> None:
        self._expect("Site", "End Site")
        pname = self.joints[parent]["name"]
        self._expect("{", f"after End Site of {pname}")
        offset = self._offset(f"End Site of {pname}")
        tok = self._take("'}'", f"closing the End Site of {pname}")
        if tok[0] != "}":
            self._fail(f"an End Site holds only an OFFSET, found {tok[0][:40]!r} (End Site of {pname!r})", tok[1],
                       "close the End Site with '}' after its OFFSET; End Sites have no channels or children")  # fmt: skip
        self._add(name=None, parent=parent, offset=offset, channels=(), column=self.column, line=line)

    def _offset(self, owner: str) -> tuple[float, float, float]:
        line = self._expect("OFFSET", f"first in {owner}")
        vals = []
        for k in range(3):
            tok = self._take("a number", f"OFFSET of {owner}")
            if tok[1] != line:
                self._fail(f"OFFSET of {owner} has {k} numbers, expected 3", line, "write OFFSET x y z")
            vals.append(_number(tok[0], self.path, tok[1], f"OFFSET of {owner}"))
        nxt = self._peek()
        if nxt is not None and nxt[1] == line and _NUMBER.match(nxt[0]):
            self._fail(f"OFFSET of {owner} has more than 3 numbers ({nxt[0][:40]!r})", line, "write OFFSET x y z")
        return (vals[0], vals[1], vals[2])

    def _channels(self, owner: str) -> tuple[str, ...]:
        line = self._take("CHANNELS", owner)[1]
        tok = self._take("the channel count", f"CHANNELS of {owner}")
        if not _COUNT.match(tok[0]) or int(tok[0]) > 6:
            self._fail(f"CHANNELS of {owner}: the count {tok[0][:40]!r} is not a number from 0 to 6", line,
                       "write CHANNELS N NAME...: at most 3 position and 3 rotation channels")  # fmt: skip
        n, out = int(tok[0]), []
        for k in range(n):
            tok = self._peek()
            if tok is None or tok[1] != line:
                self._fail(f"CHANNELS of {owner} announces {n} channels but lists {k}", line,
                           "make the count match the channel names")  # fmt: skip
            self.pos += 1
            name = _CHANNELS.get(tok[0].upper())
            if name is None:
                self._fail(f"unknown channel {tok[0][:40]!r} in joint {owner!r}", line,
                           "channels are Xposition, Yposition, Zposition, Xrotation, Yrotation, Zrotation",
                           element=f"joint {owner!r}")  # fmt: skip
            if name in out:
                self._fail(f"channel {name} appears twice in joint {owner!r}", line, "list each channel once")
            out.append(name)
        nxt = self._peek()
        if nxt is not None and nxt[1] == line:
            self._fail(f"CHANNELS of {owner} announces {n} channels but lists more ({nxt[0][:40]!r})", line,
                       "make the count match the channel names")  # fmt: skip
        return tuple(out)

    def _joints(self) -> list[BvhJoint]:
        taken = set(self.lines_of)
        out = []
        for j in self.joints:
            name = j["name"]
            if name is None:  # an End Site: <parent>_End, made unique
                stem = f"{self.joints[j['parent']]['name']}_End"
                name, k = stem, 2
                while name in taken:
                    name, k = f"{stem}_{k}", k + 1
                taken.add(name)
            out.append(BvhJoint(name, j["parent"], j["offset"], j["channels"], j["column"], j["line"],
                                end_site=j["name"] is None))  # fmt: skip
        return out


def _number(text: str, path: str, line: int, what: str) -> float:
    if not _NUMBER.match(text):
        raise BVHError(f"{what}: {text[:40]!r} is not a number", path=path, line=line,
                       fix="numbers are decimal (1.5, -2, 3e-4); remove stray text")  # fmt: skip
    v = float(text)
    if not abs(v) <= MAX_BVH_NUMBER:
        raise BVHError(f"{what}: {text[:40]} is beyond +-{MAX_BVH_NUMBER:g}", path=path, line=line,
                       fix="check the export (units, a corrupt value)")  # fmt: skip
    return v


_FRAMES = re.compile(r"\s*frames\s*:\s*(\S+)\s*\Z", re.I)
_FRAME_TIME = re.compile(r"\s*frame\s+time\s*:\s*(\S+)\s*\Z", re.I)


def _motion_header(lines: list[str], motion_at: int, path: str) -> tuple[int, float, int]:
    """Frames, Frame Time and the 0-based index of the Frame Time line."""
    fix = "after MOTION write 'Frames: N' and 'Frame Time: SECONDS' on two lines"
    i = motion_at + 1
    m = _FRAMES.match(lines[i]) if i < len(lines) else None
    if m is None:
        found = repr(lines[i][:60]) if i < len(lines) else "the end of the file"
        raise BVHError(f"expected 'Frames: N' after MOTION, found {found}", path=path, line=i + 1, fix=fix)
    if not _COUNT.match(m[1]):
        raise BVHError(f"Frames: {m[1][:40]!r} is not a whole number", path=path, line=i + 1, fix=fix)
    frames = int(m[1])
    if frames == 0:
        raise BVHError("Frames: 0, the clip has no frames", path=path, line=i + 1, fix="export at least one frame")
    if frames > limit("MER_MAX_BVH_FRAMES"):
        msg, how = too_big("MER_MAX_BVH_FRAMES", frames)
        raise BVHError(msg, path=path, line=i + 1, fix=how)
    i += 1
    m = _FRAME_TIME.match(lines[i]) if i < len(lines) else None
    if m is None:
        found = repr(lines[i][:60]) if i < len(lines) else "the end of the file"
        raise BVHError(f"expected 'Frame Time: SECONDS', found {found}", path=path, line=i + 1, fix=fix)
    ft = _number(m[1], path, i + 1, "Frame Time")
    if not ft > 0:
        raise BVHError(f"Frame Time must be positive (seconds per frame), got {m[1]}", path=path, line=i + 1,
                       fix="write the seconds per frame, e.g. Frame Time: 0.0333333 for 30 Hz")  # fmt: skip
    return frames, ft, i


def _column_labels(joints: list[BvhJoint]) -> list[str]:
    return [f"{c} of {j.name!r}" for j in joints for c in j.channels]


def _parse_frames(lines: list[str], header: int, frames: int, joints: list[BvhJoint], path: str, *,
                  cut_short: bool) -> np.ndarray:  # fmt: skip
    """(F, C) values of the frame lines after the Frame Time line (0-based index ``header``).

    Read in blocks of :data:`_BLOCK` lines into the preallocated table: the memory is the table and
    one block's words, not a Python string per number of the file."""
    C = sum(len(j.channels) for j in joints)
    end = len(lines)
    while end > header + 1 and not lines[end - 1].strip():
        end -= 1
    n = end - (header + 1)  # frame lines
    first = header + 2  # 1-based line of the first frame
    check_motion_size(frames, C, what="the BVH's channel table (frames x channels)", error=BVHError, path=path,
                      line=header + 1)  # fmt: skip
    values = np.empty((min(frames, n), C))
    labels = None
    for b0 in range(0, min(frames, n), _BLOCK):
        block = lines[header + 1 + b0 : header + 1 + min(b0 + _BLOCK, frames, n)]
        rows = [line.split() for line in block]
        for i, row in enumerate(rows):
            if len(row) != C:
                _wrong_count(row, b0 + i, C, n, first, path, cut_short)
        got = None
        if not any(_NOT_NUMERIC.search(line) for line in block):  # no letters: float() reads exactly our syntax
            try:
                got = np.fromiter(map(float, itertools.chain.from_iterable(rows)), np.float64, len(rows) * C)
            except ValueError:
                pass
        if got is None:
            labels = labels or _column_labels(joints)
            _find_bad_number(rows, first + b0, path, labels)
        values[b0 : b0 + len(rows)] = got.reshape(len(rows), C)
        bad = ~(np.abs(values[b0 : b0 + len(rows)]) <= MAX_BVH_NUMBER)
        if bad.any():
            i, c = (int(x[0]) for x in np.nonzero(bad))
            raise BVHError(f"value {rows[i][c][:40]} of {_column_labels(joints)[c]} is not finite or beyond "
                           f"+-{MAX_BVH_NUMBER:g}", path=path, line=first + b0 + i, element=f"frame {b0 + i + 1}",
                           fix="repair or drop the frames with NaN/inf (the capture has gaps)")  # fmt: skip
    if n < frames:
        raise BVHError(f"truncated: the file has {n} of the {frames} frames that 'Frames:' announces",
                       path=path, line=first + n - 1 if n else header + 1,
                       fix=f"the file was cut short (interrupted copy?): fetch it again, or set Frames: {n}")  # fmt: skip
    if n > frames:
        raise BVHError(f"{n} frame lines, but 'Frames:' says {frames}", path=path, line=first + frames,
                       fix=f"set Frames: {n}, or delete the lines after frame {frames}")  # fmt: skip
    return values


def _wrong_count(row: list[str], i: int, C: int, n: int, first: int, path: str, cut_short: bool):
    if not row:
        raise BVHError("blank line inside the frame data", path=path, line=first + i, fix="remove the blank line")
    if i == n - 1 and cut_short and len(row) < C:
        raise BVHError(f"truncated last frame: {len(row)} of {C} values; the file ends mid-line", path=path,
                       line=first + i, fix="the file was cut short: fetch it again, or delete the last line "
                       "and lower Frames: by one")  # fmt: skip
    raise BVHError(f"{len(row)} values on this frame line, expected {C} (one per channel of the hierarchy)",
                   path=path, line=first + i, element=f"frame {i + 1}",
                   fix="every frame line needs one number per channel, in hierarchy order")  # fmt: skip


def _find_bad_number(rows: list[list[str]], first: int, path: str, labels: list[str]):
    for i, row in enumerate(rows):
        for c, cell in enumerate(row):
            if not _NUMBER.match(cell):
                raise BVHError(f"{cell[:40]!r} is not a number ({labels[c]})", path=path, line=first + i,
                               element=f"frame {i + 1}",
                               fix="frame lines hold decimal numbers only (1.5, -2, 3e-4); no NaN, inf or text")  # fmt: skip
    raise AssertionError("unreachable: a frame value failed to parse but every cell looks numeric")
