"""``mer view``: the robot itself in the browser, moving with a retargeted motion beside the scaled
reference (:mod:`mer_models.export.viewer`; viser, an optional extra)."""

from __future__ import annotations

import argparse
import sys
import time


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="see a retargeted motion: the robot's meshes in the browser, beside the scaled reference",
        description="Serve a 3D view of MOTION.csv (a motion of --robot in its LAFAN1 layout, as mer retarget -o writes it) "
        "on this machine: the robot's meshes (or its collision shapes where it has none) moving frame by frame, with a "
        "timeline to scrub and play, and, with --reference SRC --source ROBOT, the source motion scaled to the robot beside "
        'it. Open the printed address in a browser; Ctrl-C stops. Needs the viewer extra: pip install "mer[viewer]".',
    )
    p.add_argument("motion", metavar="MOTION.csv", help="the retargeted motion (mer retarget -o OUT.csv)")
    p.add_argument("--robot", required=True, help="the robot MOTION.csv moves (the retarget's --target)")
    p.add_argument("--reference", metavar="SRC", help="the motion it was retargeted from (the retarget's INPUT), shown scaled "
                   "to the robot")  # fmt: skip
    p.add_argument("--source", help="robot of --reference (e.g. g1), or bvh, smpl, joints (default for a human reference: "
                   "its kind, from the file)")
    p.add_argument("--body-model", metavar="PATH", help="SMPL body model of an SMPL --reference (docs/kinematics.md)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate of MOTION.csv [Hz] (default 30, what mer retarget writes)")
    p.add_argument("--reference-fps", type=float, default=30.0, help="frame rate of a CSV --reference [Hz] (default 30)")
    p.add_argument("--meshes", metavar="DIR", help="a folder with the robot's mesh files, besides the registered description's "
                   "own folder (e.g. the folder the robot was registered from)")  # fmt: skip
    p.add_argument("--collision", action="store_true", help="draw the robot's collision shapes, not its meshes")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken; 0: any)")
    p.add_argument("--paused", action="store_true", help="start paused at the first frame")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mer_data.base.errors import MerError
    from mer_data.motion.sources import BvhOptions, human_kind, read_source
    from mer_data.robots.registry import as_robot
    from mer_models.export.viewer import require_viser, serve_motion
    from mer_models.export.viewer_guard import stop_on_sigterm

    require_viser()  # before any reading: the one thing a first try lacks
    from mer_models.export.geometry import robot_meshes
    from mer_models.export.viewer import VIEWER_MAX_FACES

    robot = as_robot(args.robot)
    motion = _target_motion(read_source(args.motion, robot, fps=args.fps).motion, robot)
    points = nodes = ref_skel = None
    if args.reference is not None:
        human = human_kind(args.reference, args.source)
        if args.source is None and not human:
            raise MerError("--reference needs --source: the robot of the reference motion", fix="add e.g. --source g1")
        src = read_source(args.reference, human or as_robot(args.source), fps=args.reference_fps,
                          bvh=BvhOptions(body_model=args.body_model))  # fmt: skip
        feats = src.features()
        if len(feats) != motion.num_frames:
            raise MerError(f"the reference has {len(feats)} frames at 30 Hz, the motion {motion.num_frames}: it is not the "
                           "motion this one was retargeted from", path=args.reference,
                           fix="give the retarget's own INPUT (and --reference-fps / --fps where they were not 30 Hz)")  # fmt: skip
        from mer_data.kinematics.jointmap import joint_map
        from mer_models.retarget.long_horizon import prepare_reference

        _, scaled, shift, _ = prepare_reference(feats, src.skeleton, robot.skeleton)  # as the retarget scaled it
        nodes = scaled + shift
        points = nodes[:, joint_map(robot.skeleton, src.skeleton).any(0)]  # the key points the energy tracks
        ref_skel = src.skeleton
    meshes = robot_meshes(robot, mesh_dir=args.meshes, visual=not args.collision, max_faces=VIEWER_MAX_FACES)
    viewer = serve_motion(motion, robot=robot, meshes=meshes, reference_points=points, reference_nodes=nodes,
                          reference_skeleton=ref_skel, host=args.host, port=args.port, play=not args.paused)  # fmt: skip
    drawn = "its meshes" if meshes.kind == "mesh" else "its collision shapes (no mesh file found; --meshes DIR)"
    print(f"viewing {robot.name} ({motion.num_frames} frames, {drawn}) at {viewer.url}  (Ctrl-C to stop)", flush=True)
    stop_on_sigterm()  # `kill` ends it as Ctrl-C does: connections closed, exit 0
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        viewer.close()
    return 0


def _target_motion(m, robot):
    """The :class:`~mer_models.export.writers.TargetMotion` of a robot motion read from its CSV
    (a :class:`~mer_data.motion.lafan1.Motion`)."""
    import torch

    from mer_data.kinematics.rotations import quat_to_matrix
    from mer_models.export.writers import TargetMotion

    rot = quat_to_matrix(torch.from_numpy(m.base_quat)).numpy()
    return TargetMotion(robot.skeleton, float(m.fps), m.node_angles(robot.skeleton), m.base_pos, rot)
