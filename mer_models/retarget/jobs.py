"""A dataset run's work list (``mer retarget --input DIR --targets ...``): the source clips of a folder
or a Hub dataset, and the (target, clip) pairs of this shard, each with where its outputs go."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from mer_data.base.errors import MerError

__all__ = ["Job", "find_clips", "find_bvh_clips", "plan_jobs"]


@dataclass(frozen=True)
class Job:
    """One (target, clip) pair and where its outputs go."""

    target: str
    clip: str
    source_path: Path
    out_dir: Path

    def output(self, kind: str) -> Path:
        return self.out_dir / self.target / (f"{self.clip}.metrics.json" if kind == "metrics" else f"{self.clip}.{kind}")

    def done(self) -> bool:
        return self.output("metrics").is_file()


def find_clips(input_spec: str, source: str) -> dict[str, Path]:
    """clip name → motion file of ``source``: ``DIR/<source>/*.csv[.gz]`` (LAFAN1 layout), else
    ``DIR/*.csv[.gz]``; ``hf://OWNER/NAME[@REV]`` is downloaded (only ``<source>/`` files)."""
    from mer_data.shards.sources import clip_name, discover_clips, resolve_input

    root = resolve_input(input_spec, [source])
    if (root / source).is_dir():
        return discover_clips(root, [source])[source]
    if not any(clip_name(p) is not None for p in root.iterdir()):
        raise MerError(
            f"no motions of {source!r} in the input: neither {source}/*.csv nor *.csv",
            path=root,
            fix=f"point --input at a folder holding {source}/<clip>.csv (LAFAN1 layout) or <clip>.csv files",
        )
    return discover_clips(root.parent, [root.name])[root.name]  # the same regular-file and duplicate checks


def find_bvh_clips(input_spec: str, kind: str = "bvh") -> dict[str, Path]:
    """clip name → file of a human ``kind`` (bvh, smpl, joints) in a local folder
    (:func:`mer_data.motion.sources.human_files`)."""
    from mer_data.motion.sources import human_files

    if str(input_spec).startswith("hf://"):
        raise MerError(f"{kind} input is read from a local folder", fix="download the files and pass --input DIR")
    return human_files(input_spec, kind)


def plan_jobs(clips: dict[str, Path], targets: Sequence[str], out_dir: Path, shard_index: int = 0, num_shards: int = 1) -> list[Job]:
    """This shard's jobs: every ``num_shards``-th of the (target, clip) pairs sorted by target, clip."""
    if num_shards < 1 or not 0 <= shard_index < num_shards:
        raise MerError(f"--shard-index {shard_index} is not in 0..{num_shards - 1}", fix="use 0 <= --shard-index < --num-shards")
    jobs = [Job(t, c, p, out_dir) for t in sorted(set(targets)) for c, p in sorted(clips.items())]
    return jobs[shard_index::num_shards]
