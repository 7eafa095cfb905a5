"""Writers of a retargeted motion: LAFAN1-style CSV, BeyondMimic npz, Foxglove MCAP.

All take a :class:`TargetMotion` and write atomically (temporary file, then rename).

**CSV** (no header, comma separated, 6 decimals, one row per frame)::

    root x, y, z [m], root quaternion x, y, z, w (scalar last), joint angles [rad]

The joints are in the order of the robot card's ``lafan1_columns`` when it has one (g1, h1,
h1_2: the LAFAN1 robot layout), else in the skeleton's node order (``Skeleton.joint_names``: the
actuated URDF joints, depth-first; ``mer robots show NAME`` lists them). :func:`csv_columns` gives
the order.

**npz** (the mjlab / BeyondMimic ``csv_to_npz`` layout, resampled like ``csv_to_npz`` to
``fps`` = 50 Hz by default, the trackers' control rate: angles and positions linearly, the base
orientation by slerp; ``fps=None`` keeps the motion's rate): ``fps``, ``joint_pos``
(F, D), ``joint_vel`` (F, D), ``body_pos_w`` (F, L, 3), ``body_quat_w`` (F, L, 4, **wxyz**),
``body_lin_vel_w``, ``body_ang_vel_w`` (F, L, 3, world frame), plus ``joint_names`` (D,) (the CSV's
joint order) and ``body_names`` (L,): the URDF links of the base and of every joint node.
``order="mjlab"`` (default) keeps the CSV's joint order and mer's skeleton (URDF, depth-first) body
order, which for G1 is MuJoCo's / mjlab's; ``order="isaaclab"`` writes joints and bodies in Isaac
Lab's articulation order (breadth-first), as BeyondMimic's npz has them, for the robots in
:data:`ISAACLAB_VERIFIED` (:func:`isaaclab_order`).

**MCAP**: JSON channels ``/tf`` (``foxglove.FrameTransforms``, one message per frame) and
``/skeleton`` (``foxglove.SceneUpdate``), plus ``/reference`` (``foxglove.SceneUpdate`` spheres at
the scaled reference key points) when given. The schemas embedded are Foxglove's official JSON
schemas (:mod:`mer_data.shards.foxglove`), so Foxglove's and Lichtblick's 3D panels draw them.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mer_data.base.atomic import atomic_write
from mer_data.base.finite import require_finite
from mer_data.kinematics.fk import fk_skeleton, link_rotations, skeleton_tensors
from mer_data.kinematics.rotations import matrix_to_axis_angle, matrix_to_quat, quat_slerp, quat_to_matrix
from mer_data.motion.features import finite_difference
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
    "isaaclab_order",
    "NPZ_FPS",
    "NPZ_ORDERS",
    "ISAACLAB_VERIFIED",
]

#: Frame rate of npz outputs: the control rate of the mjlab / BeyondMimic trackers [Hz].
NPZ_FPS = 50.0
#: Joint/body layouts of npz outputs: mjlab (URDF order, MuJoCo's) or isaaclab (breadth-first, BeyondMimic's).
NPZ_ORDERS = ("mjlab", "isaaclab")
#: Robots whose breadth-first order :func:`isaaclab_order` has been checked against Isaac Lab's
#: published articulation order (tests/models/export/test_npz_order.py); others are refused for ``isaaclab``.
ISAACLAB_VERIFIED = frozenset({"g1"})


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


def isaaclab_order(skel: Skeleton) -> tuple[tuple[str, ...], list[int]]:
    """Isaac Lab's articulation order of ``skel``: (joint names, body node indices).

    PhysX parses an articulation breadth-first: the root link, then its children, then theirs, each
    link's children in the order the URDF declares them (the USD prim order); fixed-joint links are
    merged into their parents (Isaac Lab's URDF importer default), as they are in mer's skeleton.
    Joints follow their child links. Verified for the robots in :data:`ISAACLAB_VERIFIED`; raises
    :class:`~mer_data.base.errors.OutputError` for any other robot (importer settings, locked joints and
    prim order can differ, so the order is not guaranteed there).
    """
    from mer_data.base.errors import OutputError

    if skel.name not in ISAACLAB_VERIFIED:
        raise OutputError(
            f"the Isaac Lab joint/body order is verified only for {', '.join(sorted(ISAACLAB_VERIFIED))}, not for {skel.name!r}",
            element="npz order 'isaaclab'",
            fix="write the default mjlab order (--npz-order mjlab) and reorder by the npz's joint_names/body_names "
            "to your articulation's robot.joint_names/body_names, or convert mer's CSV with the tracker's csv_to_npz (docs/trackers.md)",
        )
    order, queue = [], [0]
    while queue:
        j = queue.pop(0)
        order.append(j)
        queue += [c for c in skel.children(j) if skel.node_kinds[c] != "site"]
    return tuple(skel.node_names[j] for j in order[1:]), order


def body_arrays(motion: TargetMotion, links: list[int] | None = None) -> dict[str, np.ndarray]:
    """Body (URDF link) poses and velocities of the nodes ``links`` (default: the base and every
    joint node, in node order): names (L,), positions (F, L, 3) [m], quaternions (F, L, 4) wxyz,
    linear (F, L, 3) [m/s] and angular (F, L, 3) [rad/s] velocities, world frame."""
    skel = motion.skeleton
    pos, rot = motion.forward_kinematics()
    if links is None:
        links = [j for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"]
    lrot = link_rotations(torch.from_numpy(rot), torch.from_numpy(np.array(skel.rest_rotations))).numpy()[:, links]
    bpos = pos[:, links]
    return {
        "body_names": np.array([skel.link_names[j] for j in links]),
        "body_pos_w": bpos,
        "body_quat_w": matrix_to_quat(torch.from_numpy(lrot)).numpy(),
        "body_lin_vel_w": finite_difference(torch.from_numpy(bpos), motion.fps, dim=0).numpy(),
        "body_ang_vel_w": _angular_velocity(lrot, motion.fps),
    }


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


def write_npz(path: str | Path, motion: TargetMotion, *, fps: float | None = NPZ_FPS, order: str = "mjlab", robot: Robot | None = None) -> Path:
    """The mjlab / BeyondMimic npz at ``fps`` [Hz], joints and bodies in ``order`` (one of
    :data:`NPZ_ORDERS`; see module docstring)."""
    from mer_data.base.errors import OutputError

    if order not in NPZ_ORDERS:
        raise OutputError(f"unknown npz order {order!r}", path=path, fix=f"use one of {', '.join(NPZ_ORDERS)}")
    check_motion_finite(motion, path)
    links = None
    if order == "isaaclab":
        cols, links = isaaclab_order(motion.skeleton)
    else:
        cols = csv_columns(motion.skeleton, robot)
    if fps is not None:
        motion = resample_motion(motion, fps)
    jp = _joint_matrix(motion, cols)
    arrays = {
        "fps": np.array(motion.fps),
        "joint_pos": jp.astype(np.float32),
        "joint_vel": finite_difference(torch.from_numpy(jp), motion.fps, dim=0).numpy().astype(np.float32),
        "joint_names": np.array(cols),
    }
    for k, v in body_arrays(motion, links).items():
        arrays[k] = v if k == "body_names" else v.astype(np.float32)
    require_finite(arrays, path=path, what="npz motion")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return atomic_write(path, buf.getvalue())


def write_mcap(path: str | Path, motion: TargetMotion, *, reference_points: np.ndarray | None = None) -> Path:
    """Foxglove MCAP of the motion (see module docstring).

    ``reference_points``: (F, K, 3) scaled reference key points [m] drawn as red spheres.
    """
    from mcap.writer import Writer

    from mer_data.shards.foxglove import (
        FRAME_TRANSFORMS_SCHEMA,
        SCENE_UPDATE_SCHEMA,
        frame_transforms,
        scene_update,
        sphere_scene,
    )

    check_motion_finite(motion, path)
    if reference_points is not None:
        require_finite({"reference_points": reference_points}, path=path, what="reference key points")
    skel = motion.skeleton
    prefix = skel.name
    base_rotvec = matrix_to_axis_angle(torch.from_numpy(motion.base_rot)).numpy()
    buf = io.BytesIO()
    w = Writer(buf)
    w.start(profile="", library="mer")
    tf_schema = w.register_schema("foxglove.FrameTransforms", "jsonschema", FRAME_TRANSFORMS_SCHEMA)
    sc_schema = w.register_schema("foxglove.SceneUpdate", "jsonschema", SCENE_UPDATE_SCHEMA)
    tf = w.register_channel("/tf", "json", tf_schema)
    sk = w.register_channel("/skeleton", "json", sc_schema)
    frames = frame_transforms(skel, prefix, motion.base_pos, base_rotvec, motion.q, 0, motion.fps)
    w.add_message(sk, log_time=0, publish_time=0, data=scene_update(skel, prefix, 0))
    for seq, (ns, data) in enumerate(frames):
        w.add_message(tf, log_time=ns, publish_time=ns, data=data, sequence=seq)
    if reference_points is not None:
        rc = w.register_channel("/reference", "json", sc_schema)
        for seq, (ns, _) in enumerate(frames):
            msg = sphere_scene(reference_points[seq], ns, entity_id="reference")
            w.add_message(rc, log_time=ns, publish_time=ns, data=msg, sequence=seq)
    w.finish()
    return atomic_write(path, buf.getvalue())
