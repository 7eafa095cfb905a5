"""What a build did: files, counts, skipped and failed clips (``build-report*.json``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .schema import ShardMeta

__all__ = ["BuildReport"]


@dataclass
class BuildReport:
    """What a build did (also written as ``build-report*.json`` next to the shards)."""

    out: str
    build_id: str
    config: dict
    files: list[dict] = field(default_factory=list)  # name, status (built / up to date), windows, samples, bytes
    clips: int = 0
    frames: int = 0
    windows: int = 0
    samples: int = 0
    short: list[dict] = field(default_factory=list)
    failed: list[dict] = field(default_factory=list)
    seconds: float = 0.0
    card: str | None = None

    def add_file(self, path: Path, meta: ShardMeta, status: str) -> None:
        """Count one shard file (``status``: "built" or "up to date")."""
        c = meta.counts()
        self.files.append({"name": path.name, "status": status, "robot": meta.robot, "split": meta.split,
                           "windows": c["windows"], "samples": c["samples"], "bytes": path.stat().st_size})  # fmt: skip
        self.clips += c["clips"]
        self.frames += c["frames"]
        self.windows += c["windows"]
        self.samples += c["samples"]
        for s in meta.sources:
            if s["status"] == "short":
                self.short.append({"robot": meta.robot, **s})
            elif s["status"] == "failed":
                self.failed.append({"robot": meta.robot, **s})

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    def summary(self) -> str:
        built = sum(f["status"] == "built" for f in self.files)
        lines = [
            f"{len(self.files)} shard file(s) in {self.out} ({built} built, {len(self.files) - built} up to date): "
            f"{self.clips} clips, {self.frames} frames, {self.windows} windows, {self.samples} samples "
            f"in {self.seconds:.1f} s"
        ]
        for s in sorted(self.short, key=lambda s: (s["robot"], s["clip"])):
            lines.append(f"  skipped (shorter than a window): {s['robot']}/{s['clip']} ({s.get('frames', 0)} frames)")
        for s in sorted(self.failed, key=lambda s: (s["robot"], s["clip"])):
            lines.append(f"  FAILED {s['robot']}/{s['clip']}: {s['error']}")
        return "\n".join(lines)
