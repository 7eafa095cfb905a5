"""Reading a tracker's npz back (:func:`read_npz`): the arrays, checked against the robot they are
read for by the names mer writes in them (``joint_names``, ``body_names``), so that an npz written
for one robot, or in the other tracker's order, is refused by name instead of loading the wrong
joints. An npz without names (a tracker's own ``csv_to_npz`` output) is checked by its shapes only,
with a warning.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path

import numpy as np

from mer_data.base.errors import MerError
from mer_data.robots.articulation import TRACKERS, articulation
from mer_data.robots.registry import Robot

log = logging.getLogger(__name__)

__all__ = ["NPZ_KEYS", "read_npz"]

#: The arrays both trackers' ``MotionLoader`` read.
NPZ_KEYS = ("fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w", "body_lin_vel_w", "body_ang_vel_w")


def _first_difference(have: list[str], want: tuple[str, ...]) -> str:
    for i, (a, b) in enumerate(zip(have, want)):
        if a != b:
            return f"position {i}: {a!r} where {b!r} belongs"
    return f"{len(have)} names where {len(want)} belong"


def read_npz(path: str | Path, robot: Robot, tracker: str) -> dict[str, np.ndarray]:
    """The arrays of the npz at ``path`` read for ``robot`` and ``tracker`` (``"mjlab"`` or
    ``"beyondmimic"``), loaded without pickle.

    Raises:
        MerError: not a readable npz, a key missing, names of another robot (the joints it lacks or
            has too many of, by name), the other tracker's order, shapes that do not fit the robot.
    """
    if tracker not in TRACKERS:
        raise MerError(f"unknown tracker {tracker!r}", fix=f"one of {', '.join(TRACKERS)}")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise MerError(f"cannot read the npz: {exc}", path=path, fix="give an npz written by `mer retarget --npz`") from None
    missing = [k for k in NPZ_KEYS if k not in arrays]
    if missing:
        raise MerError(f"the npz has no {', '.join(missing)}", path=path, fix="give an npz written by `mer retarget --npz`")
    art = articulation(robot)
    joints, bodies = art.order(tracker)
    want_j = tuple(art.joints[j].name for j in joints)
    want_b = tuple(art.bodies[b].name for b in bodies)
    for key, want, what in (("joint_names", want_j, "joints"), ("body_names", want_b, "bodies")):
        if key not in arrays:
            continue
        have = [str(x) for x in np.asarray(arrays[key]).ravel()]
        if tuple(have) == want:
            continue
        extra, lacking = sorted(set(have) - set(want)), sorted(set(want) - set(have))
        if extra or lacking:
            said = []
            if extra:
                said.append(
                    f"{len(extra)} {what} {robot.name!r} does not have ({', '.join(extra[:5])}{', ...' if len(extra) > 5 else ''})"
                )
            if lacking:
                said.append(f"none of its {', '.join(lacking[:5])}{', ...' if len(lacking) > 5 else ''}")
            raise MerError(f"the npz was written for another robot: its {key} name {' and '.join(said)}", path=path,
                           element=key, fix=f"retarget to {robot.name!r}: `mer retarget ... --target {robot.name} --npz OUT.npz "
                           f"--npz-for {tracker}`")  # fmt: skip
        other = next((t for t in TRACKERS if t != tracker), tracker)
        o_j, o_b = art.order(other)
        other_names = tuple(art.joints[j].name for j in o_j) if key == "joint_names" else tuple(art.bodies[b].name for b in o_b)
        said = f"{other}'s order" if tuple(have) == other_names else f"another order ({_first_difference(have, want)})"
        raise MerError(f"the npz's {what} are {robot.name!r}'s but in {said}, not {tracker}'s", path=path, element=key,
                       fix=f"write it again with --npz-for {tracker}")  # fmt: skip
    if "joint_names" not in arrays or "body_names" not in arrays:
        log.warning("%s has no joint_names / body_names: only its shapes are checked against %s", path, robot.name)
    d = np.asarray(arrays["joint_pos"]).shape
    b = np.asarray(arrays["body_pos_w"]).shape
    if len(d) != 2 or d[1] != len(want_j) or len(b) != 3 or b[1] != len(want_b) or b[0] != d[0]:
        raise MerError(f"the npz's joint_pos {d} and body_pos_w {b} do not fit {robot.name!r} ({len(want_j)} joints, "
                       f"{len(want_b)} bodies)", path=path, fix=f"retarget to {robot.name!r} with --npz-for {tracker}")  # fmt: skip
    return arrays
