"""The body a key-point proposal reads: zero-pose geometry in a body frame, its limbs and its digits.

* **Body frame**: the root frame (x forward, y left, z up), turned 180° about z when the joint
  names say left where the geometry says right (iCub's root frame looks backwards).
* **Digits**: a node where several moving chains branch within a small reach (under a fifth of
  the robot's size) at the end of a limb is a hand (or gripper); the joints below it are fingers.
* **Limbs**: the chains of moving joints to the leaf links, grouped by their last joint; a chain
  that ends on another one's way (a sensor frame or a motor rotor hanging mid-limb) is part of that
  limb, not a limb of its own; a limb's joints are those no other limb shares.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from mer_data.skeleton import Skeleton

from .builder import zero_pose_link_transforms
from .urdf import UrdfModel

__all__ = ["Body", "Limb", "digit_locks", "side_of_name", "DIGIT_REACH"]

#: A branching end is a hand when everything below it lies within this fraction of the robot's size.
DIGIT_REACH = 0.2
_LEFT = re.compile(r"(^|[_\W])(l|left)([_\W]|$)|^left|left|_L($|_)|(^|_)L_", re.I)
_RIGHT = re.compile(r"(^|[_\W])(r|right)([_\W]|$)|^right|right|_R($|_)|(^|_)R_", re.I)


def side_of_name(name: str) -> str | None:
    """``left``/``right`` when the name says so unambiguously, else None."""
    left, right = bool(_LEFT.search(name)), bool(_RIGHT.search(name))
    if left and not right:
        return "left"
    if right and not left:
        return "right"
    return None


@dataclass
class Limb:
    """Unshared joint chain of one limb: ``joints`` base → tip, ``tip`` its lowest point (body frame)."""

    joints: list[int]
    end: int
    leaves: list[str]
    tip: np.ndarray


@dataclass
class Body:
    """Zero-pose geometry of a skeleton in the body frame (see module docstring)."""

    urdf: UrdfModel
    skel: Skeleton
    t: dict[str, np.ndarray]  # link → 4x4 body ← link at the zero pose
    pos: np.ndarray  # (J, 3) node positions
    axes: np.ndarray  # (J, 3) node axes
    link_node: dict[str, int]
    flipped: bool = False
    size: float = field(init=False)

    def __post_init__(self) -> None:
        pts = np.array([m[:3, 3] for m in self.t.values()])
        self.size = float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 0.0

    @classmethod
    def of(cls, urdf: UrdfModel, skel: Skeleton) -> "Body":
        t = zero_pose_link_transforms(urdf, dict(skel.locked))
        body = cls(urdf, skel, t, skel.rest_positions, np.asarray(skel.axes), _link_nodes(urdf, skel))
        if body._names_disagree_with_sides():
            flip = np.diag([-1.0, -1.0, 1.0, 1.0])
            body.t = {k: flip @ v for k, v in t.items()}
            body.pos = body.pos @ flip[:3, :3]
            body.axes = body.axes @ flip[:3, :3]
            body.flipped = True
        return body

    # ---- geometry ---------------------------------------------------------------------------
    def p(self, link: str) -> np.ndarray:
        return self.t[link][:3, 3]

    def fixed_descendants(self, link: str) -> list[str]:
        """``link`` and the links below it through fixed or locked joints."""
        out, stack = [], [link]
        moving = set(self.skel.node_names)
        while stack:
            l = stack.pop()
            out.append(l)
            stack.extend(j.child for j in self.urdf.children_of(l) if j.name not in moving)
        return out

    def rigid_frames(self, link: str) -> list[str]:
        """Links fixed to ``link`` by ``fixed`` joints only (not locked fingers)."""
        out, stack = [], [link]
        while stack:
            l = stack.pop()
            out.append(l)
            stack.extend(j.child for j in self.urdf.children_of(l) if j.type == "fixed")
        return out

    def collision_points(self, links: list[str]) -> np.ndarray:
        """(K, 3) body-frame extreme points of the primitive collision shapes of ``links``."""
        pts = [
            (self.t[l][:3, :3] @ self.urdf.collision_points[l].T + self.t[l][:3, 3:]).T
            for l in links
            if l in self.urdf.collision_points
        ]
        return np.concatenate(pts) if pts else np.zeros((0, 3))

    def offset_in(self, link: str, p: np.ndarray) -> tuple[float, float, float]:
        """Body-frame point ``p`` as an offset in ``link``'s frame (rounded to 0.1 mm)."""
        t = self.t[link]
        return tuple(float(x) for x in np.round(t[:3, :3].T @ (p - t[:3, 3]), 4))

    def at(self, link: str, offset) -> np.ndarray:
        t = self.t[link]
        return t[:3, :3] @ np.asarray(offset, dtype=float) + t[:3, 3]

    # ---- limbs ------------------------------------------------------------------------------
    def limbs(self) -> list[Limb]:
        skel = self.skel
        has_child = {j.parent for j in self.urdf.joints}
        links_of: dict[int, list[str]] = {}
        for link, n in self.link_node.items():
            links_of.setdefault(n, []).append(link)
        by_end: dict[int, list[str]] = {}
        for leaf in self.urdf.links:
            if leaf not in has_child and leaf != self.urdf.root and self.link_node[leaf] != 0:
                by_end.setdefault(self.link_node[leaf], []).append(leaf)
        ends = self._sum_up(by_end)
        ends = {e: by_end[e] for e in by_end if ends[e] == 1}  # an end with another below: mid-limb frames
        passes = self._sum_up(ends)  # how many limb ends lie at or below each node
        limbs = []
        for end, leaves in ends.items():
            own = []
            for n in skel.path_to_root(end):
                if n == 0 or passes[n] > 1:
                    break
                own.append(n)
            own.reverse()
            tip = min((self.p(l) for n in own for l in links_of.get(n, ())), key=lambda q: q[2])
            limbs.append(Limb(own, end, leaves, tip))
        return limbs

    def _sum_up(self, ends) -> np.ndarray:
        """(J,) number of ``ends`` at or below each node (one sweep: parents come first)."""
        n = np.zeros(self.skel.num_nodes, np.int64)
        for e in ends:
            n[e] += 1
        for j in range(self.skel.num_nodes - 1, 0, -1):
            n[self.skel.parents[j]] += n[j]
        return n

    def _names_disagree_with_sides(self) -> bool:
        """True when more limbs are named for the side opposite to where they are (a backward root frame)."""
        agree = disagree = 0
        for limb in self.limbs():
            y = self.pos[limb.end][1]
            sides = {side_of_name(self.skel.node_names[n]) for n in limb.joints} - {None}
            if len(sides) != 1 or abs(y) < 0.02:
                continue
            if (sides == {"left"}) == (y > 0):
                agree += 1
            else:
                disagree += 1
        return disagree > agree


def _link_nodes(urdf: UrdfModel, skel: Skeleton) -> dict[str, int]:
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


def digit_locks(body: Body) -> tuple[dict[str, float], list[int]]:
    """Finger joints to lock (joint → 0 clipped into its limits) and the hand nodes they hang from.

    A hand is a node at the end of a limb (two moving joints or more above it) where two or more
    moving chains branch and everything below stays within :data:`DIGIT_REACH` of the robot's
    size. Mimic fingers are not listed: they are held with their master.
    """
    skel = body.skel
    kids: dict[int, list[int]] = {}
    for j in range(1, skel.num_nodes):
        if skel.node_kinds[j] == "revolute":
            kids.setdefault(int(skel.parents[j]), []).append(j)
    # bounding box of the links each node's subtree carries, summed up in one sweep (linear)
    lo = np.full((skel.num_nodes, 3), np.inf)
    hi = np.full((skel.num_nodes, 3), -np.inf)
    for link, n in body.link_node.items():
        lo[n] = np.minimum(lo[n], body.p(link))
        hi[n] = np.maximum(hi[n], body.p(link))
    for j in range(skel.num_nodes - 1, 0, -1):
        par = int(skel.parents[j])
        lo[par] = np.minimum(lo[par], lo[j])
        hi[par] = np.maximum(hi[par], hi[j])
    depth = skel.depth
    locks: dict[str, float] = {}
    hands: list[int] = []
    taken: set[int] = set()
    for h in range(1, skel.num_nodes):
        if h in taken or len(kids.get(h, ())) < 2 or depth[h] < 3:
            continue
        corners = np.stack(np.meshgrid(*zip(lo[h], hi[h]), indexing="ij"), -1).reshape(-1, 3)
        reach = float(np.linalg.norm(corners - body.pos[h], axis=1).max())
        if reach >= DIGIT_REACH * body.size:
            continue
        sub, stack = [], list(kids[h])
        while stack:
            n = stack.pop()
            sub.append(n)
            stack.extend(kids.get(n, ()))
        taken.update(sub)
        hands.append(h)
        for n in sorted(sub):
            if skel.mimic_source[n] in taken:  # a mimic finger is held with its master
                continue
            j = body.urdf.joint(skel.node_names[n])
            j_lo = -np.inf if j.lower is None or j.type == "continuous" else j.lower
            j_hi = np.inf if j.upper is None or j.type == "continuous" else j.upper
            locks[j.name] = float(np.clip(0.0, j_lo, j_hi))
    return locks, hands
