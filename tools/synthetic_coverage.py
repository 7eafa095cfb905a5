"""How much of LAFAN1 the synthetic motion generator covers (issue 11), per robot.

For every actuated joint: the share of LAFAN1 angles (all clips of the robot) inside the synthetic
range (min..max over the generated set); the same for the height (z) of every key point and for
the base states: tilt [rad] (angle between the base's z axis and the world's), height [m], speed
[m/s] (3-D and horizontal, central differences). A second column uses the synthetic 0.5-99.5 %
range instead of min..max (what most of the synthetic data spans, not a few frames). For the base
states also how much the two distributions overlap (histogram intersection, 1: identical) and
their 5 / 50 / 95 % points. Also the joint jerk |d^3 q| [rad/frame^3] of both. Nothing is
written: LAFAN1 is CC BY-NC-ND, only these figures are reported.

    python tools/synthetic_coverage.py [--data ../shared/data/lafan1] [--robots g1 h1]
                                       [--clips 200] [--seconds 20] [--seed 0] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mer_data.motion.lafan1 import Motion, read_lafan1_csv  # noqa: E402
from mer_data.robots.registry import get_skeleton  # noqa: E402
from mer_data.skeleton import Skeleton  # noqa: E402
from mer_data.synthesis import clip_seed, ground_heights, synthesize  # noqa: E402
from mer_data.synthesis.quat import qmatrix  # noqa: E402

#: Base-state rows: name -> histogram range for the overlap figure.
BASE = {"base:tilt": (0.0, np.pi), "base:height": (0.0, 1.6), "base:speed": (0.0, 8.0), "base:speed_xy": (0.0, 8.0)}


def quantities(skel: Skeleton, motions: list[Motion]) -> dict[str, np.ndarray]:
    """Per-frame values pooled over ``motions``: ``joint:<name>``, ``kp:<key point>``, the base states of :data:`BASE`."""
    out: dict[str, list[np.ndarray]] = {}
    kps = skel.keypoint_nodes()
    for m in motions:
        q = m.node_angles(skel)
        z = ground_heights(skel, m)
        for j in np.flatnonzero(skel.dof_mask):
            out.setdefault(f"joint:{skel.node_names[j]}", []).append(q[:, j])
        for k, v in kps.items():
            out.setdefault(f"kp:{k}", []).append(z[:, v])
        vel = np.gradient(m.base_pos, axis=0) * m.fps  # (F, 3) m/s
        out.setdefault("base:tilt", []).append(np.arccos(np.clip(qmatrix(m.base_quat)[:, 2, 2], -1.0, 1.0)))
        out.setdefault("base:height", []).append(m.base_pos[:, 2])
        out.setdefault("base:speed", []).append(np.linalg.norm(vel, axis=1))
        out.setdefault("base:speed_xy", []).append(np.linalg.norm(vel[:, :2], axis=1))
        out.setdefault("jerk", []).append(np.abs(np.diff(m.node_angles(skel)[:, skel.dof_mask], 3, axis=0)).ravel())
    return {k: np.concatenate(v) for k, v in out.items()}


def coverage(real: np.ndarray, syn: np.ndarray) -> tuple[float, float]:
    """Shares of ``real`` inside syn's min..max and inside its 0.5-99.5 % range."""
    a, b = syn.min(), syn.max()
    c, d = np.percentile(syn, [0.5, 99.5])
    return float(np.mean((real >= a) & (real <= b))), float(np.mean((real >= c) & (real <= d)))


def overlap(real: np.ndarray, syn: np.ndarray, lo: float, hi: float, bins: int = 64) -> float:
    """Histogram intersection of the two distributions over [lo, hi] (values beyond in the end bins): 0..1."""
    h = [np.histogram(np.clip(x, lo, hi), bins, (lo, hi))[0] / len(x) for x in (real, syn)]
    return float(np.minimum(*h).sum())


def report(robot: str, data: Path, clips: int, seconds: float, seed: int) -> dict:
    skel = get_skeleton(robot)
    t0 = time.perf_counter()
    syn = [synthesize(skel, seconds, 30.0, clip_seed(seed, robot, i)).motion for i in range(clips)]
    gen_s = time.perf_counter() - t0
    real = [read_lafan1_csv(p, robot) for p in sorted((data / robot).glob("*.csv*"))]
    S, R = quantities(skel, syn), quantities(skel, real)
    rows = {}
    for k in S:
        if k == "jerk":
            continue
        full, robust = coverage(R[k], S[k])
        rows[k] = {
            "lafan1": [float(R[k].min()), float(R[k].max())], "synthetic": [float(S[k].min()), float(S[k].max())],
            "coverage": full, "coverage_p99": robust,
        }  # fmt: skip
        if k in BASE:
            rows[k] |= {
                "overlap": overlap(R[k], S[k], *BASE[k]),
                "percentiles": {"lafan1": np.percentile(R[k], [5, 50, 95]).tolist(), "synthetic": np.percentile(S[k], [5, 50, 95]).tolist()},
            }  # fmt: skip
    joints = [v["coverage"] for k, v in rows.items() if k.startswith("joint:")]
    kps = [v["coverage"] for k, v in rows.items() if k.startswith("kp:")]
    return {
        "robot": robot, "lafan1_clips": len(real), "lafan1_frames": int(sum(m.num_frames for m in real)),
        "synthetic_clips": clips, "synthetic_frames": int(sum(m.num_frames for m in syn)), "generate_s": gen_s,
        "rows": rows,
        "summary": {
            "joint_median": float(np.median(joints)), "joint_min": float(np.min(joints)),
            "keypoint_median": float(np.median(kps)), "keypoint_min": float(np.min(kps)),
            "base_tilt": rows["base:tilt"]["coverage"], "base_height": rows["base:height"]["coverage"],
            "base_speed": rows["base:speed"]["coverage"], "base_speed_xy": rows["base:speed_xy"]["coverage"],
        },
        "jerk": {
            "synthetic": {"max": float(S["jerk"].max()), "mean": float(S["jerk"].mean()), "p99": float(np.percentile(S["jerk"], 99))},
            "lafan1": {"max": float(R["jerk"].max()), "mean": float(R["jerk"].mean()), "p99": float(np.percentile(R["jerk"], 99))},
        },
    }  # fmt: skip


def render(r: dict) -> str:
    lines = [
        f"{r['robot']}: LAFAN1 {r['lafan1_clips']} clips / {r['lafan1_frames']} frames; synthetic {r['synthetic_clips']} "
        f"clips / {r['synthetic_frames']} frames (generated in {r['generate_s']:.1f} s)",
        f"  {'quantity':34s} {'LAFAN1 range':>17s} {'synthetic range':>17s} {'cover':>7s} {'p99':>7s}",
    ]
    for k, v in r["rows"].items():
        lines.append(
            f"  {k:34s} {v['lafan1'][0]:8.2f}..{v['lafan1'][1]:<7.2f} {v['synthetic'][0]:8.2f}..{v['synthetic'][1]:<7.2f} "
            f"{100 * v['coverage']:6.1f}% {100 * v['coverage_p99']:6.1f}%"
        )
    lines.append(f"  {'base state':34s} {'LAFAN1 5/50/95 %':>20s} {'synthetic 5/50/95 %':>20s} {'overlap':>8s}")
    for k in BASE:
        v = r["rows"][k]
        pr, ps = (" ".join(f"{x:.2f}" for x in v["percentiles"][w]) for w in ("lafan1", "synthetic"))
        lines.append(f"  {k:34s} {pr:>20s} {ps:>20s} {v['overlap']:8.2f}")
    s, j = r["summary"], r["jerk"]
    lines += [
        f"  joints: median {100 * s['joint_median']:.1f}%, min {100 * s['joint_min']:.1f}%;  key-point heights: median "
        f"{100 * s['keypoint_median']:.1f}%, min {100 * s['keypoint_min']:.1f}%",
        f"  base tilt {100 * s['base_tilt']:.1f}%;  base height {100 * s['base_height']:.1f}%;  base speed {100 * s['base_speed']:.1f}% "
        f"(horizontal {100 * s['base_speed_xy']:.1f}%)",
        f"  jerk [rad/frame^3]: synthetic max {j['synthetic']['max']:.3f}, mean {j['synthetic']['mean']:.4f}, p99 "
        f"{j['synthetic']['p99']:.3f};  LAFAN1 max {j['lafan1']['max']:.3f}, mean {j['lafan1']['mean']:.4f}, p99 {j['lafan1']['p99']:.3f}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    shared = Path(os.environ.get("MER_SHARED", ROOT.parent / "shared"))
    ap.add_argument("--data", type=Path, default=shared / "data" / "lafan1", help="LAFAN1 folder with g1/, h1/")
    ap.add_argument("--robots", nargs="+", default=["g1", "h1"])
    ap.add_argument("--clips", type=int, default=200, help="synthetic clips per robot")
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds per synthetic clip")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    results = [report(r, args.data, args.clips, args.seconds, args.seed) for r in args.robots]
    print(json.dumps(results, indent=1) if args.json else "\n\n".join(render(r) for r in results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
