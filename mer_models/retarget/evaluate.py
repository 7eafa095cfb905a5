"""Evaluation on LAFAN1-layout motion folders, in the paper's table layout (Table II).

The source robot's clips (``INPUT/<source>/*.csv[.gz]``) are split (``paper``: 3 training clips
per robot, the rest held out), cut into 60-frame origin-normalized windows exactly as the shards
cut them (:mod:`mer_data.motion.windows`), and retargeted to each target robot as independent windows
(the paper evaluates 60-frame clips), by the model and/or the optimisation baseline on the very
same windows. When ``INPUT/<target>/`` has the same clip (G1 and H1 share LAFAN1), that window
is the target's ground truth for the ``gt_*`` metrics. Metrics: :mod:`mer_models.retarget.metrics`.

``in-domain`` = windows of the split's training clips; ``out-of-domain`` = the held-out clips.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from mer_data.base.errors import MerError
from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.collision import collision_model
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import Robot, as_robot
from mer_models.config import EnergyConfig, SamplerConfig
from mer_models.solver.optimize import DEFAULT_GN_ITERS, DEFAULT_ITERS
from mer_models.zoo.checkpoint import Checkpoint, check_robot

from .artifacts import ARTIFACT_KEYS, motion_artifacts
from .balance import BALANCE_KEYS
from .clip import balance_inputs
from .inference import model_batch, optimize_batch
from .metrics import summarize, window_metrics

log = logging.getLogger(__name__)

__all__ = ["EvalOptions", "collect_windows", "evaluate", "format_table", "DOMAINS"]

DOMAINS = ("in-domain", "out-of-domain")
METHODS = ("model", "refine", "optimize")


@dataclass(frozen=True)
class EvalOptions:
    """Which windows and how to retarget them.

    Attributes:
        split: ``paper``, ``all`` or a split file (:func:`mer_data.motion.splits.resolve_split`).
        window, stride: window length and stride [frames].
        max_windows: at most this many windows per domain, spread evenly over the clips (None: all).
        methods: ``model``, ``refine`` (the model, then at most ``refine`` optimiser iterations from
            its output) and/or ``optimize``.
        steps, guidance, init_noise: sampler overrides (None: the checkpoint's).
        batch_size: windows per forward pass.
        seed: sampling noise.
        opt_iters, opt_gn_iters: the optimiser's Adam and (most) Levenberg-Marquardt iterations.
        scaling: how the reference is scaled to the target (:mod:`mer_data.kinematics.scaling`).
        refine: Levenberg-Marquardt iterations of the ``refine`` method.
        bf16: the model's network under bfloat16 autocast (:mod:`mer_models.diffusion.precision`).
        artifacts: also the artifact metrics of every window (:mod:`mer_models.retarget.artifacts`).
        physics: the optimiser's physical terms (``optimize`` and ``refine``;
            :class:`~mer_models.solver.physics.PhysicsConfig`), None: without.
        bvh: how BVH files are read (source ``bvh``; :class:`~mer_data.motion.sources.BvhOptions`).
        balance: the optimiser's balance term (``optimize`` and ``refine``;
            :class:`~mer_models.solver.balance_term.BalanceConfig`; docs/model.md §Balance), None: without.
    """

    split: str = "paper"
    window: int = 60
    stride: int = 60
    max_windows: int | None = None
    methods: tuple[str, ...] = ("model", "optimize")
    steps: int | None = None
    guidance: float | None = None
    init_noise: float | None = None
    batch_size: int = 16
    seed: int = 0
    opt_iters: int = DEFAULT_ITERS
    opt_gn_iters: int = DEFAULT_GN_ITERS
    scaling: str = "segments"
    refine: int = 5
    bf16: bool = False
    artifacts: bool = True
    physics: object = None
    bvh: object = None
    balance: object = None


def _clip_files(folder: Path) -> dict[str, Path]:
    out = {}
    for p in sorted(folder.glob("*.csv")) + sorted(folder.glob("*.csv.gz")):
        out[p.name[: -len(".csv.gz")] if p.name.endswith(".gz") else p.stem] = p
    return out


def _robot_folder(root: Path, robot: str) -> Path | None:
    d = root / robot
    return d if d.is_dir() else None


def _joints(skel) -> dict[str, int]:
    """URDF joint name → node of every revolute joint (``at_limit/<joint>`` in the report)."""
    return {n: i for i, (n, k) in enumerate(zip(skel.urdf_joint_names, skel.node_kinds)) if k == "revolute"}


def collect_windows(input_dir: str | Path, robot: str | Robot, opts: EvalOptions) -> dict[str, list[dict]]:
    """domain → windows ``{clip, start, reference (T, J, 9), skeleton}`` of the source: a robot
    (``DIR/<robot>/*.csv``) or, for ``"bvh"``, the humans of ``DIR/bvh/*.bvh`` (each clip its own
    skeleton, :func:`mer_data.motion.sources.read_source`)."""
    from mer_data.motion.lafan1 import read_lafan1_csv
    from mer_data.motion.sources import HUMAN_SOURCES, human_files, read_source
    from mer_data.motion.splits import EVAL, TRAIN, resolve_split
    from mer_data.motion.windows import make_windows, window_features, window_starts

    root = Path(input_dir)
    human = isinstance(robot, str) and robot.lower() in HUMAN_SOURCES
    if human:
        source = robot.lower()
        files = human_files(root, source)
    else:
        robot = as_robot(robot)
        source = robot.name
        folder = _robot_folder(root, source)
        if folder is None:
            raise MerError(f"no folder {source}/ in {root}", path=root, fix=f"point --input at a folder holding {source}/*.csv")
        files = _clip_files(folder)
        if not files:
            raise MerError(f"no .csv or .csv.gz motions in {folder}", path=folder)
    split = resolve_split(opts.split, {source: list(files)})[source]
    motions, skels, chosen = {}, {}, {TRAIN: [], EVAL: []}
    for clip, path in files.items():
        if human:
            src = read_source(path, source, bvh=opts.bvh)
            motion, skels[clip] = src.motion, src.skeleton
        else:
            motion, skels[clip] = read_lafan1_csv(path, robot), robot.skeleton
        starts = window_starts(motion.num_frames, opts.window, opts.stride)
        if len(starts) == 0:
            log.warning("%s: %d frames, shorter than a window; skipped", path, motion.num_frames)
            continue
        motions[clip] = motion
        chosen[split[clip]] += [(clip, int(s)) for s in starts]
    out = {}
    for dom, key in zip(DOMAINS, (TRAIN, EVAL)):
        w = chosen[key]
        if opts.max_windows is not None and len(w) > opts.max_windows:
            idx = np.unique(np.linspace(0, len(w) - 1, opts.max_windows).round().astype(int))
            w = [w[i] for i in idx]
        windows = []
        for clip in dict.fromkeys(c for c, _ in w):  # clips in order; features only for chosen windows
            starts = np.array([s for c, s in w if c == clip], np.int64)
            wb = make_windows(motions[clip], skels[clip], starts, opts.window)
            feats = window_features(wb.pos, wb.q, wb.base_rotvec, motions[clip].fps)
            windows += [{"clip": clip, "start": int(s), "reference": feats[k], "skeleton": skels[clip]} for k, s in enumerate(starts)]
        out[dom] = windows
    return out


def _target_windows(input_dir: Path, target: Robot, windows: list[dict], opts: EvalOptions) -> list[np.ndarray | None]:
    """The target robot's own windows of the same clips and starts, where its data has them."""
    from mer_data.motion.lafan1 import read_lafan1_csv
    from mer_data.motion.windows import make_windows, window_features

    folder = _robot_folder(input_dir, target.name)
    if folder is None or not target.card.lafan1_columns:
        return [None] * len(windows)
    files = _clip_files(folder)
    skel = target.skeleton
    out: list[np.ndarray | None] = []
    cache: dict[str, object] = {}
    for w in windows:
        path = files.get(w["clip"])
        if path is None:
            out.append(None)
            continue
        if w["clip"] not in cache:
            cache[w["clip"]] = read_lafan1_csv(path, target)
        m = cache[w["clip"]]
        if w["start"] + opts.window > m.num_frames:
            out.append(None)
            continue
        wb = make_windows(m, skel, np.array([w["start"]]), opts.window)
        out.append(window_features(wb.pos, wb.q, wb.base_rotvec, m.fps)[0])
    return out


WINDOW_FPS = 30.0  # the windows' frame rate (LAFAN1's, the model's)


def _batches(windows: list[dict], size: int) -> list[tuple[int, int]]:
    """[a, b) ranges of at most ``size`` consecutive windows whose sources share one node layout."""
    out, a = [], 0
    while a < len(windows):
        b = a + 1
        while b < len(windows) and b - a < size and windows[b]["skeleton"].node_names == windows[a]["skeleton"].node_names:
            b += 1
        out.append((a, b))
        a = b
    return out


def _window_artifacts(motion: dict, batch: dict, tgt, geometry, windows: list[dict], masses=None) -> dict[str, np.ndarray]:
    """The artifact metrics (:mod:`.artifacts`; with ``masses`` the balance metrics, :mod:`.balance`,
    without joint torques) of every window of a batch: key → (B,)."""
    keys = ARTIFACT_KEYS + (tuple(k for k in BALANCE_KEYS if not k.startswith("torque")) if masses is not None else ())
    out: dict[str, list[float]] = {k: [] for k in keys}
    q, bp, br = (motion[k].detach().double().cpu().numpy() for k in ("q", "base_pos", "base_rot"))
    for b, x in enumerate(windows):
        a = motion_artifacts(q[b], bp[b], br[b], WINDOW_FPS, tgt, geometry, x["reference"], x["skeleton"], masses=masses)
        for k in keys:
            out[k].append(a[k])
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def evaluate(
    input_dir: str | Path,
    source: str,
    targets: Sequence[str],
    *,
    checkpoint: Checkpoint | None = None,
    opts: EvalOptions = EvalOptions(),
    energy: EnergyConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Evaluate; returns a JSON-ready report (see :func:`format_table`)."""
    input_dir = Path(input_dir)
    from mer_data.motion.sources import HUMAN_SOURCES

    human = isinstance(source, str) and source.lower() in HUMAN_SOURCES
    src_robot = source.lower() if human else as_robot(source)  # every name resolved once, here
    tgt_robots = {t: as_robot(t) for t in targets}
    methods = tuple(opts.methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise MerError(f"unknown method(s) {unknown}; known: {', '.join(METHODS)}")
    if opts.bf16 and not ("model" in methods or "refine" in methods):
        raise MerError("--bf16 runs the model's network in bfloat16; the optimiser has no network",
                       fix="drop --bf16, or add --methods model (or refine)")  # fmt: skip
    if "model" in methods or "refine" in methods:
        if human:
            raise MerError("the model was trained on robot sources only: it has never seen a human (BVH) source",
                           fix="evaluate --methods optimize")  # fmt: skip
        if checkpoint is None:
            raise MerError("evaluating the model needs --model", fix="pass --model PATH, or --methods optimize")
        for t in targets:
            check_robot(checkpoint, t, "targets")
        check_robot(checkpoint, source, "references")
    model_energy = energy or (checkpoint.run.energy if checkpoint is not None else EnergyConfig())
    opt_energy = energy or EnergyConfig()
    windows = collect_windows(input_dir, src_robot, opts)
    rows = []
    for target in targets:
        tgt = tgt_robots[target].skeleton
        geometry = collision_model(tgt_robots[target]) if opts.artifacts or opts.physics is not None else None
        etas: dict[str, np.ndarray] = {}
        for dom in DOMAINS:
            w = windows[dom]
            if not w:
                continue
            gts = _target_windows(input_dir, tgt_robots[target], w, opts)
            for method in methods:
                vals: dict[str, list[np.ndarray]] = {}
                sec = 0.0  # the retargeting's time (not the metrics')
                for a, b in _batches(w, opts.batch_size):
                    t0 = time.time()
                    ref = w[a]["skeleton"]  # one node layout per batch (a robot's; or humans' of one studio)
                    phys_kw = {"physics": opts.physics, "geometry": geometry, "ref_skeleton": ref, "fps": WINDOW_FPS,
                               "target_skeleton": tgt} if opts.physics is not None else {}  # fmt: skip
                    if opts.balance is not None:
                        phys_kw["balance"] = balance_inputs(tgt, opts.balance, WINDOW_FPS)
                    samples = []
                    for x, gt in zip(w[a:b], gts[a:b]):
                        fp = x["skeleton"].fingerprint
                        if fp not in etas:
                            etas[fp] = joint_map(tgt, x["skeleton"])
                        samples.append(TrainingSample(x["reference"], x["skeleton"], tgt, etas[fp], gt,
                                                      {"clip": x["clip"], "start": x["start"]}))  # fmt: skip
                    batch = collate(samples, scaling=opts.scaling)
                    if method in ("model", "refine"):
                        run = checkpoint.run
                        over = {k: float(v) for k, v in {"guidance": opts.guidance, "init_noise": opts.init_noise}.items() if v is not None}
                        sampler = SamplerConfig(**{**run.sampler.__dict__, **over})
                        gen = torch.Generator().manual_seed(opts.seed + a)
                        motion = model_batch(checkpoint.model, batch, sampler, energy=model_energy, steps=opts.steps, generator=gen,
                                             bf16=opts.bf16)  # fmt: skip
                        if method == "refine":
                            motion = optimize_batch(opt_energy, batch, gn_iters=opts.refine, init=motion, **phys_kw)
                    else:
                        motion = optimize_batch(opt_energy, batch, iters=opts.opt_iters, gn_iters=opts.opt_gn_iters, **phys_kw)
                    sec += time.time() - t0
                    for k, v in window_metrics(motion, batch, keypoints={"base": 0, **tgt.keypoints}, joints=_joints(tgt)).items():
                        vals.setdefault(k, []).append(v)
                    if geometry is not None and opts.artifacts:
                        for k, v in _window_artifacts(motion, batch, tgt, geometry, w[a:b], mass_model(tgt_robots[target])).items():
                            vals.setdefault(k, []).append(v)
                summary = summarize({k: np.concatenate(v) for k, v in vals.items()})
                row = {"robot": target, "domain": dom, "method": method, "windows": len(w), "seconds": round(sec, 2),
                       "frames_per_s": round(len(w) * opts.window / max(sec, 1e-9), 1), "metrics": summary}  # fmt: skip
                rows.append(row)
                if progress is not None:
                    progress(f"{target:9s} {dom:13s} {method:8s} {len(w)} windows, {row['seconds']} s")
    return {
        "source": source,
        "targets": list(targets),
        "model": str(checkpoint.path) if checkpoint is not None else None,
        "options": {**opts.__dict__, "methods": list(methods),
                    "physics": None if opts.physics is None else dataclasses.asdict(opts.physics),
                    "bvh": None if opts.bvh is None else dataclasses.asdict(opts.bvh),
                    "balance": None if opts.balance is None else dataclasses.asdict(opts.balance)},  # fmt: skip
        "rows": rows,
    }


_COLS = (("g_mpbpe", "E_g-mpbpe [m]"), ("mpboe", "E_mpboe [rad]"), ("mpbve", "E_mpbve [m/s]"), ("jerk_frame", "E_smooth [rad/fr^3]"), ("ref_jerk_frame", "source jerk"), ("limit_violation", "limits"))
_ART_COLS = (("floor_frames", "feet < -1 cm"), ("floor_depth_max", "deepest [m]"), ("skate_median", "skate med [m/s]"),
             ("floating_frames", "floating"), ("selfpen_1cm_frames", "self-pen > 1 cm"), ("speed_frames", "over speed limit"),
             ("body_floor_frames", "any body < -1 cm"), ("hover_frames", "hovering"), ("balance_infeasible", "infeasible"),
             ("zmp_out_single", "ZMP out, 1 foot"), ("zmp_out_double", "ZMP out, 2+"))  # fmt: skip
_GT_COLS = (("gt_mpbpe", "vs data: pos [m]"), ("gt_mpboe", "orient [rad]"), ("gt_mpbve", "vel [m/s]"))


def _cell(m: dict, k: str) -> str:
    v = m.get(k)
    if not v or not np.isfinite(v["mean"]):
        return "-"
    if k == "limit_violation":
        return f"{v['mean']:.3f}"
    return f"{v['mean']:.4g}±{v['std']:.2g}"


def format_table(report: dict) -> str:
    """The report as text in the paper's layout: an in-domain block, then an out-of-domain block."""
    lines = [f"source {report['source']}  model {report['model'] or '-'}  split {report['options']['split']}"]
    head = f"{'robot':10s} {'method':9s} {'win':>5s} {'fr/s':>7s}  " + "  ".join(f"{t:>18s}" for _, t in _COLS)
    has_gt = any(np.isfinite(r["metrics"].get("gt_mpbpe", {}).get("mean", np.nan)) for r in report["rows"])
    if has_gt:
        head += "  " + "  ".join(f"{t:>16s}" for _, t in _GT_COLS)
    for dom in DOMAINS:
        rows = [r for r in report["rows"] if r["domain"] == dom]
        if not rows:
            continue
        lines += ["", f"{dom}", head]
        for r in rows:
            s = f"{r['robot']:10s} {r['method']:9s} {r['windows']:5d} {r.get('frames_per_s', float('nan')):7.0f}  " + "  ".join(f"{_cell(r['metrics'], k):>18s}" for k, _ in _COLS)
            if has_gt:
                s += "  " + "  ".join(f"{_cell(r['metrics'], k):>16s}" for k, _ in _GT_COLS)
            lines.append(s)
        if any(r["metrics"].get("floor_frames") for r in rows):
            lines += ["", f"{dom}: artifacts (share of frames; mean over windows; docs/model.md §Evaluation)",
                      f"{'robot':10s} {'method':9s}  " + "  ".join(f"{t:>16s}" for _, t in _ART_COLS)]  # fmt: skip
            for r in rows:
                cells = []
                for k, _ in _ART_COLS:
                    v = r["metrics"].get(k, {}).get("mean", float("nan"))
                    cells.append(f"{v:16.3f}" if np.isfinite(v) else f"{'-':>16s}")
                lines.append(f"{r['robot']:10s} {r['method']:9s}  " + "  ".join(cells))
    return "\n".join(lines)

