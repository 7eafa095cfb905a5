"""The metrics row every retarget prints (one file: one row; a dataset: one row per clip and target)
and the legend under it. One name per metric: a column's header is its key in ``--json``,
``<clip>.metrics.json`` and ``summary.json`` with the unit in brackets, and docs/model.md
§Evaluation metrics uses the same keys. A new column is one line of :data:`METRIC_COLUMNS`."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Column", "METRIC_COLUMNS", "metric_header", "metric_cells", "metric_legend", "format_summary"]


@dataclass(frozen=True)
class Column:
    """One column: ``key`` in the metrics dict, ``header`` (the key, the unit in brackets), the number
    ``fmt`` (a format spec), and ``legend``, what it measures in a few words."""

    key: str
    header: str
    fmt: str
    legend: str

    @property
    def width(self) -> int:
        return max(len(self.header), 8)


METRIC_COLUMNS: tuple[Column, ...] = (
    Column("g_mpbpe", "g_mpbpe[m]", ".4f", "mean distance of the shared key points from the reference scaled to the robot"),
    Column("mpboe", "mpboe[rad]", ".3f", "mean angle of the base, feet and hands from their orientation goals"),
    Column("mpbve", "mpbve[m/s]", ".3f", "mean error of the key points' velocities"),
    Column("jerk_frame", "jerk_frame[rad/f3]", ".4f", "mean |third difference| of the joint angles per frame (the paper's E_smooth)"),
    Column("limit_violation", "limit_violation", ".3f", "share of frames with a joint outside its URDF limits"),
    Column("floor_frames", "floor_frames", ".3f", "share of frames with a foot more than 1 cm below the floor"),
    Column("skate_median", "skate_median[m/s]", ".3f", "median horizontal speed of a foot in contact with the floor"),
    Column("selfpen_1cm_frames", "selfpen_1cm_frames", ".3f", "share of frames with two bodies more than 1 cm inside each other"),
    Column("speed_frames", "speed_frames", ".3f", "share of frame pairs with a joint faster than its URDF velocity limit"),
    Column("body_floor_frames", "body_floor_frames", ".3f", "share of frames with any body more than 1 cm below the floor"),
    Column("hover_frames", "hover_frames", ".3f", "share of the source's foot-down frames with the stance sole over 1 cm above the floor"),
    Column("balance_infeasible", "balance_infeasible", ".3f", "share of contact frames whose demanded contact wrench the floor cannot supply"),
    Column("zmp_out_single", "zmp_out_single", ".3f", "share of single-support frames with the ZMP over 2 cm outside the stance foot"),
)


def metric_header() -> str:
    """The header cells of :data:`METRIC_COLUMNS`."""
    return " ".join(f"{c.header:>{c.width}s}" for c in METRIC_COLUMNS)


def metric_cells(row: dict) -> str:
    """One row's cells of :data:`METRIC_COLUMNS` (``-`` where a metric is missing or undefined)."""
    cells = []
    for c in METRIC_COLUMNS:
        v = row.get(c.key)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        cells.append(f"{v:>{c.width}{c.fmt}}" if ok else f"{'-':>{c.width}s}")
    return " ".join(cells)


def metric_legend(columns: tuple[Column, ...] = METRIC_COLUMNS) -> str:
    """The legend printed under the row: each header and what it measures (docs/model.md §Evaluation metrics)."""
    w = max(len(c.header) for c in columns)
    return "\n".join(f"  {c.header:<{w}s}  {c.legend}" for c in columns)


def format_summary(summary: dict) -> str:
    """A dataset run's summary as a text table (one line per clip and target), the totals and the legend."""
    lines = [f"{'target':10s} {'clip':28s} {'frames':>7s} {metric_header()}"]
    for r in sorted(summary["rows"], key=lambda r: (r["target"], r["clip"])):
        lines.append(f"{r['target']:10s} {r['clip'][:28]:28s} {r['frames']:7d} {metric_cells(r)}")
    fps = summary.get("frames_per_second")
    procs = summary.get("workers", 1)
    lines.append(f"{summary['jobs']} pairs in this shard: {summary['done_before']} skipped (done before), {summary['done_now']} now "
                 f"({summary['frames']} frames in {summary['seconds']} s" + (f", {fps} frames/s" if fps else "")
                 + (f", {procs} processes)" if procs > 1 else ")"))  # fmt: skip
    if summary["rows"]:
        lines.append(metric_legend())
    return "\n".join(lines)
