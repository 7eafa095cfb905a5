"""One name per metric (issue 52, item 4): the printed row's headers are the ``--json`` keys (the unit
in brackets), the legend under the row names every column, and docs/model.md uses the same keys."""

from __future__ import annotations

import re
from pathlib import Path

from mer_models.retarget.columns import METRIC_COLUMNS, metric_cells, metric_header, metric_legend

REPO = Path(__file__).resolve().parents[3]


def test_each_header_is_its_key_and_the_cells_line_up():
    for c in METRIC_COLUMNS:
        assert re.fullmatch(re.escape(c.key) + r"(\[[^\]]+\])?", c.header), c.header
        assert c.legend and not c.legend.endswith(".")
    row = {c.key: 0.5 for c in METRIC_COLUMNS} | {"floor_frames": float("nan")}
    head, cells = metric_header(), metric_cells(row)
    assert len(head) == len(cells) and head.split() == [c.header for c in METRIC_COLUMNS]
    assert cells.split()[[c.key for c in METRIC_COLUMNS].index("floor_frames")] == "-"
    assert [line.split()[0] for line in metric_legend().splitlines()] == [c.header for c in METRIC_COLUMNS]


def test_the_docs_name_each_column_by_its_key_and_no_old_header_is_left():
    model = (REPO / "docs" / "model.md").read_text(encoding="utf-8")
    for c in METRIC_COLUMNS:
        assert f"`{c.key}`" in model, c.key
    old = ("floor<-1cm", "jerk[r/f3]", "g-mpbpe[m]", "skate[m/s]", "selfpen>1cm", ">vel.lim")
    for path in [REPO / "README.md", *(REPO / "docs").glob("*.md")]:
        text = path.read_text(encoding="utf-8")
        assert not [o for o in old if o in text], path
