"""Train / evaluation splits of the clips (paper, Experiment Setup).

* ``paper``: per robot, 3 training clips -- one ``dance``, one ``fallAndGetUp``, one ``fight`` --
  and every other clip held out for evaluation as unseen motion. The paper does not name its
  clips; mer takes, per category, the first clip in sorted name order. For LAFAN1 that is
  ``dance1_subject1``, ``fallAndGetUp1_subject1`` and ``fight1_subject2`` for every robot
  (``fightAndSports*`` is its own category).
* ``all``: every clip is a training clip (nothing held out).
* a file: one clip per line (``clip`` or ``robot/clip``; ``#`` starts a comment) naming the
  training clips; every other clip is held out for evaluation.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Mapping, Sequence

from mer_data.base.errors import SplitError

__all__ = ["PAPER_CATEGORIES", "TRAIN", "EVAL", "clip_category", "resolve_split", "read_split_file"]

TRAIN, EVAL = "train", "eval"
PAPER_CATEGORIES = ("dance", "fallAndGetUp", "fight")
_CATEGORY = re.compile(r"^([A-Za-z]+)")


def clip_category(clip: str) -> str:
    """Motion category of a LAFAN1 clip name: the leading letters (``fight1_subject2`` -> ``fight``)."""
    m = _CATEGORY.match(clip)
    return m.group(1) if m else ""


def read_split_file(path: str | Path) -> list[tuple[str | None, str, int]]:
    """Entries ``(robot or None, clip, line)`` of a split file."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise SplitError(f"cannot read the split file ({exc.strerror})", path=p) from None
    out = []
    for i, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        robot, _, clip = line.rpartition("/")
        if not clip or " " in line or "," in line:
            raise SplitError(f"cannot read {raw.strip()!r}", path=p, line=i, fix="write one `clip` or `robot/clip` per line")
        out.append((robot or None, clip, i))
    if not out:
        raise SplitError("the split file names no clips", path=p, fix="list the training clips, one per line")
    return out


def resolve_split(spec: str, clips: Mapping[str, Sequence[str]]) -> dict[str, dict[str, str]]:
    """Assign every clip of every robot to ``"train"`` or ``"eval"``.

    Args:
        spec: ``"paper"``, ``"all"`` or the path of a split file.
        clips: robot -> its clip names.

    Returns:
        robot -> clip -> split, clips in sorted order.
    """
    out: dict[str, dict[str, str]] = {}
    if spec == "all":
        return {r: {c: TRAIN for c in sorted(cs)} for r, cs in clips.items()}
    if spec == "paper":
        for robot, cs in clips.items():
            chosen = set()
            for cat in PAPER_CATEGORIES:
                of_cat = sorted(c for c in cs if clip_category(c) == cat)
                if not of_cat:
                    raise SplitError(
                        f"the paper split needs a {cat!r} clip for robot {robot!r}, and there is none",
                        element=f"robot {robot}",
                        fix="use --split all or a split file listing the training clips",
                    )
                chosen.add(of_cat[0])
            out[robot] = {c: TRAIN if c in chosen else EVAL for c in sorted(cs)}
        return out
    entries = read_split_file(spec)
    for robot, clip, line in entries:
        robots = [robot] if robot else list(clips)
        if robot and robot not in clips:
            raise SplitError(
                f"robot {robot!r} is not being built (robots: {', '.join(clips)})", path=spec, line=line
            )
        if not any(clip in clips[r] for r in robots):
            raise SplitError(
                f"no clip {clip!r} in the input" + (f" for robot {robot!r}" if robot else ""),
                path=spec,
                line=line,
                fix="check the spelling: clip names are file names without .csv/.csv.gz",
            )
    for r, cs in clips.items():
        train = {c for rr, c, _ in entries if rr in (None, r)}
        out[r] = {c: TRAIN if c in train else EVAL for c in sorted(cs)}
    return out
