"""``mer demo``: the walk a new user takes, offline, on the embedded defaults.

1. the robot registry: joint maps from the reference robot to every robot, body-part scales;
2. training shards from an embedded default -- a short synthetic walk generated in code for every
   built-in robot with a LAFAN1 layout (no LAFAN1 data ships with mer: its licence forbids it),
   written as LAFAN1 CSVs, built into HDF5 shards, inspected, loaded as a batch, and written
   once more as an MCAP file to look at in Foxglove.

``docs/shards.md`` shows the same build on the real data.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from mer_data.jointmap import keypoint_pairs
from mer_data.motion_io import write_lafan1_csv
from mer_data.registry import BUILTIN_ROBOTS, get_skeleton, list_robots
from mer_data.scaling import body_part_scales
from mer_data.shards import BuildConfig, ShardDataset, build_shards, format_inspection, inspect_shards
from mer_data.shards.config import PAPER_TARGETS
from mer_data.synthetic import walking_motion


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on embedded defaults (offline)")
    p.add_argument("--source", default="g1", help="reference robot (default g1)")
    p.add_argument("--out", metavar="DIR", help="where to write the demo's files (default: a new temporary folder)")
    p.add_argument("--workers", type=int, default=1, help="worker processes for the shard build (default 1)")
    p.set_defaults(func=cmd_demo)


def show_registry(source_name: str) -> list:
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
    paths = []
    for robot in robots:
        for i, (turn, phase) in enumerate(((0.1, 0.0), (-0.2, 1.0)), start=1):
            m = walking_motion(robot, seconds, turn_rate=turn, phase=phase)
            paths.append(write_lafan1_csv(folder / robot / f"synthetic_walk{i}.csv", m))
    return paths


def cmd_demo(args) -> int:
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

    from mer_data.samples import collate

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
    print(f"demo files: {out}")
    return 0
