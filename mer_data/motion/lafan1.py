"""LAFAN1 robot motion files: reading and writing ``.csv`` / ``.csv.gz`` in a robot's column layout.

Layout (no header, comma separated, one frame per row)::

    root x, y, z [m, world, z up], root quaternion x, y, z, w (scalar LAST), joint angles [rad]

with the joint angles in the order of the robot card's ``lafan1_columns`` (g1: 29, h1: 19, h1_2: 27
joints). Any registered robot whose card names such a column order is read the same way. Inside mer
quaternions are scalar-first (w, x, y, z): the conversion happens here, at the edge.
"""

from __future__ import annotations

import gzip
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import MerError, MotionFormatError
from mer_data.base.finite import require_finite
from mer_data.base.safe_io import gunzip_limited, read_regular_file
from mer_data.robots.registry import Robot, as_robot
from mer_data.skeleton import Skeleton

from .csv_numeric import parse_numeric_csv
from .plausibility import check_motion_arrays

log = logging.getLogger(__name__)

__all__ = [
    "Motion",
    "QUAT_TOLERANCE",
    "ROOT_COLUMNS",
    "lafan1_columns",
    "read_motion_bytes",
    "decompress_motion",
    "parse_lafan1",
    "read_lafan1_csv",
    "write_lafan1_csv",
    "motion_suffixes",
]

#: A root quaternion whose norm differs from 1 by at most this is renormalized; beyond, refused.
#: (Six printed decimals put the norm within ~2e-6 of 1; the real G1/H1 data stays within 9e-7.)
QUAT_TOLERANCE = 1e-3
ROOT_COLUMNS = ("root_pos_x", "root_pos_y", "root_pos_z", "root_quat_x", "root_quat_y", "root_quat_z", "root_quat_w")


def motion_suffixes() -> tuple[str, ...]:
    """File name endings read as motions."""
    return (".csv", ".csv.gz")


@dataclass(frozen=True, eq=False)
class Motion:
    """One robot motion sampled at ``fps``.

    Attributes:
        robot: registered robot name.
        fps: frame rate [Hz].
        base_pos: (F, 3) float64 base position in the world [m].
        base_quat: (F, 4) float64 unit base orientation, **wxyz**, world <- base.
        joints: (F, D) float64 joint angles [rad], in the order of ``columns``.
        columns: (D,) URDF joint names.
        warnings: what :mod:`mer_data.motion.plausibility` found unusual when the file was read.
    """

    robot: str
    fps: float
    base_pos: np.ndarray
    base_quat: np.ndarray
    joints: np.ndarray
    columns: tuple[str, ...]
    warnings: tuple[str, ...] = ()

    @property
    def num_frames(self) -> int:
        return int(self.base_pos.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def node_angles(self, skel: Skeleton) -> np.ndarray:
        """(F, J) float64 angle per skeleton node (0 at the base, sites and unlisted nodes)."""
        idx = _column_nodes(skel, self.columns)
        q = np.zeros((self.num_frames, skel.num_nodes))
        q[:, idx] = self.joints
        return q

    def with_arrays(self, **kw) -> "Motion":
        return replace(self, **kw)


def _column_nodes(skel: Skeleton, columns: tuple[str, ...]) -> np.ndarray:
    name_to_node = {n: j for j, n in enumerate(skel.node_names) if skel.node_kinds[j] == "revolute"}
    missing = [c for c in columns if c not in name_to_node]
    if missing:
        raise MotionFormatError(
            f"{skel.name}: motion columns {missing} are not joints of the skeleton",
            element="lafan1_columns",
            fix="lafan1_columns in the robot card must name the robot's actuated URDF joints",
        )
    return np.array([name_to_node[c] for c in columns], dtype=np.int64)


def lafan1_columns(robot: Robot) -> tuple[str, ...]:
    """The joint column order of a robot's CSV layout: its card's ``lafan1_columns`` (the LAFAN1
    robot datasets' order: g1, h1, h1_2), else mer's own layout, the skeleton's actuated joints in
    node order (what ``mer retarget -o`` writes for every other robot).

    Raises:
        MotionFormatError: the card's layout does not match the skeleton.
    """
    r = robot
    cols = r.card.lafan1_columns
    if not cols:
        return tuple(r.skeleton.joint_names)
    joints = set(r.skeleton.joint_names)
    missing, extra = sorted(joints - set(cols)), [c for c in cols if c not in joints]
    if missing or extra or len(set(cols)) != len(cols):
        raise MotionFormatError(
            f"lafan1_columns of {r.name!r} must list every actuated joint once"
            + (f"; missing {missing}" if missing else "")
            + (f"; not actuated joints: {extra}" if extra else ""),
            path=r.card.path,
            element="lafan1_columns",
            fix="list each actuated URDF joint exactly once, in the CSV's order",
        )
    return tuple(cols)


def read_motion_bytes(path: str | Path) -> bytes:
    """The bytes of a ``.csv`` or ``.csv.gz`` file (decompressed).

    Only regular files are read (a directory, FIFO, dangling link or link loop is refused before
    anything is opened for reading), and neither the file nor its decompressed content may exceed
    ``MER_MAX_MOTION_BYTES`` (:mod:`mer_data.base.limits`).
    """
    p = Path(path)
    return decompress_motion(read_motion_file(p), p)


def read_motion_file(path: str | Path) -> bytes:
    """The raw bytes of a motion file (still gzipped for ``.gz``), checked as :func:`read_motion_bytes` says."""
    return read_regular_file(
        path, MotionFormatError, "MER_MAX_MOTION_BYTES", fix="pass a regular .csv or .csv.gz file of robot motion"
    )


def decompress_motion(raw: bytes, path: str | Path) -> bytes:
    """``raw`` file bytes -> CSV bytes (gunzipped when ``path`` ends in ``.gz``, at most
    ``MER_MAX_MOTION_BYTES`` of output: a gzip bomb is refused, not expanded)."""
    if not str(path).endswith(".gz"):
        return raw
    return gunzip_limited(raw, path, MotionFormatError, "MER_MAX_MOTION_BYTES")


def _looks_like(exc: MotionFormatError, data: bytes, robot: Robot) -> MotionFormatError:
    """``exc`` where the first row's column count is another registered robot's layout: then saying
    which robot(s) it looks like, and to give that ``--source``."""
    n = data.split(b"\n", 1)[0].count(b",") + 1
    if exc.line is None or n == len(ROOT_COLUMNS) + len(lafan1_columns(robot)):
        return exc
    from mer_data.robots.registry import list_robots

    alike = []
    for other in list_robots():
        try:
            if other.name != robot.name and len(ROOT_COLUMNS) + len(lafan1_columns(other)) == n:
                alike.append(other.name)
        except MerError:
            continue  # a robot without a LAFAN1 layout
    if not alike:
        return exc
    return MotionFormatError(f"{exc.message}; {n} columns is the layout of {' or '.join(alike)}, not {robot.name}",
                             path=exc.path, line=exc.line, element=exc.element,
                             fix=f"give the robot the file belongs to: --source {alike[0]}"
                                 f"{' (or ' + ', '.join(alike[1:]) + ')' if len(alike) > 1 else ''}")  # fmt: skip


def parse_lafan1(
    data: bytes,
    robot: Robot,
    *,
    path: str | Path = "<bytes>",
    fps: float = 30.0,
    quat_tolerance: float = QUAT_TOLERANCE,
    plausibility: bool = True,
) -> Motion:
    """Parse LAFAN1 CSV bytes of ``robot`` into a :class:`Motion` (quaternion converted to wxyz).

    With ``plausibility`` (the default) the values are checked by
    :func:`mer_data.motion.plausibility.check_motion_arrays`: the impossible is refused (MotionFormatError
    with line and column), the unusual is logged and kept in ``Motion.warnings``.
    """
    r = robot
    cols = lafan1_columns(r)
    ncols = len(ROOT_COLUMNS) + len(cols)
    what = f"{r.name}: root xyz, root quaternion xyzw, {len(cols)} joint angles"
    try:
        a = parse_numeric_csv(data, ncols, path=str(path), what=what)
    except MotionFormatError as exc:
        raise _looks_like(exc, data, r) from None
    if not (fps > 0 and np.isfinite(fps)):
        raise MotionFormatError(f"frame rate must be positive, got {fps}", path=path)
    xyzw = a[:, 3:7]
    norm = np.sqrt(np.einsum("ij,ij->i", xyzw, xyzw))
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= quat_tolerance))
    if len(bad):
        i = int(bad[0])
        raise MotionFormatError(
            f"root quaternion (columns 4-7) has norm {norm[i]:.6g}, not 1 within {quat_tolerance:g} "
            f"({len(bad)} frame(s) like this)",
            path=path,
            line=i + 1,
            element="root quaternion",
            fix="columns 4-7 must be the unit quaternion x, y, z, w (scalar last); check the column order",
        )
    quat = np.empty((len(a), 4))
    quat[:, 0] = xyzw[:, 3]
    quat[:, 1:] = xyzw[:, :3]
    quat /= norm[:, None]
    base_pos, joints = np.ascontiguousarray(a[:, :3]), np.ascontiguousarray(a[:, 7:])
    warnings: list[str] = []
    if plausibility:
        warnings = check_motion_arrays(base_pos, quat, joints, cols, r.skeleton, float(fps), path=path)
        for w in warnings:
            log.warning("unusual motion: %s", w)
    return Motion(
        robot=r.name,
        fps=float(fps),
        base_pos=base_pos,
        base_quat=quat,
        joints=joints,
        columns=cols,
        warnings=tuple(warnings),
    )


def read_lafan1_csv(
    path: str | Path, robot: str | Robot, *, fps: float = 30.0, quat_tolerance: float = QUAT_TOLERANCE
) -> Motion:
    """Read a LAFAN1 ``.csv`` / ``.csv.gz`` motion of ``robot`` (a name is resolved here, once).

    Raises:
        MotionFormatError: naming the file, the line and the cell (wrong column count, non-numeric
            or non-finite cell, truncated last row, empty file, non-unit quaternion).
        UnknownRobotError: ``robot`` is not registered.
    """
    r = as_robot(robot)  # unknown robot: fail before reading
    return parse_lafan1(read_motion_bytes(path), r, path=path, fps=fps, quat_tolerance=quat_tolerance)


def write_lafan1_csv(path: str | Path, motion: Motion, *, decimals: int = 6, robot: Robot | None = None) -> Path:
    """Write ``motion`` in its robot's LAFAN1 layout (gzip-compressed when the name ends in ``.gz``).

    The joint columns are written in the card's order, whatever order ``motion.columns`` has.
    ``robot``: the motion's robot when the caller has it resolved (else looked up by ``motion.robot``).
    """
    cols = lafan1_columns(robot if robot is not None else as_robot(motion.robot))
    pos = {c: i for i, c in enumerate(motion.columns)}
    missing = [c for c in cols if c not in pos]
    if missing:
        raise MotionFormatError(f"the motion has no column for joints {missing}", path=path)
    require_finite({"base_pos": motion.base_pos, "base_quat": motion.base_quat, "joints": motion.joints}, path=path,
                   what="motion")  # fmt: skip
    q = motion.base_quat
    table = np.column_stack([motion.base_pos, q[:, 1:4], q[:, 0:1], motion.joints[:, [pos[c] for c in cols]]])
    lines = "\n".join(",".join(f"{v:.{decimals}f}" for v in row) for row in table) + "\n"
    data = lines.encode()
    p = Path(path)
    return atomic_write(p, gzip.compress(data, mtime=0) if p.name.endswith(".gz") else data)
