"""Key points of a human (BVH-like hierarchy): which joint is each of the 14 key points, and the clip's
most neutral standing frame (:mod:`mer_data.motion.human` builds the skeleton from them; its
docstring says the naming rules)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from mer_data.base.errors import BVHError
from mer_data.skeleton import KEYPOINTS

from .bvh import BvhMotion, split_joint_name

__all__ = ["KEYPOINT_NAMES", "KeypointChoice", "assign_keypoints", "keypoint_table", "standing_frame", "ancestors", "is_below"]

#: Name cores (see :func:`~mer_data.motion.bvh.split_joint_name`) of each key point's joint, in
#: order of preference: the first set that names a joint on the side wins.
KEYPOINT_NAMES: dict[str, tuple[frozenset[str], ...]] = {
    "hip": (frozenset({"upleg", "upperleg", "thigh", "femur", "hip", "upperthigh"}),),
    "knee": (frozenset({"leg", "lowerleg", "lowleg", "loleg", "shin", "calf", "knee", "tibia"}),),
    "ankle": (frozenset({"ankle"}), frozenset({"foot"})),
    "toe": (frozenset({"toe", "toes", "toebase", "toe0", "ball"}),),
    "shoulder": (frozenset({"arm", "upperarm", "uparm", "humerus"}), frozenset({"shoulder"})),
    "elbow": (frozenset({"forearm", "lowerarm", "lowarm", "loarm", "elbow", "radius"}),),
    "hand": (frozenset({"wrist"}), frozenset({"hand"})),
}
#: (upper, lower) key point parts that must run down the hierarchy.
_CHAINS = (("hip", "knee"), ("knee", "ankle"), ("ankle", "toe"), ("shoulder", "elbow"), ("elbow", "hand"))


@dataclass(frozen=True)
class KeypointChoice:
    """Where a key point sits: ``joint`` (a BVH joint or End Site name) and how it was chosen."""

    key: str
    joint: str
    how: str


# ---- the hierarchy ----------------------------------------------------------------------------


def ancestors(bvh: BvhMotion, k: int) -> list[int]:
    """The joints above ``k``, its parent first."""
    out = []
    while bvh.joints[k].parent >= 0:
        k = bvh.joints[k].parent
        out.append(k)
    return out


def is_below(bvh: BvhMotion, k: int, top: int) -> bool:
    """True if joint ``k`` is a strict descendant of ``top``."""
    return top in ancestors(bvh, k)


# ---- key points -------------------------------------------------------------------------------


def _depth(bvh: BvhMotion, k: int) -> int:
    return len(ancestors(bvh, k))


def _by_name(bvh: BvhMotion, side: str, part: str, under: int | None) -> tuple[int, str] | None:
    parsed = [split_joint_name(j.name) for j in bvh.joints]
    for cores in KEYPOINT_NAMES[part]:
        found = [k for k, (s, c) in enumerate(parsed) if s == side and c in cores and not bvh.joints[k].end_site
                 and (under is None or is_below(bvh, k, under))]  # fmt: skip
        if found:
            k = min(found, key=lambda i: (_depth(bvh, i), i))
            return k, f"name ({parsed[k][1]})"
    return None


def _toe(bvh: BvhMotion, side: str, ankle: int) -> tuple[int, str] | None:
    hit = _by_name(bvh, side, "toe", ankle)
    if hit is not None:
        return hit
    kids = bvh.children(ankle)
    joints = [k for k in kids if not bvh.joints[k].end_site]
    if joints:
        return joints[0], "first child of the ankle"
    if kids:
        return kids[0], "End Site of the ankle"
    return None


def _joint_list(bvh: BvhMotion) -> str:
    names = [j.name for j in bvh.joints]
    shown = ", ".join(names[:200])
    return shown + (f" ... ({len(names)} in all)" if len(names) > 200 else "")


def _check_overrides(bvh: BvhMotion, given: Mapping[str, str]) -> None:
    from mer_data.robots.urdf_checks import did_you_mean

    names = bvh.joint_names
    for key, joint in given.items():
        if key not in KEYPOINTS:
            raise BVHError(f"{key!r} is not a key point", path=bvh.path, element="keypoints",
                           fix=did_you_mean(key, KEYPOINTS, f"key points are {', '.join(KEYPOINTS)}"))  # fmt: skip
        if joint not in names:
            raise BVHError(f"key point {key!r}: the file has no joint {joint!r}", path=bvh.path,
                           element=f"key point {key}",
                           fix=did_you_mean(joint, names, f"name one of its joints: {_joint_list(bvh)}"))  # fmt: skip


def assign_keypoints(bvh: BvhMotion, keypoints: Mapping[str, str] | None = None) -> dict[str, KeypointChoice]:
    """The joint of each of the 14 key points (module docstring): ``keypoints`` (key point -> joint
    name, may be partial) first, names for the rest.

    Raises:
        BVHError: a key point no joint is named for (the message lists the joints), an unknown key
            point or joint in ``keypoints``, or a limb that does not run down the hierarchy.
    """
    given = dict(keypoints or {})
    _check_overrides(bvh, given)
    out: dict[str, KeypointChoice] = {}
    for key in KEYPOINTS:  # ankles come before toes
        if key in given:
            out[key] = KeypointChoice(key, given[key], "given")
            continue
        side, part = key.split("_")
        if part == "toe":
            hit = _toe(bvh, side, bvh.index(out[f"{side}_ankle"].joint))
        else:
            hit = _by_name(bvh, side, part, None)
        if hit is None:
            like = "/".join(c for cores in KEYPOINT_NAMES[part] for c in sorted(cores))
            raise BVHError(
                f"no joint found for key point {key!r} (no {side} joint named like {like})",
                path=bvh.path,
                element=f"key point {key}",
                fix=f"name it: keypoints={{{key!r}: JOINT}}; the joints are: {_joint_list(bvh)}",
            )
        out[key] = KeypointChoice(key, bvh.joints[hit[0]].name, hit[1])
    _check_chains(bvh, out)
    return out


def _check_chains(bvh: BvhMotion, out: dict[str, KeypointChoice]) -> None:
    for key in KEYPOINTS:
        if key.startswith("left_") and out[key].joint == out["right_" + key[5:]].joint:
            raise BVHError(f"{key!r} and {'right_' + key[5:]!r} are the same joint {out[key].joint!r}", path=bvh.path,
                           element=f"key point {key}", fix="give each side its own joint in keypoints=")  # fmt: skip
    for side in ("left", "right"):
        for upper, lower in _CHAINS:
            a, b = out[f"{side}_{upper}"], out[f"{side}_{lower}"]
            if not is_below(bvh, bvh.index(b.joint), bvh.index(a.joint)):
                raise BVHError(
                    f"key point {b.key!r} ({b.joint}) is not below {a.key!r} ({a.joint}) in the hierarchy",
                    path=bvh.path,
                    element=f"key point {b.key}",
                    fix=f"give the limb's joints: keypoints={{{a.key!r}: JOINT, {b.key!r}: JOINT}}",
                )


def keypoint_table(bvh: BvhMotion, *, keypoints: Mapping[str, str] | None = None, frame: int = 0) -> str:
    """The key point assignment as a table (as ``mer robots register`` prints): joint, its position
    at ``frame`` [m] (z up, x forward: left points have y > 0) and how it was chosen."""
    choice = assign_keypoints(bvh, keypoints)
    pos = bvh.positions(slice(frame, frame + 1))[0]
    lines = [f"key points of {bvh.path} (position at frame {frame + 1} [m], z up, x forward):"]
    for key in KEYPOINTS:
        c = choice[key]
        x, y, z = pos[bvh.index(c.joint)]
        lines.append(f"    {key:15s} {c.joint:24s} ({x:+.3f}, {y:+.3f}, {z:+.3f})  {c.how}")
    return "\n".join(lines)


def standing_frame(bvh: BvhMotion, keypoints: Mapping[str, str] | None = None, grid_fps: float = 30.0) -> int:
    """The frame in which the human stands most neutrally: legs straight, trunk upright, feet level,
    arms down (the sum of the knee bends, the trunk's tilt, half the arms' angles from hanging [rad],
    and 10 x the ankles' height difference [m]), among the frames on the ``grid_fps`` grid where the
    file's rate is a multiple of it (so the same motion at 30 or 120 Hz picks the same instant).

    Used as the zero pose of a clip whose rest pose is not a standing one (``rest_frame``): scaling
    reads the standing heights, trunk frame and limb directions there (:mod:`mer_data.kinematics.scaling`).
    """
    choice = assign_keypoints(bvh, keypoints)
    step = bvh.fps / grid_fps
    frames = np.arange(0, bvh.num_frames, int(round(step))) if step >= 1 and abs(step - round(step)) < 1e-6 else np.arange(bvh.num_frames)
    pos = bvh.positions(frames)

    def at(k: str) -> np.ndarray:
        return pos[:, bvh.index(choice[k].joint)]

    def angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        c = (u * v).sum(-1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-9)
        return np.arccos(np.clip(c, -1.0, 1.0))

    down = np.array([0.0, 0.0, -1.0])
    score = np.zeros(len(frames))
    for side in ("left", "right"):
        hip, knee, ankle = at(f"{side}_hip"), at(f"{side}_knee"), at(f"{side}_ankle")
        score += angle(knee - hip, ankle - knee)  # knee bend
        score += 0.5 * angle(at(f"{side}_elbow") - at(f"{side}_shoulder"), down)  # arm raised
    trunk = 0.5 * (at("left_shoulder") + at("right_shoulder")) - 0.5 * (at("left_hip") + at("right_hip"))
    score += angle(trunk, -down)
    score += 10.0 * np.abs(at("left_ankle")[:, 2] - at("right_ankle")[:, 2])
    return int(frames[int(np.argmin(score))])
