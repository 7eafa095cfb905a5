"""Plausibility of a motion read from a file: refuse the physically impossible, warn on the unusual.

Checked on the frames as read (before resampling), so every message names the file, the CSV line
(frame ``i`` is line ``i + 1``) and the column (1-3 root x, y, z; 4-7 root quaternion; 8.. joints
in the robot card's ``lafan1_columns`` order).

=========================  ==========================  ==============================
quantity                   refused (impossible)        warned (unusual)
=========================  ==========================  ==============================
root coordinate            ``|x|, |y|, |z| > 1e4 m``   ``z < -1 m`` or ``z > 5 m``
joint angle                > pi rad past a limit       > 0.5 rad past a limit
root speed (frame diff)    > 1000 m/s                  > 15 m/s
joint speed (frame diff)   > 1000 rad/s                > 60 rad/s
root angular speed         --                          > 60 rad/s
=========================  ==========================  ==============================

Continuous joints are only bounded in magnitude (``|q| > 1e4 rad`` refused) and speed: their angle
may wind. On the 80 real LAFAN1 G1/H1 clips nothing is refused; the warnings are listed in
docs/shards.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mer_data.base.errors import MotionFormatError
from mer_data.skeleton import Skeleton

__all__ = ["Bounds", "BOUNDS", "check_motion_arrays"]


@dataclass(frozen=True)
class Bounds:
    """Thresholds of :func:`check_motion_arrays` (SI units: m, rad, s)."""

    max_root_coordinate: float = 1e4
    warn_root_z: tuple[float, float] = (-1.0, 5.0)
    max_beyond_limit: float = math.pi
    warn_beyond_limit: float = 0.5
    max_continuous_angle: float = 1e4
    max_root_speed: float = 1000.0
    warn_root_speed: float = 15.0
    max_joint_speed: float = 1000.0
    warn_joint_speed: float = 60.0
    warn_root_angular_speed: float = 60.0


BOUNDS = Bounds()
_FIX = "check the column order, the units (metres, radians: not millimetres or degrees) and the --fps of the file"


def _first(mask: np.ndarray) -> tuple[int, int, int]:
    """(row, column, count) of the first True of a (F, C) mask."""
    rows, cols = np.nonzero(mask)
    return int(rows[0]), int(cols[0]), int(len(rows))


def _refuse(msg: str, path, row: int, column: str) -> MotionFormatError:
    return MotionFormatError(msg, path=path, line=row + 1, element=column, fix=_FIX)


def check_motion_arrays(
    base_pos: np.ndarray,
    base_quat: np.ndarray,
    joints: np.ndarray,
    columns: tuple[str, ...],
    skel: Skeleton,
    fps: float,
    *,
    path: str | Path = "<motion>",
    bounds: Bounds = BOUNDS,
) -> list[str]:
    """Check a motion as read from its file; return the warnings, raise on the impossible.

    Args:
        base_pos: (F, 3) root position [m]; base_quat: (F, 4) unit quaternion (any order: only
            ``|<q_i, q_i+1>|`` is used); joints: (F, D) angles [rad] of ``columns``.
        skel: the robot's skeleton (limits, continuous joints); fps: frame rate of the file [Hz].

    Raises:
        MotionFormatError: naming the file, the line and the column of the first impossible value.
    """
    b = bounds
    warnings: list[str] = []
    nodes = np.array([skel.node_index(c) for c in columns], dtype=np.int64)
    cont = np.asarray(skel.continuous, bool)[nodes]
    lo, hi = skel.lower[nodes], skel.upper[nodes]

    far = np.abs(base_pos) > b.max_root_coordinate
    if far.any():
        r, c, n = _first(far)
        raise _refuse(
            f"root coordinate {base_pos[r, c]:.6g} m in column {c + 1} is beyond +-{b.max_root_coordinate:g} m "
            f"({n} value(s) like this)", path, r, f"column {c + 1}",
        )  # fmt: skip
    z = base_pos[:, 2]
    odd = (z < b.warn_root_z[0]) | (z > b.warn_root_z[1])
    if odd.any():
        r = int(np.flatnonzero(odd)[0])
        warnings.append(
            f"{path}:{r + 1}: root height {z[r]:.3g} m (column 3) is outside {b.warn_root_z[0]:g}..{b.warn_root_z[1]:g} m "
            f"({int(odd.sum())} frame(s))"
        )

    beyond = np.maximum(lo - joints, joints - hi)
    beyond[:, cont] = np.abs(joints[:, cont]) - b.max_continuous_angle + b.max_beyond_limit
    bad = beyond > b.max_beyond_limit
    if bad.any():
        r, c, n = _first(bad)
        raise _refuse(
            f"joint {columns[c]!r} (column {c + 8}) is at {joints[r, c]:.6g} rad, far outside its limits "
            f"[{lo[c]:.4g}, {hi[c]:.4g}] ({n} value(s) more than {b.max_beyond_limit:.4g} rad past a limit)",
            path, r, f"column {c + 8}",
        )  # fmt: skip
    odd = beyond > b.warn_beyond_limit
    odd[:, cont] = False
    if odd.any():
        r, c, n = _first(odd)
        warnings.append(
            f"{path}:{r + 1}: joint {columns[c]!r} (column {c + 8}) at {joints[r, c]:.4g} rad is "
            f"{beyond[r, c]:.3g} rad outside its limits [{lo[c]:.4g}, {hi[c]:.4g}] ({n} value(s) past {b.warn_beyond_limit:g} rad)"
        )

    if len(base_pos) < 2:
        return warnings
    speed = np.linalg.norm(np.diff(base_pos, axis=0), axis=1) * fps
    _speed_check(speed[:, None], b.max_root_speed, b.warn_root_speed, "m/s", lambda c: "root position (columns 1-3)", path, warnings)
    jspeed = np.abs(np.diff(joints, axis=0)) * fps
    _speed_check(jspeed, b.max_joint_speed, b.warn_joint_speed, "rad/s", lambda c: f"joint {columns[c]!r} (column {c + 8})", path, warnings)
    dot = np.abs(np.einsum("ij,ij->i", base_quat[1:], base_quat[:-1])).clip(0.0, 1.0)
    wspeed = 2.0 * np.arccos(dot) * fps
    odd = wspeed > b.warn_root_angular_speed
    if odd.any():
        r = int(np.flatnonzero(odd)[0])
        warnings.append(
            f"{path}:{r + 2}: the root turns at {wspeed[r]:.3g} rad/s between lines {r + 1} and {r + 2} "
            f"(columns 4-7; {int(odd.sum())} frame(s) over {b.warn_root_angular_speed:g} rad/s)"
        )
    return warnings


def _speed_check(speed, refuse: float, warn: float, unit: str, what, path, warnings: list[str]) -> None:
    """Speeds (F-1, C) from consecutive frames: refuse past ``refuse``, warn past ``warn``."""
    bad = speed > refuse
    if bad.any():
        r, c, n = _first(bad)
        raise MotionFormatError(
            f"{what(c)} moves at {speed[r, c]:.6g} {unit} between lines {r + 1} and {r + 2}, beyond the "
            f"physically possible {refuse:g} {unit} ({n} step(s) like this)",
            path=path,
            line=r + 2,
            element=what(c),
            fix=_FIX + "; a file that joins several takes must be split at the jump",
        )
    odd = speed > warn
    if odd.any():
        r, c, n = _first(odd)
        warnings.append(
            f"{path}:{r + 2}: {what(c)} moves at {speed[r, c]:.3g} {unit} between lines {r + 1} and {r + 2} "
            f"({n} step(s) over {warn:g} {unit})"
        )
