"""The robot itself, live in a browser: its meshes moving with a retargeted motion beside the scaled
reference, on a timeline to scrub or play (``mer view``; viser, the viewer mjlab uses).

:func:`serve_motion` starts a viser server on loopback (``127.0.0.1``, a port of the user's) and
draws, in a world with z up:

- the robot (:func:`~mer_models.export.geometry.robot_meshes`): per body of its articulation one
  mesh, its visual meshes where they can be read, else its collision shapes, moved each frame to
  the body's pose (:meth:`~mer_data.robots.articulation.Articulation.body_poses`); collision shapes
  are joined by the skeleton's bones (dark grey, as the video draws them:
  :func:`~mer_models.export.geometry.bone_segments`), so the robot reads as one body;
- the scaled reference (when given): its bones and the key points the energy tracks (red),
  ``beside`` the robot (to its left at the first frame) or on it;
- a floor grid (0.5 m squares) and green marks under feet in contact
  (:func:`mer_data.motion.contacts.foot_contacts`, both for the robot and the reference).

The panel has a frame slider (scrub), play / pause, the playback speed, "follow" (the camera
follows the robot: every frame is drawn about its base's x, y and the floor moves under it, as in
the video) and "reference beside". The page and its scripts come from the viser package itself
(nothing is fetched from the internet). viser is an optional dependency (``pip install
"mer[viewer]"``); without it :func:`require_viser` refuses with that command.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mer_data.base.errors import MerError
from mer_data.robots.registry import Robot
from mer_data.skeleton import Skeleton

from .geometry import RobotMeshes, bone_segments
from .viewer_guard import own_origin_only
from .writers import TargetMotion, check_motion_finite

log = logging.getLogger(__name__)

__all__ = ["VIEWER_INSTALL", "VIEWER_MAX_FACES", "require_viser", "MotionViewer", "serve_motion"]

#: How to install the viewer's package.
VIEWER_INSTALL = 'pip install "mer[viewer]"  (or: pip install viser)'
#: The face budget of the robot in the browser (the G1's meshes have 393,270 faces; software WebGL draws 100,000 in seconds).
VIEWER_MAX_FACES = 100_000
MESH_RGB = (107, 153, 219)  # as the video's meshes (mer_models.export.video.MESH_RGB)
COLLISION_RGB = (219, 153, 82)
REFERENCE_RGB = (214, 38, 41)
CONTACT_RGB = (51, 168, 51)
BONE_RGB = (45, 45, 45)  # the bones joining collision shapes: darker than the floor grid, not the meshes' blue
_UI_RGB = (96, 96, 96)  # the panel's buttons: grey, so nothing but the robot is blue


def require_viser():
    """The ``viser`` module, or a MerError naming the pip command that installs it."""
    try:
        import viser
    except ImportError:
        raise MerError("the viewer needs the viser package, which is not installed", fix=VIEWER_INSTALL) from None
    return viser


def _wxyz(rot: np.ndarray) -> np.ndarray:
    import torch

    from mer_data.kinematics.rotations import matrix_to_quat

    return matrix_to_quat(torch.from_numpy(np.asarray(rot, np.float64))).numpy()


@dataclass
class MotionViewer:
    """A running viewer (:func:`serve_motion`). ``url`` is the page; :meth:`show` moves to a frame,
    :meth:`close` stops the server."""

    server: object
    url: str
    num_frames: int
    fps: float
    _show: object = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def show(self, frame: int) -> None:
        """Move the timeline to frame ``frame`` (0-based) in every connected browser."""
        self._show(int(frame), move_slider=True)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.server.stop()

    def __enter__(self) -> "MotionViewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve_motion(
    motion: TargetMotion,
    *,
    robot: Robot | None = None,
    meshes: RobotMeshes | None = None,
    mesh_dir: str | Path | None = None,
    reference_points: np.ndarray | None = None,
    reference_nodes: np.ndarray | None = None,
    reference_skeleton: Skeleton | None = None,
    host: str = "127.0.0.1",
    port: int = 8080,
    play: bool = True,
    bones: bool | None = None,
) -> MotionViewer:
    """Start the viewer of ``motion`` (module docstring) and return at once; the server runs in
    background threads until :meth:`MotionViewer.close`.

    Args:
        robot: the motion's registered robot (default: the robot its skeleton is named after, when
            the skeleton is that robot's own); meshes: what draws it, if made already (default:
            :func:`~mer_models.export.geometry.robot_meshes` with :data:`VIEWER_MAX_FACES`, looking
            for mesh files also under ``mesh_dir``).
        reference_points: (F, K, 3) scaled reference key points [m]; reference_nodes: (F, Jr, 3)
            every node of the scaled reference and ``reference_skeleton`` for its bones (optional).
        host, port: where to listen (port 0: any free port); play: start playing.
        bones: draw the skeleton's bones between the robot's pieces (default: when they are collision
            shapes, which do not touch each other; visual meshes join by themselves).

    Raises:
        MerError: viser not installed, a skeleton no registered robot has, shapes that do not
        match, non-finite values.
    """
    viser = require_viser()
    from mer_data.motion.contacts import foot_contacts, sole_points
    from mer_data.robots.articulation import articulation
    from mer_data.shards.foxglove import registered_robot

    from .geometry import robot_meshes

    check_motion_finite(motion)
    skel = motion.skeleton
    robot = robot if robot is not None else registered_robot(skel)
    if robot is None or robot.skeleton.fingerprint != skel.fingerprint:
        raise MerError(f"the motion's skeleton {skel.name!r} is not a registered robot's (scaled or edited): the viewer draws "
                       "a robot's own bodies", fix="view a motion of a registered robot (mer robots list)")  # fmt: skip
    F = motion.num_frames
    for name, a, width in (("reference_points", reference_points, None), ("reference_nodes", reference_nodes,
                           reference_skeleton.num_nodes if reference_skeleton is not None else None)):  # fmt: skip
        if a is not None and (
            np.ndim(a) != 3 or np.shape(a)[0] != F or np.shape(a)[2] != 3 or (width and np.shape(a)[1] != width)
        ):
            raise MerError(f"{name} have shape {np.shape(a)}, expected ({F}, {width or 'K'}, 3): one per frame of the motion")
        if a is not None and not np.isfinite(a).all():
            raise MerError(f"{name} hold non-finite positions", fix="view a finite reference")
    meshes = meshes if meshes is not None else robot_meshes(robot, mesh_dir=mesh_dir, max_faces=VIEWER_MAX_FACES)
    art = articulation(robot)
    node_pos, node_rot = motion.forward_kinematics()
    body_pos, body_rot = art.body_poses(node_pos, node_rot)
    body_quat = _wxyz(body_rot)
    centre = np.concatenate([node_pos[:, 0, :2], np.zeros((F, 1))], axis=1)  # the follow camera's target
    r0 = np.asarray(motion.base_rot[0])
    heading = np.arctan2(r0[1, 0], r0[0, 0])
    beside = 1.0 * np.array([-np.sin(heading), np.cos(heading), 0.0])  # 1 m to the robot's left at the first frame
    ref_feet = None
    if reference_nodes is not None and reference_skeleton is not None:
        ref_feet = _feet(
            reference_nodes, foot_contacts(reference_nodes, reference_skeleton, motion.fps), sole_points(reference_skeleton)
        )
    rob_feet = _feet(node_pos, foot_contacts(node_pos, skel, motion.fps), sole_points(skel))

    with own_origin_only(host):  # its websocket answers its own page only (viewer_guard)
        server = viser.ViserServer(host=host, port=port, label=f"mer: {robot.name}", verbose=False)
    server.gui.configure_theme(control_width="medium", show_share_button=False, brand_color=_UI_RGB)
    scene = server.scene
    scene.set_up_direction("+z")
    grid = scene.add_grid("/floor", width=12.0, height=12.0, plane="xy", cell_size=0.5, section_size=1.0)
    handles = []
    for bm in meshes.bodies:
        rgb = MESH_RGB if bm.source == "mesh" else COLLISION_RGB
        h = scene.add_mesh_simple(f"/robot/{meshes.body_names[bm.body]}", bm.vertices.astype(np.float32), bm.faces.astype(np.uint32),
                                  color=rgb, flat_shading=False, side="double")  # fmt: skip
        handles.append((bm.body, h))
    feet_h = scene.add_point_cloud("/contacts", np.zeros((4, 3), np.float32), CONTACT_RGB, point_size=0.08, point_shape="circle",
                                   point_shading="flat", visible=False)  # fmt: skip
    rob_bones_h = None
    if bones if bones is not None else meshes.kind != "mesh":
        rob_bones_h = scene.add_line_segments("/robot/bones", bone_segments(node_pos[0], skel.parents).astype(np.float32), BONE_RGB,
                                              thickness=0.03)  # fmt: skip
    bones_h = goals_h = None
    if reference_nodes is not None and reference_skeleton is not None:
        bones_h = scene.add_line_segments("/reference/bones", np.zeros((reference_skeleton.num_nodes - 1, 2, 3), np.float32),
                                          REFERENCE_RGB, thickness=0.02)  # fmt: skip
    if reference_points is not None:
        goals_h = scene.add_point_cloud("/reference/goals", np.zeros((np.shape(reference_points)[1], 3), np.float32), REFERENCE_RGB,
                                        point_size=0.05, point_shape="circle")  # fmt: skip
    target = np.array([0.0, 0.0, 0.7]) + (0.5 * beside if bones_h is not None or goals_h is not None else 0.0)
    server.initial_camera.look_at = tuple(target)  # a three-quarter view from the front right, robot and reference in it
    server.initial_camera.position = tuple(
        target + 2.6 * np.array([np.cos(heading - 0.7), np.sin(heading - 0.7), 0.0]) + [0, 0, 0.5]
    )

    gui = server.gui
    label = gui.add_markdown("")
    slider = gui.add_slider("frame", min=0, max=max(F - 1, 1), step=1, initial_value=0)
    playing = gui.add_checkbox("play", initial_value=play)
    speed = gui.add_slider("speed", min=0.1, max=2.0, step=0.1, initial_value=1.0)
    follow = gui.add_checkbox("follow the robot", initial_value=True)
    side = gui.add_checkbox("reference beside", initial_value=True, disabled=bones_h is None and goals_h is None)
    lock = threading.Lock()

    def show(f: int, move_slider: bool = False) -> None:
        f = int(np.clip(f, 0, F - 1))
        if move_slider and int(slider.value) != f:
            slider.value = f  # its callback draws the frame
            return
        shift = -centre[f] if follow.value else np.zeros(3)
        ref_shift = shift + (beside if side.value else 0.0)
        with lock, server.atomic():
            for b, h in handles:
                h.position = body_pos[f, b] + shift
                h.wxyz = body_quat[f, b]
            if rob_bones_h is not None:
                rob_bones_h.points = bone_segments(node_pos[f] + shift, skel.parents).astype(np.float32)
            grid.position = tuple(np.mod(shift, 1.0) * [1, 1, 0]) if follow.value else (0.0, 0.0, 0.0)
            marks = [p + shift for p in rob_feet[f] if np.isfinite(p).all()]
            if ref_feet is not None:
                marks += [p + ref_shift for p in ref_feet[f] if np.isfinite(p).all()]
            if marks:
                feet_h.points = np.array(marks, np.float32)
            feet_h.visible = bool(marks)
            if bones_h is not None:
                nodes = np.asarray(reference_nodes[f], np.float64) + ref_shift
                bones_h.points = bone_segments(nodes, reference_skeleton.parents).astype(np.float32)
            if goals_h is not None:
                goals_h.points = (np.asarray(reference_points[f], np.float64) + ref_shift).astype(np.float32)
            label.content = f"**{robot.name}** ({meshes.kind}) &nbsp; frame {f + 1}/{F} &nbsp; t = {f / motion.fps:.2f} s"

    @slider.on_update
    def _(_event) -> None:
        show(slider.value)

    for box in (follow, side):
        box.on_update(lambda _event: show(slider.value))
    show(0)
    viewer = MotionViewer(server, f"http://{host if host not in ('0.0.0.0', '::') else '127.0.0.1'}:{server.get_port()}", F,
                          float(motion.fps), show)  # fmt: skip

    def run() -> None:  # playback: the slider moves at the motion's rate times the speed
        clock = time.perf_counter()
        while not viewer._stop.wait(1.0 / motion.fps):
            if playing.value and F > 1:
                now = time.perf_counter()
                step = max(1, int(round((now - clock) * motion.fps * speed.value)))
                clock = now
                slider.value = (int(slider.value) + step) % F
            else:
                clock = time.perf_counter()

    viewer._thread = threading.Thread(target=run, name="mer-viewer-playback", daemon=True)
    viewer._thread.start()
    log.info(
        "viewer of %s (%d frames, robot drawn as %s, %d faces) at %s", robot.name, F, meshes.kind, meshes.num_faces, viewer.url
    )
    return viewer


def _feet(pos: np.ndarray, contact: np.ndarray, soles: dict[str, list[int]]) -> np.ndarray:
    """(F, 2, 3) a point on the floor under each foot in contact (its lowest sole point), NaN elsewhere."""
    out = np.full((pos.shape[0], 2, 3), np.nan)
    for i, nodes in enumerate(soles.values()):
        if nodes:
            p = np.asarray(pos)[:, nodes]
            low = p[np.arange(len(p)), p[..., 2].argmin(1)]
            out[contact[:, i], i] = low[contact[:, i]] * [1, 1, 0] + [0, 0, 0.003]
    return out
