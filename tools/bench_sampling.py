"""Benchmark: EDM Heun with few steps against the 1000-step sampler, in the same run.

Prints, per sampler: network evaluations (NFE), milliseconds per 60-frame window, and the metrics
of the retargeted windows (mer_models.retarget.metrics), plus the NFE ratio and the relative metric change
against the 1000-step reference. Goal: >= 30x fewer evaluations with metrics within 5 %.

    PYTHONPATH=. python tools/bench_sampling.py --model /tmp/mer-tiny --input /path/to/lafan1 \
        --source g1 --targets h1 atlas --windows 16 --steps 8 12 16

Without --input the windows are synthetic motion generated in code.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.registry import get_skeleton
from mer_models.config import SamplerConfig
from mer_models.retarget.evaluate import EvalOptions, collect_windows
from mer_models.retarget.inference import sample_conditions
from mer_models.retarget.metrics import summarize, window_metrics
from mer_models.training.synthetic import SyntheticDataset
from mer_models.zoo.checkpoint import load_checkpoint

KEYS = ("g_mpbpe", "mpboe", "mpbve", "jerk")


def windows(args) -> list[np.ndarray]:
    if args.input:
        w = collect_windows(args.input, args.source, EvalOptions(max_windows=args.windows))["out-of-domain"]
        return [x["reference"] for x in w][: args.windows]
    ds = SyntheticDataset(args.source, (args.source,), size=args.windows, seed=11)
    return [ds[i].reference for i in range(args.windows)]


def run_sampler(ckpt, batch, method, steps, seed, guidance):
    model = ckpt.model
    cfg = SamplerConfig(**{**ckpt.run.sampler.__dict__, "steps": steps, "guidance": guidance})
    cond = model.conditions(batch)
    stats = {}
    t0 = time.perf_counter()
    d = sample_conditions(model, cond, cfg, energy=ckpt.run.energy, method=method, generator=torch.Generator().manual_seed(seed), stats=stats)
    dt = time.perf_counter() - t0
    motion = model.decode(d, cond)
    m = summarize(window_metrics(motion, batch))
    return stats["nfe"], dt, {k: m[k]["mean"] for k in KEYS}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="checkpoint folder")
    p.add_argument("--input", help="LAFAN1-layout folder (default: synthetic windows)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=["h1"])
    p.add_argument("--windows", type=int, default=8)
    p.add_argument("--steps", type=int, nargs="+", default=[8, 12, 16])
    p.add_argument("--reference-steps", type=int, default=1000)
    p.add_argument("--reference-method", default="euler", choices=["euler", "ancestral", "heun"])
    p.add_argument("--guidance", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--json", help="also write the results to this file")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    ckpt = load_checkpoint(args.model)
    refs = windows(args)
    src = get_skeleton(args.source)
    results = []
    print(f"model {args.model}  windows {len(refs)} x 60 frames  threads {torch.get_num_threads()}  guidance {args.guidance}")
    for target in args.targets:
        tgt = get_skeleton(target)
        batch = collate([TrainingSample(r, src, tgt, joint_map(tgt, src)) for r in refs])
        rows = [("heun", n) for n in args.steps] + [(args.reference_method, args.reference_steps)]
        res = {}
        for method, steps in rows:
            nfe, dt, m = run_sampler(ckpt, batch, method, steps, args.seed, args.guidance)
            res[(method, steps)] = (nfe, dt, m)
        ref_nfe, ref_dt, ref_m = res[(args.reference_method, args.reference_steps)]
        print(f"\n{args.source} -> {target}")
        print(f"{'sampler':16s} {'NFE':>5s} {'ms/window':>10s} {'NFE ratio':>9s}  " + "  ".join(f"{k:>16s}" for k in KEYS))
        for (method, steps), (nfe, dt, m) in res.items():
            rel = "  ".join(f"{m[k]:>8.4g} ({(m[k] - ref_m[k]) / ref_m[k] * 100:+5.1f}%)" for k in KEYS)
            print(f"{method + '-' + str(steps):16s} {nfe:5d} {dt / len(refs) * 1000:10.1f} {ref_nfe / nfe:9.1f}  {rel}")
            results.append({"target": target, "sampler": method, "steps": steps, "nfe": nfe, "ms_per_window": dt / len(refs) * 1000,
                            "nfe_ratio_vs_reference": ref_nfe / nfe, "metrics": m,
                            "relative_change": {k: (m[k] - ref_m[k]) / ref_m[k] for k in KEYS}})  # fmt: skip
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)


if __name__ == "__main__":
    main()
