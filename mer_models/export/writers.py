"""Writers of a retargeted motion: LAFAN1-style CSV, a motion tracker's npz (mjlab or BeyondMimic), Foxglove MCAP.

All take a :class:`TargetMotion` and write atomically (temporary file, then rename).

**CSV** (no header, comma separated, 6 decimals, one row per frame)::

    root x, y, z [m], root quaternion x, y, z, w (scalar last), joint angles [rad]

The joints are in the order of the robot card's ``lafan1_columns`` when it has one (g1, h1,
h1_2: the LAFAN1 robot layout), else in the skeleton's node order (``Skeleton.joint_names``: the
actuated URDF joints, depth-first; ``mer robots show NAME`` lists them). :func:`csv_columns` gives
the order.

**npz** (the keys of mjlab's / BeyondMimic's ``csv_to_npz`` output, for one tracker: ``tracker`` is
required, ``"mjlab"`` or ``"beyondmimic"``; docs/trackers.md), resampled like ``csv_to_npz`` to
``fps`` = 50 Hz by default, the trackers' control rate (angles and positions linearly, the base
orientation by slerp; ``fps=None`` keeps the motion's rate): ``fps`` (1,) (int64 for BeyondMimic,
float64 for mjlab, as their converters write it; a whole number of Hz), ``joint_pos``,
``joint_vel`` (F, D) float32, ``body_pos_w`` (F, B, 3), ``body_quat_w`` (F, B, 4, **wxyz**),
``body_lin_vel_w``, ``body_ang_vel_w`` (F, B, 3, world frame) float32, plus ``joint_names`` (D,)
and ``body_names`` (B,) (plain unicode arrays: ``np.load`` reads them without pickle;
:func:`~mer_models.export.npz_read.read_npz` checks them when mer reads the npz back). The joints and bodies are the robot's **own articulation**
(:mod:`mer_data.robots.articulation`): every joint of its description (locked joints at their
locked value, mimic joints from their master) and every body a simulator makes of it, so the
arrays line up with the robot's model as the tracker loads it; they are in the tracker's order
(mjlab: MuJoCo's depth-first order; beyondmimic: Isaac Lab's breadth-first order), because
neither tracker's ``MotionLoader`` reads the names. ``body_lin_vel_w`` is what each tracker logs:
the link origin's velocity for mjlab (``body_link_lin_vel_w``), the centre of mass's for
BeyondMimic (Isaac Lab's ``body_lin_vel_w``).

**MCAP** (:mod:`mer_data.shards.foxglove`): JSON channels ``/tf`` (``foxglove.FrameTransforms``, one message per
frame; frames named after the robot's URDF / MJCF links, ``world`` the fixed frame), ``/robot``
(``foxglove.SceneUpdate``: the robot's collision shapes on its link frames), ``/robot_description``
(the URDF as ``std_msgs/String``, which Foxglove's URDF layer reads), ``/skeleton`` (mer's stick
figure), plus ``/reference`` (spheres at the scaled reference key points) when given. The
foxglove.* schemas embedded are Foxglove's official JSON schemas (:mod:`mer_data.shards.foxglove`).
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import MerError, OutputError, UnknownRobotError
from mer_data.base.finite import require_finite
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.kinematics.rotations import matrix_to_axis_angle, matrix_to_quat, quat_slerp, quat_to_matrix
from mer_data.motion.features import finite_difference
from mer_data.robots.articulation import TRACKERS, articulation
from mer_data.robots.registry import Robot, load_robot
from mer_data.skeleton import Skeleton

__all__ = [
    "TargetMotion",
    "csv_columns",
    "check_motion_finite",
    "resample_motion",
    "write_csv",
    "write_npz",
    "write_mcap",
    "require_tracker",
    "npz_robot",
    "NPZ_FPS",
    "NPZ_TRACKERS",
]

log = logging.getLogger(__name__)

#: Frame rate of npz outputs: the control rate of the mjlab / BeyondMimic trackers [Hz].
NPZ_FPS = 50.0
#: The trackers an npz is written for: each reads joints and bodies in its own order (docs/trackers.md).
NPZ_TRACKERS = TRACKERS


@dataclass(frozen=True)
class TargetMotion:
    """A retargeted motion of one robot, world frame.

    Attributes:
        skeleton: the target skeleton.
        fps: [Hz].
        q: (F, J) float64 angle per node [rad] (0 at base and sites).
        base_pos: (F, 3) [m]; base_rot: (F, 3, 3) world ← base.
    """

    skeleton: Skeleton
    fps: float
    q: np.ndarray
    base_pos: np.ndarray
    base_rot: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.q.shape[0])

    def base_quat(self) -> np.ndarray:
        """(F, 4) wxyz."""
        return matrix_to_quat(torch.from_numpy(np.asarray(self.base_rot, np.float64))).numpy()

    def forward_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        """Node positions (F, J, 3) and rotations (F, J, 3, 3) (node frames), float64."""
        st = skeleton_tensors(self.skeleton, torch.float64)
        pos, rot = fk_skeleton(
            st, torch.from_numpy(self.q), torch.from_numpy(self.base_pos), base_rot=torch.from_numpy(self.base_rot)
        )
        return pos.numpy(), rot.numpy()


def check_motion_finite(motion: TargetMotion, path: str | Path | None = None) -> None:
    """Refuse (OutputError) a motion with NaN/inf angles, positions or rotations: nothing is written."""
    require_finite({"q": motion.q, "base_pos": motion.base_pos, "base_rot": motion.base_rot}, path=path,
                   what=f"retargeted motion of {motion.skeleton.name!r}")  # fmt: skip


def csv_columns(skel: Skeleton, robot: Robot | None = None) -> tuple[str, ...]:
    """The joint order of the CSV: the card's ``lafan1_columns`` if any, else node order.

    ``robot``: the skeleton's robot, resolved by the caller; without it the card is looked up by
    the skeleton's name (a skeleton no robot is registered under, e.g. augmented: node order).
    """
    if robot is not None:
        cols = robot.card.lafan1_columns
    else:
        try:
            cols = load_robot(skel.name).card.lafan1_columns
        except Exception:  # noqa: BLE001 - an unregistered (e.g. augmented or test) skeleton
            cols = None
    if cols and set(cols) == set(skel.joint_names):
        return tuple(cols)
    return skel.joint_names


def _joint_matrix(motion: TargetMotion, cols: tuple[str, ...]) -> np.ndarray:
    idx = [motion.skeleton.node_index(c) for c in cols]
    return np.asarray(motion.q, np.float64)[:, idx]


def write_csv(path: str | Path, motion: TargetMotion, *, decimals: int = 6, robot: Robot | None = None) -> Path:
    """The target's LAFAN1-style CSV (see module docstring); ``robot``: the target, when resolved already."""
    check_motion_finite(motion, path)
    cols = csv_columns(motion.skeleton, robot)
    quat = motion.base_quat()
    table = np.column_stack([motion.base_pos, quat[:, 1:4], quat[:, :1], _joint_matrix(motion, cols)])
    buf = io.StringIO()
    np.savetxt(buf, table, fmt=f"%.{decimals}f", delimiter=",")
    return atomic_write(path, buf.getvalue().encode())


def _angular_velocity(rot: np.ndarray, fps: float) -> np.ndarray:
    """(F, L, 3, 3) → (F, L, 3) world angular velocity [rad/s] (central differences, one-sided ends)."""
    r = torch.from_numpy(rot)
    F = r.shape[0]
    if F < 2:
        return np.zeros(rot.shape[:-1])
    nxt = torch.cat([r[1:], r[-1:]])
    prv = torch.cat([r[:1], r[:-1]])
    dt = torch.full((F,), 2.0 / fps, dtype=r.dtype)
    dt[0] = dt[-1] = 1.0 / fps
    w = matrix_to_axis_angle(nxt @ prv.transpose(-1, -2))  # world-frame increment
    return (w / dt[:, None, None]).numpy()


def resample_motion(motion: TargetMotion, fps: float) -> TargetMotion:
    """``motion`` at ``fps`` [Hz] on :func:`mer_data.motion.resample.output_times`' grid: angles and base
    position linearly, base orientation by slerp (as ``csv_to_npz`` and :func:`mer_data.motion.resample.resample`)."""
    from mer_data.motion.resample import output_times

    if fps <= 0 or not np.isfinite(fps):
        raise ValueError(f"fps must be a positive number, got {fps}")
    if fps == motion.fps or motion.num_frames < 2:
        return motion
    u = output_times(motion.num_frames, motion.fps, fps)
    i = np.minimum(np.floor(u).astype(int), motion.num_frames - 2)
    a = (u - i)[:, None]
    q = motion.q[i] * (1 - a) + motion.q[i + 1] * a
    base_pos = motion.base_pos[i] * (1 - a) + motion.base_pos[i + 1] * a
    quat = torch.from_numpy(motion.base_quat())
    rot = quat_to_matrix(quat_slerp(quat[i], quat[i + 1], torch.from_numpy(a[:, 0]))).numpy()
    return TargetMotion(motion.skeleton, float(fps), q, base_pos, rot)


def require_tracker(tracker: str | None, flag: str = "--npz-for") -> str:
    """``tracker`` if it is one of :data:`NPZ_TRACKERS`; else a :class:`MerError` that names both."""
    if tracker in NPZ_TRACKERS:
        return tracker
    said = "no tracker was named" if tracker is None else f"unknown tracker {tracker!r}"
    mj, bm = (f'{flag}"mjlab"', f'{flag}"beyondmimic"') if flag.endswith("=") else (f"{flag} mjlab", f"{flag} beyondmimic")
    raise MerError(
        f"an npz is read by one tracker, in its own joint and body order, and {said}: {mj} (MuJoCo's depth-first "
        f"order, mjlab's MotionLoader) or {bm} (Isaac Lab's breadth-first order, BeyondMimic's MotionLoader); neither "
        "loader reads the names, so the other order loads the wrong joints without an error",
        fix=f"add {mj} or {bm} (docs/trackers.md)",
    )


def npz_robot(skel: Skeleton, robot: Robot | None = None, path: str | Path | None = None) -> Robot:
    """The registered robot whose articulation an npz of ``skel`` holds: ``robot``, or the robot
    ``skel`` is named after; refused (OutputError) where ``skel`` is not that robot's skeleton (scaled,
    augmented): its articulation would not match the motion."""
    if robot is None:
        try:
            robot = load_robot(skel.name)
        except UnknownRobotError:
            robot = None
    if robot is None or robot.skeleton.fingerprint != skel.fingerprint:
        raise OutputError(
            f"the motion's skeleton {skel.name!r} is not a registered robot's (scaled or edited); an npz holds the "
            "robot's own articulation",
            path=path, fix="retarget to the registered robot, or write the CSV (-o) instead",
        )  # fmt: skip
    return robot


def write_npz(
    path: str | Path, motion: TargetMotion, *, tracker: str, fps: float | None = NPZ_FPS, robot: Robot | None = None
) -> Path:
    """The npz ``tracker`` (``"mjlab"`` or ``"beyondmimic"``) reads, at ``fps`` [Hz] (see the module
    docstring); ``robot``: the motion's robot, when resolved already.

    Raises:
        MerError: no or an unknown tracker (both choices named); OutputError: non-finite values, a
        skeleton that is not a registered robot's, a frame rate that is not a whole number of Hz.
    """
    tracker = require_tracker(tracker, "tracker=")
    check_motion_finite(motion, path)
    art = articulation(npz_robot(motion.skeleton, robot, path))
    if art.ball_joints:
        log.warning("%s: the MJCF's ball joints %s are written as three hinges each (_x, _y, _z), as in the model "
                    "`mer robots export --mjcf` writes, not as the MJCF's quaternions", path, ", ".join(art.ball_joints))  # fmt: skip
    if fps is not None:
        motion = resample_motion(motion, fps)
    rate = int(round(motion.fps))
    if abs(motion.fps - rate) > 1e-9 or rate <= 0:
        raise OutputError(f"an npz's fps is a whole number of Hz (the trackers' converters write an int), not {motion.fps:g}",
                          path=path, fix="give --npz-fps a whole number, e.g. 50")  # fmt: skip
    joints, bodies = art.order(tracker)
    jp = art.joint_values(motion.q)[:, joints]
    node_pos, node_rot = motion.forward_kinematics()
    pos, rot = art.body_poses(node_pos, node_rot)
    pos, rot = pos[:, bodies], rot[:, bodies]
    if tracker == "beyondmimic":  # Isaac Lab logs each link's centre-of-mass velocity
        com = np.stack([art.bodies[b].com for b in bodies])
        moving = pos + np.einsum("fbij,bj->fbi", rot, com)
    else:  # mjlab logs body_link_lin_vel_w: the body frame's origin
        moving = pos
    arrays = {
        # as each tracker's converter writes it: BeyondMimic `[output_fps]` of an int, mjlab's of a float
        "fps": np.array([rate], np.int64 if tracker == "beyondmimic" else np.float64),
        "joint_pos": jp.astype(np.float32),
        "joint_vel": finite_difference(torch.from_numpy(jp), motion.fps, dim=0).numpy().astype(np.float32),
        "body_pos_w": pos.astype(np.float32),
        "body_quat_w": matrix_to_quat(torch.from_numpy(rot)).numpy().astype(np.float32),
        "body_lin_vel_w": finite_difference(torch.from_numpy(moving), motion.fps, dim=0).numpy().astype(np.float32),
        "body_ang_vel_w": _angular_velocity(rot, motion.fps).astype(np.float32),
        "joint_names": np.array([art.joints[j].name for j in joints]),
        "body_names": np.array([art.bodies[b].name for b in bodies]),
    }
    require_finite(arrays, path=path, what="npz motion")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return atomic_write(path, buf.getvalue())


def write_mcap(
    path: str | Path, motion: TargetMotion, *, reference_points: np.ndarray | None = None, robot: Robot | None = None
) -> Path:
    """Foxglove MCAP of the motion (see the module docstring and :mod:`mer_data.shards.foxglove`).

    ``reference_points``: (F, K, 3) scaled reference key points [m] drawn as red spheres.
    ``robot``: the motion's robot (default: the registered robot the skeleton is named after, when
    the skeleton is that robot's; else the skeleton's own links are the frames).
    """
    from mcap.writer import Writer

    from mer_data.shards.foxglove import (
        DESCRIPTION_SCHEMA,
        FRAME_TRANSFORMS_SCHEMA,
        SCENE_UPDATE_SCHEMA,
        description_message,
        link_frames,
        robot_scene,
        skeleton_scene,
        sphere_scene,
        tf_messages,
    )

    check_motion_finite(motion, path)
    if reference_points is not None:
        require_finite({"reference_points": reference_points}, path=path, what="reference key points")
    skel = motion.skeleton
    try:
        robot = npz_robot(skel, robot, path)
    except OutputError:
        robot = None  # not a registered robot's skeleton: its nodes' links are the frames
    node_pos, node_rot = motion.forward_kinematics()
    frames = link_frames(skel, node_pos, node_rot, robot)
    buf = io.BytesIO()
    w = Writer(buf)
    w.start(profile="", library="mer")
    tf_schema = w.register_schema("foxglove.FrameTransforms", "jsonschema", FRAME_TRANSFORMS_SCHEMA)
    sc_schema = w.register_schema("foxglove.SceneUpdate", "jsonschema", SCENE_UPDATE_SCHEMA)
    tf = w.register_channel("/tf", "json", tf_schema)
    sk = w.register_channel("/skeleton", "json", sc_schema)
    w.add_message(sk, log_time=0, publish_time=0, data=skeleton_scene(skel, 0))
    if robot is not None:
        rb = w.register_channel("/robot", "json", sc_schema)
        w.add_message(rb, log_time=0, publish_time=0, data=robot_scene(robot, 0))
        text = description_message(robot)
        if text is not None:
            ds = w.register_channel("/robot_description", "json", w.register_schema("std_msgs/String", "jsonschema", DESCRIPTION_SCHEMA))
            w.add_message(ds, log_time=0, publish_time=0, data=text)
    msgs = tf_messages(frames, motion.fps)
    for seq, (ns, data) in enumerate(msgs):
        w.add_message(tf, log_time=ns, publish_time=ns, data=data, sequence=seq)
    if reference_points is not None:
        rc = w.register_channel("/reference", "json", sc_schema)
        for seq, (ns, _) in enumerate(msgs):
            msg = sphere_scene(reference_points[seq], ns, entity_id="reference")
            w.add_message(rc, log_time=ns, publish_time=ns, data=msg, sequence=seq)
    w.finish()
    return atomic_write(path, buf.getvalue())
