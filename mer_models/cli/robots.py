"""``mer robots list|show|register|unregister``."""

from __future__ import annotations

import argparse
import json
import sys

from mer_data.robots.register import parse_lock, register_robot
from mer_data.robots.registry import list_robots, load_robot, unregister_robot
from mer_data.robots.table import skeleton_table
from mer_data.skeleton import KEYPOINTS, Skeleton


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("robots", help="list, show, register and unregister robots")
    rs = p.add_subparsers(dest="robots_cmd", required=True, metavar="{list,show,register,unregister}")

    q = rs.add_parser("list", help="all known robots")
    q.add_argument("--json", action="store_true", help="machine-readable output")
    q.set_defaults(func=cmd_list)

    q = rs.add_parser("show", help="one robot's skeleton graph")
    q.add_argument("name")
    q.add_argument("--json", action="store_true", help="machine-readable output")
    q.set_defaults(func=cmd_show)

    q = rs.add_parser("register", help="add a robot from its URDF or MJCF")
    q.add_argument("name", help="lower-case name, e.g. my_humanoid")
    src = q.add_mutually_exclusive_group(required=True)
    src.add_argument("--urdf", help="the robot's URDF (plain XML, no xacro)")
    src.add_argument("--mjcf", help="the robot's MJCF (MuJoCo XML, <mujoco> root; read with MuJoCo's compiler)")
    q.add_argument("--keypoints", help="YAML/JSON file of the 14 key points; proposed from the description if omitted")
    q.add_argument("--lock", action="append", default=[], metavar="JOINT=VALUE", help="hold a joint at a value [rad]")
    q.add_argument("--force", action="store_true", help="replace a robot of the same name")
    q.add_argument("--dry-run", action="store_true", help="print what would be registered (the `show` table) and write nothing")
    q.set_defaults(func=cmd_register)

    q = rs.add_parser("unregister", help="remove a registered robot")
    q.add_argument("name")
    q.set_defaults(func=cmd_unregister)


def robot_json(skel: Skeleton, *, source: str, urdf: str) -> dict:
    """What ``mer robots show --json`` prints."""
    return {
        "name": skel.name,
        "source": source,
        "urdf": urdf,
        "num_nodes": skel.num_nodes,
        "num_dof": skel.num_dof,
        "node_names": list(skel.node_names),
        "node_kinds": list(skel.node_kinds),
        "parents": skel.parents.tolist(),
        "axes": skel.axes.tolist(),
        "offsets": skel.offsets.tolist(),
        "lower": skel.lower.tolist(),
        "upper": skel.upper.tolist(),
        "nominal": skel.nominal.tolist(),
        "keypoints": {k: int(skel.keypoints[k]) for k in KEYPOINTS},
        "urdf_joint_names": list(skel.urdf_joint_names),
        "link_names": list(skel.link_names),
        "mimic_source": skel.mimic_source.tolist(),
        "locked": dict(skel.locked),
    }


def cmd_list(args) -> int:
    robots = list_robots()
    if args.json:
        rows = [
            {
                "name": r.name,
                "source": "built-in" if r.builtin else "user",
                "num_nodes": r.skeleton.num_nodes,
                "num_dof": r.skeleton.num_dof,
                "keypoints": sum(v >= 0 for v in r.skeleton.keypoints.values()),
                "lafan1": r.card.lafan1_columns is not None,
                "description": r.card.description,
                "path": str(r.folder),
            }
            for r in robots
        ]
        print(json.dumps(rows, indent=2))
        return 0
    print(f"{'name':10s} {'source':9s} {'nodes':>5s} {'dof':>4s} {'keypts':>6s} {'lafan1':6s} description")
    for r in robots:
        s = r.skeleton
        kp = sum(v >= 0 for v in s.keypoints.values())
        print(
            f"{r.name:10s} {'built-in' if r.builtin else 'user':9s} {s.num_nodes:5d} {s.num_dof:4d} "
            f"{kp:3d}/14 {'yes' if r.card.lafan1_columns else '-':6s} {r.card.description}"
        )
    return 0


def _geometry(r) -> dict:
    """What the robot collides with: shapes by source, and the bodies that only have fitted capsules."""
    from mer_data.robots.collision import collision_model

    m = collision_model(r)
    fitted = sorted({m.link[i] for i in range(m.num_shapes) if m.source[i] == "fitted"})
    return {"file": r.card.collision, "shapes": m.counts(), "fitted_bodies": fitted, "missing_meshes": list(m.missing),
            "checked_pairs": int(len(m.pairs))}  # fmt: skip


def cmd_show(args) -> int:
    r = load_robot(args.name)
    s = r.skeleton
    geo = _geometry(r)
    if args.json:
        print(json.dumps({**robot_json(s, source="built-in" if r.builtin else "user", urdf=str(r.urdf_path)), "collision": geo},
                         indent=2))  # fmt: skip
        return 0
    print(skeleton_table(s, description=r.card.description, urdf=str(r.urdf_path), source="built-in" if r.builtin else "user"))
    names = {"mesh": "mesh hulls", "primitive": "primitives", "fitted": "fitted capsules"}
    counts = ", ".join(f"{n} {names[k]}" for k, n in geo["shapes"].items())
    print(f"collision ({geo['file'] or 'from the URDF'}): {counts}; {geo['checked_pairs']} body pairs checked for self-penetration")
    if geo["fitted_bodies"]:
        print(f"  fitted capsules (no geometry in the description): {', '.join(geo['fitted_bodies'])}")
    if geo["missing_meshes"]:
        print(f"  meshes that could not be read: {', '.join(geo['missing_meshes'])}")
    return 0


def cmd_register(args) -> int:
    locks = dict(parse_lock(t) for t in args.lock)
    path, expect = (args.mjcf, "mjcf") if args.mjcf is not None else (args.urdf, "urdf")
    report = register_robot(
        args.name, path, keypoints_file=args.keypoints, locks=locks, force=args.force, dry_run=args.dry_run, expect=expect
    )
    if args.dry_run:
        print(skeleton_table(report.skeleton, description=report.card.description, urdf=str(report.urdf_path), source="dry run"))
    print(report.summary())
    return 0


def cmd_unregister(args) -> int:
    folder = unregister_robot(args.name)
    print(f"unregistered {args.name!r} (removed {folder})", file=sys.stdout)
    return 0
