"""Foot contacts of a source motion: per frame and foot, is the foot on the ground?

A foot's *sole points* are its ankle and toe key points (whichever the skeleton has). Per frame,
the foot's height is that of its lowest sole point above the foot's *standing level* (a low
percentile of that height over the clip: robust to where a sole sits under its key points and to
a floor that is not at z = 0), and its speed the horizontal speed of that point. A foot goes down
when it is lower than ``on_height`` and slower than ``on_speed``, and comes up only when it is
higher than ``off_height`` or faster than ``off_speed`` (hysteresis: no flicker at the
thresholds). Defaults (docs/model.md §Evaluation): down below 3 cm and 0.4 m/s, up above 5 cm or
0.8 m/s, standing level the 5th percentile.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mer_data.skeleton import Skeleton

__all__ = ["ContactConfig", "FEET", "sole_points", "foot_contacts"]

FEET = ("left", "right")


@dataclass(frozen=True)
class ContactConfig:
    """Thresholds of :func:`foot_contacts` [m], [m/s]."""

    on_height: float = 0.03
    off_height: float = 0.05
    on_speed: float = 0.4
    off_speed: float = 0.8
    level_percentile: float = 5.0


def sole_points(skel: Skeleton) -> dict[str, list[int]]:
    """Foot → the nodes of its ankle and toe key points (empty where the skeleton has neither)."""
    return {side: [n for n in (skel.keypoints.get(f"{side}_ankle", -1), skel.keypoints.get(f"{side}_toe", -1)) if n >= 0]
            for side in FEET}  # fmt: skip


def foot_contacts(positions: np.ndarray, skel: Skeleton, fps: float, cfg: ContactConfig = ContactConfig()) -> np.ndarray:
    """Contact labels of a motion.

    Args:
        positions: (F, J, 3) world node positions [m] (e.g. features[..., 3:6]).
        skel: the motion's skeleton; fps: its frame rate [Hz].

    Returns:
        (F, 2) bool, columns left and right foot (all False for a foot without sole points).
    """
    pos = np.asarray(positions, np.float64)
    F = pos.shape[0]
    out = np.zeros((F, len(FEET)), bool)
    for i, nodes in enumerate(sole_points(skel).values()):
        if not nodes or F == 0:
            continue
        z = pos[:, nodes, 2]
        low = z.argmin(1)
        h = z[np.arange(F), low]
        h = h - np.percentile(h, cfg.level_percentile)
        xy = pos[:, nodes, :2][np.arange(F), low]  # the lowest point's position...
        nxt = pos[np.minimum(np.arange(F) + 1, F - 1)][:, nodes, :2][np.arange(F), low]  # ...that point a frame on
        prv = pos[np.maximum(np.arange(F) - 1, 0)][:, nodes, :2][np.arange(F), low]
        steps = np.where(np.arange(F)[:, None] < F - 1, nxt - xy, xy - prv)
        speed = np.linalg.norm(steps, axis=1) * fps
        down = False
        for t in range(F):
            if down:
                down = not (h[t] > cfg.off_height or speed[t] > cfg.off_speed)
            else:
                down = h[t] < cfg.on_height and speed[t] < cfg.on_speed
            out[t, i] = down
    return out
