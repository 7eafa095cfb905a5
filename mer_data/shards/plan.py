"""Planning a build: which clips go to which shard file, with which metadata; the output folder.

The clips of every robot are split (train/eval), the clip *names* are dealt round-robin into
``num_shards`` shards (so a clip's G1 and H1 versions land in the same shard), and every
(robot, split, shard) becomes one file ``<robot>-<split>-<shard>-of-<num_shards>.<h5|mcap>``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import uuid
from dataclasses import dataclass
from pathlib import Path

from mer_data import __version__
from mer_data.base.errors import MerError, ShardBuildError
from mer_data.motion.lafan1 import lafan1_columns
from mer_data.motion.sources import HUMAN_SOURCES, human_files
from mer_data.motion.splits import resolve_split
from mer_data.robots.registry import list_robots, load_robot
from mer_data.skeleton import Skeleton

from .config import BuildConfig
from .humans import human_groups
from .reader import open_shard
from .schema import ShardMeta
from .sources import discover_clips, resolve_input
from .synthetic_source import synthetic_clips

__all__ = ["Part", "Plan", "plan_build", "part_name", "part_key", "PART_RE", "EXTENSIONS", "temp_name", "check_out", "clean_temp"]

EXTENSIONS = {"hdf5": ".h5", "mcap": ".mcap"}
PART_RE = re.compile(r"^(?P<robot>[a-z][a-z0-9_-]*)-(?P<split>train|eval)-(?P<index>\d{5})-of-(?P<num>\d{5})\.(h5|mcap)$")


def part_name(robot: str, split: str, index: int, num: int) -> str:
    return f"{robot}-{split}-{index:05d}-of-{num:05d}"


def part_key(build_id: str, part: str, shas: dict[str, str]) -> str:
    """Identity of a shard file's content: the build and the sha256 of every one of its clips."""
    blob = json.dumps({"build_id": build_id, "part": part, "sources": shas}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def temp_name(path: Path) -> Path:
    """``.<name>.tmp-<pid>-<random>`` beside ``path`` (unique across processes and machines)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}")


@dataclass
class Part:
    """One shard file to build: its clips (in name order) and where it goes."""

    name: str
    robot: str
    split: str
    index: int
    clips: list[str]
    final: Path


@dataclass
class Plan:
    build_id: str
    config_json: dict
    targets: list[str]
    skeletons: dict[str, str]  # name -> Skeleton JSON
    clips: dict[str, dict[str, Path | str]]  # robot -> clip -> file, or a synthetic source string
    parts: dict[str, Part]
    metas: dict[str, ShardMeta]  # part name -> metadata template


def _resolve_targets(targets: tuple[str, ...]) -> list[str]:
    if targets == ("all",):
        return [r.name for r in list_robots()]
    for t in targets:
        load_robot(t)  # UnknownRobotError lists the known robots
    return list(targets)


def plan_build(cfg: BuildConfig, out: Path, shard_index: int | None) -> Plan:
    """Resolve robots, targets, input, clips and split; lay out the shard files of ``shard_index``."""
    if shard_index is not None and not 0 <= shard_index < cfg.num_shards:
        raise ShardBuildError(
            f"shard index {shard_index} is outside 0..{cfg.num_shards - 1}", fix="--shard-index I with 0 <= I < --num-shards"
        )
    kinds = [r for r in cfg.robots if r in HUMAN_SOURCES]
    robots = [r for r in cfg.robots if r not in HUMAN_SOURCES]
    if kinds and (cfg.synthetic or len(cfg.robots) > 1):
        raise ShardBuildError(f"a build from human motion takes --robots {kinds[0]} alone, from a folder",
                              fix="build the robots' shards separately")  # fmt: skip
    for r in robots:  # unknown robot (or, reading files, no LAFAN1 layout): refuse before touching anything
        load_robot(r) if cfg.synthetic else lafan1_columns(load_robot(r))
    targets = _resolve_targets(cfg.targets)
    clips: dict[str, dict[str, Path | str]]
    humans: dict[str, Skeleton] = {}
    if cfg.synthetic:
        clips = dict(synthetic_clips(cfg.robots, cfg.synthetic))
    elif robots:
        clips = dict(discover_clips(resolve_input(cfg.input, cfg.robots), cfg.robots))
    else:  # human motion: one reference per body among the clips (mer_data.shards.humans, docs/shards.md)
        if cfg.input.startswith("hf://"):
            raise ShardBuildError(f"{kinds[0]} input is read from a local folder", fix="download the files and pass --input DIR")
        groups, humans = human_groups(human_files(cfg.input, kinds[0]), kinds[0], cfg.human_options())
        clips = dict(groups)
    splits = resolve_split(cfg.split, {r: list(c) for r, c in clips.items()})
    refs = list(clips) if humans else list(cfg.robots)
    names = sorted(set(refs) | set(targets))
    skeletons = {n: (humans[n] if n in humans else load_robot(n).skeleton).to_json() for n in names}
    resolved = {
        "splits": splits,
        "targets": targets,
        "skeleton_fingerprints": {n: hashlib.sha256(skeletons[n].encode()).hexdigest() for n in names},
    }
    build_id = cfg.build_id(resolved)
    config_json = {**cfg.to_dict(), "resolved": resolved}
    N = cfg.num_shards
    shard_of = {c: i % N for i, c in enumerate(sorted(set().union(*map(set, clips.values()))))}
    wanted = range(N) if shard_index is None else [shard_index]
    parts: dict[str, Part] = {}
    for r in refs:
        for c in clips[r]:
            s = shard_of[c]
            if s not in wanted:
                continue
            name = part_name(r, splits[r][c], s, N)
            if name not in parts:
                parts[name] = Part(name, r, splits[r][c], s, [], out / f"{name}{EXTENSIONS[cfg.format]}")
            parts[name].clips.append(c)
    metas = {
        p.name: ShardMeta(
            robot=p.robot, split=p.split, shard_index=p.index, num_shards=N, window=cfg.window, fps=cfg.out_fps,
            targets=targets, variants=cfg.variants(p.split),
            skeletons={n: skeletons[n] for n in sorted({p.robot, *targets})},
            config=config_json, build_id=build_id, mer_version=__version__,
        )  # fmt: skip
        for p in parts.values()
    }
    return Plan(build_id, config_json, targets, skeletons, clips, parts, metas)


def check_out(out: Path, build_id: str, ours: set[str]) -> None:
    """Refuse to mix shards of different builds in one folder."""
    foreign = []
    for p in sorted(out.iterdir()):
        if not PART_RE.match(p.name):
            continue
        try:
            bid = open_shard(p).meta.build_id
        except MerError:
            if p.name in ours:
                continue  # one of ours, damaged: rebuilt
            bid = "unreadable"
        if bid != build_id:
            foreign.append(p.name)
    if foreign:
        raise ShardBuildError(
            f"the output folder holds {len(foreign)} shard file(s) of another build "
            f"(different configuration or inputs), e.g. {foreign[0]}",
            path=out,
            fix="choose a new --out folder, or delete the old shard files first",
        )


def clean_temp(out: Path, parts: list[Part]) -> None:
    """Remove what an interrupted build of these files left: temporary shard files and pieces."""
    for part in parts:
        for p in out.glob(f".{part.final.name}.tmp-*"):
            p.unlink(missing_ok=True)
        for p in (out / ".partial" / part.name).glob("*.tmp-*"):
            p.unlink(missing_ok=True)
