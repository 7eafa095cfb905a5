"""Train/eval splits: the paper's choice, all, split files and their errors."""

from __future__ import annotations

import pytest

from mer_data.base.errors import SplitError
from mer_data.motion.splits import EVAL, TRAIN, clip_category, resolve_split

LAFAN1_CLIPS = [
    "dance1_subject1", "dance1_subject2", "dance2_subject1", "fallAndGetUp1_subject1", "fallAndGetUp2_subject2",
    "fight1_subject2", "fight1_subject3", "fightAndSports1_subject1", "walk1_subject1", "run1_subject2",
]  # fmt: skip


def test_categories():
    assert clip_category("fightAndSports1_subject1") == "fightAndSports"
    assert clip_category("fight1_subject2") == "fight"
    assert clip_category("fallAndGetUp2_subject3") == "fallAndGetUp"


def test_paper_split_picks_one_clip_per_category():
    s = resolve_split("paper", {"g1": LAFAN1_CLIPS, "h1": list(reversed(LAFAN1_CLIPS))})
    train = {c for c, v in s["g1"].items() if v == TRAIN}
    assert train == {"dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2"}
    assert s["g1"] == s["h1"]
    assert sum(v == EVAL for v in s["g1"].values()) == len(LAFAN1_CLIPS) - 3


def test_paper_split_on_the_real_clips(lafan1_dir):
    for robot in ("g1", "h1"):
        clips = sorted(p.name[:-4] for p in (lafan1_dir / robot).glob("*.csv"))
        s = resolve_split("paper", {robot: clips})[robot]
        assert len(clips) == 40 and sum(v == EVAL for v in s.values()) == 37
        assert {c for c, v in s.items() if v == TRAIN} == {"dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2"}


def test_paper_split_needs_every_category():
    with pytest.raises(SplitError, match="'fight' clip"):
        resolve_split("paper", {"g1": ["dance1_subject1", "fallAndGetUp1_subject1", "walk1_subject1"]})


def test_all():
    s = resolve_split("all", {"g1": ["b", "a"]})
    assert s == {"g1": {"a": TRAIN, "b": TRAIN}}


def test_split_file(tmp_path):
    f = tmp_path / "split.txt"
    f.write_text("# training clips\nwalk1_subject1\nh1/run1_subject2  # only for h1\n\n")
    s = resolve_split(str(f), {"g1": LAFAN1_CLIPS, "h1": LAFAN1_CLIPS})
    assert {c for c, v in s["g1"].items() if v == TRAIN} == {"walk1_subject1"}
    assert {c for c, v in s["h1"].items() if v == TRAIN} == {"walk1_subject1", "run1_subject2"}


def test_split_file_errors(tmp_path):
    f = tmp_path / "split.txt"
    f.write_text("walk1_subject1\nwalk9_subject9\n")
    with pytest.raises(SplitError) as exc:
        resolve_split(str(f), {"g1": LAFAN1_CLIPS})
    assert exc.value.line == 2 and "walk9_subject9" in str(exc.value)
    f.write_text("atlas/walk1_subject1\n")
    with pytest.raises(SplitError, match="robot 'atlas' is not being built"):
        resolve_split(str(f), {"g1": LAFAN1_CLIPS})
    f.write_text("# nothing\n")
    with pytest.raises(SplitError, match="names no clips"):
        resolve_split(str(f), {"g1": LAFAN1_CLIPS})
    with pytest.raises(SplitError, match="cannot read"):
        resolve_split(str(tmp_path / "missing.txt"), {"g1": LAFAN1_CLIPS})
