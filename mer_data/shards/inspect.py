"""``mer shards inspect``: what a shard file or folder holds (metadata only, no window is decoded)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .reader import PathsLike, find_shards, open_shard

__all__ = ["inspect_shards", "format_inspection"]


def inspect_shards(paths: PathsLike) -> dict[str, Any]:
    """A JSON-ready summary: per file (format, version, robot, split, counts, bytes) and totals."""
    files = []
    totals: dict[str, dict[str, int]] = {}
    configs = {}
    for p in find_shards(paths):
        shard = open_shard(p)
        m = shard.meta
        c = m.counts()
        files.append(
            {
                "path": str(p), "format": shard.format, "format_version": m.format_version, "mer_version": m.mer_version,
                "robot": m.robot, "split": m.split, "shard": f"{m.shard_index}/{m.num_shards}", "window": m.window,
                "fps": m.fps, "targets": m.targets, "variants": m.variants, "bytes": Path(p).stat().st_size,
                "build_id": m.build_id, **c,
                "short": [s["clip"] for s in m.sources if s.get("status") == "short"],
                "failed": [{"clip": s["clip"], "error": s.get("error", "")} for s in m.sources if s.get("status") == "failed"],
            }
        )  # fmt: skip
        t = totals.setdefault(f"{m.robot}/{m.split}", {"files": 0, "clips": 0, "frames": 0, "windows": 0, "samples": 0, "bytes": 0})
        t["files"] += 1
        for k in ("clips", "frames", "windows", "samples"):
            t[k] += c[k]
        t["bytes"] += Path(p).stat().st_size
        configs[m.build_id] = m.config
    return {
        "files": files,
        "totals": dict(sorted(totals.items())),
        "robots": sorted({f["robot"] for f in files}),
        "targets": sorted({t for f in files for t in f["targets"]}),
        "format_versions": sorted({f["format_version"] for f in files}),
        "configs": configs,
    }


def format_inspection(info: dict[str, Any]) -> str:
    """Human-readable text of :func:`inspect_shards`."""
    lines = []
    for f in info["files"]:
        lines.append(
            f"{f['path']}: {f['format']} v{f['format_version']}, {f['robot']} {f['split']} shard {f['shard']}, "
            f"{f['clips']} clips, {f['frames']} frames, {f['windows']} windows x {f['window']} frames @ {f['fps']:g} Hz, "
            f"{f['samples']} samples, {f['bytes'] / 1e6:.2f} MB"
        )
        if f["short"]:
            lines.append(f"  skipped (shorter than a window): {', '.join(f['short'])}")
        for fail in f["failed"]:
            lines.append(f"  FAILED {fail['clip']}: {fail['error']}")
    lines.append("")
    lines.append(f"{'robot/split':16s} {'files':>5s} {'clips':>6s} {'frames':>9s} {'windows':>8s} {'samples':>9s} {'MB':>9s}")
    for key, t in info["totals"].items():
        lines.append(
            f"{key:16s} {t['files']:5d} {t['clips']:6d} {t['frames']:9d} {t['windows']:8d} {t['samples']:9d} {t['bytes'] / 1e6:9.2f}"
        )
    lines.append(f"targets: {', '.join(info['targets'])}")
    for bid, cfg in info["configs"].items():
        shown = {k: v for k, v in cfg.items() if k != "resolved"}
        lines.append(f"build {bid[:12]}: " + ", ".join(f"{k}={v}" for k, v in shown.items()))
    return "\n".join(lines)
