"""``mer shards build``: clips -> pieces (in parallel) -> shard files (atomic), resumable.

Plan. The clips of every robot are split (train/eval), the clip *names* are dealt round-robin into
``num_shards`` shards (so a clip's G1 and H1 versions land in the same shard), and every
(robot, split, shard) becomes one file ``<robot>-<split>-<shard>-of-<num_shards>.<h5|mcap>``.
``shard_index`` builds only that shard's files: machines can build disjoint parts of a corpus
under any scheduler, into one shared folder.

Execution. Each clip is processed by a worker process into a *piece* under
``OUT/.partial/<part>/`` (temporary name, then rename). When all clips of a file are done, the
builder merges its pieces into ``OUT/.<file>.tmp-<pid>`` and renames that into place. So a shard
file is either complete or absent; a failing clip stops the build (or, with ``keep_going``, is
recorded in the shard's metadata) and leaves no partial shard. A re-run with the same arguments
removes stale temporary files, keeps every finished shard whose inputs are unchanged (checked by
sha256), reuses every finished piece, and builds the rest.
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator

import torch

from .. import __version__
from ..errors import MerError, ShardBuildError
from ..motion_io import lafan1_columns
from ..registry import list_robots, load_robot
from ..splits import resolve_split
from .card import write_card
from .clips import BuildContext, ClipResult, ClipTask, process_clip
from .config import BuildConfig
from .hdf5_io import Hdf5Shard, Hdf5ShardWriter
from .mcap_io import McapShardWriter
from .reader import open_shard
from .schema import ShardMeta
from .sources import discover_clips, resolve_input, sha256_bytes

log = logging.getLogger(__name__)

__all__ = ["build_shards", "BuildReport", "part_name", "PART_RE", "EXTENSIONS"]

EXTENSIONS = {"hdf5": ".h5", "mcap": ".mcap"}
PART_RE = re.compile(r"^(?P<robot>[a-z][a-z0-9_-]*)-(?P<split>train|eval)-(?P<index>\d{5})-of-(?P<num>\d{5})\.(h5|mcap)$")
Progress = Callable[[int, int, "ClipResult | None"], None]


def part_name(robot: str, split: str, index: int, num: int) -> str:
    return f"{robot}-{split}-{index:05d}-of-{num:05d}"


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

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    def summary(self) -> str:
        built = sum(f["status"] == "built" for f in self.files)
        lines = [
            f"{len(self.files)} shard file(s) in {self.out} ({built} built, {len(self.files) - built} up to date): "
            f"{self.clips} clips, {self.frames} frames, {self.windows} windows, {self.samples} samples "
            f"in {self.seconds:.1f} s"
        ]
        for s in self.short:
            lines.append(f"  skipped (shorter than a window): {s['robot']}/{s['clip']} ({s.get('frames', 0)} frames)")
        for s in self.failed:
            lines.append(f"  FAILED {s['robot']}/{s['clip']}: {s['error']}")
        return "\n".join(lines)


@dataclass
class _Part:
    name: str
    robot: str
    split: str
    index: int
    clips: list[str]
    final: Path


def _resolve_targets(targets: tuple[str, ...]) -> list[str]:
    if targets == ("all",):
        return [r.name for r in list_robots()]
    for t in targets:
        load_robot(t)  # UnknownRobotError lists the known robots
    return list(targets)


def _part_key(build_id: str, part: str, shas: dict[str, str]) -> str:
    blob = json.dumps({"build_id": build_id, "part": part, "sources": shas}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_out(out: Path, build_id: str, ours: set[str]) -> None:
    """Refuse to mix shards of different builds in one folder."""
    foreign = []
    for p in sorted(out.iterdir()):
        if not PART_RE.match(p.name):
            continue
        try:
            bid = open_shard(p).meta.build_id
        except MerError:
            if p.name in ours:
                continue  # one of ours, damaged: rebuilt below
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


def _clean_temp(out: Path, parts: list[_Part]) -> None:
    for part in parts:
        for p in out.glob(f".{part.final.name}.tmp-*"):
            p.unlink(missing_ok=True)
        for p in (out / ".partial" / part.name).glob("*.tmp-*"):
            p.unlink(missing_ok=True)


_CTX: BuildContext | None = None


def _init_worker(ctx: BuildContext) -> None:
    global _CTX
    _CTX = ctx
    torch.set_num_threads(1)


def _work(task: ClipTask) -> ClipResult:
    assert _CTX is not None
    return process_clip(_CTX, task)


def _run(ctx: BuildContext, tasks: list[ClipTask], workers: int) -> Iterator[ClipResult]:
    if workers <= 1 or len(tasks) <= 1:
        for t in tasks:
            yield process_clip(ctx, t)
        return
    method = "fork" if sys.platform.startswith("linux") else "spawn"
    with multiprocessing.get_context(method).Pool(min(workers, len(tasks)), _init_worker, (ctx,)) as pool:
        yield from pool.imap_unordered(_work, tasks)


def _merge(part: _Part, meta: ShardMeta, results: dict[str, ClipResult], cfg: BuildConfig) -> None:
    tmp = part.final.with_name(f".{part.final.name}.tmp-{os.getpid()}")
    if cfg.format == "hdf5":
        writer: Hdf5ShardWriter | McapShardWriter = Hdf5ShardWriter(tmp, meta, compression=cfg.compression)
    else:
        writer = McapShardWriter(tmp, meta, preview=cfg.mcap_preview)
    try:
        for clip in part.clips:
            piece = results[clip].piece
            if piece is None:
                continue
            if isinstance(writer, Hdf5ShardWriter):
                writer.append_piece(piece)
            else:
                src = Hdf5Shard(piece)
                writer.append(src.rows(0, src.num_rows))
                src.close()
        writer.close(meta)
        _fsync(tmp)
        os.replace(tmp, part.final)
    except BaseException:
        writer.abort()
        raise
    shutil.rmtree(part.final.parent / ".partial" / part.name, ignore_errors=True)


def build_shards(
    config: BuildConfig,
    out: str | Path,
    *,
    workers: int = 1,
    shard_index: int | None = None,
    keep_going: bool = False,
    progress: Progress | None = None,
) -> BuildReport:
    """Build (or finish building) the shards of ``config`` into ``out``.

    Args:
        workers: clip-processing processes (1: in this process).
        shard_index: build only this shard (0 .. num_shards-1); None builds all.
        keep_going: record failing clips in the shards' metadata and build the rest.
        progress: called as ``progress(done_clips, total_clips, result)``.

    Raises:
        ShardBuildError: bad input folder, a foreign build in ``out``, or a failing clip without
            ``keep_going`` (no shard of that clip's file is written).
        UnknownRobotError, MotionFormatError, SplitError: unknown robot, robot without a LAFAN1
            layout, split that does not fit the clips.
    """
    t0 = time.perf_counter()
    cfg = config
    if shard_index is not None and not 0 <= shard_index < cfg.num_shards:
        raise ShardBuildError(f"shard index {shard_index} is outside 0..{cfg.num_shards - 1}", fix="--shard-index I with 0 <= I < --num-shards")
    for r in cfg.robots:
        lafan1_columns(r)  # unknown robot or no layout: refuse before touching anything
    targets = _resolve_targets(cfg.targets)
    root = resolve_input(cfg.input, cfg.robots)
    clips = discover_clips(root, cfg.robots)
    splits = resolve_split(cfg.split, {r: list(c) for r, c in clips.items()})
    names = sorted(set(cfg.robots) | set(targets))
    skeletons = {n: load_robot(n).skeleton.to_json() for n in names}
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
    out = Path(out)
    parts: dict[str, _Part] = {}
    for r in cfg.robots:
        for c in clips[r]:
            s = shard_of[c]
            if s not in wanted:
                continue
            name = part_name(r, splits[r][c], s, N)
            if name not in parts:
                parts[name] = _Part(name, r, splits[r][c], s, [], out / f"{name}{EXTENSIONS[cfg.format]}")
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
    out.mkdir(parents=True, exist_ok=True)
    _check_out(out, build_id, {p.final.name for p in parts.values()})
    _clean_temp(out, list(parts.values()))

    report = BuildReport(out=str(out), build_id=build_id, config=config_json)
    done_metas: dict[str, ShardMeta] = {}
    todo: list[_Part] = []
    for p in parts.values():
        if p.final.is_file():
            try:
                meta = open_shard(p.final).meta
            except MerError:
                meta = None
            shas = {c: sha256_bytes(clips[p.robot][c].read_bytes()) for c in p.clips}
            if meta is not None and meta.part_key == _part_key(build_id, p.name, shas):
                done_metas[p.name] = meta
                shutil.rmtree(out / ".partial" / p.name, ignore_errors=True)  # leftovers of a crash
                continue
        todo.append(p)
    tasks = [
        ClipTask(p.robot, c, str(clips[p.robot][c]), p.split, p.name, str(out / ".partial" / p.name / f"{c}.piece"))
        for p in todo
        for c in p.clips
    ]
    order = {p.name: i for i, p in enumerate(todo)}  # files one after another (each done early), and
    tasks.sort(key=lambda t: (order[t.part], -os.path.getsize(t.path)))  # largest clips first in each
    total = sum(len(p.clips) for p in parts.values())
    done = total - len(tasks)
    if progress:
        progress(done, total, None)

    ctx = BuildContext(cfg, skeletons, metas)
    results: dict[str, dict[str, ClipResult]] = {p.name: {} for p in todo}
    by_name = {p.name: p for p in todo}
    gen = _run(ctx, tasks, workers)
    try:
        for res in gen:
            done += 1
            if progress:
                progress(done, total, res)
            if res.status == "failed" and not keep_going:
                raise ShardBuildError(
                    f"{res.record['error']}\n  (nothing was written for {res.task.part}; "
                    "pass --keep-going to record failing clips and build the rest)"
                )
            part_results = results[res.task.part]
            part_results[res.task.clip] = res
            p = by_name[res.task.part]
            if len(part_results) == len(p.clips):
                shas = {c: part_results[c].record["sha256"] for c in p.clips}
                meta = replace(
                    metas[p.name],
                    part_key=_part_key(build_id, p.name, shas),
                    sources=[part_results[c].record for c in p.clips],
                )
                _merge(p, meta, part_results, cfg)
                done_metas[p.name] = meta
                report.files.append(_file_entry(p.final, meta, "built"))
    finally:
        gen.close()
    try:
        (out / ".partial").rmdir()  # only when empty: pieces of other shard indices may still be there
    except OSError:
        pass
    for name, meta in done_metas.items():
        if not any(f["name"] == parts[name].final.name for f in report.files):
            report.files.append(_file_entry(parts[name].final, meta, "up to date"))
    report.files.sort(key=lambda f: f["name"])
    for name in sorted(done_metas):
        meta = done_metas[name]
        counts = meta.counts()
        report.clips += counts["clips"]
        report.frames += counts["frames"]
        report.windows += counts["windows"]
        report.samples += counts["samples"]
        for s in meta.sources:
            if s["status"] == "short":
                report.short.append({"robot": meta.robot, **s})
            elif s["status"] == "failed":
                report.failed.append({"robot": meta.robot, **s})
    report.seconds = time.perf_counter() - t0
    report.card = str(write_card(out))
    suffix = "" if shard_index is None else f"-{shard_index:05d}-of-{N:05d}"
    tmp = out / f".build-report{suffix}.json.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(report.to_dict(), indent=1, sort_keys=True))
    os.replace(tmp, out / f"build-report{suffix}.json")
    for s in report.short:
        log.warning("skipped %s/%s: %s", s["robot"], s["clip"], s.get("error", "shorter than a window"))
    return report


def _file_entry(path: Path, meta: ShardMeta, status: str) -> dict:
    c = meta.counts()
    return {"name": path.name, "status": status, "robot": meta.robot, "split": meta.split,
            "windows": c["windows"], "samples": c["samples"], "bytes": path.stat().st_size}  # fmt: skip
