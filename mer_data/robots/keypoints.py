"""Propose the 14 key points of a robot nobody has described yet, from its geometry and names.

Rules (body frame: x forward, y left, z up, at the zero pose; :mod:`mer_data.robots.keypoint_body`):

* **fingers** (several moving chains branching within a small reach at the end of a limb) are
  locked at 0 (clipped into their limits); the hand key point goes to the wrist/palm they hang from;
* **limbs** are the joint chains to the leaf links that no other chain shares; left is y > 0;
* **legs** are the limbs whose ends are lowest; with two limbs per side on the ground (a
  quadruped) the hind pair are the legs and the front pair stand in for the arms;
* a leg whose last joint is far above its lowest point (a point foot: quadrupeds, Bolt, P441A)
  ends at the **knee**, and its foot frame is the **ankle** (no toe); a wheel at the end of a leg
  is the ankle (no toe); otherwise the knee is the bending joint nearest the leg's middle (named
  knee/kfe/calf first) and the ankle the last joint;
* the **hip/shoulder** is the last joint before the knee/elbow that is not a twist about the
  thigh/upper arm;
* the **toe** is a fixed frame named toe/tip under the foot, else the front-bottom point of the
  foot's primitive collision shapes, else the front of the foot's sole frames (low);
* the **hand** is a fixed hand/palm/gripper frame under the last arm joint; else, on an arm that
  ends at a wrist, the wrist (or the far end of its collision shapes); on an arm that ends at
  the elbow, a site on the forearm link, 0.79 upper-arm lengths from the elbow (the human
  forearm/upper-arm ratio) towards the link's centre of mass (low).

Each proposal comes with a confidence: ``high`` (geometry and names agree), ``medium`` (geometry
only, or a documented convention), ``low`` (an estimate worth checking), or ``absent`` with the reason.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field

import numpy as np

from mer_data.skeleton import KEYPOINTS

from .builder import build_skeleton
from .card import DEFAULT_BODY_PARTS, KeypointSpec, RobotCard
from .keypoint_body import Body, Limb, digit_locks, side_of_name
from .urdf import UrdfModel

log = logging.getLogger(__name__)

__all__ = ["KeypointProposal", "RobotProposal", "propose_robot", "propose_keypoints", "FOREARM_RATIO"]

#: Human forearm (elbow → wrist) over upper arm (shoulder → elbow): 0.146 / 0.186 of body height
#: (Drillis & Contini segment lengths). Used only for an arm that ends at its elbow.
FOREARM_RATIO = 0.79
_SIDE_EPS = 0.02  # |y| below this [m] is the mid-plane
_SAME_PLACE = 0.02  # joints closer than this [m] act at one place
_POINT_FOOT = 0.3  # a last leg joint further than this fraction of the leg above the ground is a knee
_NAMES = {
    "knee": re.compile(r"knee|kny|kfe|shin|calf|tibia|lowerleg|lower_leg", re.I),
    "elbow": re.compile(r"elbow|elb|(^|_)el[xyz]?($|_)|forearm", re.I),
    "toe": re.compile(r"toe|tip", re.I),
    "hand": re.compile(r"hand|palm|gripper|(^|_)ee($|_)|tcp", re.I),
    "wheel": re.compile(r"wheel", re.I),
}


@dataclass(frozen=True)
class KeypointProposal:
    """A proposed key point (``spec`` None when absent) and how sure the proposal is.

    ``by_design`` marks an absence that is the answer, not a failure to find one: a point foot or a
    wheel has no toe, a robot whose only limb on a side is its leg has no arm there. Such key points
    are not worth checking (:attr:`needs_check`).
    """

    key: str
    spec: KeypointSpec | None
    confidence: str  # "high" | "medium" | "low" | "absent" ("given": from the user's key-point file)
    reason: str
    position: tuple[float, float, float] | None = None  # zero pose, root frame [m]
    by_design: bool = False

    @property
    def needs_check(self) -> bool:
        """Worth a look before use: an estimate (``low``), or absent where the robot may well have one."""
        return self.confidence == "low" or (self.confidence == "absent" and not self.by_design)


@dataclass(frozen=True)
class RobotProposal:
    """Key points, the joints to lock (fingers) and notes on the conventions applied."""

    keypoints: dict[str, KeypointProposal]
    locked: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


def propose_keypoints(urdf: UrdfModel, locked: dict[str, float] | None = None) -> dict[str, KeypointProposal]:
    """Propose all 14 key points of ``urdf`` (joints in ``locked`` held at their value)."""
    return propose_robot(urdf, locked).keypoints


def propose_robot(urdf: UrdfModel, locked: dict[str, float] | None = None) -> RobotProposal:
    """Propose key points and finger locks for ``urdf`` (joints in ``locked`` held at their value)."""
    locked = dict(locked or {})
    body = Body.of(urdf, _skeleton(urdf, locked))
    fingers, hand_nodes = digit_locks(body)
    hands = [body.skel.link_names[h] for h in hand_nodes]
    notes = []
    if fingers:
        held_before = len(body.skel.locked)
        body = Body.of(urdf, _skeleton(urdf, {**locked, **fingers}))
        followers = len(body.skel.locked) - held_before - len(fingers)
        notes.append(
            f"locked {len(fingers)} finger joint(s) at 0 (clipped into their limits)"
            + (f", with the {followers} mimic joint(s) that follow them," if followers else "")
            + " below " + ", ".join(repr(l) for l in hands)
            + ": motions carry no finger data; the hand key point is the wrist/palm"
        )
    if body.flipped:
        notes.append("the root frame looks backwards (left-named limbs at y < 0): sides and front read in it turned 180° about z")
    out: dict[str, KeypointProposal] = {}
    limbs = body.limbs()
    quad = False
    for side, sign in (("left", 1.0), ("right", -1.0)):
        mine = [l for l in limbs if sign * body.pos[l.end][1] > _SIDE_EPS]
        legs, arms, quad_side = _split_legs_arms(mine)
        quad |= quad_side
        _propose_leg(out, side, legs[0] if legs else None, body)
        _propose_arm(out, side, arms[0] if arms else None, body, quad_side, legs_only=bool(legs) and not arms)
    if quad:
        notes.append("quadruped: hind legs are the legs, front legs stand in for the arms (hip → shoulder, knee → elbow, foot → hand)")
    return RobotProposal({k: _in_root_frame(out[k], body) for k in KEYPOINTS}, fingers, tuple(notes))


def _skeleton(urdf: UrdfModel, locked: dict[str, float]):
    blank = RobotCard(
        name="proposal", urdf=urdf.path, keypoints={k: None for k in KEYPOINTS}, locked=locked,
        body_parts=DEFAULT_BODY_PARTS,
    )  # fmt: skip
    return build_skeleton(urdf, blank)


def _in_root_frame(p: KeypointProposal, body: Body) -> KeypointProposal:
    if p.position is None or not body.flipped:
        return p
    x, y, z = p.position
    return KeypointProposal(p.key, p.spec, p.confidence, p.reason, (-x, -y, z), p.by_design)


def _split_legs_arms(limbs: list[Limb]) -> tuple[list[Limb], list[Limb], bool]:
    """Legs: lowest-ending limbs; two limbs of a side on the ground → hind is leg, front is arm."""
    if not limbs:
        return [], [], False
    lowest = min(l.tip[2] for l in limbs)
    span = max(l.tip[2] for l in limbs) - lowest
    ground = [l for l in limbs if l.tip[2] - lowest < max(0.05, 0.1 * span)]
    if len(ground) >= 2:
        ground.sort(key=lambda l: l.tip[0])
        return [ground[0]], [ground[-1]], True
    rest = sorted((l for l in limbs if l not in ground), key=lambda l: -len(l.joints))
    return ground, rest, False


def _kp(key: str, body: Body, spec: KeypointSpec, confidence: str, reason: str) -> KeypointProposal:
    return KeypointProposal(key, spec, confidence, reason, tuple(float(x) for x in body.at(spec.link, spec.offset)))


def _node(key: str, body: Body, n: int, confidence: str, reason: str) -> KeypointProposal:
    return _kp(key, body, KeypointSpec(body.skel.link_names[n]), confidence, f"{body.skel.node_names[n]} ({reason})")


def _absent(key: str, reason: str, by_design: bool = False) -> KeypointProposal:
    """An absent key point; ``by_design`` when the robot has no such part (nothing to check)."""
    return KeypointProposal(key, None, "absent", reason, by_design=by_design)


def _named(body: Body, nodes: list[int], kind: str) -> list[int]:
    pat = _NAMES[kind]
    return [n for n in nodes if pat.search(body.skel.node_names[n]) or pat.search(body.skel.link_names[n])]


def _bending(body: Body, joints: list[int], start: np.ndarray, end: np.ndarray) -> list[int]:
    """Joints whose axis is across start → end (they bend the limb rather than twist it)."""
    d = end - start
    d = d / max(np.linalg.norm(d), 1e-9)
    return [n for n in joints if abs(body.axes[n] @ d) < 0.5]


def _middle_joint(body: Body, joints: list[int], start: np.ndarray, end: np.ndarray) -> int:
    """Of ``joints``, the one that bends the limb nearest the middle of start → end."""
    mid = (start + end) / 2
    cands = _bending(body, joints, start, end) or list(joints)
    return min(cands, key=lambda n: np.linalg.norm(body.pos[n] - mid))


def _pivot(body: Body, cluster: list[int], next_joint: int) -> int:
    """Hip/shoulder: the last joint of ``cluster`` that is not a twist about the segment to ``next_joint``
    (joints at the knee/elbow's own place are skipped)."""
    for n in reversed(cluster):
        seg = body.pos[next_joint] - body.pos[n]
        length = np.linalg.norm(seg)
        if length < _SAME_PLACE:  # part of the knee/elbow itself (a two-axis elbow), not the pivot
            continue
        if abs(body.axes[n] @ seg) / length < 0.7:
            return n
    return cluster[-1]


# ---- legs -----------------------------------------------------------------------------------
@dataclass
class _Leg:
    hip: int
    knee: int
    ankle: KeypointProposal | None  # without the key name set: filled by the caller
    kind: str  # "foot" | "point" | "wheel"
    by_name: bool


def _lowest_frame(body: Body, link: str) -> str | None:
    frames = body.rigid_frames(link)[1:]
    return min(frames, key=lambda l: body.p(l)[2], default=None)


def _is_wheel(body: Body, n: int) -> bool:
    """A leg's last joint named wheel (joint or link)."""
    return bool(_NAMES["wheel"].search(body.skel.link_names[n]) or _NAMES["wheel"].search(body.skel.node_names[n]))


def _leg_points(limb: Limb, body: Body, key: str) -> _Leg:
    """Hip, knee and ankle of a leg (front legs of a quadruped use the same rules)."""
    joints = limb.joints
    last = joints[-1]
    top = body.pos[joints[0]]
    length = max(top[2] - limb.tip[2], 1e-6)
    wheel = _is_wheel(body, last) and len(joints) >= 3
    point = not wheel and (body.pos[last][2] - limb.tip[2]) > _POINT_FOOT * length and len(joints) >= 2
    if point:  # the last joint is the knee; the foot frame (or the lowest collision point) is the ankle
        knee, by_name = last, bool(_named(body, [last], "knee"))
        link = body.skel.link_names[last]
        foot = _lowest_frame(body, link)
        if foot is not None:
            ankle = _kp(key, body, KeypointSpec(foot), "", f"foot frame {foot!r} (point foot)")
        else:
            pts = body.collision_points(body.rigid_frames(link))
            ankle = None
            if len(pts):
                low = pts[np.argmin(pts[:, 2])]
                ankle = _kp(key, body, KeypointSpec(link, body.offset_in(link, low)), "",
                            f"lowest collision point of {link!r} (point foot)")  # fmt: skip
        kind = "point"
    else:
        inner = joints[:-1]
        named = [n for n in _named(body, inner, "knee") if n != joints[0]]
        knee = _middle_joint(body, named or inner[1:] or inner or joints, top, body.pos[last])
        by_name = bool(named)
        if wheel:
            ankle = _kp(key, body, KeypointSpec(body.skel.link_names[last]), "", f"{body.skel.node_names[last]} (wheel centre)")
            kind = "wheel"
        else:
            ankle = _kp(key, body, KeypointSpec(body.skel.link_names[last]), "", f"{body.skel.node_names[last]} (last leg joint)")
            kind = "foot"
    i = joints.index(knee)
    hip = _pivot(body, joints[:i] or joints[:1], knee)
    return _Leg(hip, knee, ankle, kind, by_name)


def _side_ok(body: Body, limb: Limb, side: str) -> bool:
    names = {side_of_name(body.skel.node_names[n]) for n in limb.joints} - {None}
    return names in (set(), {side})


def _with(p: KeypointProposal, confidence: str, suffix: str = "") -> KeypointProposal:
    return KeypointProposal(p.key, p.spec, confidence, p.reason + suffix, p.position)


def _propose_leg(out: dict, side: str, limb: Limb | None, body: Body) -> None:
    keys = [f"{side}_{k}" for k in ("hip", "knee", "ankle", "toe")]
    if limb is None or len(limb.joints) < 2:
        for k in keys:
            out[k] = _absent(k, f"no {side} leg chain found")
        return
    leg = _leg_points(limb, body, keys[2])
    conf = "high" if leg.by_name and _side_ok(body, limb, side) else "medium"
    how = ", by name" if conf == "high" else ", by geometry"
    out[keys[0]] = _node(keys[0], body, leg.hip, conf, f"last hip joint that is not a thigh twist{how}")
    out[keys[1]] = _node(keys[1], body, leg.knee, conf, f"knee{how}")
    if leg.ankle is None:
        out[keys[2]] = _absent(keys[2], "the leg ends at the knee with no foot frame or collision shape")
        out[keys[3]] = _absent(keys[3], "point foot: no toe", by_design=True)
        return
    out[keys[2]] = _with(leg.ankle, conf if leg.kind == "foot" else "medium")
    if leg.kind == "point":
        out[keys[3]] = _absent(keys[3], "point foot: the foot is the ankle key point", by_design=True)
    elif leg.kind == "wheel":
        out[keys[3]] = _absent(keys[3], "wheel foot: the wheel centre is the ankle key point", by_design=True)
    else:
        out[keys[3]] = _toe(keys[3], limb.joints[-1], body)


def _toe(key: str, ankle: int, body: Body) -> KeypointProposal:
    foot = body.skel.link_names[ankle]
    links = body.rigid_frames(foot)
    named = [l for l in links[1:] if _NAMES["toe"].search(l)]
    if named:
        best = max(named, key=lambda l: body.p(l)[0])
        return _kp(key, body, KeypointSpec(best), "high", f"fixed frame {best!r}")
    a = body.pos[ankle]
    pts = body.collision_points(links)
    if len(pts):
        p = np.array([pts[:, 0].max(), a[1], pts[:, 2].min()])
        return _kp(key, body, KeypointSpec(foot, body.offset_in(foot, p)), "medium",
                   f"front-bottom of the collision shapes of {foot!r}")  # fmt: skip
    # sole frames (force sensors, sole, contact points): the front of those at sole level
    frames = [body.p(l) for l in links[1:] if abs(body.p(l)[1] - a[1]) < 0.08]
    if frames:
        f = np.array(frames)
        sole = f[:, 2].min()
        at_sole = f[f[:, 2] < sole + 0.015]
        if at_sole[:, 0].max() - a[0] > 0.03:
            p = np.array([at_sole[:, 0].max(), a[1], sole])
            return _kp(key, body, KeypointSpec(foot, body.offset_in(foot, p)), "low",
                       f"front of the sole frames under {foot!r} (no toe frame, no collision shape)")  # fmt: skip
    return _absent(key, f"no toe frame, collision shape or sole frame ahead of {foot!r}; give it as link + offset")


# ---- arms -----------------------------------------------------------------------------------
def _propose_arm(out: dict, side: str, limb: Limb | None, body: Body, quad: bool, legs_only: bool = False) -> None:
    """Shoulder, elbow and hand of ``side``; ``legs_only``: the side's only limb is its leg (no arm by design)."""
    keys = [f"{side}_{k}" for k in ("shoulder", "elbow", "hand")]
    if limb is None or len(limb.joints) < 2:
        for k in keys:
            if legs_only and limb is None:
                out[k] = _absent(k, f"no {side} arm: the only {side} limb is the leg", by_design=True)
            else:
                out[k] = _absent(k, f"no {side} arm chain found")
        return
    if quad:  # front legs stand in for the arms: hip → shoulder, knee → elbow, foot → hand
        leg = _leg_points(limb, body, keys[2])
        why = ", front leg standing in for the arm"
        out[keys[0]] = _node(keys[0], body, leg.hip, "medium", f"front hip{why}")
        out[keys[1]] = _node(keys[1], body, leg.knee, "medium", f"front knee{why}")
        if leg.ankle is None:
            out[keys[2]] = _absent(keys[2], "the front leg has no foot frame or collision shape")
        else:
            out[keys[2]] = _with(leg.ankle, "medium", why)
        return
    joints = limb.joints
    last = joints[-1]
    named_elbow = [n for n in _named(body, joints, "elbow") if n != joints[0]]
    elbow = _middle_joint(body, named_elbow or joints[1:] or joints, body.pos[joints[0]], body.pos[last])
    i = joints.index(elbow)
    shoulder = _pivot(body, joints[:i] or joints[:1], elbow)
    conf = "high" if named_elbow and _side_ok(body, limb, side) else "medium"
    out[keys[0]] = _node(keys[0], body, shoulder, conf, "last shoulder joint that is not an upper-arm twist")
    out[keys[1]] = _node(keys[1], body, elbow, conf, "elbow")
    out[keys[2]] = _hand(keys[2], body, shoulder, elbow, last, side)


def _hand(key: str, body: Body, shoulder: int, elbow: int, last: int, side: str) -> KeypointProposal:
    link = body.skel.link_names[last]
    frames = body.rigid_frames(link)
    named = [l for l in frames[1:] if _NAMES["hand"].search(l)]
    if named:
        best = max(named, key=lambda l: np.linalg.norm(body.p(l) - body.pos[shoulder]))
        return _kp(key, body, KeypointSpec(best), "high", f"fixed frame {best!r}")
    if last != elbow:  # the arm ends at a wrist: the wrist, or the far end of its collision shapes
        d = body.pos[last] - body.pos[elbow]
        d = d / max(np.linalg.norm(d), 1e-9)
        pts = body.collision_points(frames)
        if len(pts):
            reach = float(((pts - body.pos[last]) @ d).max())
            if reach > 0.01:
                p = body.pos[last] + reach * d
                return _kp(key, body, KeypointSpec(link, body.offset_in(link, p)), "medium",
                           f"far end of the collision shapes of {link!r} along the forearm")  # fmt: skip
        return _node(key, body, last, "medium", "last arm joint: the wrist")
    # the arm ends at the elbow: a site on the forearm link, towards its centre of mass
    upper = float(np.linalg.norm(body.pos[elbow] - body.pos[shoulder]))
    com = _com(body, frames)
    d = None if com is None else com - body.pos[elbow]
    if d is None or np.linalg.norm(d) < 0.02:
        d = body.pos[elbow] - body.pos[shoulder]  # no usable inertial: continue the upper arm
    d = d / max(np.linalg.norm(d), 1e-9)
    p = body.pos[elbow] + FOREARM_RATIO * upper * d
    return _kp(key, body, KeypointSpec(link, body.offset_in(link, p)), "low",
               f"the {side} arm ends at the elbow: {FOREARM_RATIO} upper-arm lengths along the forearm "
               "(human proportions); check it")  # fmt: skip


def _com(body: Body, links: list[str]) -> np.ndarray | None:
    """Body-frame centre of the inertial origins of ``links`` (unweighted), or None."""
    coms = [body.at(l, body.urdf.inertial_coms[l]) for l in links if l in body.urdf.inertial_coms]
    return np.mean(coms, axis=0) if coms else None
