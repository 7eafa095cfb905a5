"""Propose the 14 key points of a robot nobody has described yet, from its geometry and names.

Rules (URDF convention: x forward, y left, z up, at the zero pose):

* **limbs**: every leaf link defines a chain of moving joints from the base; the joints a chain does
  not share with any other chain are its limb. A limb is on the left if its end has y > 0.
* **legs** are the limbs whose ends are lowest; on a robot with two limbs per side that both reach
  the ground (a quadruped) the rear pair are the legs and the front pair stand in for the arms.
* **arms** are the remaining limbs of a side that end away from the body's mid-plane (the head, on
  the mid-plane, is ignored); the longest one wins.
* on a limb, the **knee/elbow** is, among the joints named so (knee, kny, elbow, el...) or else all,
  the one whose axis crosses the limb (it bends, not twists) nearest the limb's middle; the
  **hip/shoulder** is the last joint before it that is not a twist about the thigh/upper arm;
  the **ankle** is the limb's last joint; the **toe** is a fixed frame named toe/tip under the foot,
  else the front-bottom point of the foot's primitive collision shapes; the **hand** is a fixed
  hand/palm/gripper frame under the last arm joint, else that joint when it is not the elbow.

Each proposal comes with a confidence: ``high`` (name and geometry agree), ``medium`` (geometry
only), ``low`` (a guess worth checking), or ``absent`` with the reason.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .robot_card import DEFAULT_BODY_PARTS, KeypointSpec, RobotCard
from .skeleton import KEYPOINTS
from .skeleton_builder import build_skeleton, zero_pose_link_transforms
from .urdf import UrdfModel

__all__ = ["KeypointProposal", "propose_keypoints"]

_SIDE_EPS = 0.02  # |y| below this [m] is the mid-plane
_NAMES = {
    "knee": re.compile(r"knee|kny|shin|calf|tibia", re.I),
    "elbow": re.compile(r"elbow|elb|(^|_)el[xyz]?($|_)|forearm", re.I),
    "hip": re.compile(r"hip|hp[xyz]|thigh|femur", re.I),
    "shoulder": re.compile(r"shoulder|sh[xyz]|(^|_)sh($|_)|scap|clav", re.I),
    "ankle": re.compile(r"ankle|ak[xyz]|foot", re.I),
    "toe": re.compile(r"toe|tip", re.I),
    "hand": re.compile(r"hand|palm|gripper|(^|_)ee($|_)|tcp|wrist", re.I),
}
_LEFT = re.compile(r"(^|[_\W])(l|left)([_\W]|$)|^left|left|_L($|_)|(^|_)L_", re.I)
_RIGHT = re.compile(r"(^|[_\W])(r|right)([_\W]|$)|^right|right|_R($|_)|(^|_)R_", re.I)


@dataclass(frozen=True)
class KeypointProposal:
    """A proposed key point (``spec`` None when absent) and how sure the proposal is."""

    key: str
    spec: KeypointSpec | None
    confidence: str  # "high" | "medium" | "low" | "absent"
    reason: str
    position: tuple[float, float, float] | None = None  # zero pose, root frame [m]


def _side_of_name(name: str) -> str | None:
    left, right = bool(_LEFT.search(name)), bool(_RIGHT.search(name))
    if left and not right:
        return "left"
    if right and not left:
        return "right"
    return None


def propose_keypoints(urdf: UrdfModel, locked: dict[str, float] | None = None) -> dict[str, KeypointProposal]:
    """Propose all 14 key points of ``urdf`` (joints in ``locked`` held at their value)."""
    locked = dict(locked or {})
    blank = RobotCard(
        name="proposal", urdf=urdf.path, keypoints={k: None for k in KEYPOINTS}, locked=locked,
        body_parts=DEFAULT_BODY_PARTS,
    )  # fmt: skip
    skel = build_skeleton(urdf, blank)
    t_root = zero_pose_link_transforms(urdf, dict(skel.locked))
    pos = skel.rest_positions
    link_node = _link_nodes(urdf, skel)

    # ---- limbs: unshared joint chains to the leaf links ----------------------------------------
    has_child = {j.parent for j in urdf.joints}
    leaves = [l for l in urdf.links if l not in has_child and l != urdf.root]
    chains: dict[str, list[int]] = {}
    for leaf in leaves:
        node = link_node[leaf]
        chain = [n for n in reversed(skel.path_to_root(node)) if n != 0]
        if chain:
            chains[leaf] = chain
    # group leaves that end on the same last joint (fingers of one hand, corner frames of a foot)
    by_end: dict[int, list[str]] = {}
    for leaf, chain in chains.items():
        by_end.setdefault(chain[-1], []).append(leaf)
    limbs = []
    ends = list(by_end)
    for end in ends:
        chain = [n for n in reversed(skel.path_to_root(end)) if n != 0]
        others = {a for e in ends if e != end for a in skel.path_to_root(e)}
        own = [n for n in chain if n not in others]
        if not own:
            continue
        leaf_links = by_end[end]
        tip = max((t_root[l][:3, 3] for l in leaf_links), key=lambda p: -p[2])  # lowest leaf point
        limbs.append({"joints": own, "end": end, "leaves": leaf_links, "tip": tip})

    proposals: dict[str, KeypointProposal] = {}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        mine = [l for l in limbs if sign * pos[l["end"]][1] > _SIDE_EPS]
        legs, arms, quad = _split_legs_arms(mine, pos)
        leg = legs[0] if legs else None
        arm = arms[0] if arms else None
        _propose_leg(proposals, side, leg, skel, urdf, t_root, pos)
        _propose_arm(proposals, side, arm, skel, urdf, t_root, pos, quad)
    return {k: proposals[k] for k in KEYPOINTS}


def _link_nodes(urdf: UrdfModel, skel) -> dict[str, int]:
    """Every link → the node that carries it."""
    out = {urdf.root: 0}
    node_of_link = {l: i for i, l in enumerate(skel.link_names) if skel.node_kinds[i] == "revolute"}
    node_names = set(skel.node_names)
    stack = [urdf.root]
    while stack:
        link = stack.pop()
        for j in urdf.children_of(link):
            out[j.child] = node_of_link.get(j.child, out[link]) if j.name in node_names else out[link]
            stack.append(j.child)
    return out


def _split_legs_arms(limbs, pos):
    """Legs: lowest-ending limbs; quadruped: two limbs near the ground → rear is leg, front is arm."""
    if not limbs:
        return [], [], False
    lowest = min(l["tip"][2] for l in limbs)
    span = max(l["tip"][2] for l in limbs) - lowest
    ground = [l for l in limbs if l["tip"][2] - lowest < max(0.05, 0.1 * span)]
    if len(ground) >= 2:  # quadruped-like: legs front and rear
        ground.sort(key=lambda l: l["tip"][0])
        return [ground[0]], [ground[-1]], True
    legs = ground
    rest = [l for l in limbs if l not in legs]
    rest.sort(key=lambda l: -len(l["joints"]))
    return legs, rest, False


def _named(skel, urdf_names, kind: str) -> list[int]:
    pat = _NAMES[kind]
    return [n for n in urdf_names if pat.search(skel.node_names[n]) or pat.search(skel.link_names[n])]


def _middle_joint(skel, joints: list[int], pos, start: np.ndarray, end: np.ndarray) -> int | None:
    """Of ``joints``, the one that bends the limb nearest the middle of start → end."""
    mid = (start + end) / 2
    cands = _bending(skel, joints, pos, start, end) or list(joints)
    if not cands:
        return None
    return min(cands, key=lambda n: np.linalg.norm(pos[n] - mid))


def _pivot(skel, cluster: list[int], next_joint: int, pos) -> int:
    """Hip/shoulder: the last joint of the cluster that is not a twist about the limb itself.

    A joint whose axis runs along the segment to the knee/elbow (a thigh or upper-arm twist)
    does not mark the pivot; the last one that bends the segment does.
    """
    for n in reversed(cluster):
        seg = pos[next_joint] - pos[n]
        length = np.linalg.norm(seg)
        if length < 1e-6 or abs(skel.axes[n] @ seg) / length < 0.7:
            return n
    return cluster[-1]


def _bending(skel, joints: list[int], pos, start: np.ndarray, end: np.ndarray) -> list[int]:
    """Joints whose axis is across the limb (they bend it rather than twist it)."""
    d = end - start
    d = d / max(np.linalg.norm(d), 1e-9)
    return [n for n in joints if abs(skel.axes[n] @ d) < 0.5]


def _spec_at_node(skel, node: int) -> KeypointSpec:
    return KeypointSpec(skel.link_names[node])


def _leg_points(leg, skel, urdf, t_root, pos):
    """(hip node, knee node, ankle spec/pos/node, by-name?) of a leg chain.

    A leg whose last joint is the knee (a point-footed leg, e.g. a quadruped's calf joint) ends in
    a foot frame: the ankle is then the lowest fixed frame under that joint.
    """
    joints = leg["joints"]
    last = joints[-1]
    knee_named_last = bool(_NAMES["knee"].search(skel.node_names[last])) and len(joints) >= 2
    if knee_named_last:
        knee, by_name = last, True
        frames = [l for l in _fixed_descendants(urdf, skel.link_names[last])[1:]]
        foot = min(frames, key=lambda l: t_root[l][2, 3], default=None)
        ankle = None if foot is None else (KeypointSpec(foot), t_root[foot][:3, 3], None)
    else:
        named = [n for n in _named(skel, joints, "knee") if n not in (joints[0], last)]
        knee = _middle_joint(skel, named or joints[1:-1] or joints, pos, pos[joints[0]], pos[last])
        by_name = bool(named)
        ankle = (_spec_at_node(skel, last), pos[last], last)
    i = joints.index(knee)
    hip = _pivot(skel, joints[:i] or joints[:1], knee, pos)
    return hip, knee, ankle, by_name


def _propose_leg(out, side, leg, skel, urdf, t_root, pos) -> None:
    keys = [f"{side}_{k}" for k in ("hip", "knee", "ankle", "toe")]
    if leg is None or len(leg["joints"]) < 2:
        for k in keys:
            out[k] = KeypointProposal(k, None, "absent", f"no {side} leg chain found")
        return
    joints = leg["joints"]
    name_side = {_side_of_name(skel.node_names[n]) for n in joints} - {None}
    side_ok = name_side in (set(), {side})
    hip, knee, ankle, by_name = _leg_points(leg, skel, urdf, t_root, pos)
    conf = "high" if by_name and side_ok else "medium"
    how = ", by name" if conf == "high" else ", by geometry"
    out[keys[0]] = KeypointProposal(keys[0], _spec_at_node(skel, hip), conf,
                                    f"{skel.node_names[hip]} (last hip joint that is not a thigh twist{how})", tuple(pos[hip]))
    out[keys[1]] = KeypointProposal(keys[1], _spec_at_node(skel, knee), conf, f"{skel.node_names[knee]} (knee{how})", tuple(pos[knee]))
    if ankle is None:
        out[keys[2]] = KeypointProposal(keys[2], None, "absent", "the leg ends at the knee with no foot frame")
        out[keys[3]] = KeypointProposal(keys[3], None, "absent", "no foot")
        return
    spec, p, node = ankle
    if node is None:
        out[keys[2]] = KeypointProposal(keys[2], spec, "medium", f"foot frame {spec.link!r} (point foot)", tuple(p))
        out[keys[3]] = KeypointProposal(keys[3], None, "absent", "point foot: no toe")
        return
    out[keys[2]] = KeypointProposal(keys[2], spec, conf, f"{skel.node_names[node]} (last leg joint{how})", tuple(p))
    out[keys[3]] = _toe(keys[3], node, skel, urdf, t_root, pos)


def _fixed_descendants(urdf: UrdfModel, link: str) -> list[str]:
    out, stack = [], [link]
    while stack:
        l = stack.pop()
        out.append(l)
        stack.extend(j.child for j in urdf.children_of(l) if j.type == "fixed")
    return out


def _toe(key, ankle, skel, urdf, t_root, pos) -> KeypointProposal:
    foot = skel.link_names[ankle]
    links = _fixed_descendants(urdf, foot)
    named = [l for l in links[1:] if _NAMES["toe"].search(l)]
    if named:
        best = max(named, key=lambda l: t_root[l][0, 3])
        p = t_root[best][:3, 3]
        return KeypointProposal(key, KeypointSpec(best), "high", f"fixed frame {best!r}", tuple(p))
    pts = [t_root[l][:3, :3] @ urdf.collision_points[l].T + t_root[l][:3, 3:] for l in links if l in urdf.collision_points]
    if pts:
        allp = np.concatenate(pts, axis=1).T  # (K, 3) root frame
        p = np.array([allp[:, 0].max(), pos[ankle][1], allp[:, 2].min()])
        t = t_root[foot]
        offset = t[:3, :3].T @ (p - t[:3, 3])
        offset = np.round(offset, 4)
        p = t[:3, :3] @ offset + t[:3, 3]
        return KeypointProposal(
            key, KeypointSpec(foot, tuple(float(x) for x in offset)), "medium",
            f"front-bottom of the collision shapes of {foot!r}", tuple(p),
        )  # fmt: skip
    return KeypointProposal(
        key, None, "absent", f"no toe frame and no primitive collision shape under {foot!r}; give it as link + offset"
    )


def _propose_arm(out, side, arm, skel, urdf, t_root, pos, quad: bool) -> None:
    keys = [f"{side}_{k}" for k in ("shoulder", "elbow", "hand")]
    if arm is None or len(arm["joints"]) < 2:
        for k in keys:
            out[k] = KeypointProposal(k, None, "absent", f"no {side} arm chain found")
        return
    if quad:  # front legs stand in for the arms: hip -> shoulder, knee -> elbow, foot -> hand
        hip, knee, ankle, _ = _leg_points(arm, skel, urdf, t_root, pos)
        why = " (front leg standing in for the arm)"
        out[keys[0]] = KeypointProposal(keys[0], _spec_at_node(skel, hip), "low", f"{skel.node_names[hip]}{why}", tuple(pos[hip]))
        out[keys[1]] = KeypointProposal(keys[1], _spec_at_node(skel, knee), "low", f"{skel.node_names[knee]}{why}", tuple(pos[knee]))
        if ankle is None:
            out[keys[2]] = KeypointProposal(keys[2], None, "absent", "the front leg has no foot frame")
        else:
            out[keys[2]] = KeypointProposal(keys[2], ankle[0], "low", f"front foot {ankle[0].link!r}{why}", tuple(ankle[1]))
        return
    joints = arm["joints"]
    last = joints[-1]
    named_elbow = [n for n in _named(skel, joints, "elbow") if n != joints[0]]
    elbow = _middle_joint(skel, named_elbow or joints[1:] or joints, pos, pos[joints[0]], pos[last])
    i = joints.index(elbow)
    shoulder = _pivot(skel, joints[:i] or joints[:1], elbow, pos)
    conf = "high" if named_elbow else "medium"
    out[keys[0]] = KeypointProposal(keys[0], _spec_at_node(skel, shoulder), conf,
                                    f"{skel.node_names[shoulder]} (last shoulder joint that is not an upper-arm twist)", tuple(pos[shoulder]))
    out[keys[1]] = KeypointProposal(keys[1], _spec_at_node(skel, elbow), conf, f"{skel.node_names[elbow]} (elbow)", tuple(pos[elbow]))
    # hand: a fixed hand frame under the last joint, else the last joint (if beyond the elbow)
    links = _fixed_descendants(urdf, skel.link_names[last])
    named = [l for l in links[1:] if _NAMES["hand"].search(l)]
    if named:
        best = max(named, key=lambda l: np.linalg.norm(t_root[l][:3, 3] - pos[shoulder]))
        out[keys[2]] = KeypointProposal(keys[2], KeypointSpec(best), "high", f"fixed frame {best!r}", tuple(t_root[best][:3, 3]))
    elif last != elbow:
        out[keys[2]] = KeypointProposal(keys[2], _spec_at_node(skel, last), "medium", f"{skel.node_names[last]} (last arm joint)", tuple(pos[last]))
    else:
        out[keys[2]] = KeypointProposal(
            keys[2], None, "absent", f"the {side} arm ends at the elbow; give the hand as link + offset"
        )
