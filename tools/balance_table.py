"""The balance table (docs/model.md §Balance): could the robot's mass do what the motion shows?

For each source robot and clip, frames ``--start``..``--end`` (0-based; 600..1050 = lines 601-1050) of
the source's LAFAN1 CSV, retargeted to every target with mer's optimiser: ``optimize`` (key points
alone, ``mer retarget --no-physics``: the kinematic solution), ``physics`` (the default physical
terms) and ``balance`` (key points and the balance term: ``--no-physics --balance``), next to the
target's own CSV of the clip where the input folder has it (Unitree's retargeting), those same frames:
measured with :func:`mer_models.retarget.balance.balance_metrics` (floor z = 0, URDF masses; joint
torques only with ``--torques``: their LP is most of the time). Fidelity: g-mpbpe (against mer's own
goals) and, for target h1, the mean distance of H1's bodies in the pelvis frame to Unitree's H1
(``tools/bench_unitree_h1.py``), each also as a ratio to the kinematic solution of the same clip;
speed: seconds per retarget and its ratio to the kinematic solution's.

    python tools/balance_table.py --input ../shared/data/lafan1 --sources g1 h1 --targets g1 h1 h1_2 --json out.json

Prints one row per (source, target, motion): the mean over the clips of each clip's share; every run
is also appended to ``--json`` as it finishes (a long run can be read while it goes). Reads LAFAN1
data: never commit its output.
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
sys.path.insert(0, str(REPO / "tools"))

from bench_unitree_h1 import pelvis_frame  # noqa: E402

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors  # noqa: E402
from mer_data.kinematics.rotations import quat_to_matrix  # noqa: E402
from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.inertia import mass_model  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.export.writers import TargetMotion  # noqa: E402
from mer_models.retarget.balance import balance_metrics  # noqa: E402
from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features  # noqa: E402
from mer_models.solver.balance_term import BalanceConfig  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

CLIPS = ("walk1_subject1", "run1_subject2", "jumps1_subject1", "dance1_subject1", "fallAndGetUp1_subject1", "fight1_subject2")
FPS = 30.0
METHODS = {
    "optimize": {},
    "physics": {"physics": PhysicsConfig()},
    "balance": {"balance": BalanceConfig()},
    "physics+balance": {"physics": PhysicsConfig(), "balance": BalanceConfig()},
    "rows": {"balance": BalanceConfig(method="rows", rounds=2, margin=0.0)},
}
COLS = (("balance_infeasible", "infeasible", 1), ("zmp_out_single", "zmp>2cm 1ft", 1), ("zmp_out_double", "zmp>2cm 2+", 1),
        ("zmp_out_dist", "out 1ft[cm]", 100), ("pull_frames", "pull", 1), ("slip_frames", "slip", 1),
        ("flight_frames", "flight", 1), ("torque_frames", ">effort", 1), ("g_mpbpe", "g-mpbpe", 1), ("g_ratio", "x kin", 1),
        ("h1_dist", "toH1[cm]", 100), ("h1_ratio", "x kin", 1), ("seconds", "s", 1), ("s_ratio", "x kin", 1),
        ("body_floor_frames", "body<-1cm", 1), ("limit_violation", "limits", 1), ("speed_frames", ">speed", 1), ("jerk_frame", "jerk", 1))  # fmt: skip


def _measure(robot, q, base_pos, base_rot, torques: bool) -> dict:
    skel = robot.skeleton
    pos, rot = fk_skeleton(skeleton_tensors(skel, torch.float64), torch.from_numpy(np.asarray(q, np.float64)[:, : skel.num_nodes]),
                           torch.from_numpy(np.asarray(base_pos, np.float64)), base_rot=torch.from_numpy(np.asarray(base_rot, np.float64)))  # fmt: skip
    return balance_metrics(pos.numpy(), rot.numpy(), FPS, skel, mass_model(robot), collision_model(robot), torques=torques)


def _unitree(path: Path, robot, sl: slice) -> TargetMotion:
    u = read_lafan1_csv(path, robot)
    return TargetMotion(robot.skeleton, FPS, u.node_angles(robot.skeleton)[sl], u.base_pos[sl],
                        quat_to_matrix(torch.from_numpy(u.base_quat[sl])).numpy())  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/, ...)")
    p.add_argument("--sources", nargs="+", default=["g1", "h1"])
    p.add_argument("--targets", nargs="+", default=["g1", "h1", "h1_2"])
    p.add_argument("--clips", nargs="+", default=list(CLIPS))
    p.add_argument("--start", type=int, default=600)
    p.add_argument("--end", type=int, default=1050)
    p.add_argument("--methods", nargs="+", default=["optimize", "balance"], choices=list(METHODS))
    p.add_argument("--balance-config", default="{}", help="BalanceConfig fields as JSON, e.g. '{\"rounds\": 4}'")
    p.add_argument("--torques", action="store_true", help="also the joint torques (their LP is most of the time)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--physics-method", choices=["penalty", "constraints"], default=PhysicsConfig().method,
                   help="the physical terms' method of the physics methods (PhysicsConfig.method; default %(default)s)")
    p.add_argument("--json", help="append every run here as it finishes (JSON lines), then the table's rows")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    sl = slice(args.start, args.end)
    bcfg = json.loads(args.balance_config)
    def one(n: str, v):
        if n == "balance":
            return BalanceConfig(**{**dataclasses.asdict(v), **bcfg})
        return dataclasses.replace(v, method=args.physics_method) if n == "physics" else v

    methods = {k: {n: one(n, v) for n, v in kw.items()} for k, kw in METHODS.items()}
    out = Path(args.json) if args.json else None

    def record(row: dict) -> None:
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")

    runs: list[dict] = []
    targets = {t: load_robot(t) for t in args.targets}
    geos = {t: collision_model(r) for t, r in targets.items()}
    h1 = load_robot("h1")
    for s in args.sources:
        src = load_robot(s)
        for clip in args.clips:
            m = read_lafan1_csv(Path(args.input) / s / f"{clip}.csv", src)
            feats = source_features(m.base_pos, m.base_quat, m.node_angles(src.skeleton), src.skeleton, FPS)[sl]
            h1_csv = Path(args.input) / "h1" / f"{clip}.csv"
            h1_local = pelvis_frame(*_unitree(h1_csv, h1, sl).forward_kinematics()) if h1_csv.is_file() else None
            for t, robot in targets.items():
                own = Path(args.input) / t / f"{clip}.csv"
                if own.is_file() and not any(r["target"] == t and r["clip"] == clip and r["motion"] == "Unitree" for r in runs):
                    u = _unitree(own, robot, sl)
                    met = _measure(robot, u.q, u.base_pos, u.base_rot, args.torques)
                    runs.append({"source": "-", "target": t, "clip": clip, "motion": "Unitree", **met})
                    record(runs[-1])
                base: dict = {}
                for method in args.methods:
                    t0 = time.perf_counter()
                    res = retarget_features(feats, src.skeleton, robot.skeleton, method="optimize", fps=FPS, **methods[method])
                    sec = time.perf_counter() - t0
                    mo = res.motion
                    met = _measure(robot, mo.q, mo.base_pos, mo.base_rot, args.torques)
                    seq = sequence_metrics(feats, src.skeleton, mo, prepared=res.prepared, geometry=geos[t])
                    met.update(
                        {k: seq[k] for k in ("g_mpbpe", "body_floor_frames", "limit_violation", "speed_frames", "jerk_frame")}
                    )
                    met["seconds"] = sec
                    met["h1_dist"] = (float(np.linalg.norm(pelvis_frame(*mo.forward_kinematics()) - h1_local, axis=-1).mean())
                                      if t == "h1" and h1_local is not None else float("nan"))  # fmt: skip
                    if method == args.methods[0]:  # the ratios are to the first method's
                        base = met
                    for k, b in (("g_ratio", "g_mpbpe"), ("h1_ratio", "h1_dist"), ("s_ratio", "seconds")):
                        met[k] = met[b] / base[b] if base else float("nan")
                    runs.append({"source": s, "target": t, "clip": clip, "motion": f"mer {method}", **met})
                    record(runs[-1])
                    print(f"{s}->{t} {clip} mer {method}: {sec:.1f} s, infeasible {met['balance_infeasible']:.3f}, "
                          f"single-support ZMP out {met['zmp_out_single']:.3f}", file=sys.stderr)  # fmt: skip
    rows = []
    for key in dict.fromkeys((r["source"], r["target"], r["motion"]) for r in runs):
        ms = [r for r in runs if (r["source"], r["target"], r["motion"]) == key]
        row = {"source": key[0], "target": key[1], "motion": key[2], "clips": len(ms)}
        for k, _, _ in COLS:
            v = np.array([x.get(k, float("nan")) if x.get(k) is not None else float("nan") for x in ms], np.float64)
            row[k] = float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
        rows.append(row)
    print(
        f"frames {args.start + 1}-{args.end} of {', '.join(args.clips)}; mean over clips of each clip's figure (docs/model.md §Balance)"
    )
    print(f"{'source':6s} {'target':6s} {'motion':13s} " + " ".join(f"{h:>11s}" for _, h, _ in COLS))
    for r in rows:
        cells = [f"{r[k] * s:11.3f}" if np.isfinite(r[k]) else f"{'-':>11s}" for k, _, s in COLS]
        print(f"{r['source']:6s} {r['target']:6s} {r['motion']:13s} " + " ".join(cells))
    for r in rows:
        record({"table_row": r})
    return 0


if __name__ == "__main__":
    sys.exit(main())
