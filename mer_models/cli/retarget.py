"""``mer retarget``: a motion file, or a whole dataset, of a source robot → the same motions on target robots."""

from __future__ import annotations

import argparse
import sys


def check_refine(args: argparse.Namespace) -> None:
    """Refuse ``--refine K`` below 0 before any work starts (``mer retarget`` and ``mer evaluate``)."""
    if args.refine < 0:
        from mer_data.base.errors import MerError

        raise MerError(f"--refine must be >= 0, got {args.refine}", fix="give --refine K with K >= 0 (0: the model alone)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "retarget",
        help="retarget a LAFAN1-layout CSV to another robot",
        description="Retarget INPUT (CSV in the source robot's LAFAN1 layout) to the target robot. "
        "Outputs: CSV in the target's layout (-o), BeyondMimic npz, Foxglove MCAP, PNG film strip, GIF/MP4 video. "
        "Or a whole dataset: --input DIR|hf://REPO --targets ROBOT... --out DIR retargets every clip to every "
        "target (batched, resumable, --shard-index/--num-shards for array jobs; docs/model.md).",
    )
    p.add_argument("input", nargs="?", help="source motion, .csv or .csv.gz (root xyz, quat xyzw, joints)")
    p.add_argument("--source", required=True, help="robot of the input motion (e.g. g1)")
    p.add_argument("--target", help="robot to retarget to (e.g. h1)")
    d = p.add_argument_group("datasets")
    d.add_argument("--input", dest="input_dir", metavar="DIR|hf://REPO",
                   help="folder with SOURCE/*.csv[.gz] (LAFAN1 layout) or *.csv[.gz], or a Hub dataset hf://OWNER/NAME[@REV]")
    d.add_argument("--targets", nargs="+", help="robots to retarget every clip to")
    d.add_argument("--out", help="output folder: OUT/TARGET/CLIP.csv (+ .npz), CLIP.metrics.json, summary.json")
    d.add_argument("--formats", nargs="+", default=["csv"], choices=["csv", "npz"], help="files per clip (default csv)")
    d.add_argument("--shard-index", type=int, default=0, help="this job's share of the (target, clip) pairs (0-based)")
    d.add_argument("--num-shards", type=int, default=1, help="number of jobs sharing the dataset")
    d.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("-o", "--output", help="output CSV in the target's LAFAN1-style layout")
    p.add_argument("--npz", help="also write an npz in the mjlab / BeyondMimic layout (docs/trackers.md)")
    p.add_argument("--npz-fps", type=float, default=50.0, help="frame rate of npz outputs [Hz] (default 50, the trackers' rate; "
                   "resampled like csv_to_npz: lerp + slerp)")
    p.add_argument("--npz-order", choices=["mjlab", "isaaclab"], default="mjlab",
                   help="joint/body order of the npz: mjlab (default; URDF order, as MuJoCo/mjlab) or isaaclab "
                   "(breadth-first, as Isaac Lab/BeyondMimic; verified robots only: g1) (docs/trackers.md)")
    p.add_argument("--mcap", help="also write a Foxglove MCAP")
    p.add_argument("--plot", help="also write a PNG of stick figures over time")
    p.add_argument("--video", metavar="OUT.gif|OUT.mp4", help="also write a video: the scaled reference and the retarget side by "
                   "side (GIF: base install; MP4: needs ffmpeg)")
    p.add_argument("--video-fps", type=float, help="frame rate of the video [Hz] (default: the motion's 30; lower renders faster)")
    p.add_argument("--model", help="checkpoint folder, zoo name or ORG/NAME for --method diffusion "
                   "(default: the bundled model mer-base, trained on synthetic motion only)")
    p.add_argument("--method", choices=["diffusion", "optimize"], help="default: diffusion for a file, optimize for a dataset")
    p.add_argument("--steps", type=int, help="sampler steps (default: the model's, <= 20)")
    p.add_argument("--guidance", type=float, help="test-time energy guidance step (default: the model's)")
    p.add_argument("--seed", type=int, default=0, help="sampling seed")
    p.add_argument("--refine", type=int, default=0, metavar="K", help="diffusion: then at most K optimiser iterations from the "
                   "model's output (fast and exact; default 0: the model alone)")
    p.add_argument("--bf16", action="store_true", help="diffusion: the network in bfloat16 (about twice as fast on CPUs with AMX "
                   "or AVX512-BF16 and on GPUs, within 0.5 mm of float32 on LAFAN1; emulated and slower elsewhere: a warning says so)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the input (resampled to 30 Hz)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--allow-unseen", action="store_true", help="retarget to a robot the model never saw (zero-shot)")
    p.add_argument("--physics", action=argparse.BooleanOptionalAction, default=True,
                   help="the optimiser (--method optimize, --refine) keeps every body above the floor and every joint "
                        "within its URDF speed limit (default; about half the frames/s: --no-physics for key points "
                        "alone; docs/decisions.md, Physical terms of the optimiser)")
    p.set_defaults(func=cmd_retarget)


def physics_option(args):
    """The optimiser's physical terms (their default weights), None with ``--no-physics``."""
    if not args.physics:
        return None
    from mer_models.solver.physics import PhysicsConfig

    return PhysicsConfig()


def cmd_retarget(args) -> int:
    from mer_data.base.errors import MerError
    from mer_models.retarget.clip import retarget_file

    if args.input_dir is not None or args.targets is not None:
        return _dataset(args)
    if args.input is None or args.target is None:
        raise MerError("give an INPUT file and --target, or a dataset: --input DIR --targets ROBOT... --out DIR")
    args.method = args.method or "diffusion"
    if not any([args.output, args.npz, args.mcap, args.plot, args.video]):
        raise MerError("nothing to write", fix="give -o OUT.csv and/or --npz/--mcap/--plot/--video")
    check_refine(args)
    kw = {"steps": args.steps, "guidance": args.guidance, "seed": args.seed, "allow_unseen": args.allow_unseen, "refine": args.refine,
          "bf16": args.bf16}  # fmt: skip
    if args.method == "optimize":
        if args.refine:
            raise MerError("--refine refines a model's output", fix="use it with --method diffusion (the optimiser alone needs no refinement)")
        if args.bf16:
            raise MerError("--bf16 runs the model's network in bfloat16; the optimiser has no network", fix="drop --bf16, or use --method diffusion")
        kw = {}
    model = args.model
    if model is None and args.method == "diffusion":
        from mer_models.zoo import DEFAULT_MODEL

        model = DEFAULT_MODEL
        print(f"no --model: using the bundled model {model!r} (trained on synthetic motion only; `mer zoo info {model}`)", file=sys.stderr)
    res = retarget_file(
        args.input, args.source, args.target, out_csv=args.output, npz=args.npz, mcap=args.mcap, plot=args.plot,
        video=args.video, video_fps=args.video_fps,
        model=model, method=args.method, input_fps=args.fps, device=args.device, npz_fps=args.npz_fps, npz_order=args.npz_order,
        physics=physics_option(args), **kw,
    )  # fmt: skip
    m = res.motion
    print(f"{args.source} -> {args.target} ({res.method}): {m.num_frames} frames at {m.fps:g} Hz", file=sys.stderr)
    for kind, path in res.outputs.items():
        print(f"wrote {kind}: {path}")
    return 0


def _dataset(args) -> int:
    import json

    from mer_data.base.errors import MerError
    from mer_models.retarget.dataset import format_summary, retarget_dataset

    missing = [n for n, v in (("--input", args.input_dir), ("--targets", args.targets), ("--out", args.out)) if v is None]
    if missing or args.input is not None or args.target is not None:
        raise MerError(
            "a dataset run takes --input DIR, --targets and --out (and no INPUT file or --target)"
            + (f"; missing: {', '.join(missing)}" if missing else ""),
            fix="e.g. mer retarget --input lafan1/ --source g1 --targets h1 atlas --out retargeted/",
        )
    if args.npz_order != "mjlab":
        raise MerError(f"--npz-order {args.npz_order} is for single-file runs; dataset runs write the mjlab order",
                       fix="drop --npz-order, or retarget the clips one by one (mer retarget CLIP.csv --npz OUT.npz --npz-order isaaclab)")
    if args.video is not None:
        raise MerError("--video writes one file's video; a dataset run does not make videos",
                       fix="retarget the clip you want to see on its own: mer retarget CLIP.csv --source ... --target ... --video OUT.gif")
    method = args.method or "optimize"
    check_refine(args)
    if args.refine and method != "diffusion":
        raise MerError("--refine refines a model's output", fix="use it with --method diffusion (the optimiser alone needs no refinement)")
    if args.bf16 and method != "diffusion":
        raise MerError("--bf16 runs the model's network in bfloat16; the optimiser has no network", fix="drop --bf16, or add --method diffusion")
    checkpoint, kw = None, {}
    if method == "diffusion":
        from mer_models.zoo import DEFAULT_MODEL
        from mer_models.zoo.checkpoint import resolve_model

        checkpoint = resolve_model(args.model or DEFAULT_MODEL, args.device)
        kw = {"steps": args.steps, "guidance": args.guidance, "seed": args.seed, "allow_unseen": args.allow_unseen, "bf16": args.bf16,
              "refine": args.refine}  # fmt: skip
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(unit="clip", file=sys.stderr, desc="retarget")

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()

    try:
        summary = retarget_dataset(
            args.input_dir, args.source, args.targets, args.out, method=method, checkpoint=checkpoint,
            formats=args.formats, shard_index=args.shard_index, num_shards=args.num_shards, input_fps=args.fps, npz_fps=args.npz_fps,
            device=args.device, progress=progress, physics=physics_option(args), **kw,
        )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    print(json.dumps(summary, indent=1) if args.json else format_summary(summary))
    return 0
