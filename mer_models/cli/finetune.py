"""``mer finetune``: adapt a model to a new robot (add its skeleton to the targets, continue training)."""

from __future__ import annotations

import argparse
import os
import sys

from .train import add_run_overrides


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "finetune",
        help="fine-tune a model for a robot it never saw",
        description="Continue training BASE (a zoo name, a checkpoint folder or a Hub id ORG/NAME; a diffusion model "
        "or a warm start) with ROBOT added to its training targets. The --out folder is a checkpoint that records its "
        "base; publish it with `mer zoo publish OUT --name NAME --repo-id ORG/NAME`.",
    )
    p.add_argument("--base", required=True, help="the model to start from (zoo name, folder or ORG/NAME)")
    p.add_argument("--revision", help="revision of the base (zoo names and Hub ids; default: the pinned one)")
    p.add_argument("--robot", required=True, help="the registered robot to add (mer robots register NAME --urdf FILE)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--shards", nargs="+", metavar="PATH", help="shard files or folders: their reference windows are used")
    src.add_argument("--synthetic", type=int, metavar="N",
                     help="N synthetic windows of --source (no data needed; a warm start's are its training crop long)")  # fmt: skip
    p.add_argument("--out", required=True, help="checkpoint folder to write")
    p.add_argument("--steps", type=int, default=200, help="optimiser steps of the fine-tune (default 200)")
    p.add_argument("--source", default="g1", help="reference robot of --synthetic data (default g1)")
    p.add_argument("--split", default="train", choices=["train", "eval", "all"], help="shard windows to use (default train)")
    p.add_argument("--fraction", type=float, default=0.5, help="share of samples retargeted to the new robot (default 0.5)")
    p.add_argument("--resume", action="store_true", help="continue the fine-tune in --out exactly")
    add_run_overrides(p, "the base's")
    p.set_defaults(func=cmd_finetune)


def cmd_finetune(args) -> int:
    from mer_models.training.finetune import finetune

    from .train import show_progress

    res = finetune(args.base, args.robot, args.out, shards=args.shards, synthetic=args.synthetic, steps=args.steps,
                   source=args.source, split=args.split, new_fraction=args.fraction, revision=args.revision,
                   resume=args.resume, device=args.device, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                   log_every=args.log_every, save_every=args.save_every, progress=show_progress)  # fmt: skip
    if os.environ.get("RANK", "0") == "0":
        print(f"checkpoint {res.path} at step {res.step}: {args.base} fine-tuned for {args.robot}")
        print(f"publish it: mer zoo publish {res.path} --name NAME --repo-id ORG/NAME", file=sys.stderr)
    return 0
