"""``mer shards build|inspect|card|push``."""

from __future__ import annotations

import argparse
import json
import os
import sys

from mer_data.shards.config import FORMATS, PAPER_TARGETS


def add_parser(sub: argparse._SubParsersAction) -> argparse._SubParsersAction:
    """Add ``mer shards``; returns its sub-command group (``mer_models`` adds ``solve`` to it)."""
    p = sub.add_parser("shards", help="build and inspect training shards (LAFAN1 robot CSVs -> HDF5/MCAP)")
    ss = p.add_subparsers(dest="shards_cmd", required=True, metavar="{build,inspect,card,push,solve}")

    b = ss.add_parser("build", help="build training shards from robot motion CSVs, human motion (BVH, SMPL .npz, joint positions) or synthetic motion")
    src = b.add_mutually_exclusive_group(required=True)
    src.add_argument("--input", metavar="DIR|hf://REPO_ID", help="folder with ROBOT/*.csv[.gz] (or human files: KIND/* or *), or a Hub dataset (hf://OWNER/NAME[@REV])")
    src.add_argument("--synthetic", type=int, metavar="N", help="N clips of synthetic motion per robot instead (any registered robot; no data needed)")
    b.add_argument("--synthetic-seconds", type=float, default=20.0, metavar="S", help="seconds per synthetic clip (default 20)")
    b.add_argument("--synthetic-seed", type=int, default=0, metavar="S", help="seed of the synthetic motion (default 0)")
    b.add_argument("--robots", nargs="+", required=True, metavar="ROBOT", help="source robots, e.g. g1 h1 (with --input: robots with motion data); "
                   "or one human kind: bvh, smpl or joints (a folder of .bvh, SMPL-family .npz or joint-position .npy files; docs/shards.md)")
    b.add_argument("--body-model", metavar="PATH", help="--robots smpl: the SMPL / SMPL+H / SMPL-X model .npz or folder "
                   "(default: $MER_BODY_MODELS, else body_models in the user config)")
    b.add_argument("--up", choices=["x", "y", "z", "-x", "-y", "-z"], help="human files: their up axis (default: the reader's)")
    b.add_argument("--out", required=True, metavar="DIR", help="output folder")
    b.add_argument("--format", choices=FORMATS, default="hdf5", help="shard format (default hdf5)")
    b.add_argument("--window", type=int, default=60, help="frames per window (default 60)")
    b.add_argument("--stride", type=int, default=None, help="frames between window starts (default: the window)")
    b.add_argument("--fps", type=float, default=None, help="frame rate of the input files [Hz] (default: a CSV 30; human files "
                   "their own, joint positions without one 20); windows are 30 Hz")
    b.add_argument("--split", default="all", metavar="all|paper|FILE", help="all (default: every clip trains), paper (the paper's "
                   "split: 3 training clips per robot, the rest held out for evaluation), or a file of training clips")
    b.add_argument("--targets", nargs="+", default=list(PAPER_TARGETS), metavar="ROBOT", help="target robots (default: the paper's seven; 'all' = every registered robot)")
    b.add_argument("--augment", type=int, default=4, metavar="N", help="augmented target skeletons per training window and target (default 4)")
    b.add_argument("--seed", type=int, default=0, help="augmentation seed (default 0)")
    b.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N", help="worker processes (default: all cores)")
    b.add_argument("--shard-index", type=int, default=None, metavar="I", help="build only shard I (0-based) of --num-shards")
    b.add_argument("--num-shards", type=int, default=1, metavar="N", help="deal the clips into N disjoint shards (default 1)")
    b.add_argument("--keep-going", action="store_true", help="record failing clips and build the rest (exit status 1 if any failed)")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    b.set_defaults(func=cmd_build)

    i = ss.add_parser("inspect", help="format version, robots, counts, configuration and sizes of shards")
    i.add_argument("path", metavar="PATH", nargs="+", help="shard file(s) or folder(s)")
    i.add_argument("--json", action="store_true", help="machine-readable output")
    i.set_defaults(func=cmd_inspect)

    c = ss.add_parser("card", help="(re)write the dataset card of a shard folder from its metadata")
    c.add_argument("path", metavar="DIR", help="shard folder")
    c.add_argument("--out", metavar="FILE", help="where to write it (default DIR/README.md)")
    c.add_argument("--input-label", metavar="INPUT", help="input to show in the rebuild command (e.g. hf://OWNER/NAME)")
    c.set_defaults(func=cmd_card)

    u = ss.add_parser("push", help="upload a shard folder to a Hub dataset repository (shards, card, mer_meta.json)")
    u.add_argument("path", metavar="DIR", help="shard folder (one build)")
    u.add_argument("repo_id", metavar="REPO_ID", help="dataset repository OWNER/NAME (created if missing)")
    u.add_argument("--private", action="store_true", help="create the repository private")
    u.add_argument("--message", metavar="TEXT", help="commit message")
    u.add_argument("--ignore-license", action="store_true",
                   help="push LAFAN1-derived shards (CC BY-NC-ND 4.0) anyway: only if you hold the rights to distribute them")
    u.set_defaults(func=cmd_push)
    return ss


def cmd_build(args) -> int:
    from mer_data.shards import BuildConfig, build_shards

    try:
        synthetic = args.synthetic is not None
        human = any(r in ("bvh", "smpl", "joints") for r in args.robots)  # mer_data.motion.sources.HUMAN_SOURCES
        if not human and (args.body_model or args.up):
            raise ValueError("--body-model and --up read human files (--robots bvh|smpl|joints)")
        if synthetic and args.synthetic < 1:
            raise ValueError(f"--synthetic must be at least 1 clip per robot, got {args.synthetic}")
        config = BuildConfig(
            input="synthetic" if synthetic else args.input, robots=tuple(args.robots), format=args.format,
            window=args.window, stride=args.stride, fps=30.0 if human or args.fps is None else args.fps, split=args.split,
            body_model=args.body_model, up=args.up, human_fps=args.fps if human else None,
            targets=tuple(args.targets), augment=args.augment, seed=args.seed, num_shards=args.num_shards,
            synthetic=args.synthetic or 0, synthetic_seconds=args.synthetic_seconds, synthetic_seed=args.synthetic_seed,
        )  # fmt: skip
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(unit="clip", desc="shards", dynamic_ncols=True, file=sys.stderr)

    frames = [0]

    def progress(done: int, total: int, res) -> None:
        if bar is None:
            return
        bar.total = total
        if res is not None:
            frames[0] += res.record.get("frames", 0)
            bar.set_postfix_str(f"{res.task.robot}/{res.task.clip} {res.status}, {frames[0]} frames", refresh=False)
        bar.n = done
        bar.refresh()

    try:
        report = build_shards(
            config, args.out, workers=args.workers, shard_index=args.shard_index, keep_going=args.keep_going, progress=progress
        )
    finally:
        if bar is not None:
            bar.close()
    print(report.summary())
    print(f"split {config.split}: " + {"all": "every clip trains (--split paper: the paper's 3 training clips per robot, the rest eval)",
                                        "paper": "the paper's 3 training clips per robot, the rest eval (--split all: every clip trains)"}
          .get(config.split, "the training clips of the split file, the rest eval"))  # fmt: skip
    print(f"dataset card: {report.card}")
    return 1 if report.failed else 0


def cmd_inspect(args) -> int:
    from mer_data.shards import format_inspection, inspect_shards

    info = inspect_shards(args.path)
    print(json.dumps(info, indent=1) if args.json else format_inspection(info))
    return 0


def cmd_card(args) -> int:
    from mer_data.shards import write_card, write_sidecar

    print(write_card(args.path, input_label=args.input_label, dest=args.out))
    if args.out is None:
        print(write_sidecar(args.path))
    return 0


def cmd_push(args) -> int:
    from mer_data.shards import push_shards

    res = push_shards(args.path, args.repo_id, private=args.private, ignore_license=args.ignore_license, message=args.message)
    print(f"pushed {len(res.files)} file(s) to {res.repo_id} at {res.commit}")
    print(f"read it with ShardDataset(\"hf://datasets/{res.repo_id}@{res.commit}\")")
    return 0
