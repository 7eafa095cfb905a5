"""The balance table (docs/model.md §Balance): could the robot's mass do what the motion shows?

For each clip, frames ``--start``..``--end`` (0-based; 600..1050 = lines 601-1050) of the source
robot's LAFAN1 CSV, retargeted to every target with mer's optimiser without its physical terms
(``mer retarget --no-physics``) and with them (the default), and, where the input folder has the
target's own CSV of the clip (Unitree's retargeting), those same frames: measured with
:func:`mer_models.retarget.balance.balance_metrics` (floor z = 0, URDF masses, torques with the
most favourable contact split).

    python tools/balance_table.py --input ../shared/data/lafan1 --targets g1 h1 h1_2

Prints one row per (target, motion): shares of all frames that are infeasible, of contact frames
with the ZMP outside by > 2 cm (single and double support apart), median distance outside in single
support [cm], pulling, slipping, flight frames, frames with a joint over its effort limit; the mean
over the clips (each clip's share, then averaged). Reads LAFAN1 data: never commit its output.
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

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors  # noqa: E402
from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.inertia import mass_model  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.retarget.balance import balance_metrics  # noqa: E402
from mer_models.retarget.clip import retarget_features, source_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

CLIPS = ("walk1_subject1", "run1_subject2", "jumps1_subject1", "dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2")
FPS = 30.0
COLS = (("balance_infeasible", "infeasible", 1), ("zmp_out_single", "zmp>2cm 1ft", 1), ("zmp_out_double", "zmp>2cm 2+", 1),
        ("zmp_out_dist", "out 1ft[cm]", 100), ("pull_frames", "pull", 1), ("slip_frames", "slip", 1),
        ("flight_frames", "flight", 1), ("torque_frames", ">effort", 1))  # fmt: skip


def _measure(robot, q, base_pos, base_rot, torques: bool) -> dict:
    skel = robot.skeleton
    pos, rot = fk_skeleton(skeleton_tensors(skel, torch.float64), torch.from_numpy(np.asarray(q, np.float64)[:, : skel.num_nodes]),
                           torch.from_numpy(np.asarray(base_pos, np.float64)), base_rot=torch.from_numpy(np.asarray(base_rot, np.float64)))  # fmt: skip
    return balance_metrics(pos.numpy(), rot.numpy(), FPS, skel, mass_model(robot), collision_model(robot), torques=torques)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/, ...)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=["g1", "h1", "h1_2"])
    p.add_argument("--clips", nargs="+", default=list(CLIPS))
    p.add_argument("--start", type=int, default=600)
    p.add_argument("--end", type=int, default=1050)
    p.add_argument("--methods", nargs="+", default=["optimize", "physics"], choices=["optimize", "physics"])
    p.add_argument("--no-torques", action="store_true", help="skip the joint torques (their LP is most of the time)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", help="also write every figure here")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    src = load_robot(args.source)
    sl = slice(args.start, args.end)
    feats = {}
    for clip in args.clips:
        m = read_lafan1_csv(Path(args.input) / args.source / f"{clip}.csv", src)
        feats[clip] = source_features(m.base_pos, m.base_quat, m.node_angles(src.skeleton), src.skeleton, FPS)[sl]
    rows = []
    for t in args.targets:
        robot = load_robot(t)
        per: dict[str, list[dict]] = {}
        for clip in args.clips:
            own = Path(args.input) / t / f"{clip}.csv"
            if own.is_file():
                u = read_lafan1_csv(own, robot)
                from mer_data.kinematics.rotations import quat_to_matrix

                rot = quat_to_matrix(torch.from_numpy(u.base_quat[sl])).numpy()
                per.setdefault("Unitree", []).append(_measure(robot, u.node_angles(robot.skeleton)[sl], u.base_pos[sl], rot,
                                                              not args.no_torques))  # fmt: skip
            for method in args.methods:
                physics = PhysicsConfig() if method == "physics" else None
                t0 = time.perf_counter()
                res = retarget_features(feats[clip], src.skeleton, robot.skeleton, method="optimize", fps=FPS, physics=physics)
                sec = time.perf_counter() - t0
                mo = res.motion
                t0 = time.perf_counter()
                met = _measure(robot, mo.q, mo.base_pos, mo.base_rot, not args.no_torques)
                print(f"{t} {clip} mer {method}: retarget {sec:.1f} s, metric {time.perf_counter() - t0:.1f} s, "
                      f"infeasible {met['balance_infeasible']:.3f}", file=sys.stderr)  # fmt: skip
                per.setdefault(f"mer {method}", []).append({**met, "clip": clip})
        for label, ms in per.items():
            row = {"target": t, "motion": label, "clips": len(ms)}
            for k, _, _ in COLS:
                v = np.array([x[k] for x in ms], np.float64)
                row[k] = float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
            row["per_clip"] = [{k: x.get(k) for k in ("clip", "balance_infeasible", "zmp_out_single", "torque_frames")} for x in ms]
            rows.append(row)
    print(f"{args.source} source, frames {args.start + 1}-{args.end} of {', '.join(args.clips)}; mean over clips of each "
          "clip's share (docs/model.md §Balance)")  # fmt: skip
    print(f"{'target':7s} {'motion':13s} " + " ".join(f"{h:>11s}" for _, h, _ in COLS))
    for r in rows:
        cells = [f"{r[k] * s:11.3f}" if np.isfinite(r[k]) else f"{'-':>11s}" for k, _, s in COLS]
        print(f"{r['target']:7s} {r['motion']:13s} " + " ".join(cells))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
