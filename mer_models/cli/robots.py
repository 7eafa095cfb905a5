"""``mer robots list|show|register|keypoints|unregister|export``.

Only :mod:`argparse` is imported at module level (``mer --help`` stays fast); each command imports
what it uses.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mer_data.robots.registry import Robot
    from mer_data.skeleton import Skeleton


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``mer robots`` and its sub-commands to ``sub``."""
    p = sub.add_parser("robots", help="list, show, register, unregister and export robots")
    rs = p.add_subparsers(dest="robots_cmd", required=True, metavar="{list,show,register,keypoints,unregister,export}")

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
    q.add_argument("--keypoints", metavar="FILE",
                   help="YAML/JSON file of key points that correct the proposal: only those that change, or all 14 "
                   "(`mer robots keypoints NAME --write FILE` writes the current set)")
    q.add_argument("--lock", action="append", default=[], metavar="JOINT=VALUE", help="hold a joint at a value [rad]")
    q.add_argument("--force", action="store_true", help="replace a robot of the same name")
    q.add_argument("--dry-run", action="store_true", help="print what would be registered and write nothing")
    q.add_argument("--verbose", action="store_true", dest="full",
                   help="with --dry-run: also print the node table (what `mer robots show` prints once registered)")
    q.set_defaults(func=cmd_register)

    q = rs.add_parser("keypoints", help="print or write a robot's 14 key points as an editable --keypoints file",
                      description="Print a robot's key points as a YAML key-point file (with a comment header), or "
                      "write it with --write. Edit it and pass it to `mer robots register NAME --urdf FILE --keypoints "
                      "FILE --force`; a file of only the key points that change is merged over the proposal.")
    q.add_argument("name")
    q.add_argument("--write", metavar="FILE", help="write the file here instead of printing it")
    q.set_defaults(func=cmd_keypoints)

    q = rs.add_parser("unregister", help="remove a registered robot")
    q.add_argument("name")
    q.set_defaults(func=cmd_unregister)

    q = rs.add_parser("export", help="write a robot's MuJoCo model (the model a tracker loads with its npz)",
                      description="Write the robot's MuJoCo model: free base, every joint of its description with its "
                      "limits, inertia, collision geometry, meshes where their files are there; bodies and joints in "
                      "the order of its npz for mjlab (docs/trackers.md).")
    q.add_argument("name")
    out = q.add_mutually_exclusive_group(required=True)
    out.add_argument("--mjcf", metavar="OUT.xml", help="where to write the MJCF")
    out.add_argument("--mjlab", metavar="DIR", help="write a self-contained mjlab folder here: the MJCF with position "
                     "actuators, sole contact spheres, contact exclusions and sensors, its meshes and licences, and a "
                     "Python package with the entity config and a tracking task (docs/trackers.md)")
    q.add_argument("--motion", action="append", default=[], metavar="NPZ",
                   help="with --mjlab: an npz for mjlab to copy into the folder (checked: this robot's joints and bodies "
                   "in mjlab's order); repeat for more")
    q.add_argument("--meshes", metavar="DIR", help="with --mjlab: a folder with the description's mesh files, besides "
                   "its own")
    q.add_argument("--force", action="store_true", help="with --mjlab: replace DIR if it exists")
    q.set_defaults(func=cmd_export)


def robot_json(skel: Skeleton, *, source: str, urdf: str) -> dict[str, Any]:
    """What ``mer robots show --json`` prints."""
    from mer_data.skeleton import KEYPOINTS

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


def cmd_list(args: argparse.Namespace) -> int:
    """``mer robots list``: every robot, built-ins first."""
    from mer_data.robots.registry import list_robots

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


def _geometry(r: Robot) -> dict[str, Any]:
    """What the robot collides with: shapes by source, and the bodies that only have fitted capsules."""
    from mer_data.robots.collision import collision_model

    m = collision_model(r)
    fitted = sorted({m.link[i] for i in range(m.num_shapes) if m.source[i] == "fitted"})
    return {"file": r.card.collision, "shapes": m.counts(), "fitted_bodies": fitted, "missing_meshes": list(m.missing),
            "checked_pairs": int(len(m.pairs))}  # fmt: skip


def cmd_show(args: argparse.Namespace) -> int:
    """``mer robots show NAME``: the node table and what the robot collides with."""
    from mer_data.robots.registry import load_robot
    from mer_data.robots.table import skeleton_table

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


def cmd_register(args: argparse.Namespace) -> int:
    """``mer robots register``: the summary (key points, what to check, where the card went); the node table with --verbose."""
    from mer_data.robots.register import parse_lock, register_robot
    from mer_data.robots.table import skeleton_table

    locks = dict(parse_lock(t) for t in args.lock)
    path, expect = (args.mjcf, "mjcf") if args.mjcf is not None else (args.urdf, "urdf")
    report = register_robot(
        args.name, path, keypoints_file=args.keypoints, locks=locks, force=args.force, dry_run=args.dry_run, expect=expect
    )
    print(report.summary())
    if args.full:
        print()
        print(skeleton_table(report.skeleton, description=report.card.description, urdf=str(report.urdf_path),
                             source="dry run" if args.dry_run else "user"))  # fmt: skip
    elif args.dry_run:
        print("  (--verbose adds the node table)")
    return 0


def cmd_keypoints(args: argparse.Namespace) -> int:
    """``mer robots keypoints NAME [--write FILE]``: the current key points as an editable key-point file."""
    from mer_data.base.atomic import atomic_write
    from mer_data.base.errors import OutputError
    from mer_data.robots.register import keypoints_yaml
    from mer_data.robots.registry import load_robot

    robot = load_robot(args.name)
    text = keypoints_yaml(robot)
    if args.write is None:
        sys.stdout.write(text)
        return 0
    try:
        atomic_write(args.write, text)
    except OSError as exc:
        raise OutputError(f"cannot write the key-point file: {exc.strerror or exc}", path=args.write,
                          fix="give a file path in a folder you can write to") from None  # fmt: skip
    print(f"wrote the 14 key points of {robot.name!r} to {args.write}: edit it, then "
          f"`mer robots register {robot.name} --urdf FILE --keypoints {args.write} --force`")  # fmt: skip
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    """``mer robots export NAME --mjcf OUT.xml | --mjlab DIR``: the robot's MuJoCo model, or its mjlab folder."""
    from mer_data.base.errors import MerError
    from mer_data.robots.registry import load_robot
    from mer_models.export.mjcf import write_mjcf

    r = load_robot(args.name)
    if args.mjlab is None:
        if args.motion or args.meshes or args.force:
            raise MerError("--motion, --meshes and --force go with --mjlab", fix="add --mjlab DIR, or leave them out")
    else:
        from mer_models.export.mjlab import export_mjlab

        e = export_mjlab(r, args.mjlab, mesh_dir=args.meshes, motions=args.motion, replace=args.force)
        rule = sum(d.source["gains"] == "rule" for d in e.drives)
        print(f"wrote {e.folder}: {e.xml.name} ({len(e.drives)} position actuators, {rule} with mer's rule gains; "
              f"{len(e.standing.spheres)} sole spheres; {len(e.excluded)} excluded body pairs), {len(e.meshes)} meshes, "
              f"licences: {', '.join(e.licences) or 'none found'}, motions: {', '.join(e.motions) or 'none'}")
        print(f"  mjlab task {e.task!r}: `pip install -e {e.folder}`, then `train {e.task} "
              f"--env.commands.motion.motion-file MOTION.npz` (the numbers mer chose: {e.package.name}/README.md)")
        return 0
    path = write_mjcf(args.mjcf, r)
    print(f"wrote {path}: the MuJoCo model of {args.name!r} (bodies and joints in the order of `mer retarget "
          "--npz OUT.npz --npz-for mjlab`)")
    return 0


def cmd_unregister(args: argparse.Namespace) -> int:
    """``mer robots unregister NAME``: remove a user robot."""
    from mer_data.robots.registry import unregister_robot

    folder = unregister_robot(args.name)
    print(f"unregistered {folder.name!r} (removed {folder})", file=sys.stdout)
    return 0
