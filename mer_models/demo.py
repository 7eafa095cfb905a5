"""``mer demo``: the walk a new user takes, offline, on the embedded defaults.

Today it shows the robot registry, the joint maps from G1 to every robot and the body-part scales;
later stages (shards, retargeting) extend it.
"""

from __future__ import annotations

import argparse

from mer_data.jointmap import keypoint_pairs
from mer_data.registry import get_skeleton, list_robots
from mer_data.scaling import body_part_scales


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on embedded defaults (offline)")
    p.add_argument("--source", default="g1", help="reference robot (default g1)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    robots = list_robots()
    source = get_skeleton(args.source)
    print(f"mer demo: {len(robots)} robots in the registry; reference robot {source.name!r}\n")
    print(f"{'robot':10s} {'nodes':>5s} {'dof':>4s} {'pairs':>5s} {'alpha_root':>10s}  key points shared with the reference")
    for r in robots:
        s = r.skeleton
        pairs = keypoint_pairs(s, source)
        scales = body_part_scales(source, s)
        names = ", ".join(k for k, _, _ in pairs if k != "base")
        print(f"{r.name:10s} {s.num_nodes:5d} {s.num_dof:4d} {len(pairs):5d} {scales['root']:10.3f}  {names}")
    return 0
