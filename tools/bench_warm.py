"""Benchmark: the warm-start model against the optimiser and mer-base, on every LAFAN1 pair, in one run.

For each source (G1, H1) and each of the 8 built-in targets: ``--windows`` 60-frame windows of the
source's LAFAN1 clips (``--split all``, as ``mer evaluate --max-windows``), retargeted by

* ``warm``: the warm-start network alone (``--model``, default ``mer-warm``);
* ``warm + K``: then K whole-window LM iterations (``--refine``, default 2 and 3), the ``refine`` path;
* ``capped``: the optimiser with its coarse stage capped at 3 iterations (no network);
* ``optimiser``: the full optimiser (``mer evaluate --methods optimize``);
* ``mer-base + 2``: the diffusion model (``--base``) + 2 iterations.

Every path gets the same batch (collation, the goals, timed once and added to each path's time)
and the optimiser's physical terms as ``mer evaluate`` runs them (``--no-physics``: without;
``--physics-method``: the method, default the package's (``PhysicsConfig().method``); constraints: :mod:`mer_models.solver.constrained`).
Printed per pair: g-mpbpe [m] and its ratio to the optimiser's, jerk (``E_smooth``
[rad/frame^3]) and its ratio, the share of frames over a joint limit, and time per 960 frames
[ms] with its ratios to the capped and to the full optimiser; then the means over pairs and the
issue's bars. ``--threads`` torch threads (default 2). Nothing is written unless ``--json``: the
figures come from LAFAN1 (CC BY-NC-ND), keep the file outside the repository.

    PYTHONPATH=$PWD python tools/bench_warm.py --input ../shared/data/lafan1 [--model mer-warm] [--windows 32] [--json /tmp/warm.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mer_data.kinematics.jointmap import joint_map  # noqa: E402
from mer_data.motion.samples import TrainingSample, collate  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.registry import as_robot  # noqa: E402
from mer_models.config import EnergyConfig  # noqa: E402
from mer_models.retarget.evaluate import EvalOptions, collect_windows  # noqa: E402
from mer_models.retarget.inference import model_batch, optimize_batch  # noqa: E402
from mer_models.retarget.metrics import summarize, window_metrics  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402
from mer_models.zoo.checkpoint import resolve_model  # noqa: E402

TARGETS = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def run_pair(src: str, target: str, windows: list, warm, base, args) -> dict:
    s, t = as_robot(src), as_robot(target)
    eta = joint_map(t.skeleton, s.skeleton)
    energy = EnergyConfig()
    phys = {}
    if not args.no_physics:
        phys = {"physics": PhysicsConfig(method=args.physics_method), "geometry": collision_model(t), "ref_skeleton": s.skeleton, "fps": 30.0,
                "target_skeleton": t.skeleton}  # fmt: skip
    sec: dict[str, float] = {}
    motions: dict[str, list] = {}
    batches = []
    t_collate = 0.0
    for a in range(0, len(windows), args.batch):
        dt, batch = timed(lambda a=a: collate([TrainingSample(w["reference"], s.skeleton, t.skeleton, eta) for w in windows[a : a + args.batch]]))
        t_collate += dt
        batches.append(batch)

    def add(name: str, dt: float, m) -> None:
        sec[name] = sec.get(name, t_collate) + dt
        motions.setdefault(name, []).append(m)

    for batch in batches:
        dt, m = timed(lambda: model_batch(warm.model, batch, warm.run.sampler))
        add("warm", dt, m)
        for k in args.refine:
            dk, mk = timed(lambda k=k: optimize_batch(energy, batch, gn_iters=k, init=m, **phys))
            add(f"warm + {k}", dt + dk, mk)
        add("capped", *timed(lambda: optimize_batch(energy, batch, gn_iters=3, **phys)))
        add("optimiser", *timed(lambda: optimize_batch(energy, batch, **phys)))
        if base is not None:
            db, mb = timed(lambda: model_batch(base.model, batch, base.run.sampler))
            d2, m2 = timed(lambda: optimize_batch(energy, batch, gn_iters=2, init=mb, **phys))
            add("mer-base + 2", db + d2, m2)
    frames = sum(b["reference"].shape[0] * b["reference"].shape[1] for b in batches)
    kp = {"base": 0, **t.skeleton.keypoints}
    rows = {}
    for name, ms in motions.items():
        vals: dict[str, list] = {}
        for m, b in zip(ms, batches):
            for key, v in window_metrics(m, b, keypoints=kp).items():
                vals.setdefault(key, []).append(v)
        summ = summarize({key: np.concatenate(v) for key, v in vals.items()})
        rows[name] = {"g_mpbpe": summ["g_mpbpe"]["mean"], "jerk": summ["jerk_frame"]["mean"], "limits": summ["limit_violation"]["mean"],
                      "ms_per_960": 1e3 * sec[name] / frames * 960}  # fmt: skip
    return {"source": src, "target": target, "windows": len(windows), "frames": frames, "paths": rows}


def report(r: dict) -> str:
    p = r["paths"]
    opt, cap = p["optimiser"], p["capped"]
    lines = [f"\n{r['source']} -> {r['target']}: {r['windows']} windows, {r['frames']} frames",
             f"{'path':14s} {'g-mpbpe [m]':>12s} {'/ opt':>6s} {'jerk':>9s} {'/ opt':>6s} {'limits':>7s} {'ms/960 fr':>10s} {'/ capped':>9s} {'/ opt':>6s}"]  # fmt: skip
    for name, v in p.items():
        lines.append(f"{name:14s} {v['g_mpbpe']:12.4f} {v['g_mpbpe'] / opt['g_mpbpe']:6.2f} {v['jerk']:9.5f} {v['jerk'] / opt['jerk']:6.2f} "
                     f"{v['limits']:7.3f} {v['ms_per_960']:10.0f} {v['ms_per_960'] / cap['ms_per_960']:9.2f} {v['ms_per_960'] / opt['ms_per_960']:6.2f}")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", required=True, help="LAFAN1-layout folder (g1/, h1/)")
    ap.add_argument("--model", default="mer-warm", help="the warm-start model (zoo name or folder)")
    ap.add_argument("--base", default="mer-base", help="the diffusion model to compare (zoo name or folder; 'none': skip)")
    ap.add_argument("--sources", nargs="+", default=["g1", "h1"])
    ap.add_argument("--targets", nargs="+", default=list(TARGETS))
    ap.add_argument("--windows", type=int, default=32)
    ap.add_argument("--batch", type=int, default=16, help="windows per batch (16 x 60 = 960 frames)")
    ap.add_argument("--refine", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-physics", action="store_true")
    ap.add_argument("--physics-method", choices=("penalty", "constraints"), default=None,
                    help=f"the physical terms' method in every path (PhysicsConfig.method; default {PhysicsConfig().method})")
    ap.add_argument("--json")
    args = ap.parse_args()
    if args.no_physics and args.physics_method is not None:
        ap.error("--physics-method needs the physical terms: drop --no-physics")
    args.physics_method = args.physics_method or PhysicsConfig().method
    torch.set_num_threads(args.threads)
    warm = resolve_model(args.model)
    base = None if args.base == "none" else resolve_model(args.base)
    load0 = os.getloadavg()[0]
    print(f"warm {args.model}  base {args.base}  threads {args.threads}  physics {'off' if args.no_physics else args.physics_method}  load {load0:.2f}")
    results = []
    for src in args.sources:
        by = collect_windows(args.input, src, EvalOptions(split="all", max_windows=args.windows))
        windows = [x for ws in by.values() for x in ws][: args.windows]
        for target in args.targets:
            r = run_pair(src, target, windows, warm, base, args)
            print(report(r), flush=True)
            results.append(r)
    names = list(results[0]["paths"])
    print(f"\nmeans over {len(results)} pairs (ratios are means of per-pair ratios)")
    print(f"{'path':14s} {'g-mpbpe / opt':>14s} {'worst':>6s} {'jerk / opt':>11s} {'limits':>7s} {'t / capped':>11s} {'t / opt':>8s}")
    for n in names:
        ge = [r["paths"][n]["g_mpbpe"] / r["paths"]["optimiser"]["g_mpbpe"] for r in results]
        je = [r["paths"][n]["jerk"] / r["paths"]["optimiser"]["jerk"] for r in results]
        tc = [r["paths"][n]["ms_per_960"] / r["paths"]["capped"]["ms_per_960"] for r in results]
        to = [r["paths"][n]["ms_per_960"] / r["paths"]["optimiser"]["ms_per_960"] for r in results]
        lim = max(r["paths"][n]["limits"] for r in results)
        print(f"{n:14s} {np.mean(ge):14.3f} {max(ge):6.2f} {np.mean(je):11.3f} {lim:7.3f} {np.mean(tc):11.2f} {np.mean(to):8.2f}")
    print(f"\nbars (warm + 2): every pair <= 1.3x and mean <= 1.05x the optimiser's g-mpbpe; jerk <= the optimiser's; no limit "
          f"violation; time <= 0.5x the capped and <= 0.35x the full optimiser's.  load {load0:.2f} -> {os.getloadavg()[0]:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "results": results}, indent=1))


if __name__ == "__main__":
    main()
