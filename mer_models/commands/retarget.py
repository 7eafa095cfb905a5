"""``mer retarget``: one motion file of a source robot → the same motion on a target robot."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "retarget",
        help="retarget a LAFAN1-layout CSV to another robot",
        description="Retarget INPUT (CSV in the source robot's LAFAN1 layout) to the target robot. "
        "Outputs: CSV in the target's layout (-o), BeyondMimic npz, Foxglove MCAP, PNG film strip.",
    )
    p.add_argument("input", help="source motion, .csv or .csv.gz (root xyz, quat xyzw, joints)")
    p.add_argument("--source", required=True, help="robot of the input motion (e.g. g1)")
    p.add_argument("--target", required=True, help="robot to retarget to (e.g. h1)")
    p.add_argument("-o", "--output", help="output CSV in the target's LAFAN1-style layout")
    p.add_argument("--npz", help="also write a BeyondMimic-style npz")
    p.add_argument("--mcap", help="also write a Foxglove MCAP")
    p.add_argument("--plot", help="also write a PNG of stick figures over time")
    p.add_argument("--model", help="checkpoint folder, zoo name or ORG/NAME for --method diffusion "
                   "(default: the bundled model mer-tiny-synthetic, for demos only)")
    p.add_argument("--method", default="diffusion", choices=["diffusion", "optimize"], help="default diffusion")
    p.add_argument("--steps", type=int, help="sampler steps (default: the model's, <= 20)")
    p.add_argument("--guidance", type=float, help="test-time energy guidance step (default: the model's)")
    p.add_argument("--seed", type=int, default=0, help="sampling seed")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of the input (resampled to 30 Hz)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--allow-unseen", action="store_true", help="retarget to a robot the model never saw (zero-shot)")
    p.set_defaults(func=cmd_retarget)


def cmd_retarget(args) -> int:
    from mer_data.errors import MerError
    from mer_models.retarget import retarget_file

    if not any([args.output, args.npz, args.mcap, args.plot]):
        raise MerError("nothing to write", fix="give -o OUT.csv and/or --npz/--mcap/--plot")
    kw = {"steps": args.steps, "guidance": args.guidance, "seed": args.seed, "allow_unseen": args.allow_unseen}
    if args.method == "optimize":
        kw = {}
    model = args.model
    if model is None and args.method == "diffusion":
        from mer_models.zoo import DEFAULT_MODEL

        model = DEFAULT_MODEL
        print(f"no --model: using the bundled demo model {model!r} (synthetic training, not for real use)", file=sys.stderr)
    res = retarget_file(
        args.input, args.source, args.target, out_csv=args.output, npz=args.npz, mcap=args.mcap, plot=args.plot,
        model=model, method=args.method, input_fps=args.fps, device=args.device, **kw,
    )  # fmt: skip
    m = res.motion
    print(f"{args.source} -> {args.target} ({res.method}): {m.num_frames} frames at {m.fps:g} Hz", file=sys.stderr)
    for kind, path in res.outputs.items():
        print(f"wrote {kind}: {path}")
    return 0
