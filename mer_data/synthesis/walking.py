"""Synthetic motions generated in code (no LAFAN1 data is bundled: its licence forbids it).

:func:`walking_motion` makes a smooth, walking-like motion for any robot whose card has a LAFAN1
column layout (g1, h1, h1_2 among the built-ins): a sinusoidal gait of hips, knees and ankles (the
ankles keep the soles parallel to the ground), counter-swinging arms, a base that moves forward on
a gently curving path and is lowered every frame until the lowest foot point touches the ground.
It is what ``mer demo`` and the tests build shards from.
"""

from __future__ import annotations

import numpy as np
import torch

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.motion.lafan1 import Motion, lafan1_columns
from mer_data.robots.registry import load_robot

__all__ = ["walking_motion"]


def _side(name: str) -> str | None:
    n = name.lower()
    return "left" if "left" in n else "right" if "right" in n else None


def walking_motion(
    robot: str,
    seconds: float = 4.0,
    fps: float = 30.0,
    *,
    speed: float = 0.5,
    step_hz: float = 0.9,
    turn_rate: float = 0.1,
    phase: float = 0.0,
) -> Motion:
    """A walking-like motion of ``robot``.

    Args:
        seconds: duration [s]; ``fps``: frame rate [Hz] (frames = ``round(seconds * fps) + 1``).
        speed: forward speed [m/s]; ``step_hz``: gait cycles per second; ``turn_rate``: yaw rate [rad/s].
        phase: gait phase offset [rad] (to make several different clips).
    """
    r = load_robot(robot)
    skel = r.skeleton
    cols = lafan1_columns(r)
    node = {n: j for j, n in enumerate(skel.node_names)}
    F = int(round(seconds * fps)) + 1
    t = np.arange(F) / fps
    gait = 2 * np.pi * step_hz * t + phase
    q = np.zeros((F, skel.num_nodes))
    for side, off in (("left", 0.0), ("right", np.pi)):
        g = gait + off
        legs = [c for c in cols if _side(c) == side]
        hip = next((c for c in legs if "hip_pitch" in c), None)
        knee = next((c for c in legs if "knee" in c), None)
        ankle = next((c for c in legs if "ankle_pitch" in c), None) or next((c for c in legs if c.endswith("ankle_joint")), None)
        pitch_sign = {c: float(np.sign(skel.axes[node[c], 1]) or 1.0) for c in (hip, knee, ankle) if c}
        if hip:
            q[:, node[hip]] = pitch_sign[hip] * (-0.35 * np.sin(g) - 0.25)
        if knee:
            q[:, node[knee]] = 0.55 + 0.35 * np.maximum(0.0, np.sin(g + 0.5 * np.pi))
        if ankle:  # keep the sole level: the pitch angles along the leg sum to zero
            total = sum(pitch_sign[c] * q[:, node[c]] for c in (hip, knee) if c)
            q[:, node[ankle]] = -pitch_sign[ankle] * total
        arm = [c for c in cols if _side(c) == side]
        shoulder = next((c for c in arm if "shoulder_pitch" in c), None)
        elbow = next((c for c in arm if "elbow" in c), None)
        if shoulder:
            q[:, node[shoulder]] = 0.3 * np.sin(g + np.pi)
        if elbow:
            j = node[elbow]
            q[:, j] = np.clip(0.4 + 0.1 * np.sin(g), skel.lower[j], skel.upper[j])
    lo, hi = skel.lower, skel.upper
    margin = 0.02 * (hi - lo)
    q = np.clip(q, lo + margin, hi - margin)
    q[:, skel.node_kinds.index("base")] = 0.0

    yaw = turn_rate * t
    roll = 0.03 * np.sin(gait)
    quat = np.stack(  # yaw then roll, wxyz
        [
            np.cos(yaw / 2) * np.cos(roll / 2),
            np.cos(yaw / 2) * np.sin(roll / 2),
            np.sin(yaw / 2) * np.sin(roll / 2),
            np.sin(yaw / 2) * np.cos(roll / 2),
        ],
        axis=1,
    )
    if abs(turn_rate) > 1e-9:  # the path integrated exactly: frames depend only on their time
        xy = np.column_stack([np.sin(yaw), 1.0 - np.cos(yaw)]) * (speed / turn_rate)
    else:
        xy = np.column_stack([speed * t, np.zeros(F)])
    st = skeleton_tensors(skel, torch.float64)
    pos, _ = fk_skeleton(st, torch.from_numpy(q), torch.zeros(F, 3, dtype=torch.float64), base_quat=torch.from_numpy(quat))
    feet = [v for k, v in skel.keypoints.items() if v >= 0 and ("toe" in k or "ankle" in k)]
    lowest = pos[:, feet, 2].min(dim=1).values.numpy() if feet else pos[:, :, 2].min(dim=1).values.numpy()
    base = np.column_stack([xy, -lowest])
    idx = [node[c] for c in cols]
    return Motion(robot=r.name, fps=float(fps), base_pos=base, base_quat=quat, joints=q[:, idx], columns=cols)
