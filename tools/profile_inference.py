"""Profile: where the time of a retargeting goes, model against the optimiser, in one run.

One batch of ``--windows`` 60-frame windows of the source robot (LAFAN1 when ``--input`` is given,
else synthetic motion generated in code), retargeted to each ``--targets`` robot. Every stage is
timed on its own (best of ``--repeat`` after an untimed warm-up):

* ``collate``: ``TrainingSample`` list -> batch (reference scaling, goals; shared by every method);
* ``conditions``: ``RetargetModel.conditions`` (skeleton graphs, normalisation);
* ``network``: ``sample_conditions`` with the checkpoint's sampler (reference encoder + denoiser
  evaluations), in float32 and under bfloat16 autocast;
* ``decode``: diffusion space -> angles and base pose;
* ``refine K``: ``optimize_batch(gn_iters=K)`` warm-started from the model's output;
* ``optimiser``: ``optimize_batch`` from scratch (the peer: what the model would replace);
* ``metrics``: ``window_metrics`` (not part of any method's time below).

Printed per target: the stage table (ms for the batch), g-mpbpe [m] of the model alone, of the
model + K iterations and of the optimiser, and frames/s of each path with its ratio to the
optimiser's (collate counted in every path). ``--ops N`` adds the N most expensive operators of
the network call (``torch.profiler``, self CPU time).

    PYTHONPATH=$PWD python tools/profile_inference.py [--model mer-base] [--input ../shared/data/lafan1] \\
        [--source g1] [--targets h1] [--windows 16] [--refine 1 2 3 5] [--threads 2] [--ops 12] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable

import torch

from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.registry import get_skeleton
from mer_models.config import EnergyConfig
from mer_models.retarget.evaluate import EvalOptions, collect_windows
from mer_models.retarget.inference import optimize_batch, sample_conditions
from mer_models.retarget.metrics import summarize, window_metrics
from mer_models.training.synthetic import SyntheticDataset
from mer_models.zoo.checkpoint import resolve_model


def best_ms(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Best wall time [ms] of ``repeat`` calls after one untimed warm-up call, and the last result."""
    out = fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, (time.perf_counter() - t0) * 1e3)
    return best, out


def references(args) -> list:
    if args.input:
        by_domain = collect_windows(args.input, args.source, EvalOptions(split="all", max_windows=args.windows))
        w = [x["reference"] for ws in by_domain.values() for x in ws][: args.windows]  # split "all": every clip eligible
        if not w:
            raise SystemExit(f"no 60-frame window of {args.source} in {args.input}")
        return w
    ds = SyntheticDataset(args.source, (args.source,), size=args.windows, seed=11)
    return [ds[i].reference for i in range(args.windows)]


def g_mpbpe(motion, batch, tgt) -> float:
    return float(summarize(window_metrics(motion, batch, keypoints={"base": 0, **tgt.keypoints}))["g_mpbpe"]["mean"])


def profile_target(ckpt, refs, src, target: str, args) -> dict:
    tgt = get_skeleton(target)
    eta = joint_map(tgt, src)
    samples = [TrainingSample(r, src, tgt, eta) for r in refs]
    model, sampler, energy = ckpt.model, ckpt.run.sampler, ckpt.run.energy
    opt_energy = EnergyConfig()  # as `mer evaluate`: the optimiser and the refinement use the default energy
    ms: dict[str, float] = {}
    ms["collate"], batch = best_ms(lambda: collate(samples), args.repeat)
    ms["conditions"], cond = best_ms(lambda: model.conditions(batch), args.repeat)

    def network(bf16: bool):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            return sample_conditions(model, model.conditions(batch), sampler, energy=energy).float()

    ms["network fp32"], d = best_ms(lambda: network(False), args.repeat)
    ms["network fp32"] -= ms["conditions"]  # network() builds its own conditions: the encoder caches on them
    ms["network bf16"], _ = best_ms(lambda: network(True), args.repeat)
    ms["network bf16"] -= ms["conditions"]
    ms["decode"], motion = best_ms(lambda: model.decode(d, cond), args.repeat)
    ms["metrics"], _ = best_ms(lambda: window_metrics(motion, batch), args.repeat)
    err = {"model": g_mpbpe(motion, batch, tgt)}
    for k in args.refine:
        ms[f"refine {k}"], m = best_ms(lambda k=k: optimize_batch(opt_energy, batch, gn_iters=k, init=motion), args.repeat)
        err[f"model + {k}"] = g_mpbpe(m, batch, tgt)
    ms["optimiser"], m = best_ms(lambda: optimize_batch(opt_energy, batch), args.repeat)
    err["optimiser"] = g_mpbpe(m, batch, tgt)
    model_ms = ms["collate"] + ms["conditions"] + ms["network fp32"] + ms["decode"]
    paths = {"model": model_ms, **{f"model + {k}": model_ms + ms[f"refine {k}"] for k in args.refine},
             "optimiser": ms["collate"] + ms["optimiser"]}  # fmt: skip
    frames = len(refs) * refs[0].shape[0]
    fps = {p: frames / (t / 1e3) for p, t in paths.items()}
    ops = None
    if args.ops:
        with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
            network(False)
        ops = [{"op": e.key, "self_ms": e.self_cpu_time_total / 1e3, "calls": e.count}
               for e in sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)[: args.ops]]  # fmt: skip
    return {"target": target, "frames": frames, "stage_ms": ms, "path_ms": paths, "frames_per_s": fps, "g_mpbpe": err, "ops": ops}


def report(r: dict, threads: int) -> str:
    opt = r["frames_per_s"]["optimiser"]
    lines = [f"\n-> {r['target']}: {r['frames']} frames, {threads} thread(s)", f"{'stage':16s} {'ms':>9s}"]
    lines += [f"{k:16s} {v:9.1f}" for k, v in r["stage_ms"].items()]
    lines.append(f"\n{'path':16s} {'ms':>9s} {'frames/s':>9s} {'vs optimiser':>12s} {'g-mpbpe [m]':>12s} {'vs optimiser':>12s}")
    e_opt = r["g_mpbpe"]["optimiser"]
    for p, t in r["path_ms"].items():
        e = r["g_mpbpe"][p]
        lines.append(f"{p:16s} {t:9.1f} {r['frames_per_s'][p]:9.0f} {r['frames_per_s'][p] / opt:11.2f}x {e:12.4f} {e / e_opt:11.2f}x")
    if r["ops"]:
        total = sum(o["self_ms"] for o in r["ops"])
        lines.append(f"\ntop operators of one network call (self CPU; {total:.0f} ms in these)")
        lines += [f"  {o['op']:40s} {o['self_ms']:8.1f} ms {o['calls']:6d} calls" for o in r["ops"]]
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="mer-base", help="model name or checkpoint folder (default mer-base)")
    p.add_argument("--input", help="LAFAN1-layout folder (default: synthetic windows)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=["h1"])
    p.add_argument("--windows", type=int, default=16)
    p.add_argument("--refine", type=int, nargs="*", default=[1, 2, 3, 5], help="refine iterations to time")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--ops", type=int, default=0, help="list the N most expensive operators of the network call")
    p.add_argument("--json", help="also write the results to this file")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    ckpt = resolve_model(args.model)
    ckpt.model.eval()
    refs = references(args)
    src = get_skeleton(args.source)
    load = os.getloadavg()[0]
    print(f"model {args.model}  sampler {ckpt.run.sampler.method} x {ckpt.run.sampler.steps}  source {args.source}  "
          f"windows {len(refs)}  load average {load:.2f}")  # fmt: skip
    results = []
    for target in args.targets:
        r = profile_target(ckpt, refs, src, target, args)
        print(report(r, args.threads), flush=True)
        results.append(r)
    print(f"\nload average {load:.2f} -> {os.getloadavg()[0]:.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"model": args.model, "threads": args.threads, "results": results}, fh, indent=2)


if __name__ == "__main__":
    main()
