"""Target-skeleton augmentation for training (paper, Implementation Details).

"Key links (e.g., thigh and calf) are scaled by factors between 0.5 and 2, other links between 0.67
and 1.5, and certain non-end-effector correspondences are randomly dropped; evaluations use the
original URDF skeletons."

Choices the paper leaves open (docs/shards.md):

* **Which links.** The *thigh* is every edge on the tree path from the hip key point down to the
  knee key point, the *calf* every edge from the knee down to the ankle; all edges of a segment get
  the segment's factor, so the segment's length scales by exactly that factor. Every other edge
  (pelvis to hip, spine, arms, the foot and hand sites...) is an *other* link with its own factor.
* **Symmetry.** Left/right counterparts share one factor (both thighs, both calves, and each pair
  of mirrored edges, paired by name: ``left``/``right``, ``l_``/``r_``, ``_L_``/``_R_``), so an
  augmented robot stays left/right symmetric.
* **Distribution.** Log-uniform between the bounds (the bounds are reciprocal pairs, so shrinking
  and growing are equally likely).
* **Dropped correspondences.** Each key point pair that is not an end effector
  (:data:`mer_data.kinematics.jointmap.END_EFFECTORS`) is dropped independently with probability
  ``drop_prob``; the base pair and the end effectors are never dropped.

All draws come from a caller-supplied ``numpy.random.Generator``: same seed, same augmentation.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from mer_data.kinematics.jointmap import END_EFFECTORS, keypoint_pairs
from mer_data.skeleton import KEYPOINTS, Skeleton

__all__ = [
    "AugmentConfig",
    "LinkGroups",
    "mirror_nodes",
    "leg_links",
    "link_groups",
    "draw_link_scales",
    "draw_dropped",
    "droppable_keypoints",
    "augmented_joint_map",
]


@dataclass(frozen=True)
class AugmentConfig:
    """Augmentation ranges (scale factors, dimensionless) and the drop probability."""

    key_scale: tuple[float, float] = (0.5, 2.0)
    other_scale: tuple[float, float] = (0.67, 1.5)
    drop_prob: float = 0.1

    def __post_init__(self) -> None:
        for name in ("key_scale", "other_scale"):
            lo, hi = getattr(self, name)
            if not (0 < lo <= hi and np.isfinite(hi)):
                raise ValueError(f"{name} must be 0 < low <= high, got {(lo, hi)}")
            object.__setattr__(self, name, (float(lo), float(hi)))
        if not 0.0 <= self.drop_prob < 1.0:
            raise ValueError(f"drop_prob must be in [0, 1), got {self.drop_prob}")

    def to_dict(self) -> dict:
        return {"key_scale": list(self.key_scale), "other_scale": list(self.other_scale), "drop_prob": self.drop_prob}


_SIDE = re.compile(r"left|right|Left|Right|LEFT|RIGHT|(?<![A-Za-z])[lLrR](?![A-Za-z])")
_SWAP = {"left": "right", "right": "left", "Left": "Right", "Right": "Left", "LEFT": "RIGHT", "RIGHT": "LEFT",
         "l": "r", "r": "l", "L": "R", "R": "L"}  # fmt: skip


def mirror_nodes(skel: Skeleton) -> np.ndarray:
    """(J,) index of each node's left/right counterpart (by name), or the node itself."""
    index = {n: j for j, n in enumerate(skel.node_names)}
    out = np.arange(skel.num_nodes)
    for j, name in enumerate(skel.node_names):
        other = _SIDE.sub(lambda m: _SWAP[m.group(0)], name)
        k = index.get(other, j)
        if k != j and skel.node_kinds[k] == skel.node_kinds[j]:
            out[j] = k
    return out


def _path_edges(skel: Skeleton, top: int, bottom: int) -> list[int]:
    """Nodes whose incoming edge lies on the path from ``top`` down to ``bottom`` ([] if not below)."""
    if top < 0 or bottom < 0:
        return []
    path = skel.path_to_root(bottom)
    if top not in path:
        return []
    return sorted(path[: path.index(top)])


def leg_links(skel: Skeleton) -> dict[str, list[int]]:
    """``{"thigh": nodes, "calf": nodes}``: the key links (both sides), as the nodes their edges enter."""
    kp = skel.keypoints
    out: dict[str, list[int]] = {"thigh": [], "calf": []}
    for side in ("left", "right"):
        out["thigh"] += _path_edges(skel, kp.get(f"{side}_hip", -1), kp.get(f"{side}_knee", -1))
        out["calf"] += _path_edges(skel, kp.get(f"{side}_knee", -1), kp.get(f"{side}_ankle", -1))
    return out


@dataclass(frozen=True)
class LinkGroups:
    """Edges that share one scale factor.

    Attributes:
        group: (J,) group of the edge into each node; -1 for the base (never scaled).
        kinds: (G,) ``"thigh"``, ``"calf"`` (key links) or ``"other"`` per group.
    """

    group: np.ndarray
    kinds: tuple[str, ...]

    @property
    def is_key(self) -> np.ndarray:
        return np.array([k != "other" for k in self.kinds])


def link_groups(skel: Skeleton) -> LinkGroups:
    """Group the edges of ``skel`` for scaling (see module docstring)."""
    legs = leg_links(skel)
    mirror = mirror_nodes(skel)
    group = np.full(skel.num_nodes, -1, np.int64)
    kinds: list[str] = []
    keyed: dict[object, int] = {}
    for j in range(1, skel.num_nodes):
        if j in legs["thigh"]:
            key: object = "thigh"
        elif j in legs["calf"]:
            key = "calf"
        else:
            key = ("other", min(j, int(mirror[j])))
        if key not in keyed:
            keyed[key] = len(kinds)
            kinds.append(key if isinstance(key, str) else "other")
        group[j] = keyed[key]
    return LinkGroups(group, tuple(kinds))


def draw_link_scales(
    skel: Skeleton, rng: np.random.Generator, n: int, cfg: AugmentConfig, groups: LinkGroups | None = None
) -> np.ndarray:
    """(n, J) float64 link scale factors (1 for the base), for :meth:`Skeleton.with_link_scales`."""
    g = groups or link_groups(skel)
    u = rng.random((n, len(g.kinds)))
    lo = np.where(g.is_key, np.log(cfg.key_scale[0]), np.log(cfg.other_scale[0]))
    hi = np.where(g.is_key, np.log(cfg.key_scale[1]), np.log(cfg.other_scale[1]))
    per_group = np.exp(lo + u * (hi - lo))
    scales = np.ones((n, skel.num_nodes))
    edges = g.group >= 0
    scales[:, edges] = per_group[:, g.group[edges]]
    return scales


def droppable_keypoints() -> np.ndarray:
    """(14,) bool over :data:`mer_data.skeleton.KEYPOINTS`: True where a pair may be dropped."""
    return np.array([k not in END_EFFECTORS for k in KEYPOINTS])


def draw_dropped(rng: np.random.Generator, n: int, cfg: AugmentConfig) -> np.ndarray:
    """(n, 14) bool over KEYPOINTS: correspondences to drop (never an end effector)."""
    return (rng.random((n, len(KEYPOINTS))) < cfg.drop_prob) & droppable_keypoints()


def augmented_joint_map(target: Skeleton, ref: Skeleton, dropped: np.ndarray | None = None) -> np.ndarray:
    """(J_target, J_ref) uint8 ``eta`` without the dropped key point pairs (the base pair always kept)."""
    drop = set() if dropped is None else {k for k, d in zip(KEYPOINTS, np.asarray(dropped, bool)) if d}
    eta = np.zeros((target.num_nodes, ref.num_nodes), np.uint8)
    for name, i, j in keypoint_pairs(target, ref):
        if name not in drop:
            eta[i, j] = 1
    return eta
