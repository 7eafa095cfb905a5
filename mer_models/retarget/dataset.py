"""Retargeting whole datasets: every clip of a folder (or Hub dataset) × every target robot.

``mer retarget --input DIR|hf://REPO --source g1 --targets h1 atlas --out OUT``:

* **Outputs** per (target, clip): ``OUT/<target>/<clip>.csv`` (the target's LAFAN1-style layout),
  optionally ``.npz`` (for the tracker ``npz_for`` names), and ``<clip>.metrics.json`` (the paper's metrics of
  that retarget). Each file is written atomically; the metrics file is written last, so its
  presence means the (target, clip) is finished.
* **Resumable**: finished (target, clip) pairs are skipped; a run killed at any point leaves no
  finished file behind half written (a killed writer's temporary file is swept by the next run;
  those of live runs sharing ``OUT`` are left alone) and the next run with the same arguments does
  only what is missing.
* **Sharded**: ``--shard-index I --num-shards N`` takes every N-th (target, clip) pair from the
  sorted list, so N independent jobs (a scheduler's array job) cover the dataset once.
* **Batched across clips** (optimiser): every clip is cut into segments of ``segment`` frames
  plus ``context`` frames on each side (solved with their neighbours so the temporal prior has no
  seam), and segments of several clips are solved together, up to ``frames_per_batch`` frames at
  once.
* **In processes** (optimiser, ``workers``): the pairs are cut into chunks (one target's clips in
  order, a chunk closed once it holds ``frames_per_batch`` frames: a long clip alone, short ones
  together), independent of each other and of ``workers``; chunks are solved one at a time per
  process, the largest first (:func:`.workers.run_tasks`), so ``workers=N`` writes the files
  ``workers=1`` writes.
* **The model** (``method="diffusion"``) retargets clip by clip through the long-horizon sampler,
  all of a clip's pending targets in one pass, the reference encoded once per window for all of
  them (:func:`~mer_models.retarget.long_horizon.retarget_sequences`); each pair's ``seconds`` is its
  share of that pass (in this process: ``workers`` applies to the optimiser).
* **Summary**: a table per (clip, target) at the end and ``OUT/summary.json`` (every finished
  pair, including those of earlier runs and other shards that share ``OUT``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from mer_data.base.atomic import atomic_write, real_folder, sweep_stale
from mer_data.base.errors import MerError
from mer_data.base.locks import hold_locks
from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.collision import collision_model
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import Robot, as_robot
from mer_data.skeleton import Skeleton
from mer_models.batch import graph_from_batch
from mer_models.config import EnergyConfig
from mer_models.export.writers import NPZ_FPS, TargetMotion, require_tracker, write_csv, write_npz
from mer_models.solver.optimize import optimize_motion
from mer_models.zoo.checkpoint import Checkpoint

from .artifacts import ARTIFACT_KEYS
from .balance import BALANCE_KEYS
from .clip import MODEL_FPS, model_label, retarget_features_many, sequence_metrics
from .columns import format_summary
from .jobs import Job, find_bvh_clips, find_clips, plan_jobs
from .long_horizon import prepare_reference
from .workers import run_tasks

log = logging.getLogger(__name__)

__all__ = ["FORMATS", "Job", "find_clips", "find_bvh_clips", "plan_jobs", "retarget_dataset", "format_summary"]

FORMATS = ("csv", "npz")
SUMMARY_KEYS = ("g_mpbpe", "mpboe", "mpbve", "jerk_frame", "limit_violation", *ARTIFACT_KEYS, *BALANCE_KEYS, "selfpen_worst",
                "speed_worst")


@dataclass(eq=False)
class _Clip:
    """A clip being retargeted to one target: its goals (whole clip) and the solution so far."""

    job: Job
    feats: np.ndarray  # (N, Jr, 9) world features, first base x, y at the origin
    scaled: np.ndarray  # (N, Jr, 3)
    goal_rot: np.ndarray  # (N, Jr, 3, 3)
    rot_mask: np.ndarray  # (Jr,)
    shift: np.ndarray  # (3,)
    world_feats: np.ndarray
    src: Skeleton  # the source's skeleton (a robot's, or this clip's human's)
    q: np.ndarray = field(init=False)
    base_pos: np.ndarray = field(init=False)
    base_rot: np.ndarray = field(init=False)
    pending: int = 0
    goal: np.ndarray | None = None  # (N, Jr, 3) the solver's position goals (default: ``scaled``; the stance lock edits them)

    def __post_init__(self) -> None:
        n = self.feats.shape[0]
        self.q, self.base_pos, self.base_rot = np.zeros((n, 0)), np.zeros((n, 3)), np.zeros((n, 3, 3))
        if self.goal is None:
            self.goal = self.scaled


def _segments(n: int, segment: int, context: int) -> list[tuple[int, int, int, int]]:
    """(window start, window end, core start, core end) covering 0..n-1: windows of at most
    ``segment + 2 context`` frames, each core inside its window with ``context`` frames around it
    where the clip has them."""
    span = segment + 2 * context
    out = []
    for s in range(0, n, segment):
        e = min(n, s + segment)
        a = max(0, s - context)
        b = min(n, a + span)
        a = max(0, min(a, b - span))
        out.append((a, b, s, e))
    return out


def _source(job: Job, source: Robot | str, fps: float, bvh=None) -> tuple[Skeleton, np.ndarray]:
    """A job's source skeleton and (N, Jr, 9) world features of its clip at the model's frame rate
    (:func:`mer_data.motion.sources.read_source`: a robot's CSV, or a human's BVH)."""
    from mer_data.motion.sources import read_source

    src = read_source(job.source_path, source, fps=fps, bvh=bvh)
    return src.skeleton, src.features()


def _read(job: Job, source: Robot | str, target: Skeleton, fps: float, bvh=None) -> _Clip:
    src, feats = _source(job, source, fps, bvh)
    f, scaled, shift, (goal_rot, rot_mask) = prepare_reference(feats, src, target)
    return _Clip(job, f, scaled, goal_rot, rot_mask, shift, feats, src)


def _lock_stance(c: _Clip, src: Skeleton, geometry, physics) -> None:
    """The stance lock (``physics.lock_blend``) on the whole clip's goals, so that a stance phase
    cut by a segment boundary keeps one anchor (:meth:`mer_models.solver.physics.PhysicsInputs.lock_goals`)."""
    if physics is None or geometry is None or physics.lock_blend < 0 or physics.method == "constraints":
        return  # (the constraint method edits no goal)
    from .clip import physics_inputs

    inputs = physics_inputs(c.feats, src, geometry, MODEL_FPS, physics)
    c.goal = inputs.lock_goals(torch.from_numpy(c.scaled)[None])[0].numpy()


def _solve_batch(items: list[tuple[_Clip, tuple[int, int, int, int]]], target: Skeleton, span: int,
                 energy: EnergyConfig, device: str, physics=None, geometry=None, balance=None) -> None:  # fmt: skip
    """Optimise segments of several clips (sources of one node count) in one batch and write their
    cores back into the clips (``physics``: a :class:`~mer_models.solver.physics.PhysicsConfig`, with
    the target's ``geometry``; ``balance``: the target's :class:`~mer_models.solver.balance_term.BalanceInputs`)."""
    src = items[0][0].src
    etas = {}
    for c, _ in items:
        if c.src.fingerprint not in etas:
            etas[c.src.fingerprint] = joint_map(target, c.src)
    eta_b = np.stack([etas[c.src.fingerprint] for c, _ in items])  # (B, Jt, Jr)
    B = len(items)
    span = min(span, max(b - a for _, (a, b, _, _) in items))  # short clips (BVH: 100-300 frames) are not padded to a full segment

    def pad(x: np.ndarray) -> np.ndarray:
        return x if len(x) == span else np.concatenate([x, np.repeat(x[-1:], span - len(x), 0)])

    goal = np.stack([pad(c.goal[a:b]) for c, (a, b, _, _) in items])
    grot = np.stack([pad(c.goal_rot[a:b]) for c, (a, b, _, _) in items])
    rvec = np.stack([pad(c.feats[a:b, 0, 0:3]) for c, (a, b, _, _) in items])
    one = collate([TrainingSample(items[0][0].feats[:3].astype(np.float32), src, target, eta_b[0])])  # the target's graph
    g = graph_from_batch(one, "tgt", device).select(torch.zeros(B, dtype=torch.long, device=device))
    phys = None
    if physics is not None:
        from .clip import physics_inputs

        seg = dataclasses.replace(physics, lock_blend=-1)  # the stance lock is on the whole clip's goals (_lock_stance)
        per = [physics_inputs(pad(c.feats[a:b]), c.src, geometry, MODEL_FPS, seg) for c, (a, b, _, _) in items]
        phys = dataclasses.replace(per[0], contacts=torch.cat([p.contacts for p in per]))
    out = optimize_motion(
        energy, g, torch.from_numpy(eta_b.astype(np.float32)).to(device),
        torch.from_numpy(goal).float().to(device), axis_angle_to_matrix(torch.from_numpy(rvec).float()).to(device),
        goal_rot=torch.from_numpy(grot).float().to(device),
        rot_mask=torch.from_numpy(np.stack([c.rot_mask for c, _ in items])).to(device), physics=phys, balance=balance,
    )  # fmt: skip
    q, bp, br = (out[k].double().cpu().numpy() for k in ("q", "base_pos", "base_rot"))
    for k, (c, (a, _, s, e)) in enumerate(items):
        if c.q.shape[1] != q.shape[2]:
            c.q = np.zeros((c.feats.shape[0], q.shape[2]))
        c.q[s:e], c.base_pos[s:e], c.base_rot[s:e] = q[k, s - a : e - a], bp[k, s - a : e - a], br[k, s - a : e - a]
        c.pending -= 1


def _finish(c: _Clip, target: Robot, formats: Sequence[str], method: str, seconds: float,
            npz_fps: float | None = NPZ_FPS, physics=None, geometry=None, npz_for: str | None = None) -> dict:  # fmt: skip
    """Write a finished clip's outputs (metrics file last) and return its summary row (with
    ``physics``, the whole motion made feasible first: :func:`.feasible.feasible_motion`)."""
    skel = target.skeleton
    motion = TargetMotion(skel, MODEL_FPS, c.q[:, : skel.num_nodes], c.base_pos + c.shift, c.base_rot)
    if physics is not None and geometry is not None:
        from .feasible import feasible_motion

        motion = feasible_motion(motion, geometry, physics)
    prepared = (c.feats, c.scaled, c.shift, (c.goal_rot, c.rot_mask))
    return _write(c.job, target, motion, c.world_feats, c.src, formats, method, seconds, prepared, npz_fps, npz_for)


def _finite_or_none(v):
    """JSON has no NaN: an undefined metric (no contact frame, say) is written as null."""
    return None if isinstance(v, float) and not np.isfinite(v) else v


def _write(job: Job, target: Robot, motion: TargetMotion, world_feats: np.ndarray, src: Skeleton, formats, method: str,
           seconds: float, prepared: tuple | None = None, npz_fps: float | None = NPZ_FPS,
           npz_for: str | None = None) -> dict:  # fmt: skip
    if "csv" in formats:
        write_csv(job.output("csv"), motion, robot=target)
    if "npz" in formats:
        write_npz(job.output("npz"), motion, tracker=npz_for, fps=npz_fps, robot=target)
    metrics = sequence_metrics(world_feats, src, motion, prepared=prepared, geometry=collision_model(target),
                               masses=mass_model(target))
    row = {"clip": job.clip, "target": job.target, "frames": motion.num_frames, "method": method, "seconds": round(seconds, 3),
           **{k: _finite_or_none(metrics.get(k)) for k in SUMMARY_KEYS}}  # fmt: skip
    atomic_write(job.output("metrics"), json.dumps(row, indent=1) + "\n")
    return row


def _locked_out(fn: Callable[..., dict]) -> Callable[..., dict]:
    """Run ``fn`` holding ``OUT/.retarget-<i>-of-<n>.lock``: a second run of the same shard into the
    same ``--out`` is refused (one line naming the owner), as shard builds are."""
    import functools
    import inspect

    sig = inspect.signature(fn)

    @functools.wraps(fn)
    def run(*args, **kwargs) -> dict:
        a = sig.bind(*args, **kwargs)
        a.apply_defaults()
        out = Path(a.arguments["out_dir"])
        out.mkdir(parents=True, exist_ok=True)
        name = f"retarget-{int(a.arguments['shard_index']):05d}-of-{int(a.arguments['num_shards']):05d}"
        with hold_locks(out, [name], MerError):
            return fn(*args, **kwargs)

    return run


@dataclass(frozen=True)
class _Setup:
    """What every chunk of an optimiser run shares (sent once to each worker process)."""

    src_robot: Robot | str
    robots: dict[str, Robot]
    formats: tuple[str, ...]
    method: str
    input_fps: float
    npz_fps: float | None
    npz_for: str | None
    segment: int
    context: int
    frames_per_batch: int
    energy: EnergyConfig
    device: str
    physics: Any
    bvh: Any
    balance: Any = None


def _frames_estimate(path: Path, input_fps: float) -> float:
    """About how many frames at :data:`MODEL_FPS` a clip has, without parsing it: a CSV's lines, a
    BVH's ``Frames`` x ``Frame Time`` (for grouping and ordering chunks only)."""
    import gzip

    try:
        if path.suffix.lower() == ".bvh":
            frames = period = None
            with open(path, "rb") as f:
                for line in f:
                    key, _, value = line.decode("latin-1").strip().partition(":")
                    if key.lower() == "frames":
                        frames = float(value)
                    elif key.lower() == "frame time":
                        period = float(value)
                        break
            return (frames or 0.0) * (period or 1.0 / MODEL_FPS) * MODEL_FPS
        with (gzip.open(path, "rb") if path.name.lower().endswith(".gz") else open(path, "rb")) as f:
            lines = sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))
        return lines * MODEL_FPS / input_fps
    except (OSError, ValueError, EOFError):
        return 0.0  # the reader says what is wrong with it, when the chunk runs


def _chunks(jobs: Sequence[Job], frames_per_batch: int, input_fps: float) -> list[list[Job]]:
    """The pairs cut into independent chunks (module docstring), the largest first: each target's
    clips in order, a chunk closed once it holds ``frames_per_batch`` frames."""
    chunks: list[tuple[float, list[Job]]] = []
    for target in sorted({j.target for j in jobs}):
        cur, size = [], 0.0
        for j in sorted((j for j in jobs if j.target == target), key=lambda j: j.clip):
            cur.append(j)
            size += _frames_estimate(j.source_path, input_fps)
            if size >= frames_per_batch:
                chunks.append((size, cur))
                cur, size = [], 0.0
        if cur:
            chunks.append((size, cur))
    return [c for _, c in sorted(chunks, key=lambda c: -c[0])]


def _solve_chunk(setup: _Setup, jobs: list[Job]) -> list[dict]:
    """Optimise one chunk (one target's clips): segments of its clips batched together; each
    finished pair's outputs written, its summary row returned."""
    target = setup.robots[jobs[0].target]
    physics = setup.physics
    geometry = collision_model(target) if physics is not None else None
    balance = None
    if setup.balance is not None:
        from .clip import balance_inputs

        balance = balance_inputs(target.skeleton, setup.balance, MODEL_FPS)
    span = setup.segment + 2 * setup.context
    per_batch = max(1, setup.frames_per_batch // span)
    queues: dict[tuple, list[tuple[_Clip, tuple[int, int, int, int]]]] = {}  # per source node layout
    started: dict[str, float] = {}
    rows = []
    for k, j in enumerate(jobs):
        c = _read(j, setup.src_robot, target.skeleton, setup.input_fps, setup.bvh)
        _lock_stance(c, c.src, geometry, physics)
        started[j.clip] = time.perf_counter()
        segs = _segments(c.feats.shape[0], setup.segment, setup.context)
        c.pending = len(segs)
        queues.setdefault(c.src.node_names, []).extend((c, s) for s in segs)
        last = k == len(jobs) - 1
        for key in list(queues):
            queue = queues[key]
            while len(queue) >= per_batch or (last and queue):
                items, queue = queue[:per_batch], queue[per_batch:]
                queues[key] = queue
                _solve_batch(items, target.skeleton, span, setup.energy, setup.device, physics, geometry, balance)
                for c2 in dict.fromkeys(c for c, _ in items):
                    if c2.pending == 0:
                        rows.append(_finish(c2, target, setup.formats, setup.method, time.perf_counter() - started[c2.job.clip],
                                            setup.npz_fps, physics, geometry, setup.npz_for))  # fmt: skip
    return rows


@_locked_out
def retarget_dataset(
    input_spec: str,
    source: str | Robot,
    targets: Sequence[str | Robot],
    out_dir: str | Path,
    *,
    method: str = "optimize",
    checkpoint: Checkpoint | None = None,
    formats: Sequence[str] = ("csv",),
    shard_index: int = 0,
    num_shards: int = 1,
    input_fps: float = MODEL_FPS,
    npz_fps: float | None = NPZ_FPS,
    npz_for: str | None = None,
    segment: int = 512,
    context: int = 8,
    frames_per_batch: int = 2048,
    energy: EnergyConfig | None = None,
    device: str = "cpu",
    progress: Callable[[int, int], None] | None = None,
    physics=None,
    bvh=None,
    workers: int = 1,
    balance=None,
    on_start: Callable[[dict], None] | None = None,
    **model_kw,
) -> dict:
    """Retarget every clip of ``source`` in the input to every target (see the module docstring).

    Args:
        source, targets: robots, or names resolved here once (lower layers take the :class:`Robot`).
        method: ``optimize`` (batched across clips) or ``diffusion`` (``checkpoint`` required).
        formats: any of :data:`FORMATS`; the metrics file is always written; npz_fps: npz frame rate [Hz];
            npz_for: the tracker that reads the npz files (required with ``npz``:
            :data:`~mer_models.export.writers.NPZ_TRACKERS`).
        progress: called with (pairs done, pairs to do) of this run's work.
        workers: processes of an optimiser run, one torch thread each (:mod:`.workers`; 1: this
            process, on one thread); the files do not depend on it.
        on_start: called once the work is known, with ``{"jobs", "done_before", "todo", "workers"}``
            (``done_before``: finished pairs found in ``out_dir`` and skipped).
        bvh: how to read BVH files (``source`` ``"bvh"``: a folder of human motion capture,
            :func:`find_bvh_clips`), :class:`~mer_data.motion.sources.BvhOptions`.
        physics: a :class:`~mer_models.solver.physics.PhysicsConfig`: the optimiser's physical terms
            (both methods: ``diffusion`` with ``refine``); None: key points and orientations only.
        balance: a :class:`~mer_models.solver.balance_term.BalanceConfig`: the optimiser's balance term
            (both methods, as ``physics``; docs/model.md §Balance); None: none.
        model_kw: options of ``diffusion`` (``steps``, ``guidance``, ``seed``, ``allow_unseen``, ``bf16``, and
            ``refine``: at most that many optimiser iterations from the model's output, as for one file).

    Returns:
        ``{"source", "targets", "method", "workers", "jobs", "done_before", "done_now", "frames", "seconds", "frames_per_second",
        "rows"}``;
        ``rows`` are the summary rows of every finished pair in ``out_dir`` (this run's and earlier ones).
    """
    unknown = [f for f in formats if f not in FORMATS]
    if "npz" in formats:
        require_tracker(npz_for, "npz_for=")
    if unknown:
        raise MerError(f"unknown output format(s) {unknown}; known: {', '.join(FORMATS)}")
    if method not in ("optimize", "diffusion"):
        raise MerError(f"unknown method {method!r}", fix="use --method optimize or diffusion")
    if method == "diffusion" and checkpoint is None:
        raise MerError("the diffusion method needs a model", fix="pass --model NAME, or use --method optimize")
    out_dir = Path(out_dir)
    from mer_data.motion.sources import HUMAN_SOURCES

    human = isinstance(source, str) and source.lower() in HUMAN_SOURCES
    src_robot = source.lower() if human else as_robot(source)  # a human's skeleton is each clip's own
    robots = {r.name: r for r in map(as_robot, targets)}
    source, targets = (src_robot if human else src_robot.name), list(robots)
    clips = find_bvh_clips(input_spec, source) if human else find_clips(input_spec, source)
    for t in set(targets):  # OUT/TARGET a real folder (a planted link to elsewhere is refused), then
        real_folder(out_dir / t, out_dir)  # the temporary files of killed runs swept (live writers' are left alone)
        sweep_stale(out_dir / t)
    jobs = plan_jobs(clips, targets, out_dir, shard_index, num_shards)
    todo = [j for j in jobs if not j.done()]
    log.info("%d (target, clip) pairs in this shard; %d already done, %d to do", len(jobs), len(jobs) - len(todo), len(todo))
    chunks = _chunks(todo, frames_per_batch, input_fps) if method == "optimize" else []
    used = max(1, min(workers, len(chunks)))  # processes this run starts (the model runs here)
    if on_start is not None:
        on_start({"jobs": len(jobs), "done_before": len(jobs) - len(todo), "todo": len(todo), "workers": used})
    energy = energy or EnergyConfig()
    t_start, frames_done, pairs_done = time.perf_counter(), 0, 0
    if method == "diffusion":  # clip by clip, all its pending targets in one pass (the reference encoded once per window)
        by_clip: dict[str, list[Job]] = {}
        for j in todo:
            by_clip.setdefault(j.clip, []).append(j)
        for _, cjobs in sorted(by_clip.items()):
            cjobs.sort(key=lambda j: j.target)
            t0 = time.perf_counter()
            src, world = _source(cjobs[0], src_robot, input_fps, bvh)
            results = retarget_features_many(world, src, [robots[j.target].skeleton for j in cjobs], method="diffusion", checkpoint=checkpoint,
                                             fps=MODEL_FPS, physics=physics,
                                             geometry=None if physics is None else [collision_model(robots[j.target]) for j in cjobs],
                                             balance=balance, **model_kw)  # fmt: skip
            seconds = (time.perf_counter() - t0) / len(cjobs)  # the pass is shared: each pair gets its share
            for j, res in zip(cjobs, results):
                _write(j, robots[j.target], res.motion, world, src, formats, res.method, seconds, res.prepared, npz_fps, npz_for)
                frames_done += res.motion.num_frames
                pairs_done += 1
                if progress is not None:
                    progress(pairs_done, len(todo))
    if chunks:
        setup = _Setup(src_robot, robots, tuple(formats), method, input_fps, npz_fps, npz_for, segment, context, frames_per_batch,
                       energy, device, physics, bvh, balance=balance)  # fmt: skip

        def collect(rows: list[dict]) -> None:
            nonlocal frames_done, pairs_done
            for row in rows:
                frames_done += row["frames"]
                pairs_done += 1
                if progress is not None:
                    progress(pairs_done, len(todo))

        run_tasks(_solve_chunk, setup, chunks, used, collect)
    seconds = time.perf_counter() - t_start
    rows = []
    for j in jobs:
        if j.done():
            rows.append(json.loads(j.output("metrics").read_text()))
    label = model_label(checkpoint, model_kw.get("refine")) if method == "diffusion" else method
    summary = {
        "source": source, "targets": sorted(set(targets)), "method": label, "workers": used, "jobs": len(jobs),
        "done_before": len(jobs) - len(todo), "done_now": len(todo), "frames": frames_done, "seconds": round(seconds, 3),
        "frames_per_second": round(frames_done / seconds, 1) if seconds > 0 and frames_done else None, "rows": rows,
    }  # fmt: skip
    all_rows = []
    for p in sorted(out_dir.glob("*/*.metrics.json")):
        try:
            all_rows.append(json.loads(p.read_text()))
        except (OSError, ValueError):
            continue
    atomic_write(out_dir / "summary.json", json.dumps({**summary, "rows": all_rows}, indent=1) + "\n")
    return summary

