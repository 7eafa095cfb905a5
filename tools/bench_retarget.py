"""Benchmark: mer's optimiser against mink (GMR's IK) on the same key-point targets, whole clips.

What it measures, per target robot, on one LAFAN1 clip of the source robot (default: G1,
``dance1_subject2``, the first 1800 frames = 60 s at 30 Hz), all in one run on the same machine:

* **mer**: ``mer_models.retarget.clip.retarget_features(feats, source, target, method="optimize")``,
  the whole call timed (reference preparation, batching, Levenberg-Marquardt over the whole motion),
  best wall time of ``--repeat`` runs after an untimed warm-up call on 16 frames. Its ``reference_points`` (F, K, 3), the body-part-scaled
  key-point goals in the world frame, are the targets of both methods.
* **mink**: ``tools/mink_peer.solve_keypoints`` on the same targets (the same key points, in the
  same order), GMR's scheme: frames in order, each warm-started from the previous frame, a fixed
  number of QP steps per frame (``--mink-iters``), joint limits as hard bounds, a posture task
  towards mer's nominal pose with mer's relative weight (``sqrt(w_norm K / (w_kp n_dof))``,
  ``EnergyConfig``). Solve time only (model building excluded), best of ``--repeat`` runs.

The machine's load average (start -> end) is printed with the table: other processes on a shared
machine inflate the timings, mer's (one long batched call) and mink's (many short steps) unequally;
raise ``--repeat`` when it is high.

Printed per (target, method): frames, seconds, frames/s, the mean key-point position error against
``reference_points`` [m] (mer's FK, ``mer_data.kinematics.fk.fk_skeleton``, of each method's angles and
base pose), mer's ``sequence_metrics`` of the result (``g_mpbpe`` [m], ``jerk_frame`` [rad/frame^3],
``limit_violation`` [fraction of frames], plus the largest limit excess [rad]) and the ratio of
mer's frames/s to mink's (> 1: mer is faster). For mer the key-point error and ``g_mpbpe`` measure
the same thing and agree (checked; a mismatch is logged). The two methods do not minimise quite the
same objective: mer's energy also has base/feet/hand orientation terms and a temporal smoothness
prior (``mer_models/solver/ik.py``); mink tracks positions only, frame by frame.

The command (2 threads: ``torch.set_num_threads`` and OMP/BLAS for the mink side; OpenMP threads
wait passively unless ``--omp-wait active``)::

    nice -n 5 .venv/bin/python tools/bench_retarget.py [--source g1] [--clip dance1_subject2] \\
        [--frames 1800] [--targets h1 atlas] [--mink-iters 2 5 10] [--repeat 2] [--threads 2] \\
        [--omp-wait passive|active] [--json PATH]

The clip is read from ``$MER_SHARED/data/lafan1/<source>/`` (default ``../shared``, i.e.
``/work/shared/data/lafan1``; ``--data-dir`` overrides). mink, mujoco and daqp are
**benchmark-only** packages, not mer dependencies (``pip install mink mujoco daqp``); without them
the mink rows are skipped with a note and mer's figures are still printed.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default="g1", help="source robot of the LAFAN1 clip (default g1)")
    ap.add_argument("--clip", default="dance1_subject2", help="clip name without .csv (default dance1_subject2; "
                    "the first clip of the folder when absent)")  # fmt: skip
    ap.add_argument("--data-dir", type=Path, default=None,
                    help="LAFAN1 folder with one sub-folder per robot (default $MER_SHARED/data/lafan1)")  # fmt: skip
    ap.add_argument("--frames", type=int, default=1800, help="first N frames of the clip (0: all)")
    ap.add_argument("--targets", nargs="+", default=["h1", "atlas"])
    ap.add_argument("--mink-iters", nargs="+", type=int, default=[2, 5, 10], help="mink QP steps per frame")
    ap.add_argument("--mink-solver", default="daqp", help="qpsolvers backend of mink (default daqp)")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs per row; the best wall time is reported")
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads and OMP/BLAS threads")
    ap.add_argument("--omp-wait", choices=["passive", "active"], default="passive",
                    help="OMP_WAIT_POLICY (default passive, as mer's commands set it: spinning threads starve each other "
                    "on a shared machine; mer_models.cli.main)")  # fmt: skip
    ap.add_argument("--dataset-clips", type=int, default=4,
                    help="also time a dataset of the first N clips x --targets: batched (mer retarget --input) "
                    "against one file at a time (retarget_file), same outputs; 0 skips it")  # fmt: skip
    ap.add_argument("--json", type=Path, default=None, help="also write the rows to this JSON file")
    ap.add_argument("-v", "--verbose", action="store_true")
    return ap


# OMP/BLAS thread counts must be set before numpy/torch load their libraries.
_early, _ = _parser().parse_known_args()
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(max(1, _early.threads))
os.environ["OMP_WAIT_POLICY"] = _early.omp_wait.upper()

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

from mer_data.kinematics.jointmap import keypoint_pairs  # noqa: E402
from mer_data.kinematics.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix  # noqa: E402
from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.registry import get_skeleton  # noqa: E402
from mer_data.skeleton import Skeleton  # noqa: E402
from mer_models.config import EnergyConfig  # noqa: E402
from mer_models.export.writers import TargetMotion  # noqa: E402
from mer_models.retarget.clip import MODEL_FPS, retarget_features, sequence_metrics, source_features  # noqa: E402

log = logging.getLogger("bench_retarget")

COLUMNS = (
    ("target", "{:<7}", "{}"),
    ("method", "{:<14}", "{}"),
    ("frames", "{:>6}", "{}"),
    ("seconds", "{:>8}", "{:.3f}"),
    ("frames/s", "{:>9}", "{:.1f}"),
    ("kp_err[m]", "{:>9}", "{:.4f}"),
    ("g_mpbpe[m]", "{:>10}", "{:.4f}"),
    ("jerk_frame", "{:>10}", "{:.5f}"),
    ("limit_viol", "{:>10}", "{:.4f}"),
    ("max_excess", "{:>10}", "{:.1e}"),
    ("mer/mink fps", "{:>12}", "{:.2f}x"),
)
KEYS = ("target", "method", "frames", "seconds", "fps", "kp_err", "g_mpbpe", "jerk_frame", "limit_violation",
        "max_limit_excess", "mer_over_mink_fps")  # fmt: skip


def find_clip(data_dir: Path, source: str, clip: str) -> Path:
    folder = data_dir / source
    path = folder / f"{clip}.csv"
    if path.is_file():
        return path
    clips = sorted(p for p in folder.glob("*.csv*") if p.is_file())
    if not clips:
        raise SystemExit(f"no LAFAN1 clips in {folder} (set MER_SHARED or pass --data-dir)")
    log.warning("clip %s not in %s; using the first clip, %s", clip, folder, clips[0].name)
    return clips[0]


def ordered_pairs(tgt: Skeleton, src: Skeleton) -> list[tuple[str, int, int]]:
    """keypoint_pairs in the order of ``RetargetResult.reference_points``.

    ``_reference_points`` takes the mapped *reference* nodes in ascending node order (the joint
    map's columns), which is not ``KEYPOINTS`` order; the base (node 0) stays first.
    """
    pairs = keypoint_pairs(tgt, src)
    refs = [j for _, _, j in pairs]
    if len(set(refs)) != len(refs):
        raise SystemExit(f"{tgt.name}: two key points share a reference node; the reference points are ambiguous")
    return sorted(pairs, key=lambda p: p[2])


def nodes_q(skel: Skeleton, q_dof: np.ndarray) -> np.ndarray:
    """(F, n_dof) angles in ``Skeleton.joint_names`` order → (F, J) per node (0 elsewhere)."""
    q = np.zeros((len(q_dof), skel.num_nodes))
    q[:, skel.dof_mask] = q_dof
    return q


def keypoint_error(motion: TargetMotion, nodes: list[int], targets: np.ndarray) -> float:
    """Mean over frames and key points of |FK(motion) - target| [m] (mer's FK)."""
    pos, _ = motion.forward_kinematics()
    return float(np.linalg.norm(pos[:, nodes] - targets, axis=-1).mean())


def max_limit_excess(motion: TargetMotion) -> float:
    skel = motion.skeleton
    q = motion.q[:, skel.dof_mask]
    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    return float(max(0.0, (lo - q).max(), (q - hi).max()))


def row(target, method, frames, seconds, motion, feats, src, nodes, targets) -> dict:
    m = sequence_metrics(feats, src, motion)
    return {
        "target": target,
        "method": method,
        "frames": frames,
        "seconds": seconds,
        "fps": frames / seconds,
        "kp_err": keypoint_error(motion, nodes, targets),
        "g_mpbpe": m["g_mpbpe"],
        "jerk_frame": m["jerk_frame"],
        "limit_violation": m["limit_violation"],
        "max_limit_excess": max_limit_excess(motion),
        "mer_over_mink_fps": None,
    }


def run_mer(feats, src, target, repeat, **kw):
    retarget_features(feats[:16], src, target, method="optimize", fps=MODEL_FPS, **kw)  # untimed warm-up
    best, res = math.inf, None
    for i in range(repeat):
        t0 = time.perf_counter()
        res = retarget_features(feats, src, target, method="optimize", fps=MODEL_FPS, **kw)
        dt = time.perf_counter() - t0
        log.info("mer %s run %d/%d: %.3f s (%.1f frames/s)", target, i + 1, repeat, dt, len(feats) / dt)
        best = min(best, dt)
    return res, best


def run_mink(mr, targets, names, base_pos0, base_quat0, iters, posture_cost, solver, repeat):
    import mink_peer

    best, out = math.inf, None
    for i in range(repeat):
        out = mink_peer.solve_keypoints(
            mr, targets, names, base_pos0=base_pos0, base_quat0_wxyz=base_quat0, iters_per_frame=iters,
            posture_cost=posture_cost, solver=solver,
        )  # fmt: skip
        log.info("mink %s x%d run %d/%d: %.3f s", mr.name, iters, i + 1, repeat, out["seconds"])
        best = min(best, out["seconds"])
    return out, best


def fmt_table(rows: list[dict]) -> str:
    head = " ".join(f.format(name) for name, f, _ in COLUMNS)
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = []
        for key, (_, f, vf) in zip(KEYS, COLUMNS):
            v = r[key]
            cells.append(f.format("—" if v is None else vf.format(v)))
        lines.append(" ".join(cells))
    return "\n".join(lines)


def main() -> None:
    args = _parser().parse_args()
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")  # fmt: skip
    torch.set_num_threads(max(1, args.threads))

    data_dir = args.data_dir or Path(os.environ.get("MER_SHARED", REPO.parent / "shared")) / "data" / "lafan1"
    path = find_clip(data_dir, args.source, args.clip)
    src = get_skeleton(args.source)
    motion = read_lafan1_csv(path, args.source)
    n = motion.num_frames if args.frames <= 0 else min(args.frames, motion.num_frames)
    feats = source_features(motion.base_pos[:n], motion.base_quat[:n], motion.node_angles(src)[:n], src, MODEL_FPS)
    F = len(feats)
    log.info("clip %s: %d of %d frames (%s)", path.name, F, motion.num_frames, path)

    try:
        import mink  # noqa: F401
        import mink_peer
        import mujoco  # noqa: F401

        have_mink = True
    except ImportError as exc:
        have_mink = False
        mink_note = f"mink peer skipped: {exc} (benchmark-only: pip install mink mujoco daqp)"
        log.warning(mink_note)

    energy = EnergyConfig()
    load0 = os.getloadavg()[0]  # other work on the machine skews the timings; printed with the table
    rows: list[dict] = []
    for target in args.targets:
        tgt = get_skeleton(target)
        pairs = ordered_pairs(tgt, src)
        names = [n for n, _, _ in pairs]
        nodes = [i for _, i, _ in pairs]

        res, sec = run_mer(feats, args.source, target, args.repeat)
        goals = np.asarray(res.reference_points, np.float64)
        if goals.shape != (F, len(pairs), 3):
            raise SystemExit(f"{target}: reference_points {goals.shape}, expected ({F}, {len(pairs)}, 3)")
        mer_row = row(target, "mer optimize", F, sec, res.motion, feats, src, nodes, goals)
        if abs(mer_row["kp_err"] - mer_row["g_mpbpe"]) > 1e-4:
            log.warning("%s: key-point error %.5f m differs from g_mpbpe %.5f m (key-point order?)",
                        target, mer_row["kp_err"], mer_row["g_mpbpe"])  # fmt: skip
        rows.append(mer_row)
        # mink's problem exactly: key-point positions + posture, no orientation, no temporal prior
        res_p, sec_p = run_mer(feats, args.source, target, args.repeat, energy=replace(energy, w_ori=0.0), opt_smooth=0.0)
        rows.append(row(target, "mer positions", F, sec_p, res_p.motion, feats, src, nodes, goals))

        if have_mink:
            mr = mink_peer.build_mink_robot(target)
            # mer's L_kp = w_kp/K sum|e|^2, L_norm = w_norm/n_dof sum dq^2; mink weighs by cost^2
            posture = math.sqrt(energy.w_norm * len(names) / (energy.w_kp * max(mr.n_dof, 1)))
            # frame 0 starts from the base goal and the source's base orientation, like mer
            quat0 = matrix_to_quat(axis_angle_to_matrix(torch.from_numpy(feats[:1, 0, 0:3]))).numpy()[0]
            for iters in args.mink_iters:
                out, sec_m = run_mink(mr, goals, names, goals[0, 0], quat0, iters, posture, args.mink_solver, args.repeat)
                base_rot = quat_to_matrix(torch.from_numpy(out["base_quat_wxyz"])).numpy()
                tm = TargetMotion(tgt, MODEL_FPS, nodes_q(tgt, out["q"]), out["base_pos"], base_rot)
                r = row(target, f"mink x{iters}", F, sec_m, tm, feats, src, nodes, goals)
                r["mer_over_mink_fps"] = mer_row["fps"] / r["fps"]
                rows.append(r)
        done = [f"{r['method']} {r['fps']:.1f} frames/s, {1e3 * r['kp_err']:.2f} mm" for r in rows if r["target"] == target]
        log.info("%s done: %s", target, "; ".join(done))

    load = (load0, os.getloadavg()[0])
    print(f"clip {path.name} (source {args.source}), {F} frames at {MODEL_FPS:g} Hz | targets {' '.join(args.targets)} | "
          f"threads {torch.get_num_threads()} (OMP_WAIT_POLICY {os.environ['OMP_WAIT_POLICY']}) | best of {args.repeat} | "
          + (f"mink {args.mink_solver}, posture cost = mer's w_norm/w_kp ({energy.w_norm:g}/{energy.w_kp:g})" if have_mink else "mink skipped")
          + f" | load average {load[0]:.2f} -> {load[1]:.2f} "
          f"on {os.cpu_count()} cores")  # fmt: skip
    print(fmt_table(rows))
    print("kp_err: mean |FK - reference_points| over frames and key points (mer FK); g_mpbpe, jerk_frame "
          "[rad/frame^3], limit_viol [fraction of frames]: mer's sequence_metrics; max_excess: largest limit "
          "excess [rad]; mer/mink fps > 1: mer faster.")  # fmt: skip
    if not have_mink:
        print(mink_note)
    dataset = bench_dataset(data_dir, args.source, args.targets, args.dataset_clips, args.repeat) if args.dataset_clips > 0 else None
    if args.json is not None:
        payload = {"dataset": dataset,
            "clip": str(path), "source": args.source, "frames": F, "fps": MODEL_FPS, "threads": torch.get_num_threads(),
            "repeat": args.repeat, "load_average": load, "mink_solver": args.mink_solver if have_mink else None, "rows": rows,
        }  # fmt: skip
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2))
        log.info("wrote %s", args.json)


def bench_dataset(data_dir: Path, source: str, targets: list[str], n_clips: int, repeat: int = 2) -> dict:
    """Batched dataset retargeting against one file at a time, each as its command runs by default
    (``mer retarget --input DIR`` against ``mer retarget FILE`` per clip and target): the same clips and
    targets, the optimiser with its physical terms, the CSV and the metrics (the artifact and balance
    metrics the dataset writes in ``<clip>.metrics.json`` and the single-file command prints)."""
    import shutil
    import tempfile

    from mer_models.retarget.clip import retarget_file
    from mer_models.retarget.dataset import retarget_dataset
    from mer_models.solver.physics import PhysicsConfig

    files = sorted((data_dir / source).glob("*.csv"))[:n_clips]
    with tempfile.TemporaryDirectory() as tmp:
        inp = Path(tmp) / "in" / source
        inp.mkdir(parents=True)
        for f in files:
            shutil.copy(f, inp / f.name)
        frames = sum(read_lafan1_csv(f, source).num_frames for f in files) * len(targets)
        one = batched = math.inf
        for k in range(repeat):  # alternated, best of `repeat` each: load drifts on a shared machine
            t0 = time.perf_counter()
            for t in targets:
                for f in files:
                    retarget_file(f, source, t, out_csv=Path(tmp) / f"one{k}" / t / f.name, method="optimize", physics=PhysicsConfig(),
                                  metrics=True)  # fmt: skip
            one = min(one, time.perf_counter() - t0)
            t0 = time.perf_counter()
            retarget_dataset(str(inp.parent), source, targets, Path(tmp) / f"batched{k}", workers=torch.get_num_threads(),
                             physics=PhysicsConfig())  # processes = threads; fmt: skip
            batched = min(batched, time.perf_counter() - t0)
    print(f"dataset: {len(files)} clips x {len(targets)} targets = {frames} frames | one file at a time "
          f"{one:.1f} s ({frames / one:.0f} frames/s) | batched across clips {batched:.1f} s ({frames / batched:.0f} frames/s) "
          f"| {one / batched:.2f}x")  # fmt: skip
    return {"clips": len(files), "targets": targets, "frames": frames, "one_at_a_time_s": one, "batched_s": batched}


if __name__ == "__main__":
    main()
