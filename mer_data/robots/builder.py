"""URDF + robot card → :class:`~mer_data.skeleton.Skeleton`.

Fixed joints and locked joints are merged into their parents (their transforms composed at the
locked value), mimic joints follow their master (or are locked with it), key points that do not sit
on a joint become site nodes. Anything that cannot be represented raises an error that names the
joint, the file and the fix.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from mer_data.base.errors import BrokenReferenceError, MalformedURDFError, RobotCardError, UnsupportedJointError
from mer_data.skeleton import KEYPOINTS, Skeleton

from .card import RobotCard
from .urdf import UrdfJoint, UrdfModel
from .urdf_checks import did_you_mean

log = logging.getLogger(__name__)

__all__ = ["build_skeleton", "zero_pose_link_transforms", "KEYPOINT_ON_JOINT_TOL"]

#: A key point closer than this to its link's joint node *is* that node [m].
KEYPOINT_ON_JOINT_TOL = 1e-6
_LIMIT_SLACK = 1e-9


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _motion(j: UrdfJoint, value: float) -> np.ndarray:
    """4x4 joint motion at ``value`` (rotation about / translation along the joint axis)."""
    out = np.eye(4)
    if value == 0.0 or j.type == "fixed":
        return out
    if j.type in ("revolute", "continuous"):
        out[:3, :3] = _rot(j.axis, value)
    elif j.type == "prismatic":
        out[:3, 3] = j.axis / np.linalg.norm(j.axis) * value
    return out


def _resolve_values(urdf: UrdfModel, card: RobotCard) -> tuple[dict[str, float], dict[str, tuple[str, float, float]]]:
    """Which joints are held at a value, and which follow a free master.

    Returns:
        held: joint name → value [rad or m] for locked joints and mimics of locked joints.
        follows: joint name → (free master, multiplier, offset) for mimic joints that move.
    """
    card_path = card.path
    by_name = {j.name: j for j in urdf.joints}
    held: dict[str, float] = {}
    for name, value in card.locked.items():
        if name not in by_name:
            raise RobotCardError(
                f"locked joint {name!r} is not in {urdf.path}",
                path=card_path,
                element=f"locked.{name}",
                fix=did_you_mean(name, by_name, "check the joint name in the URDF"),
            )
        j = by_name[name]
        if j.type not in ("revolute", "continuous", "prismatic"):
            raise RobotCardError(
                f"joint {name!r} is {j.type}; only revolute, continuous and prismatic joints can be locked",
                path=card_path,
                element=f"locked.{name}",
            )
        if j.lower is not None and j.upper is not None and not (
            j.lower - _LIMIT_SLACK <= value <= j.upper + _LIMIT_SLACK
        ):
            raise RobotCardError(
                f"locked value {value} of {name!r} is outside its limits [{j.lower}, {j.upper}]",
                path=card_path,
                element=f"locked.{name}",
                fix="choose a value inside the joint's limits",
            )
        held[name] = float(value)

    follows: dict[str, tuple[str, float, float]] = {}
    for j in urdf.joints:
        if j.mimic is None or j.name in held:
            continue
        master, mult, off = j.mimic
        seen = {j.name}
        while True:  # follow mimic chains to a joint that is not itself a mimic
            mj = by_name[master]
            if master in seen:
                raise UnsupportedJointError(
                    f"mimic joints form a cycle through {sorted(seen)}",
                    path=urdf.path,
                    line=j.line,
                    element=f"joint '{j.name}'",
                    fix="make one joint of the cycle independent",
                )
            seen.add(master)
            if mj.mimic is None or master in held:
                break
            master, mult, off = mj.mimic[0], mult * mj.mimic[1], mult * mj.mimic[2] + off
        if master in held:  # a locked master of any type: the mimic is held with it
            held[j.name] = mult * held[master] + off
        elif mj.type == "fixed":  # a fixed master never moves: the mimic stays at its offset
            log.warning("joint '%s' mimics the fixed joint '%s': held at its offset %g", j.name, master, off)
            held[j.name] = off
        elif mj.type not in ("revolute", "continuous"):
            raise UnsupportedJointError(
                f"mimics '{master}', a {mj.type} joint; a free mimic master must be revolute or continuous",
                path=urdf.path,
                line=j.line,
                element=f"joint '{j.name}'",
                fix=f"lock '{master}' (its mimics are then held with it): --lock {master}=VALUE",
            )
        elif j.type in ("revolute", "continuous"):
            follows[j.name] = (master, mult, off)
        else:
            raise UnsupportedJointError(  # a prismatic joint driven by a free revolute master
                f"a {j.type} joint that mimics the free joint '{master}' cannot be represented",
                path=urdf.path,
                line=j.line,
                element=f"joint '{j.name}'",
                fix=f"lock '{master}' (its mimics are then held with it): --lock {master}=VALUE",
            )
    return held, follows


def zero_pose_link_transforms(urdf: UrdfModel, held: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """4x4 root ← link transform of every link at the zero pose (locked joints at their value)."""
    held = held or {}
    out = {urdf.root: np.eye(4)}
    stack = [urdf.root]
    while stack:
        link = stack.pop()
        for j in urdf.children_of(link):
            out[j.child] = out[link] @ j.origin @ _motion(j, held.get(j.name, 0.0))
            stack.append(j.child)
    return out


def build_skeleton(urdf: UrdfModel, card: RobotCard) -> Skeleton:
    """Build the skeleton graph of ``urdf`` as described by ``card`` (see module docstring)."""
    held, follows = _resolve_values(urdf, card)

    names: list[str] = [urdf.root]
    kinds: list[str] = ["base"]
    parents: list[int] = [-1]
    axes: list[np.ndarray] = [np.zeros(3)]
    pos: list[np.ndarray] = [np.zeros(3)]
    lower: list[float] = [0.0]
    upper: list[float] = [0.0]
    rest: list[np.ndarray] = [np.eye(3)]
    links: list[str] = [urdf.root]
    jnames: list[str | None] = [None]
    continuous: list[bool] = [False]
    attached: dict[str, int] = {urdf.root: 0}  # link → node that carries it
    t_root = zero_pose_link_transforms(urdf, held)

    # depth first, children in file order: a stable topological order
    stack: list[UrdfJoint] = list(reversed(urdf.children_of(urdf.root)))
    while stack:
        j = stack.pop()
        link = j.parent
        movable = j.type in ("revolute", "continuous") and j.name not in held
        if j.type in ("prismatic", "planar", "floating") and j.name not in held:
            fix = (
                f"lock it in the robot card (locked: {{{j.name}: VALUE}}) or with --lock {j.name}=VALUE"
                if j.type == "prismatic"
                else "remove it: the floating base is added by mer; only revolute joints can move"
            )
            raise UnsupportedJointError(
                f"{j.type} joints are not supported inside the kinematic tree",
                path=urdf.path,
                line=j.line,
                element=f"joint '{j.name}'",
                fix=fix,
            )
        if movable:
            t = t_root[j.child]
            axis = t[:3, :3] @ (j.axis / np.linalg.norm(j.axis))
            node = len(names)
            names.append(j.name)
            kinds.append("revolute")
            parents.append(attached[link])
            axes.append(axis / np.linalg.norm(axis))
            pos.append(t[:3, 3].copy())
            if j.type == "continuous":
                lo, hi = (-math.pi, math.pi) if j.lower is None or j.upper is None else (j.lower, j.upper)
            else:
                lo, hi = j.lower, j.upper
            lower.append(float(lo))
            upper.append(float(hi))
            rest.append(t[:3, :3].copy())
            links.append(j.child)
            jnames.append(j.name)
            continuous.append(j.type == "continuous")
            attached[j.child] = node
        else:
            attached[j.child] = attached[link]
        stack.extend(reversed(urdf.children_of(j.child)))

    # ---- key points: joint nodes or new site nodes ------------------------------------------
    keypoints: dict[str, int] = {}
    for key in KEYPOINTS:
        spec = card.keypoints.get(key)
        if spec is None:
            keypoints[key] = -1
            continue
        if spec.link not in t_root:
            raise BrokenReferenceError(
                f"key point {key!r} names link {spec.link!r}, which is not in {urdf.path}",
                path=card.path,
                element=f"keypoints.{key}",
                fix=did_you_mean(spec.link, urdf.links, "name a link of the URDF"),
            )
        t = t_root[spec.link]
        p = t[:3, :3] @ np.asarray(spec.offset) + t[:3, 3]
        node = attached[spec.link]
        if np.linalg.norm(p - pos[node]) <= KEYPOINT_ON_JOINT_TOL:
            keypoints[key] = node
            continue
        if key in names:
            raise RobotCardError(
                f"site node {key!r} would clash with a joint of the same name",
                path=card.path,
                element=f"keypoints.{key}",
            )
        keypoints[key] = len(names)
        names.append(key)
        kinds.append("site")
        parents.append(node)
        axes.append(np.zeros(3))
        pos.append(p)
        lower.append(0.0)
        upper.append(0.0)
        rest.append(t[:3, :3].copy())
        links.append(spec.link)
        jnames.append(None)
        continuous.append(False)

    J = len(names)
    pos_a = np.asarray(pos)
    par = np.asarray(parents)
    offsets = np.zeros((J, 3))
    offsets[1:] = pos_a[1:] - pos_a[par[1:]]

    # ---- mimic relations ---------------------------------------------------------------------
    mimic_source = np.full(J, -1, np.int64)
    mimic_mult = np.ones(J)
    mimic_off = np.zeros(J)
    for name, (master, mult, off) in follows.items():
        j = names.index(name)
        mimic_source[j] = names.index(master)
        mimic_mult[j] = mult
        mimic_off[j] = off

    # ---- nominal pose ------------------------------------------------------------------------
    lo_a, hi_a = np.asarray(lower), np.asarray(upper)
    nominal = np.clip(np.zeros(J), lo_a, hi_a)
    for name, value in card.nominal.items():
        if name not in names or kinds[names.index(name)] != "revolute":
            raise RobotCardError(
                f"nominal angle for {name!r}, which is not a moving joint of this skeleton",
                path=card.path,
                element=f"nominal.{name}",
                fix=did_you_mean(name, [n for n, k in zip(names, kinds) if k == "revolute"], "name a moving joint"),
            )
        j = names.index(name)
        if not lo_a[j] - _LIMIT_SLACK <= value <= hi_a[j] + _LIMIT_SLACK:
            raise RobotCardError(
                f"nominal angle {value} of {name!r} is outside its limits [{lo_a[j]}, {hi_a[j]}]",
                path=card.path,
                element=f"nominal.{name}",
            )
        nominal[j] = value

    for what, arr in (("offsets", offsets), ("axes", np.asarray(axes)), ("rest rotations", np.asarray(rest))):
        if not np.isfinite(arr).all():
            j = int(np.flatnonzero(~np.isfinite(arr.reshape(J, -1)).all(axis=1))[0])
            raise MalformedURDFError(
                f"the {what} of node {names[j]!r} overflow to NaN/inf (the URDF's numbers are too large)",
                path=urdf.path,
                element=f"link '{links[j]}'",
                fix="check the origins and axes along this chain: lengths in metres, angles in radians",
            )
    skel = Skeleton(
        name=card.name,
        node_names=tuple(names),
        node_kinds=tuple(kinds),  # type: ignore[arg-type]
        parents=par,
        axes=np.asarray(axes),
        offsets=offsets,
        lower=lo_a,
        upper=hi_a,
        nominal=nominal,
        rest_rotations=np.asarray(rest),
        link_names=tuple(links),
        urdf_joint_names=tuple(jnames),
        mimic_source=mimic_source,
        mimic_multiplier=mimic_mult,
        mimic_offset=mimic_off,
        keypoints=keypoints,
        body_parts=card.body_parts,
        locked=held,
        continuous=np.asarray(continuous),
    )
    log.debug("built %r from %s", skel, urdf.path)
    return skel
