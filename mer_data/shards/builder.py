"""``mer shards build``: clips -> pieces (in parallel) -> shard files (atomic), resumable.

Plan (:mod:`.plan`): one file per (robot, split, shard); ``shard_index`` builds only that shard's
files, so machines can build disjoint parts of a corpus under any scheduler, into one folder.

Execution. Each clip is processed by a worker process into a *piece* under
``OUT/.partial/<file>/`` (:mod:`.clips`; temporary name, then rename). When all clips of a file
are done, the builder merges its pieces into a temporary file beside the shard and renames it into
place. So a shard file is either complete or absent; a failing clip stops the build (or, with
``keep_going``, is recorded in the shard's metadata) and leaves no partial shard. A re-run with the
same arguments removes stale temporary files, keeps every finished shard whose inputs are unchanged
(checked by sha256), reuses every finished piece, and builds the rest.
"""

from __future__ import annotations

import json
import logging
import math
import multiprocessing
import os
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

from mer_data.base.atomic import atomic_write, disk_full_as_error, real_folder, release_reserve, reserve_space
from mer_data.base.errors import MerError, ShardBuildError, ShardFormatError
from mer_data.base.locks import hold_locks
from mer_data.skeleton import Skeleton

from .card import refuse_foreign_outputs, write_card
from .clips import BuildContext, ClipResult, ClipTask, process_clip
from .config import BuildConfig
from .hdf5_io import Hdf5Shard, Hdf5ShardWriter
from .mcap_io import McapShardWriter
from .plan import Part, check_out, clean_temp, part_key, plan_build, temp_name
from .reader import open_shard
from .report import BuildReport
from .schema import BIG_COLUMNS, COLUMNS, ShardMeta
from .sidecar import write_sidecar
from .synthetic_source import source_sha256, source_size

log = logging.getLogger(__name__)

__all__ = ["build_shards", "BuildReport"]

Progress = Callable[[int, int, "ClipResult | None"], None]
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


def _fsync(path: Path, *, release: bool = False) -> None:
    """fsync ``path`` (never through a link); ``release``: first give back unused reserved room."""
    fd = os.open(path, (os.O_RDWR if release else os.O_RDONLY) | getattr(os, "O_NOFOLLOW", 0))
    try:
        if release:
            release_reserve(fd)
        os.fsync(fd)
    finally:
        os.close(fd)


#: bytes per row of the string columns (robot, clip, source sha256) in an HDF5 file, generously
_STRING_ROW_BYTES = 256


def _merge_bytes(part: Part, meta: ShardMeta, results: dict[str, ClipResult]) -> int:
    """An upper bound of the size of the merged file: its pieces (the big columns' chunks are copied
    verbatim; each piece also holds all the metadata the merged file holds once), the small columns
    uncompressed, and 256 KiB of slack."""
    pieces = [Path(results[c].piece) for c in part.clips if results[c].piece is not None]
    rows = sum(int(results[c].record.get("windows", 0)) for c in part.clips if results[c].piece is not None)
    shapes = meta.shapes()
    row = sum(_STRING_ROW_BYTES if d == "str" else math.prod(shapes[c]) * np.dtype(d).itemsize
              for c, d in COLUMNS.items() if c not in BIG_COLUMNS)  # fmt: skip
    return sum(p.stat().st_size for p in pieces) + rows * row + (256 << 10)


def _merge(part: Part, meta: ShardMeta, results: dict[str, ClipResult], cfg: BuildConfig) -> None:
    """The pieces of ``part`` -> its shard file, atomically.

    HDF5 does not survive a full disk (h5py segfaults closing the file): the merged file's room is
    claimed before HDF5 writes a byte (:func:`~mer_data.base.atomic.reserve_space`), so a full disk
    is a ``DiskFullError`` naming the shard and the bytes it needs, and nothing is left behind."""
    tmp = temp_name(part.final)
    need = _merge_bytes(part, meta, results)
    with disk_full_as_error(part.final, need):
        if cfg.format == "hdf5":
            writer: Hdf5ShardWriter | McapShardWriter = Hdf5ShardWriter(tmp, meta, compression=cfg.compression)
        else:
            writer = McapShardWriter(tmp, meta, preview=cfg.mcap_preview)
        try:
            if isinstance(writer, Hdf5ShardWriter):
                reserve_space(writer.file.id.get_vfd_handle(), need, part.final)
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
            _fsync(tmp, release=isinstance(writer, Hdf5ShardWriter))
            os.replace(tmp, part.final)
        except BaseException:
            writer.abort()
            raise
    shutil.rmtree(part.final.parent / ".partial" / part.name, ignore_errors=True)


def _up_to_date(part: Part, clips: dict[str, Path | str], build_id: str, cfg: BuildConfig, skel: Skeleton) -> ShardMeta | None:
    if not part.final.is_file():
        return None
    try:
        meta = open_shard(part.final).meta
    except MerError:
        return None
    try:
        shas = {c: source_sha256(cfg, skel, clips[c]) for c in part.clips}
    except MerError:
        return None  # rebuilt; the clip's own error is reported then
    return meta if meta.part_key == part_key(build_id, part.name, shas) else None


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
        ShardBuildError: bad input folder, a foreign build in ``out``, another live build writing
            the same shard files into ``out`` (each file is locked by ``OUT/.<file>.lock``), or a
            failing clip without ``keep_going`` (no shard of that clip's file is written).
        UnknownRobotError, MotionFormatError, SplitError: unknown robot, robot without a LAFAN1
            layout, split that does not fit the clips.
    """
    t0 = time.perf_counter()
    cfg, out = config, Path(out)
    plan = plan_build(cfg, out, shard_index)
    refuse_foreign_outputs(out, "" if shard_index is None else f"-{shard_index:05d}-of-{cfg.num_shards:05d}")
    out.mkdir(parents=True, exist_ok=True)
    names = [p.final.name for p in plan.parts.values()]
    with hold_locks(out, names, ShardBuildError):  # a second build of the same files is refused
        return _build(cfg, out, plan, t0, workers=workers, shard_index=shard_index, keep_going=keep_going,
                      progress=progress)  # fmt: skip


def _build(cfg: BuildConfig, out: Path, plan, t0: float, *, workers: int, shard_index: int | None, keep_going: bool,
           progress: Progress | None) -> BuildReport:  # fmt: skip
    """The build proper, with the locks of its files held (see :func:`build_shards`)."""
    check_out(out, plan.build_id, {p.final.name for p in plan.parts.values()})
    for p in plan.parts.values():  # a planted link would send pieces (and their clean-up) elsewhere
        real_folder(out / ".partial" / p.name, out)
    clean_temp(out, list(plan.parts.values()))

    report = BuildReport(out=str(out), build_id=plan.build_id, config=plan.config_json)
    todo: list[Part] = []
    for p in plan.parts.values():
        meta = _up_to_date(p, plan.clips[p.robot], plan.build_id, cfg, Skeleton.from_json(plan.skeletons[p.robot]))
        if meta is None:
            todo.append(p)
        else:
            report.add_file(p.final, meta, "up to date")
            shutil.rmtree(out / ".partial" / p.name, ignore_errors=True)  # leftovers of a crash
    tasks = [
        ClipTask(p.robot, c, str(plan.clips[p.robot][c]), p.split, p.name, str(out / ".partial" / p.name / f"{c}.piece"))
        for p in todo
        for c in p.clips
    ]
    order = {p.name: i for i, p in enumerate(todo)}  # files one after another (each done early), and
    tasks.sort(key=lambda t: (order[t.part], -source_size(t.path)))  # largest clips first in each
    total = sum(len(p.clips) for p in plan.parts.values())
    done = total - len(tasks)
    if progress:
        progress(done, total, None)

    results: dict[str, dict[str, ClipResult]] = {p.name: {} for p in todo}
    by_name = {p.name: p for p in todo}
    gen = _run(BuildContext(cfg, plan.skeletons, plan.metas), tasks, workers)
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
            got = results[res.task.part]
            got[res.task.clip] = res
            p = by_name[res.task.part]
            if len(got) == len(p.clips):
                shas = {c: got[c].record["sha256"] for c in p.clips}
                meta = replace(
                    plan.metas[p.name],
                    part_key=part_key(plan.build_id, p.name, shas),
                    sources=[got[c].record for c in p.clips],
                )
                _merge(p, meta, got, cfg)
                report.add_file(p.final, meta, "built")
    finally:
        gen.close()
    try:
        (out / ".partial").rmdir()  # only when empty: pieces of other shard indices may still be there
    except OSError:
        pass
    report.files.sort(key=lambda f: f["name"])
    report.seconds = time.perf_counter() - t0
    try:
        report.card = str(write_card(out))
        write_sidecar(out)
    except ShardFormatError as exc:  # e.g. this shard index got no clips at all
        log.warning("no dataset card written: %s", exc)
    suffix = "" if shard_index is None else f"-{shard_index:05d}-of-{cfg.num_shards:05d}"
    dest = out / f"build-report{suffix}.json"
    atomic_write(dest, json.dumps(report.to_dict(), indent=1, sort_keys=True))
    for s in report.short:
        log.warning("skipped %s/%s: %s", s["robot"], s["clip"], s.get("error", "shorter than a window"))
    return report
