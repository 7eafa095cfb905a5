"""Benchmark: one motion retargeted by the model to several robots in one pass, against one call per robot.

``retarget_features_many`` samples every target in one batch per window and encodes the
reference once per window (the reference encoder does not depend on the target); the peer is what
``mer retarget`` did before it, one ``retarget_features`` call per target (same model, same seed),
and the optimiser on the same clip and targets. All in one run, best wall time of ``--repeat``
after an untimed warm-up; the load average (start -> end) is printed, as the host is shared.

Printed: seconds and target-frames/s of each path, the ratio to one call per target, and the
largest difference between the two model paths' outputs (they must agree up to float rounding),
plus g-mpbpe per target of the model and of the optimiser.

    PYTHONPATH=$PWD python tools/bench_targets.py [--model mer-base] [--input ../shared/data/lafan1] \\
        [--source g1] [--clip walk1_subject1] [--frames 600] \\
        [--targets g1 h1 h1_2 atlas oli tron1 talos valkyrie] [--repeat 2] [--threads 2] [--no-optimiser]

Without ``--input`` (or when the folder lacks the clip) the source motion is synthetic (generated in code).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

from mer_data.robots.registry import get_skeleton
from mer_models.retarget.clip import MODEL_FPS, retarget_features, retarget_features_many, sequence_metrics, source_features
from mer_models.zoo.checkpoint import resolve_model

ALL = ["g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie"]


def source_motion(args) -> tuple[np.ndarray, str]:
    src = get_skeleton(args.source)
    if args.input:
        from mer_data.motion.lafan1 import read_lafan1_csv

        folder = Path(args.input) / args.source
        path = folder / f"{args.clip}.csv"
        if path.is_file():
            m = read_lafan1_csv(path, args.source)
            feats = source_features(m.base_pos, m.base_quat, m.node_angles(src), src, MODEL_FPS)[: args.frames]
            return feats, f"{path} (first {len(feats)} frames)"
    from mer_models.training.synthetic import _features, synthetic_motion

    return _features(src, synthetic_motion(src, args.frames, seed=7), MODEL_FPS), f"synthetic {args.source} motion, seed 7"


def best(fn, repeat: int):
    out = fn()
    t = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return t, out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="mer-base")
    p.add_argument("--input", help="LAFAN1-layout folder (default: synthetic motion)")
    p.add_argument("--source", default="g1")
    p.add_argument("--clip", default="walk1_subject1")
    p.add_argument("--frames", type=int, default=600)
    p.add_argument("--targets", nargs="+", default=ALL)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--no-optimiser", action="store_true", help="skip the optimiser rows")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    ckpt = resolve_model(args.model)
    ckpt.model.eval()
    feats, what = source_motion(args)
    n, k = feats.shape[0], len(args.targets)
    load = os.getloadavg()[0]
    print(f"model {args.model}, {what}: {n} frames -> {k} targets, {args.threads} thread(s), load average {load:.2f}")
    t_each, each = best(lambda: [retarget_features(feats, args.source, t, checkpoint=ckpt) for t in args.targets], args.repeat)
    t_many, many = best(lambda: retarget_features_many(feats, args.source, args.targets, checkpoint=ckpt), args.repeat)
    diff = max(float(np.abs(a.motion.q - b.motion.q).max()) for a, b in zip(each, many))
    rows = [("model, one call per target", t_each), ("model, all targets in one pass", t_many)]
    opt = None
    if not args.no_optimiser:
        t_opt, opt = best(lambda: [retarget_features(feats, args.source, t, method="optimize") for t in args.targets], 1)
        rows.append(("optimiser, per target", t_opt))
    print(f"\n{'path':34s} {'seconds':>8s} {'target-frames/s':>16s} {'vs one call per target':>23s}")
    for name, t in rows:
        print(f"{name:34s} {t:8.2f} {n * k / t:16.0f} {t_each / t:22.2f}x")
    print(f"largest joint-angle difference between the two model paths: {diff:.2e} rad")
    src = get_skeleton(args.source)
    print(f"\n{'target':10s} {'model g-mpbpe [m]':>18s} {'optimiser':>10s}")
    for i, t in enumerate(args.targets):
        e = sequence_metrics(feats, src, many[i].motion)["g_mpbpe"]
        o = f"{sequence_metrics(feats, src, opt[i].motion)['g_mpbpe']:10.4f}" if opt else f"{'-':>10s}"
        print(f"{t:10s} {e:18.4f} {o}")
    print(f"\nload average {load:.2f} -> {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
