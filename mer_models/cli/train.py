"""``mer train``: train the retargeting model on shards (or on built-in synthetic motion)."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

from mer_data.base.errors import MerError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train the guided-diffusion model",
        description="Train the model; the --out folder is the checkpoint (config.json + model.safetensors). "
        "Multi-GPU/CPU: run under `torchrun --nproc_per_node N -m mer_models train ...`.",
    )
    p.add_argument("--config", default="tiny", help="preset: tiny (CPU, minutes), base (mer-base: CPU, hours), paper (H=240, 4 layers) or warm (the warm-start model, mer-warm)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--shards", nargs="+", metavar="PATH", help="shard files or folders (mer shards build)")
    src.add_argument("--synthetic", type=int, metavar="N", help="train on N synthetic windows (no data needed)")
    p.add_argument("--out", required=True, help="checkpoint folder to write")
    p.add_argument("--steps", type=int, default=1000, help="total optimiser steps (default 1000)")
    p.add_argument("--resume", action="store_true", help="continue the checkpoint in --out exactly")
    p.add_argument("--bf16", action="store_true", help="bfloat16 autocast for the network (fast on GPUs and on CPUs with AMX or AVX512-BF16; emulated, slower than float32, elsewhere: a warning says so)")
    add_run_overrides(p, "the preset's")
    p.add_argument("--split", default="train", choices=["train", "eval", "all"], help="shard windows to train on (default train)")
    p.add_argument("--targets", nargs="+", help="only these target robots (default: all in the shards)")
    p.add_argument("--source", default="g1", help="reference robot of --synthetic data")
    p.add_argument("--workers", type=int, default=0, help="DataLoader worker processes")
    p.add_argument("--ref-group", type=int, help="samples per reference window in a batch, sharing one reference "
                   "encoding (--shards only; default: the preset's, 1; docs/model.md)")
    p.add_argument("--ema", type=float, metavar="DECAY", help="keep a moving average of the weights with this decay "
                   "(e.g. 0.999) and write it as the checkpoint's weights (default: the preset's, none; docs/model.md)")
    p.set_defaults(func=cmd_train)


def add_run_overrides(p: argparse.ArgumentParser, of: str) -> None:
    """The options ``mer train`` and ``mer finetune`` share: device and run-config overrides."""
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.add_argument("--batch-size", type=int, help=f"override {of} batch size")
    p.add_argument("--lr", type=float, help=f"override {of} learning rate")
    p.add_argument("--seed", type=int, help=f"override {of} seed")
    p.add_argument("--save-every", type=int, help="steps between checkpoints")
    p.add_argument("--log-every", type=int, help="steps between log lines")


def cmd_train(args) -> int:
    from mer_models.config import preset
    from mer_models.training.train import train

    run = preset(args.config)
    over = {k: v for k, v in {"batch_size": args.batch_size, "lr": args.lr, "seed": args.seed,
                               "save_every": args.save_every, "log_every": args.log_every,
                               "ref_group": args.ref_group, "ema": args.ema}.items() if v is not None}  # fmt: skip
    if over:
        run = run.replace(train=dataclasses.replace(run.train, **over))
    if args.steps < 1:
        raise MerError("--steps must be >= 1")
    if args.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise MerError("--device cuda but no CUDA device is available", fix="use --device cpu")
    if args.shards:
        from mer_data.shards import ShardDataset

        dataset = ShardDataset(args.shards, split=None if args.split == "all" else args.split, targets=args.targets)
        info = {"shards": [str(p) for p in dataset.paths], "split": args.split, "samples": len(dataset)}
    else:
        from mer_models.training.synthetic import SyntheticDataset

        targets = tuple(args.targets or ("g1", "h1", "atlas", "oli", "tron1"))
        dataset = SyntheticDataset(args.source, targets, size=args.synthetic, frames=run.model.frames, augment=True, seed=run.train.seed)  # fmt: skip
        info = {"synthetic": args.synthetic, "source": args.source, "targets": list(targets), "samples": len(dataset)}

    res = train(run, dataset, args.out, steps=args.steps, resume=args.resume, device=args.device, bf16=args.bf16,
                num_workers=args.workers, data_info=info, progress=show_progress)  # fmt: skip
    if os.environ.get("RANK", "0") == "0":
        print(f"checkpoint {res.path} at step {res.step}")
    return 0


def show_progress(rec: dict) -> None:
    """One line per training log record, on stderr (called on rank 0 only)."""
    if "edm" not in rec:  # the warm-start model: regression on the teacher and its energy
        print(f"step {rec['step']:6d}  loss {rec['loss']:.4f}  q {rec['q']:.5f} rad^2  fk {rec['fk']:.6f} m^2  "
              f"energy {rec['energy']:.5f}  {rec['sec_per_step']:.2f} s/step", file=sys.stderr)  # fmt: skip
        return
    print(
        f"step {rec['step']:6d}  loss {rec['loss']:.4f}  edm {rec['edm']:.4f}  f_kin {rec['f_total']:.5f} "
        f"(kp {rec['f_kp']:.5f} cst {rec['f_cst']:.5f} vel {rec['f_vel']:.5f} norm {rec['f_norm']:.5f})  "
        f"{rec['sec_per_step']:.2f} s/step",
        file=sys.stderr,
    )
