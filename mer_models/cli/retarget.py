"""``mer retarget``: a motion file, or a whole dataset, of a source robot → the same motions on target robots."""

from __future__ import annotations

import argparse
import sys


def check_refine(args: argparse.Namespace) -> None:
    """Refuse ``--refine K`` below 0 before any work starts (``mer retarget`` and ``mer evaluate``)."""
    if args.refine is not None and args.refine < 0:
        from mer_data.base.errors import MerError

        raise MerError(f"--refine must be >= 0, got {args.refine}", fix="give --refine K with K >= 0 (0: the model alone)")


def model_options(args: argparse.Namespace) -> list[str]:
    """The model options given (each only means something to a model), as typed: ``["--model mer-base", "--bf16"]``."""
    given = (("--model", args.model), ("--refine", args.refine), ("--steps", args.steps), ("--guidance", args.guidance))
    return [f"{flag} {value}" for flag, value in given if value is not None] + (["--bf16"] if args.bf16 else [])


def choose_method(args: argparse.Namespace, human: bool) -> tuple[str, str | None]:
    """The method and why (docs/model.md, The default path): ``--method`` as given, else the model when a
    model option is given, else the optimiser. A model option the chosen path would ignore is refused, never
    dropped: a human (BVH) source has only the optimiser (no model has seen a human source), and
    ``--method optimize`` runs no model."""
    from mer_data.base.errors import MerError

    given = model_options(args)
    if human and (given or args.method == "diffusion"):
        what = " ".join(given) or "--method diffusion"
        raise MerError(f"{what}: a model cannot retarget a human source (BVH, SMPL family, joint positions): mer's models were trained on robot motion "
                       "only and have never seen a human skeleton, so the model option would be ignored",
                       fix="drop it: a human source is retargeted by the optimiser (the default path); to use a model, "
                       "retarget a robot's motion (e.g. the optimiser's output CSV) with --model")  # fmt: skip
    if args.method == "optimize" and given:
        raise MerError(f"{' '.join(given)}: --method optimize runs no model, so the model option would be ignored",
                       fix="drop it, or use --method diffusion (a model option without --method selects the model)")
    if args.method is not None:
        return args.method, None
    if given:
        return "diffusion", f"a model option was given ({' '.join(given)})"
    return "optimize", "the default, the most accurate path; --method diffusion --refine 5 for the model"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "retarget",
        help="retarget a robot's LAFAN1-layout CSV, or a human (BVH, SMPL-family .npz, joint-position .npy), to a robot",
        description="Retarget INPUT (CSV in the source robot's LAFAN1 layout, or a human: .bvh motion capture, an SMPL / SMPL+H "
        "/ SMPL-X parameter .npz (AMASS, video estimators), or T x 22|24 x 3 joint positions .npy (HumanML3D)) to the "
        "target robot; the file's type comes from its content. "
        "Outputs: CSV in the target's layout (-o), a motion tracker's npz (mjlab or BeyondMimic), Foxglove MCAP, PNG film "
        "strip, GIF/MP4 video. "
        "Or a whole dataset: --input DIR|hf://REPO --targets ROBOT... --out DIR retargets every clip to every "
        "target (batched, resumable, --shard-index/--num-shards for array jobs; docs/model.md).",
    )
    p.add_argument("input", nargs="?", help="source motion: .csv or .csv.gz of a robot (root xyz, quat xyzw, joints), "
                   "or a human: .bvh, SMPL-family .npz, joint-position .npy")
    p.add_argument("--source", help="robot of the input motion (e.g. g1), or a human: bvh, smpl or joints "
                   "(default for a human file: its kind)")
    b = p.add_argument_group("human motion capture (BVH)")
    b.add_argument("--bvh-units", choices=["m", "cm", "mm", "in"], help="length unit of the BVH (default: from the figure's size)")
    b.add_argument("--bvh-up", choices=["y", "z"], help="up axis of the BVH (default: detected from where the head is)")
    b.add_argument("--bvh-keypoints", metavar="FILE", help="YAML or JSON mapping key point -> BVH joint name, for the key "
                   "points the name patterns miss or get wrong (partial is fine; docs/motion.md)")
    add_human_options(p)
    p.add_argument("--target", help="robot to retarget to (e.g. h1)")
    d = p.add_argument_group("datasets")
    d.add_argument("--input", dest="input_dir", metavar="DIR|hf://REPO",
                   help="folder with SOURCE/*.csv[.gz] (LAFAN1 layout) or *.csv[.gz], or a Hub dataset hf://OWNER/NAME[@REV]")
    d.add_argument("--targets", nargs="+", help="robots to retarget every clip to")
    d.add_argument("--out", help="output folder: OUT/TARGET/CLIP.csv (+ .npz), CLIP.metrics.json, summary.json")
    d.add_argument("--formats", nargs="+", default=["csv"], choices=["csv", "npz"],
                   help="files per clip (default csv; npz needs --npz-for)")
    d.add_argument("--shard-index", type=int, default=0, help="this job's share of the (target, clip) pairs (0-based)")
    d.add_argument("--num-shards", type=int, default=1, help="number of jobs sharing the dataset")
    d.add_argument("--workers", type=int, metavar="N", help="processes for the optimiser, one thread each (default: the cores "
                   "this process may use; the files do not depend on N)")
    d.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("-o", "--output", help="output CSV in the target's LAFAN1-style layout")
    p.add_argument("--npz", help="also write the npz a motion tracker reads; needs --npz-for (docs/trackers.md)")
    p.add_argument("--npz-fps", type=float, default=50.0, help="frame rate of npz outputs [Hz] (default 50, the trackers' rate; "
                   "resampled like csv_to_npz: lerp + slerp)")
    p.add_argument("--npz-for", choices=["mjlab", "beyondmimic"],
                   help="the tracker that reads the npz (required with --npz and --formats npz): mjlab (MuJoCo's "
                   "depth-first joint/body order) or beyondmimic (Isaac Lab's breadth-first order); each reads its own "
                   "order without checking names (docs/trackers.md)")
    p.add_argument("--mcap", help="also write a Foxglove MCAP")
    p.add_argument("--plot", help="also write a PNG of stick figures over time")
    p.add_argument("--video", metavar="OUT.gif|OUT.mp4", help="also write a video: the scaled reference and the retarget side by "
                   "side (GIF: base install; MP4: needs ffmpeg)")
    p.add_argument("--video-range", metavar="START:END", help="the part of the motion the video shows [s] (default: the "
                   "first 10 s; 30: = from 30 s to the end)")
    p.add_argument("--video-fps", type=float, help="frame rate of the video [Hz] (default: the motion's 30; lower renders faster)")
    p.add_argument("--model", help="checkpoint folder, zoo name or ORG/NAME; selects --method diffusion (without it, "
                   "--method diffusion uses the bundled model mer-base, trained on synthetic motion only)")
    p.add_argument("--method", choices=["diffusion", "optimize"],
                   help="default: optimize (the most accurate path on a CPU); diffusion when a model option (--model, --refine, "
                   "--steps, --guidance, --bf16) is given; a BVH source has the optimiser only")
    p.add_argument("--steps", type=int, help="sampler steps (default: the model's, <= 20)")
    p.add_argument("--guidance", type=float, help="test-time energy guidance step (default: the model's)")
    p.add_argument("--seed", type=int, default=0, help="sampling seed")
    p.add_argument("--refine", type=int, default=None, metavar="K", help="diffusion: then at most K optimiser iterations from the "
                   "model's output (fast and exact; default: the model's own, 0 for a diffusion model, 2 for a warm start)")
    p.add_argument("--bf16", action="store_true", help="diffusion: the network in bfloat16 (about twice as fast on CPUs with AMX "
                   "or AVX512-BF16 and on GPUs, within 0.5 mm of float32 on LAFAN1; emulated and slower elsewhere: a warning says so)")
    p.add_argument("--fps", type=float, default=None, help="frame rate of the input [Hz] (default: a CSV 30, joint positions "
                   "20 (HumanML3D's), SMPL the file's own, else 30; resampled to 30 Hz)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--allow-unseen", action="store_true", help="retarget to a robot the model never saw (zero-shot)")
    p.add_argument("--physics", action=argparse.BooleanOptionalAction, default=True,
                   help="the optimiser (--method optimize, --refine) keeps every body above the floor and every joint "
                        "within its URDF speed limit (default; 0.1-0.4x the frames/s: --no-physics for key points "
                        "alone; docs/decisions.md, Physical terms of the optimiser); a human source's stance feet also "
                        "stay on the floor without sliding while the human's foot is down (docs/model.md)")
    add_physics_method(p)
    p.add_argument("--balance", action="store_true",
                   help="the optimiser (--method optimize, --refine) also keeps the zero-moment point in the support polygon "
                        "and flight ballistic, moving the base's horizontal path with the body above the legs (opt-in; "
                        "2-9x slower, measured; docs/model.md §Balance)")
    p.set_defaults(func=cmd_retarget)


def balance_option(args):
    """The balance term (:class:`~mer_models.solver.balance_term.BalanceConfig`, its defaults) with ``--balance``,
    else None; refused where no optimiser stage runs (the model alone)."""
    if not getattr(args, "balance", False):
        return None
    if args.method != "optimize" and not args.refine:
        from mer_data.base.errors import MerError

        raise MerError("--balance works in the optimiser, and this run has none (the model alone)",
                       fix="add --method optimize, or --refine K with K > 0")  # fmt: skip
    from mer_models.solver.balance_term import BalanceConfig

    return BalanceConfig()


def add_physics_method(p) -> None:
    """``--physics-method`` (``mer retarget``, ``mer evaluate``)."""
    p.add_argument("--physics-method", choices=["constraints", "penalty"], default=None,
                   help="how the physical terms are met: constraints (the default: the plain solve, then the least "
                        "change that meets them) or penalty (weighted terms, goal edits and repair rounds); "
                        "docs/decisions.md §Physics as constraints")


def physics_option(args):
    """The optimiser's physical terms (their default weights and ``--physics-method``, the constraint method by
    default; a human source's with its own no-slip weight, :func:`~mer_models.retarget.clip.human_physics`),
    None with ``--no-physics``."""
    from mer_data.base.errors import MerError

    method = getattr(args, "physics_method", None)
    if not args.physics:
        if method is not None:
            raise MerError("--physics-method with --no-physics: there are no physical terms to meet", fix="drop one of the two")
        return None
    from mer_data.motion.sources import HUMAN_SOURCES
    from mer_models.retarget.clip import human_physics
    from mer_models.solver.physics import PhysicsConfig

    human = isinstance(getattr(args, "source", None), str) and args.source.lower() in HUMAN_SOURCES
    if method is None:
        return human_physics() if human else PhysicsConfig()
    return human_physics() if human and method == "constraints" else PhysicsConfig(method=method)


def add_human_options(p) -> None:
    """``--body-model`` and ``--up`` (SMPL-family and joint-position sources; ``mer retarget``, ``evaluate``)."""
    h = p.add_argument_group("SMPL-family parameters and joint positions (--source smpl|joints)")
    h.add_argument("--body-model", metavar="PATH", help="SMPL / SMPL+H / SMPL-X model .npz, or the folder holding smplx/, "
                   "smplh/, smpl/ (default: $MER_BODY_MODELS, else body_models in the user config; docs/kinematics.md)")
    h.add_argument("--up", choices=["x", "y", "z", "-x", "-y", "-z"], help="up axis of an SMPL or joint-position file "
                   "(default: AMASS z, joint positions and video estimators detected from where the head is)")


def bvh_options(args):
    """The human reading options of ``--bvh-units``, ``--bvh-up``, ``--bvh-keypoints``, ``--body-model``, ``--up``, ``--fps``."""
    from mer_data.base.errors import MerError
    from mer_data.motion.sources import BvhOptions, load_bvh_keypoints

    keypoints = load_bvh_keypoints(args.bvh_keypoints) if args.bvh_keypoints else None
    up = getattr(args, "up", None)
    if up is not None and args.bvh_up is not None:
        raise MerError("give --bvh-up (BVH) or --up (SMPL, joints), not both")
    return BvhOptions(units=args.bvh_units, up=up or args.bvh_up, keypoints=keypoints,
                      body_model=getattr(args, "body_model", None), fps=getattr(args, "fps", None))  # fmt: skip


def resolve_source(args, path) -> None:
    """``--source`` from a human input's kind when not given (the file's content); refuse a missing
    one for a CSV."""
    from mer_data.base.errors import MerError
    from mer_data.motion.sources import human_kind

    if args.source is None:
        kind = human_kind(path, None) if path is not None else None
        if kind is not None:
            args.source = kind
        else:
            raise MerError("--source is required for robot motion", fix="name the robot of the input, e.g. --source g1 "
                           "(or --source bvh|smpl|joints for a folder of human files)")  # fmt: skip


def cmd_retarget(args) -> int:
    from mer_data.base.errors import MerError
    from mer_data.motion.sources import HUMAN_SOURCES

    if args.input_dir is not None or args.targets is not None:
        resolve_source(args, None)
        return _dataset(args)
    if args.input is None or args.target is None:
        raise MerError("give an INPUT file and --target, or a dataset: --input DIR --targets ROBOT... --out DIR")
    resolve_source(args, args.input)
    human = args.source.lower() in HUMAN_SOURCES
    args.method, why = choose_method(args, human)
    if not any([args.output, args.npz, args.mcap, args.plot, args.video]):
        raise MerError("nothing to write", fix="give -o OUT.csv and/or --npz/--mcap/--plot/--video")
    if args.npz is not None:
        from mer_models.export.writers import require_tracker

        require_tracker(args.npz_for)
    check_refine(args)
    kw = {"steps": args.steps, "guidance": args.guidance, "seed": args.seed, "allow_unseen": args.allow_unseen, "refine": args.refine,
          "bf16": args.bf16}  # fmt: skip
    if args.method == "optimize":
        kw = {}
    if args.balance:
        kw["balance"] = balance_option(args)
    model = args.model
    if model is None and args.method == "diffusion":
        from mer_models.zoo import DEFAULT_MODEL

        model = DEFAULT_MODEL
        print(f"no --model: using the bundled model {model!r} (trained on synthetic motion only; `mer zoo info {model}`)", file=sys.stderr)
    bar, cm = _solver_bar(args.quiet)
    with cm:
        res = _retarget_one(args, model, human, kw)
    if bar is not None:
        bar.close()
    m = res.motion
    print(f"{args.source} -> {args.target} ({res.method}{': ' + why if why else ''}): {m.num_frames} frames at {m.fps:g} Hz",
          file=sys.stderr)  # fmt: skip
    for note in res.notes:
        print(note, file=sys.stderr)
    for kind, path in res.outputs.items():
        print(f"wrote {kind}: {path}", file=sys.stderr if args.json else sys.stdout)
    if args.json:
        import json

        print(json.dumps({"method": res.method, "frames": m.num_frames, "outputs": {k: str(v) for k, v in res.outputs.items()},
                          "metrics": _plain(res.metrics), "notes": res.notes}, indent=1))  # fmt: skip
    else:
        print(format_metrics(res.metrics, args.target))
    return 0


def _plain(metrics: dict | None) -> dict:
    """JSON-ready metrics: floats, None for NaN, the lists as they are."""
    import math

    out = {}
    for k, v in (metrics or {}).items():
        if isinstance(v, float) and not math.isfinite(v):
            v = None
        if isinstance(v, (int, float, str, list, type(None))):
            out[k] = v
    return out


def format_metrics(metrics: dict | None, target: str) -> str:
    """One table row of the paper's metrics and the artifact figures (docs/model.md), as dataset runs print them."""
    if not metrics:
        return ""
    from mer_models.retarget.columns import metric_cells, metric_header, metric_legend

    return f"{'target':10s} {metric_header()}\n{target:10s} {metric_cells(metrics)}\n{metric_legend()}"


def _solver_bar(quiet: bool):
    """A progress bar of the solver's iterations on stderr (none when quiet or not a terminal)."""
    import contextlib

    if quiet or not sys.stderr.isatty():
        return None, contextlib.nullcontext()
    from tqdm import tqdm

    from mer_models.solver.progress import solver_progress

    bar = tqdm(unit="it", file=sys.stderr, desc="retarget", dynamic_ncols=True, leave=False)

    def update(stage: str, done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.set_description(stage, refresh=False)
        bar.refresh()

    return bar, solver_progress(update)


def _video_range(args):
    if getattr(args, "video_range", None) is None:
        return None
    from mer_models.export.video import parse_time_range

    return parse_time_range(args.video_range)


def _retarget_one(args, model, human: bool, kw: dict):
    from mer_models.retarget.clip import retarget_file

    return retarget_file(
        args.input, args.source, args.target, out_csv=args.output, npz=args.npz, mcap=args.mcap, plot=args.plot,
        video=args.video, video_fps=args.video_fps, video_range=_video_range(args),
        model=model, method=args.method, input_fps=args.fps or 30.0, device=args.device, npz_fps=args.npz_fps, npz_for=args.npz_for,
        physics=physics_option(args), bvh=bvh_options(args) if human else None, metrics=True, **kw,
    )  # fmt: skip


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
    if "npz" in args.formats:
        from mer_models.export.writers import require_tracker

        require_tracker(args.npz_for)
    if args.video is not None:
        raise MerError("--video writes one file's video; a dataset run does not make videos",
                       fix="retarget the clip you want to see on its own: mer retarget CLIP.csv --source ... --target ... --video OUT.gif")
    from mer_data.motion.sources import HUMAN_SOURCES

    method, _ = choose_method(args, args.source.lower() in HUMAN_SOURCES)
    args.method = method
    check_refine(args)
    checkpoint, kw = None, {}
    if method == "diffusion":
        from mer_models.zoo import DEFAULT_MODEL
        from mer_models.zoo.checkpoint import resolve_model

        checkpoint = resolve_model(args.model or DEFAULT_MODEL, args.device)
        if args.allow_unseen:
            from mer_data.robots.registry import as_robot
            from mer_models.retarget.clip import zero_shot_notes

            source = args.source if args.source.lower() in ("bvh", "smpl", "joints") else as_robot(args.source).name
            for note in dict.fromkeys(n for t in args.targets for n in zero_shot_notes(checkpoint, as_robot(t).name, source)):
                print(note, file=sys.stderr)
        kw = {"steps": args.steps, "guidance": args.guidance, "seed": args.seed, "allow_unseen": args.allow_unseen, "bf16": args.bf16,
              "refine": args.refine}  # fmt: skip
    workers = args.workers
    if workers is None:
        from mer_models.retarget.workers import available_cores

        workers = available_cores() if args.device == "cpu" else 1
    elif workers < 1:
        raise MerError(f"--workers must be >= 1, got {workers}", fix="give --workers N with N >= 1 (default: the cores there are)")
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(unit="clip", file=sys.stderr, desc="retarget")

    def started(plan: dict) -> None:
        skipped = f"{plan['done_before']} of {plan['jobs']} pairs already done in {args.out}, skipped; " if plan["done_before"] else ""
        line = f"{skipped}{plan['todo']} (target, clip) pairs to do, {plan['workers']} process{'es' if plan['workers'] > 1 else ''}"
        if bar is not None:
            bar.write(line, file=sys.stderr)
        else:
            print(line, file=sys.stderr)

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.total = total
            bar.n = done
            bar.refresh()

    try:
        summary = retarget_dataset(
            args.input_dir, args.source, args.targets, args.out, method=method, checkpoint=checkpoint,
            formats=args.formats, shard_index=args.shard_index, num_shards=args.num_shards, input_fps=args.fps or 30.0, npz_fps=args.npz_fps,
            npz_for=args.npz_for, device=args.device, progress=progress, physics=physics_option(args),
            bvh=bvh_options(args) if args.source.lower() in ("bvh", "smpl", "joints") else None, workers=workers, on_start=started,
            balance=balance_option(args), **kw,
        )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    print(json.dumps(summary, indent=1) if args.json else format_summary(summary))
    return 0
