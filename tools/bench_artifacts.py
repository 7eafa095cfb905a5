"""The artifact table: what a tracking policy would trip over, mer's retargets next to Unitree's own.

For each clip, frames ``--start``..``--end`` of the G1 source (LAFAN1 robot CSVs), retargeted to
every target with the optimiser (``mer retarget --method optimize``'s path,
:func:`mer_models.retarget.clip.retarget_features`, on the excerpt), then measured with
:mod:`mer_models.retarget.artifacts` on the target's collision geometry, floor z = 0. Where the
input folder holds the target's own LAFAN1 CSVs (Unitree's retargeting of the same human clip:
h1, h1_2), the same frames of those are measured the same way, as the peer. Also g-mpbpe and jerk
of mer's retarget (the paper's metrics) and frames/s of the retargeting alone.

    python tools/bench_artifacts.py --input ../shared/data/lafan1 --json runs/artifacts.json
    python tools/bench_artifacts.py --input ../shared/data/lafan1 --methods physics   # only with the physical terms

Prints one row per (target, method) over all clips: frames with a foot below -1 cm, deepest [cm],
median foot skate in contact [cm/s], self-penetration > 1 cm, frame pairs over the URDF velocity
limit, joint-limit violations, g-mpbpe [m], jerk, frames/s. Reads LAFAN1 data: never commit its
output.
"""

from __future__ import annotations

import argparse
import dataclasses
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
from mer_models.retarget.artifacts import motion_artifacts  # noqa: E402
from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

CLIPS = ("walk1_subject1", "run1_subject2", "jumps1_subject1", "dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2")
TARGETS = ("h1", "h1_2", "atlas", "talos", "valkyrie", "oli", "tron1", "g1")
FPS = 30.0


def _row(arts: list[dict], extra: dict) -> dict:
    def mean(k):
        v = np.array([a[k] for a in arts if a.get(k) is not None], np.float64)
        v = v[np.isfinite(v)]
        return float(v.mean()) if len(v) else float("nan")

    return {"floor_frames": mean("floor_frames"), "floor_depth_max": max(a["floor_depth_max"] for a in arts),
            "skate_median": mean("skate_median"), "selfpen_1cm_frames": mean("selfpen_1cm_frames"),
            "speed_frames": mean("speed_frames"), "floating_frames": mean("floating_frames"), "body_floor_frames": mean("body_floor_frames"),
            "hover_frames": mean("hover_frames"), "skate_share": mean("skate_share"), **extra}  # fmt: skip


def _value(cls, field: str, text: str):
    """``text`` as the type of dataclass ``cls``'s field ``field`` (bool: true/false, 1/0)."""
    kind = {f.name: f.type for f in dataclasses.fields(cls)}.get(field)
    if kind is None:
        raise SystemExit(f"--set {field}=...: {cls.__name__} has no field {field!r}")
    if kind in ("bool", bool):
        if text.lower() not in ("1", "true", "0", "false"):
            raise SystemExit(f"--set {field}={text}: expected true or false")
        return text.lower() in ("1", "true")
    try:
        return {"int": int, "float": float}.get(kind if isinstance(kind, str) else kind.__name__, str)(text)
    except ValueError:
        raise SystemExit(f"--set {field}={text}: expected a {kind}") from None


def set_fields(cls, items: list[str]) -> dict:
    """``--set FIELD=VALUE ...`` as keyword arguments of dataclass ``cls`` (a clear exit on a bad item)."""
    bad = [kv for kv in items if "=" not in kv]
    if bad:
        raise SystemExit(f"--set {bad[0]}: expected FIELD=VALUE (e.g. al_iters=2)")
    return {k: _value(cls, k, v) for k, v in (kv.split("=", 1) for kv in items)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/, ...)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=list(TARGETS))
    p.add_argument("--clips", nargs="+", default=list(CLIPS))
    p.add_argument("--start", type=int, default=600, help="first frame (0-based; 600 = line 601)")
    p.add_argument("--end", type=int, default=1050)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", help="also write every figure here")
    p.add_argument("--windows", nargs="+", help="clip:first:last (0-based, last excluded), instead of --clips/--start/--end")
    p.add_argument("--methods", nargs="+", default=["optimize", "physics"], choices=["optimize", "physics", "constraints"],
                   help="mer's optimiser without its physical terms (mer retarget --no-physics), with them (the default, "
                        "the penalty method) and with them as constraints (PhysicsConfig.method); each target's runs back to back, "
                        "and a per-clip g-mpbpe table against the first")
    p.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                   help="PhysicsConfig fields for the physics and constraints methods (e.g. xy_weight=0.3 al_rounds=4)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    fields = set_fields(PhysicsConfig, args.set)
    src = load_robot(args.source)
    windows = args.windows or [f"{c}:{args.start}:{args.end}" for c in args.clips]
    per_clip: dict[tuple[str, str], dict[str, float]] = {}
    feats, slices = {}, {}
    for w in windows:
        clip, a, b = w.split(":")
        m = read_lafan1_csv(Path(args.input) / args.source / f"{clip}.csv", src)
        f = source_features(m.base_pos, m.base_quat, m.node_angles(src.skeleton), src.skeleton, FPS)
        feats[w], slices[w] = f[int(a) : int(b)], slice(int(a), int(b))
    rows = []
    for t in args.targets:
        robot = load_robot(t)
        geom = collision_model(robot)
        peer, peer_lim = [], []
        for mi, method in enumerate(args.methods):
            physics = {"physics": PhysicsConfig(**{**fields, "method": "penalty"}), "constraints": PhysicsConfig(**{**fields, "method": "constraints"})}.get(method)
            label = f"mer {method}"
            arts, g, jerk, lim, frames, sec = [], [], [], [], 0, 0.0
            for clip, f in feats.items():
                t0 = time.perf_counter()
                res = retarget_features(f, src.skeleton, robot.skeleton, method="optimize", fps=FPS, physics=physics)
                sec += time.perf_counter() - t0
                frames += len(f)
                met = sequence_metrics(f, src.skeleton, res.motion, prepared=res.prepared, geometry=geom)
                arts.append(met)
                g.append(met["g_mpbpe"])
                per_clip.setdefault((t, clip), {})[method] = met["g_mpbpe"]
                jerk.append(met["jerk_frame"])
                lim.append(met["limit_violation"])
                own, sl = Path(args.input) / t / f"{clip.split(':')[0]}.csv", slices[clip]
                if mi > 0 or not own.is_file() or t == args.source:
                    continue
                u = read_lafan1_csv(own, robot)
                q = u.node_angles(robot.skeleton)[sl]
                rot = quat_to_matrix(torch.from_numpy(u.base_quat[sl])).numpy()
                peer.append(motion_artifacts(q, u.base_pos[sl], rot, FPS, robot.skeleton, geom, f, src.skeleton))
                lo, hi = robot.skeleton.lower, robot.skeleton.upper
                rev = np.array([k == "revolute" for k in robot.skeleton.node_kinds])
                peer_lim.append(float(((q[:, rev] < lo[rev] - 1e-6) | (q[:, rev] > hi[rev] + 1e-6)).any(1).mean()))
            if peer and mi == 0:
                rows.append({"target": t, "method": "Unitree", **_row(peer, {"limit_violation": float(np.mean(peer_lim))})})
            rows.append({"target": t, "method": label, **_row(arts, {
                "limit_violation": float(np.mean(lim)), "g_mpbpe": float(np.mean(g)), "jerk_frame": float(np.mean(jerk)),
                "frames_per_s": frames / sec})})  # fmt: skip
            if mi:
                rows[-1]["fps_ratio"] = rows[-1]["frames_per_s"] / next(x["frames_per_s"] for x in rows if x["target"] == t and x["method"] == f"mer {args.methods[0]}")
            r = rows[-1]
            print(f"{t} {method}: {r['floor_frames']:.3f} below -1 cm, deepest {100 * r['floor_depth_max']:.1f} cm, "
                  f"{frames / sec:.0f} frames/s", file=sys.stderr)  # fmt: skip
    head = (f"{'target':9s} {'method':15s} {'foot<-1cm':>9s} {'body<-1cm':>9s} {'deepest':>8s} {'skate':>7s} {'>5cm/s':>6s} {'hover':>6s} {'selfpen':>8s} {'>v.lim':>7s}"
            f" {'floating':>8s} {'limits':>7s} {'g-mpbpe':>8s} {'jerk':>8s} {'fr/s':>6s} {'x':>5s}")  # fmt: skip
    print(f"{args.source} source, windows {', '.join(windows)}; shares of frames; deepest [cm], "
          "skate: median in contact [cm/s]")  # fmt: skip
    print(head)
    for r in rows:
        def num(k, scale=1.0, fmt=".3f"):
            v = r.get(k, float("nan"))
            return f"{v * scale:{fmt}}" if np.isfinite(v) else "-"

        print(f"{r['target']:9s} {r['method']:15s} {num('floor_frames'):>9s} {num('body_floor_frames'):>9s} {num('floor_depth_max', 100, '.1f'):>8s} "
              f"{num('skate_median', 100, '.1f'):>7s} {num('skate_share', 1, '.2f'):>6s} {num('hover_frames'):>6s} {num('selfpen_1cm_frames'):>8s} {num('speed_frames'):>7s} "
              f"{num('floating_frames'):>8s} {num('limit_violation'):>7s} {num('g_mpbpe', 1, '.4f'):>8s} "
              f"{num('jerk_frame', 1, '.4f'):>8s} {num('frames_per_s', 1, '.0f'):>6s} {num('fps_ratio', 1, '.2f'):>5s}")  # fmt: skip
    first = args.methods[0]
    for other in args.methods[1:]:
        print(f"\ng-mpbpe of {other} / {first}, per window")
        print(f"{'target':9s} " + " ".join(f"{c.split(':')[0][:12]:>12s}" for c in windows))
        for t in args.targets:
            cells = []
            for c in windows:
                v = per_clip.get((t, c), {})
                cells.append(f"{v[other] / v[first]:12.2f}" if other in v and v.get(first, 0) > 0 else f"{'-':>12s}")
            print(f"{t:9s} " + " ".join(cells))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        clips = [{"target": t, "clip": c, **v} for (t, c), v in per_clip.items()]
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows, "g_mpbpe_per_clip": clips}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
