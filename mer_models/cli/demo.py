"""``mer demo``: the walk a new user takes, offline, on the embedded defaults.

1. the robot registry: joint maps from the reference robot to every robot, body-part scales;
2. training shards from an embedded default -- a short synthetic walk generated in code for every
   built-in robot with a LAFAN1 layout (no LAFAN1 data ships with mer: its licence forbids it),
   written as LAFAN1 CSVs, built into HDF5 shards, inspected, loaded as a batch, and written
   once more as an MCAP file to look at in Foxglove;
3. a new robot registered from its URDF (a small humanoid generated in code,
   :mod:`mer_data.robots.example`), as ``mer robots register`` does;
4. the default model, ``mer-base``, loaded by name from the zoo (bundled with the package: no network;
   trained on synthetic motion only, every built-in robot as source and as target);
5. the synthetic G1 walk retargeted to every built-in robot and to the new one (zero-shot: the
   model never saw it), written as CSVs, one MCAP, one PNG and one GIF (the scaled reference and
   the retarget side by side), with the paper's metrics per robot.

``docs/shards.md`` shows the same build on the real data; ``docs/zoo.md`` the models.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from mer_data.base.errors import MerError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on embedded defaults (offline)")
    p.add_argument("--source", default="g1", help="reference robot (default g1)")
    p.add_argument("--out", metavar="DIR", help="where to write the demo's files (default: a new temporary folder)")
    p.add_argument("--workers", type=int, default=1, help="worker processes for the shard build (default 1)")
    p.add_argument("--model", default=None, help="zoo name, folder or ORG/NAME (default: the bundled mer-base)")
    p.add_argument("--show", default="h1", help="the robot whose result is also written as MCAP, PNG and GIF (default h1)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: the model's)")
    p.set_defaults(func=cmd_demo)


def show_registry(source_name: str) -> list:
    from mer_data.kinematics.jointmap import keypoint_pairs
    from mer_data.kinematics.scaling import body_part_scales
    from mer_data.robots.registry import get_skeleton, list_robots

    robots = list_robots()
    source = get_skeleton(source_name)
    print(f"mer demo: {len(robots)} robots in the registry; reference robot {source.name!r}\n")
    print(f"{'robot':10s} {'nodes':>5s} {'dof':>4s} {'pairs':>5s} {'alpha_root':>10s}  key points shared with the reference")
    for r in robots:
        s = r.skeleton
        pairs = keypoint_pairs(s, source)
        scales = body_part_scales(source, s)
        names = ", ".join(k for k, _, _ in pairs if k != "base")
        print(f"{r.name:10s} {s.num_nodes:5d} {s.num_dof:4d} {len(pairs):5d} {scales['root']:10.3f}  {names}")
    return robots


def write_synthetic_input(folder: Path, robots: list[str], *, seconds: float = 8.0) -> list[Path]:
    """Two synthetic walking clips per robot, as LAFAN1 CSVs under ``folder/<robot>/``."""
    from mer_data.motion.lafan1 import write_lafan1_csv
    from mer_data.synthesis.walking import walking_motion

    paths = []
    for robot in robots:
        for i, (turn, phase) in enumerate(((0.1, 0.0), (-0.2, 1.0)), start=1):
            m = walking_motion(robot, seconds, turn_rate=turn, phase=phase)
            paths.append(write_lafan1_csv(folder / robot / f"synthetic_walk{i}.csv", m))
    return paths


def cmd_demo(args) -> int:
    from mer_data.robots.example import EXAMPLE_ROBOT
    from mer_data.robots.registry import BUILTIN_ROBOTS
    from mer_data.shards import BuildConfig, ShardDataset, build_shards, format_inspection, inspect_shards
    from mer_data.shards.config import PAPER_TARGETS

    choices = [*BUILTIN_ROBOTS, EXAMPLE_ROBOT]
    if args.show not in choices:
        raise MerError(f"--show {args.show!r} is not one of the demo's robots", element=args.show, fix=f"pick one of {', '.join(choices)}")
    robots = show_registry(args.source)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="mer-demo-"))
    sources = [r.name for r in robots if r.name in BUILTIN_ROBOTS and r.card.lafan1_columns]
    write_synthetic_input(out / "input", sources)
    targets = tuple(dict.fromkeys([*PAPER_TARGETS, *sources]))
    print(f"\nsynthetic walking clips (8 s, 30 Hz) for {', '.join(sources)} -> {out / 'input'}")

    cfg = BuildConfig(input=str(out / "input"), robots=tuple(sources), split="all", targets=targets, augment=2)
    report = build_shards(cfg, out / "shards", workers=args.workers)
    print(f"\nshards: {report.summary()}\n")
    print(format_inspection(inspect_shards(out / "shards")))

    ds = ShardDataset(out / "shards")
    from torch.utils.data import DataLoader

    from mer_data.motion.samples import collate

    batch = next(iter(DataLoader(ds, batch_size=8, shuffle=True, collate_fn=collate)))
    print(f"\n{ds}")
    print(
        "one training batch: "
        + ", ".join(f"{k} {tuple(batch[k].shape)}" for k in ("reference", "target", "joint_map", "ref_scaled_pos"))
        + f"; pairs {list(zip(batch['ref_names'], batch['tgt_names']))[:4]} ..."
    )

    mcap_cfg = cfg.with_(format="mcap", mcap_preview=-1, augment=0, targets=(args.source,))
    mcap_report = build_shards(mcap_cfg, out / "mcap", workers=args.workers)
    files = sorted((out / "mcap").glob("*.mcap"))
    print(f"\nMCAP for Foxglove (3D panel: /tf and /skeleton): {mcap_report.windows} windows")
    for f in files:
        print(f"  {f}")
    print("\nreal data: see docs/shards.md (mer shards build --input hf://lvhaidong/LAFAN1_Retargeting_Dataset ...)")
    retarget_walk(args, out, [r.name for r in robots if r.name in BUILTIN_ROBOTS])
    print(f"\ndemo files: {out}")
    return 0


def retarget_walk(args, out: Path, builtins: list[str]) -> None:
    """Steps 3-5 of the walk (module docstring)."""
    from mer_data.robots.registry import robots_dir
    from mer_models.zoo import DEFAULT_MODEL, resolve
    from mer_models.zoo.checkpoint import load_checkpoint

    from .demo_walk import format_results, register_example_robot, retarget_to_all

    rep = register_example_robot(out / "urdf")
    new = rep.robot.skeleton.name
    print(f"\nregister a robot from its URDF (a small humanoid generated in code: {rep.robot.urdf_path.name})")
    print(rep.summary())
    print(f"  (in {robots_dir()}; `mer robots show {new}`, `mer robots unregister {new}` to remove it)")

    name = args.model or DEFAULT_MODEL
    res = resolve(name)  # verified once; the checkpoint is built from the verified folder
    ckpt = load_checkpoint(res.folder)
    how = {"card": "every file checked against the sha256 of its card", "hub": "checked against the Hub's content ids",
           "none": "local folder"}[res.verified]  # fmt: skip
    print(f"\nmodel {name!r}: {res.source} ({how}), {res.folder}")
    if res.card is not None:
        from mer_models.hub.brief import brief_lines

        for line in brief_lines(res.card):
            print(f"  {line}")
    print(f"  trained on targets: {', '.join(ckpt.targets)}; references: {', '.join(ckpt.references)}; step {ckpt.step}")

    src = out / "input" / args.source / "synthetic_walk1.csv"
    targets = [*builtins, new]
    print(f"\nretarget {src.name} ({args.source}) to {len(targets)} robots -> {out / 'retarget'}")
    results = retarget_to_all(src, args.source, targets, ckpt, out / "retarget", show=args.show, steps=args.steps)
    print(format_results(results))
    unseen = [r.robot for r in results if not r.seen]
    if unseen:
        print(f"zero-shot (as `mer retarget --allow-unseen`): {', '.join(unseen)}: the model never saw "
              f"{'this robot' if len(unseen) == 1 else 'these robots'}; `mer finetune --base {name} --robot {unseen[-1]} ...` adapts it")
    print("metrics against the reference scaled to each robot (docs/model.md)"
          + (f"; {name} is trained on synthetic motion only (its card, with its evaluation: `mer zoo info {name}`)"
             if name == DEFAULT_MODEL else ""))
    for r in results:
        if r.robot == args.show:
            print(f"\nMCAP (Foxglove: /tf, /skeleton, /reference): {r.outputs['mcap']}\nPNG: {r.outputs['png']}")
            print(f"GIF (scaled reference | retarget): {r.outputs['gif']}")
