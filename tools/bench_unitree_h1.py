"""Fidelity against an independent reference: mer's H1 retargets next to Unitree's own H1 retargeting.

LAFAN1's robot CSVs are Unitree's retargets of the same human clips, so for a window of a clip, mer's
G1 -> H1 retarget (the G1 CSV as source) and Unitree's H1 CSV are two retargets of one human motion.
Per window and method this prints the mean distance of H1's bodies (every node of the skeleton) in
the pelvis frame (``R_pelvis^T (p - p_pelvis)``: where the limbs are relative to the body, not where
the body is in the room) between mer's motion and Unitree's, and its ratio to the plain optimiser's
(``--no-physics``). Also g-mpbpe (against mer's own goals), the floor, hovering and skate figures.

    python tools/bench_unitree_h1.py --input ../shared/data/lafan1
    python tools/bench_unitree_h1.py --input ../shared/data/lafan1 --methods optimize penalty constraints

Windows: the developers' six (frames 601-1050 of walk1, run1, jumps1, dance1, fallAndGetUp1, fight1)
and six others (frames 1201-1650 of other clips), ``--windows clip:first:last`` (0-based, end
excluded) to choose. Reads LAFAN1 data: never commit its output.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mer_data.kinematics.rotations import quat_to_matrix  # noqa: E402
from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.export.writers import TargetMotion  # noqa: E402
from mer_models.retarget.artifacts import motion_artifacts  # noqa: E402
from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

DEV = ("walk1_subject1", "run1_subject2", "jumps1_subject1", "dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2")
OTHER = ("walk3_subject2", "run2_subject1", "jumps1_subject2", "dance2_subject1", "fallAndGetUp2_subject2", "fightAndSports1_subject1")
WINDOWS = tuple(f"{c}:600:1050" for c in DEV) + tuple(f"{c}:1200:1650" for c in OTHER)
FPS = 30.0
METHODS = {"optimize": None, "penalty": PhysicsConfig(method="penalty"), "constraints": PhysicsConfig(method="constraints")}


def pelvis_frame(pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(F, J, 3) node positions in the root node's frame: ``R_0^T (p - p_0)`` [m]."""
    return np.einsum("fji,fkj->fki", rot[:, 0], pos - pos[:, :1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/)")
    p.add_argument("--windows", nargs="+", default=list(WINDOWS), help="clip:first:last (0-based, last excluded)")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--json", help="also write every figure here")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    g1, h1 = load_robot("g1"), load_robot("h1")
    geom = collision_model(h1)
    rows = []
    for w in args.windows:
        clip, a, b = w.split(":")
        sl = slice(int(a), int(b))
        m = read_lafan1_csv(Path(args.input) / "g1" / f"{clip}.csv", g1)
        f = source_features(m.base_pos, m.base_quat, m.node_angles(g1.skeleton), g1.skeleton, FPS)[sl]
        u = read_lafan1_csv(Path(args.input) / "h1" / f"{clip}.csv", h1)
        ref = TargetMotion(h1.skeleton, FPS, u.node_angles(h1.skeleton)[sl], u.base_pos[sl], quat_to_matrix(torch.from_numpy(u.base_quat[sl])).numpy())
        ref_local = pelvis_frame(*ref.forward_kinematics())
        art = motion_artifacts(ref.q, ref.base_pos, ref.base_rot, FPS, h1.skeleton, geom, f, g1.skeleton)
        rows.append({"window": w, "method": "Unitree", "body_dist": 0.0, "seconds": float("nan"), "frames": len(f), "g_mpbpe": float("nan"),
                     "jerk_frame": float("nan"), **{k: art[k] for k in ("body_floor_frames", "hover_frames", "skate_median", "skate_share")}})  # fmt: skip
        for meth in args.methods:
            t0 = time.perf_counter()
            res = retarget_features(f, g1.skeleton, h1.skeleton, method="optimize", fps=FPS, physics=METHODS[meth])
            sec = time.perf_counter() - t0
            met = sequence_metrics(f, g1.skeleton, res.motion, prepared=res.prepared, geometry=geom)
            dist = float(np.linalg.norm(pelvis_frame(*res.motion.forward_kinematics()) - ref_local, axis=-1).mean())
            rows.append({"window": w, "method": meth, "body_dist": dist, "seconds": sec, "frames": len(f),
                         **{k: met[k] for k in ("g_mpbpe", "jerk_frame", "body_floor_frames", "hover_frames", "skate_median", "skate_share")}})  # fmt: skip
            print(f"{w} {meth}: body distance to Unitree {100 * dist:.2f} cm, g-mpbpe {met['g_mpbpe']:.4f}", file=sys.stderr)
    print(f"{'method':12s} {'to Unitree [cm]':>15s} {'x plain':>8s} {'g-mpbpe':>8s} {'x plain':>8s} {'jerk':>7s} {'body<-1cm':>9s} "
          f"{'hover':>6s} {'skate':>6s} {'>5cm/s':>6s} {'fr/s':>6s}")  # fmt: skip
    mean = {meth: {k: float(np.nanmean([r[k] for r in rows if r["method"] == meth]))
                   for k in ("body_dist", "g_mpbpe", "jerk_frame", "body_floor_frames", "hover_frames", "skate_median", "skate_share")}
            for meth in ("Unitree", *args.methods)}  # fmt: skip
    for meth in ("Unitree", *args.methods):
        v = mean[meth]
        fps = sum(r["frames"] for r in rows if r["method"] == meth) / sum(r["seconds"] for r in rows if r["method"] == meth) if meth != "Unitree" else float("nan")
        base = mean.get("optimize", v)
        print(f"{meth:12s} {100 * v['body_dist']:15.2f} {v['body_dist'] / base['body_dist']:8.2f} {v['g_mpbpe']:8.4f} "
              f"{v['g_mpbpe'] / base['g_mpbpe']:8.2f} {v['jerk_frame']:7.4f} {v['body_floor_frames']:9.3f} {v['hover_frames']:6.3f} "
              f"{100 * v['skate_median']:6.1f} {v['skate_share']:6.2f} {fps:6.0f}")  # fmt: skip
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows, "mean": mean}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
