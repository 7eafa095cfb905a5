"""A human given as joint rotations (SMPL-family parameters, or rotations derived from joint positions)
turned into the :class:`~mer_data.motion.bvh.BvhMotion` the BVH route reads.

Every human source becomes a skeleton the same way (:mod:`mer_data.motion.human`): a hierarchy of
joints with offsets and per-joint rotation channels. :func:`rig_motion` writes a rotation per joint
and frame as three Euler channels (degrees) and the root's position as three position channels, so
:func:`~mer_data.motion.human.human_skeleton`, key points, scaling and contacts need nothing new.

* **Euler orders** (:func:`channel_order`): a joint's three channels are an intrinsic Euler
  decomposition of its local rotation; the order puts the axis a human joint rarely turns 90 deg
  about in the middle (where the decomposition is singular) for the SMPL rest frame (y up, z
  forward, x to the subject's left): legs and trunk ``XZY`` (bend about x, small side bend about z),
  shoulders and wrists ``ZXY`` (the twist about the arm's x in the middle), elbows ``YZX``. Forward
  kinematics is exact whatever the order; the order only keeps the angles continuous in time.
* **Up axis**: the caller gives the (3, 3) rotation from the file's axes to z up; it is applied to
  the root's rotation and position here, so the motion is written z up (``up="z"``).
* **Facing**: a constant yaw about z so that the figure's left (left hip minus right hip) points
  along +y at the first frame, as the BVH reader does.
* **Frame rate**: rotations are resampled to 30 Hz here by slerp (positions by linear
  interpolation) when the rate is not a multiple of 30 Hz, so no Euler angle is ever interpolated;
  frames on the 30 Hz grid are copied as they are.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .bvh import BvhJoint, BvhMotion, split_joint_name

__all__ = ["channel_order", "rig_motion", "resample_rotations", "RIG_FPS"]

#: The rate a rigged motion is written at when the source's is not a multiple of it [Hz].
RIG_FPS = 30.0

_ARM = {"shoulder": "ZXY", "wrist": "ZXY", "hand": "ZXY", "elbow": "YZX"}


def channel_order(name: str) -> str:
    """Intrinsic Euler order of a joint's rotation channels (module docstring), from its name."""
    side, core = split_joint_name(name)
    return _ARM.get(core, "XZY") if side is not None else "XZY"


def resample_rotations(rot: np.ndarray, root_pos: np.ndarray, fps: float, to: float = RIG_FPS):
    """(F, J, 3, 3) rotations and (F, 3) positions at ``fps`` -> the same at ``to`` [Hz] (module
    docstring): frames copied where ``fps`` is a multiple of ``to``, else slerp / lerp. Returns
    (rot, root_pos, fps)."""
    F = rot.shape[0]
    step = fps / to
    if abs(step - round(step)) < 1e-6 and round(step) >= 1:
        k = int(round(step))
        return rot[::k], root_pos[::k], fps / k
    if F < 2:
        return rot, root_pos, to
    t = np.arange(F) / fps
    tq = np.arange(0.0, t[-1] + 1e-9, 1.0 / to)
    J = rot.shape[1]
    out = np.empty((len(tq), J, 3, 3))
    for j in range(J):
        out[:, j] = Slerp(t, Rotation.from_matrix(rot[:, j]))(tq).as_matrix()
    pos = np.stack([np.interp(tq, t, root_pos[:, i]) for i in range(3)], axis=1)
    return out, pos, to


def rig_motion(
    path: str,
    names: Sequence[str],
    parents: Sequence[int],
    offsets: np.ndarray,
    rot: np.ndarray,
    root_pos: np.ndarray,
    fps: float,
    to_z_up: np.ndarray,
    notes: Sequence[str] = (),
) -> BvhMotion:
    """A motion of joint rotations as a :class:`BvhMotion` (module docstring), metres, z up.

    Args:
        path: the source file (shown in errors).
        names: (J,) joint names (parents first); parents: (J,) parent index, -1 for the root (joint 0).
        offsets: (J, 3) each joint's position in its parent's frame at rest [m] (the root's: unused).
        rot: (F, J, 3, 3) local rotations (the root's: in the file's world axes).
        root_pos: (F, 3) the root joint's position in the file's world axes [m].
        fps: frame rate [Hz]; to_z_up: (3, 3) file axes -> z up.
    """
    rot = np.asarray(rot, np.float64)
    root_pos = np.asarray(root_pos, np.float64)
    rot, root_pos, fps = resample_rotations(rot, root_pos, fps)
    rot = rot.copy()
    rot[:, 0] = to_z_up @ rot[:, 0]
    root_pos = root_pos @ to_z_up.T
    F, J = rot.shape[:2]
    joints, cols = [], []
    column = 0
    for k in range(J):
        order = channel_order(names[k])
        chans = (("Xposition", "Yposition", "Zposition") if k == 0 else ()) + tuple(f"{a}rotation" for a in order)
        off = (0.0, 0.0, 0.0) if k == 0 else tuple(float(v) for v in offsets[k])
        joints.append(BvhJoint(names[k], int(parents[k]), off, chans, column, 0))
        eul = Rotation.from_matrix(rot[:, k]).as_euler(order, degrees=True)  # intrinsic (upper case)
        cols.append(np.concatenate([root_pos, eul], axis=1) if k == 0 else eul)
        column += len(chans)
    values = np.ascontiguousarray(np.concatenate(cols, axis=1), np.float64)
    values.setflags(write=False)
    yaw = _facing_yaw(joints, values)
    return BvhMotion(str(path), tuple(joints), values, 1.0 / fps, float(fps), "m", "z", yaw, 1,
                     (*notes, f"facing: turned {math.degrees(yaw):.1f} deg about z so that the left side is +y at frame 1"))


def _facing_yaw(joints: list[BvhJoint], values: np.ndarray) -> float:
    """Yaw [rad] turning the left hip minus the right hip at frame 1 to +y (0 without named hips)."""
    from .bvh import fk

    sides = {split_joint_name(j.name): k for k, j in enumerate(joints)}
    left, right = sides.get(("left", "hip")), sides.get(("right", "hip"))
    if left is None or right is None:
        return 0.0
    pos, _ = fk(joints, values[:1])
    v = pos[0, left] - pos[0, right]
    yaw = math.pi / 2 - math.atan2(v[1], v[0])
    return math.atan2(math.sin(yaw), math.cos(yaw))
