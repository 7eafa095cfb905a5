"""``mer evaluate``: the paper's metrics per robot, in-domain and out-of-domain."""

from __future__ import annotations

import argparse
import json
import sys

from .retarget import add_human_options, add_physics_method, bvh_options, check_refine, physics_option


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="metrics of a model (and the optimisation baseline) on LAFAN1-layout motions",
        description="Evaluate on INPUT/<source>/*.csv: 60-frame windows of the split's training clips "
        "(in-domain) and held-out clips (out-of-domain), retargeted to every --targets robot.",
    )
    p.add_argument("--model", help="checkpoint folder (or zoo name); needed for --methods model")
    p.add_argument("--input", required=True, help="folder with <robot>/*.csv motions (e.g. LAFAN1 g1/ h1/)")
    p.add_argument("--source", default="g1", help="reference robot (default g1)")
    p.add_argument("--targets", nargs="+", required=True, help="target robots")
    p.add_argument("--split", default="paper", help="paper, all, or a split file (default paper)")
    p.add_argument("--methods", nargs="+", default=None, choices=["model", "refine", "optimize"],
                   help="default: model and optimize (optimize only without --model); refine: the model, then --refine K optimiser iterations")
    p.add_argument("--refine", type=int, default=5, metavar="K", help="optimiser iterations of the refine method (default 5)")
    p.add_argument("--stride", type=int, default=60, help="window stride [frames] (default 60)")
    p.add_argument("--max-windows", type=int, help="at most N windows per domain, spread over the clips")
    p.add_argument("--steps", type=int, help="sampler steps (default: the model's)")
    p.add_argument("--guidance", type=float, help="test-time energy guidance step (default: the model's)")
    p.add_argument("--bf16", action="store_true", help="the model's network in bfloat16 (model and refine methods; fast on CPUs "
                   "with AMX or AVX512-BF16 and on GPUs, emulated and slower elsewhere)")
    p.add_argument("--init-noise", type=float, help="scale of the sampler's initial noise, 0-1 (0: deterministic; default: the model's)")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--opt-iters", type=int, default=None, help="Adam iterations of the optimiser's second stage (default 0: off)")
    p.add_argument("--opt-gn-iters", type=int, default=None, help="most Levenberg-Marquardt iterations of the optimiser (default 30; stops once converged)")
    p.add_argument("--scaling", default="segments", choices=["segments", "parts"],
                   help="how the reference is scaled to each target: per segment (default) or the paper's per body part")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.add_argument("--physics", action=argparse.BooleanOptionalAction, default=True,
                   help="the optimiser (methods optimize and refine) with its physical terms, as mer retarget (default; "
                        "--no-physics: key points alone, the paper's energy)")
    add_physics_method(p)
    p.add_argument("--balance", action="store_true",
                   help="the optimiser (methods optimize and refine) with the balance term, as mer retarget --balance "
                        "(docs/model.md §Balance)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--save", help="also write the JSON report to this file")
    b = p.add_argument_group("humans (--source bvh|smpl|joints: DIR/<source>/* or DIR/*.bvh|.npz|.npy)")
    b.add_argument("--bvh-units", choices=["m", "cm", "mm", "in"], help="length unit of the BVH files (default: from the figure's size)")
    b.add_argument("--bvh-up", choices=["y", "z"], help="up axis of the BVH files (default: detected)")
    b.add_argument("--bvh-keypoints", metavar="FILE", help="key point -> BVH joint overrides (YAML or JSON)")
    add_human_options(p)
    p.add_argument("--fps", type=float, default=None, help="frame rate of SMPL / joint-position files that say none [Hz] "
                   "(default: joint positions 20, SMPL 30)")
    p.set_defaults(func=cmd_evaluate)


def _balance(args, methods):
    """The balance term's configuration with ``--balance``, else None; refused where no method runs the optimiser."""
    if not args.balance:
        return None
    if not {"optimize", "refine"} & set(methods):
        from mer_data.base.errors import MerError

        raise MerError("--balance works in the optimiser, and none of these methods runs it: " + ", ".join(methods),
                       fix="add --methods optimize (or refine)")  # fmt: skip
    from mer_models.solver.balance_term import BalanceConfig

    return BalanceConfig()


def cmd_evaluate(args) -> int:
    from mer_data.base.atomic import atomic_write
    from mer_models.retarget.evaluate import EvalOptions, evaluate, format_table
    from mer_models.zoo.checkpoint import resolve_model

    check_refine(args)
    ckpt = resolve_model(args.model, args.device) if args.model else None
    methods = tuple(args.methods or (("model", "optimize") if ckpt is not None else ("optimize",)))
    opts = EvalOptions(split=args.split, stride=args.stride, max_windows=args.max_windows, methods=methods,
                       steps=args.steps, guidance=args.guidance, init_noise=args.init_noise, batch_size=args.batch_size, seed=args.seed, scaling=args.scaling, refine=args.refine, bf16=args.bf16,
                       physics=physics_option(args), balance=_balance(args, methods), bvh=bvh_options(args) if args.source.lower() in ("bvh", "smpl", "joints") else None,
                       **{k: v for k, v in {"opt_iters": args.opt_iters, "opt_gn_iters": args.opt_gn_iters}.items() if v is not None})  # fmt: skip
    report = evaluate(args.input, args.source, args.targets, checkpoint=ckpt, opts=opts,
                      progress=lambda s: print(s, file=sys.stderr))  # fmt: skip
    text = json.dumps(report, indent=2)
    if args.save:
        atomic_write(args.save, (text + "\n").encode())
    print(text if args.json else format_table(report))
    return 0
