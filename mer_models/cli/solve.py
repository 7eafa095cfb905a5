"""``mer shards solve``: teacher targets (the optimiser's solution of every training sample)."""

from __future__ import annotations

import argparse
import json
import sys

from mer_data.base.errors import MerError


def add_parser(ss: argparse._SubParsersAction) -> None:
    p = ss.add_parser(
        "solve",
        help="solve every training sample of shards with the optimiser (teacher targets for training)",
        description="Retarget every sample (window x target x augmentation) of the shards with the optimiser and "
        "store the solutions in teacher files (SHARD_DIR/teacher/<shard>.h5 by default); `mer train` then "
        "learns from them. Resumable: run the same command again after a kill.",
    )
    p.add_argument("path", nargs="+", metavar="PATH", help="shard file(s) or folder(s)")
    p.add_argument("--out", metavar="DIR", help="folder of the teacher files (default: teacher/ beside the shards)")
    p.add_argument("--gn-iters", type=int, default=None, metavar="N", help="most Levenberg-Marquardt iterations (default: the optimiser's)")
    p.add_argument("--scaling", choices=["segments", "parts"], default="segments", help="reference scaling (default segments)")
    p.add_argument("--optimizer-version", type=int, choices=[1, 2], default=None, metavar="V",
                   help="the optimiser's schedule: 2 (default) finishes with whole-window iterations, 1 with Jacobi "
                        "ones, as teachers solved before version 2 were (docs/model.md, The optimiser)")
    p.add_argument("--physics", action=argparse.BooleanOptionalAction, default=True,
                   help="the optimiser's physical terms, as mer retarget (default; --no-physics: key points alone, "
                        "as teachers solved before them)")
    p.add_argument("--physics-method", choices=["penalty", "constraints"], default=None,
                   help="how the physical terms are met, as mer retarget --physics-method: constraints (the default: the plain "
                        "solve, then the least change that meets them) or penalty (weighted terms and goal edits; docs/model.md)")
    p.add_argument("--batch", type=int, default=64, metavar="N", help="windows solved together (default 64)")
    p.add_argument("--shard-index", type=int, default=None, metavar="I", help="solve only shard files i with i %% N == I")
    p.add_argument("--num-shards", type=int, default=1, metavar="N", help="number of parallel jobs (default 1)")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="CPU threads of this job (default: PyTorch's, one per core); give N jobs on one machine "
                        "cores/N each (two jobs of 2 threads on 2 cores run several times slower than of 1; docs/shards.md)")
    p.add_argument("--force", action="store_true", help="solve again where a teacher file of another configuration exists")
    p.add_argument("--json", action="store_true", help="print the per-shard records as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_solve)


def cmd_solve(args) -> int:
    from mer_models.training.teacher import SolverConfig, solve_shards

    if args.batch < 1:
        raise MerError("--batch must be >= 1")
    if args.threads is not None:
        if args.threads < 1:
            raise MerError(f"--threads must be >= 1, got {args.threads}", fix="--threads 1 for one job per core")
        import torch

        torch.set_num_threads(args.threads)
    kw = {"scaling": args.scaling, "batch": args.batch}
    if not args.physics:
        if args.physics_method is not None:
            raise MerError("--physics-method with --no-physics: there are no physical terms to meet", fix="drop one of the two")
        kw["physics"] = None
    elif args.physics_method is not None:
        from mer_models.solver.physics import PhysicsConfig

        kw["physics"] = PhysicsConfig(method=args.physics_method)
    if args.gn_iters is not None:
        if args.gn_iters < 1:
            raise MerError("--gn-iters must be >= 1")
        kw["gn_iters"] = args.gn_iters
    if args.optimizer_version is not None:
        kw["optimizer_version"] = args.optimizer_version
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(unit="sample", desc="solve", dynamic_ncols=True, file=sys.stderr)

    def progress(done: int, total: int, msg: str) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.set_postfix_str(msg, refresh=False)
            bar.refresh()

    try:
        recs = solve_shards(args.path, solver=SolverConfig(**kw), out=args.out, shard_index=args.shard_index,
                            num_shards=args.num_shards, force=args.force, device=args.device, progress=progress)  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    if args.json:
        print(json.dumps(recs, indent=2))
    else:
        for r in recs:
            print(f"{r['teacher']}: {r['samples']} samples, {r['status']}, {r['frames_per_s']:.0f} frames/s, mean energy {r['energy_mean']:.2e}")
    return 0
