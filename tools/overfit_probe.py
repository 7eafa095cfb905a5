"""Probe: can a configuration fit a handful of its own training samples, and how fast?

Trains on ``--samples`` fixed samples of one (source, target) pair of the shards (URDF skeletons,
with the shards' teacher; every ``--every``-th in shard order), the whole set as every batch, and after every ``--chunk`` steps reports
the one-step (the checkpoint's sampler) g-mpbpe [m] on those samples ("fit") and on as many other
samples of the same pair ("held"), next to the teacher's own g-mpbpe on the fitted samples (the
floor: the model learns the teacher). A model that cannot get near the teacher on samples it sees
at every step is limited by its optimisation or its representation, not by the amount of data.

    PYTHONPATH=$PWD python tools/overfit_probe.py --shards SHARDS --out runs/probe [--source g1] [--target h1] \\
        [--samples 16] [--every 5] [--steps 500] [--chunk 100] [--init mer_models/bundled/mer-base] [--config base] \\
        [--lr 7e-4] [--lr-decay-steps N] [--lr-min-ratio R] [--grad-clip C] [--lam L] [--start-frac F] [--norm-first] [--layers N] [--hidden H] [--ffn F] [--diagnose] [--bf16] [--threads 1]

Each chunk resumes the previous one exactly (``mer_models.training.train.train``); one JSON line per chunk
is printed and appended to ``OUT.probe.jsonl``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch
from safetensors import safe_open
from torch.utils.data import Subset

from mer_data.motion.samples import collate
from mer_data.robots.registry import get_skeleton
from mer_data.shards import ShardDataset
from mer_models.config import EnergyConfig, preset
from mer_models.retarget.inference import optimize_batch, sample_conditions
from mer_models.retarget.metrics import summarize, window_metrics
from mer_models.training.train import clean_samples, train
from mer_models.zoo.checkpoint import resolve_model


def g_mpbpe(motion, batch, keypoints) -> float:
    return float(summarize(window_metrics(motion, batch, keypoints=keypoints))["g_mpbpe"]["mean"])


def _model_motion(model_dir: str | Path, batch):
    """(model, its conditions of ``batch``, checkpoint, its one-sampler motion)."""
    ckpt = resolve_model(str(model_dir))
    m = ckpt.model.eval()
    with torch.no_grad():
        cond = m.conditions(batch)
        return m, cond, ckpt, m.decode(sample_conditions(m, cond, ckpt.run.sampler, energy=ckpt.run.energy), cond)


def model_error(model_dir: str | Path, batch, keypoints) -> float:
    return g_mpbpe(_model_motion(model_dir, batch)[3], batch, keypoints)


def where_the_error_sits(model_dir: str | Path, batch, keypoints) -> dict[str, float]:
    """The model's g-mpbpe on ``batch`` [m] (``fit``, as :func:`model_error`) and its motion against the
    teacher's: mean |angle difference| over actuated
    joints [rad] (all, and split by where the teacher's angle sits: within 3 % of its range from a
    limit or not, with the share near a limit), mean base position difference [m], and the g-mpbpe
    [m] of the teacher's angles under the model's base pose and of the model's angles on the
    teacher's base pose."""
    m, cond, ckpt, mine = _model_motion(model_dir, batch)
    with torch.no_grad():
        taught = m.decode(clean_samples(m, batch, cond, ckpt.run), cond)
    g = cond.tgt_graph
    diff = (mine["q"] - taught["q"]).abs()
    actuated = g.dof[:, None].expand_as(diff)
    u = (taught["q"] - g.lower[:, None]) / (g.upper - g.lower).clamp_min(1e-9)[:, None]
    near = actuated & (torch.minimum(u, 1 - u) < 0.03)
    mid = actuated & ~near
    base = {"base_pos": mine["base_pos"], "base_rot": mine["base_rot"]}
    return {
        "fit": g_mpbpe(mine, batch, keypoints),
        "angle_rad": float(diff[actuated].mean()),
        "angle_rad_near_limit": float(diff[near].mean()) if near.any() else float("nan"),
        "angle_rad_mid_range": float(diff[mid].mean()),
        "near_limit_share": float(near.sum() / actuated.sum()),
        "base_m": float((mine["base_pos"] - taught["base_pos"]).norm(dim=-1).mean()),
        "teacher_angles_model_base": g_mpbpe({"q": taught["q"], **base}, batch, keypoints),
        "model_angles_teacher_base": g_mpbpe({"q": mine["q"], "base_pos": taught["base_pos"],
                                              "base_rot": taught["base_rot"]}, batch, keypoints),  # fmt: skip
    }


def ffn_width(weights: Path) -> int | None:
    """The feed-forward width of a ``model.safetensors`` (None: no feed-forward layers)."""
    with safe_open(str(weights), "pt") as f:
        widths = {f.get_slice(k).get_shape()[0] for k in f.keys() if k.endswith(".ffn.0.weight")}
    if len(widths) > 1:
        raise SystemExit(f"{weights}: feed-forward layers of different widths {sorted(widths)}")
    return widths.pop() if widths else None


def widen_ffn(state: dict[str, torch.Tensor], ffn: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """``state`` with every decoder layer's feed-forward hidden width raised to ``ffn``, computing
    the same function: the new first-layer rows are random (PyTorch's default scale, so they get
    gradients), their biases and the second layer's new columns zero."""
    gen = torch.Generator().manual_seed(seed)
    out = dict(state)
    for key, w in state.items():
        if key.endswith(".ffn.0.weight"):
            old, H = w.shape
            if ffn < old:
                raise SystemExit(f"--ffn {ffn} is narrower than the checkpoint's {old}")
            bound = 1 / H**0.5
            extra = (torch.rand(ffn - old, H, generator=gen, dtype=torch.float32) * 2 - 1) * bound
            out[key] = torch.cat([w, extra.to(w.dtype)], 0)
            b = key[: -len("weight")] + "bias"
            out[b] = torch.cat([state[b], state[b].new_zeros(ffn - old)])
            w2 = key.replace(".ffn.0.weight", ".ffn.3.weight")
            out[w2] = torch.cat([state[w2], state[w2].new_zeros(state[w2].shape[0], ffn - old)], 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shards", required=True, nargs="+", help="shards with teacher files (mer shards solve)")
    ap.add_argument("--out", required=True, help="checkpoint folder")
    ap.add_argument("--source", default="g1")
    ap.add_argument("--target", default="h1")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--every", type=int, default=5, help="take every K-th sample of the pair (default 5)")
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--chunk", type=int, default=100)
    ap.add_argument("--config", default="base")
    ap.add_argument("--init", help="start from this checkpoint's weights (default: from scratch)")
    ap.add_argument("--lr", type=float)
    ap.add_argument("--lr-decay-steps", type=int, help="cosine decay of the rate over N steps after the warm-up (default: constant)")
    ap.add_argument("--lr-min-ratio", type=float, help="the decayed rate as a share of --lr (default: the preset's)")
    ap.add_argument("--grad-clip", type=float, help="gradient norm clip (default: the preset's)")
    ap.add_argument("--lam", type=float, help="weight of the energy term in the loss (default: the preset's EnergyConfig.lam)")
    ap.add_argument("--start-frac", type=float)
    ap.add_argument("--norm-first", action="store_true")
    ap.add_argument("--layers", type=int, help="layers per decoder (default: the preset's; from scratch only)")
    ap.add_argument("--hidden", type=int, help="token width (default: the preset's; from scratch only)")
    ap.add_argument("--ffn", type=int, help="feed-forward width; with --init, the checkpoint widened to it "
                    "function-preservingly (new units start silent)")
    ap.add_argument("--diagnose", action="store_true", help="also report where the fitted samples' error sits "
                    "(angles and base against the teacher's, each swapped in turn)")
    ap.add_argument("--bf16", action="store_true", help="bfloat16 autocast in training (GPUs; CPUs with AMX or AVX512-BF16 only)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    every = ShardDataset(args.shards, targets=[args.target], augmented=False, teacher=None)
    paths = [p for p, f in zip(every.paths, every.files) if f.meta.robot == args.source]  # the source's shard files
    if not paths:
        raise SystemExit(f"no shard of source robot {args.source} in {args.shards} (sources: {', '.join(every.robots)})")
    ds = ShardDataset(paths, targets=[args.target], augmented=False, teacher=True)
    idx = list(range(len(ds)))
    fit_idx = idx[:: args.every][: args.samples]  # every K-th window of the pair, in shard order
    held_idx = idx[2 :: args.every][: args.samples]  # two windows later: the same clips, other frames
    if len(held_idx) < args.samples:
        raise SystemExit(f"{len(idx)} {args.source} -> {args.target} samples in the shards: too few for "
                         f"{args.samples} samples every {args.every}; lower --every or --samples")  # fmt: skip
    kp = {"base": 0, **get_skeleton(args.target).keypoints}
    fit_batch, held_batch = collate([ds[i] for i in fit_idx]), collate([ds[i] for i in held_idx])
    teacher = g_mpbpe(optimize_batch(EnergyConfig(), fit_batch), fit_batch, kp)
    run = preset(args.config)
    over = {"batch_size": args.samples, "save_every": args.chunk, "log_every": 10, "warmup": 20, "lr_decay_steps": 0}
    for key in ("lr", "lr_decay_steps", "lr_min_ratio", "grad_clip"):
        if getattr(args, key) is not None:
            over[key] = getattr(args, key)
    if args.start_frac is not None:
        over["start_frac"] = args.start_frac
    run = run.replace(train=dataclasses.replace(run.train, **over))
    if args.norm_first:
        run = run.replace(model=dataclasses.replace(run.model, norm_first=True))
    for key in ("layers", "hidden", "ffn"):
        if getattr(args, key) is not None:
            run = run.replace(model=dataclasses.replace(run.model, **{key: getattr(args, key)}))
    if args.init and args.ffn is None:  # the checkpoint's own width (the bundled mer-base: 768)
        run = run.replace(model=dataclasses.replace(run.model, ffn=ffn_width(Path(args.init) / "model.safetensors") or run.model.ffn))
    if args.lam is not None:
        run = run.replace(energy=dataclasses.replace(run.energy, lam=args.lam))
    out = Path(args.out)
    log_path = out.parent / f"{out.name}.probe.jsonl"
    first = {"step": 0, "teacher": teacher, "samples": args.samples, "pair": f"{args.source}->{args.target}"}
    if args.init:
        fit = where_the_error_sits(args.init, fit_batch, kp) if args.diagnose else {"fit": model_error(args.init, fit_batch, kp)}
        first.update(fit, held=model_error(args.init, held_batch, kp))
    print(json.dumps(first), flush=True)
    with open(log_path, "a") as fh:
        fh.write(json.dumps(first) + "\n")
    for step in range(args.chunk, args.steps + 1, args.chunk):
        t0 = time.process_time()
        init = Path(args.init) / "model.safetensors" if args.init and step == args.chunk else None
        if init is not None and args.ffn is not None:
            from safetensors.torch import load_file, save_file

            out.mkdir(parents=True, exist_ok=True)
            save_file(widen_ffn(load_file(str(init)), args.ffn), str(out / "widened.safetensors"))
            init = out / "widened.safetensors"
        train(run, Subset(ds, fit_idx), out, steps=step, resume=step > args.chunk, init=init, bf16=args.bf16)
        fit = where_the_error_sits(out, fit_batch, kp) if args.diagnose else {"fit": model_error(out, fit_batch, kp)}
        row = {"step": step, **fit, "held": model_error(out, held_batch, kp),
               "teacher": teacher, "cpu_min": round((time.process_time() - t0) / 60, 2)}  # fmt: skip
        print(json.dumps(row), flush=True)
        with open(log_path, "a") as fh:
            fh.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
