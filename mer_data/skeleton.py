"""The central type: an immutable robot skeleton graph (the paper's ``g = {phi_v, phi_e, psi}``).

Nodes, in a stable topological order (``parents[j] < j``):

* node 0 is the floating base (the URDF root link);
* one node per revolute or continuous joint that is not locked (fixed joints and locked joints are
  merged into their parent, their transforms composed);
* one fixed *site* node per key point that does not sit on a joint (a toe, a hand: ``link + offset``),
  appended after the joints.

All geometry is expressed at the zero pose in the **root frame** (the base link's frame), and every
node frame is aligned with the root frame at the zero pose. With that choice a node's rotation axis
``axes[j]`` and its parent→node vector ``offsets[j]`` are all forward kinematics needs:
``R_j = R_parent @ Rot(axes[j], q_j)``, ``p_j = p_parent + R_parent @ offsets[j]``. The URDF link's
own orientation is recovered as ``R_j @ rest_rotations[j]``.

Units: metres and radians.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Mapping, Sequence

import numpy as np

__all__ = [
    "Skeleton",
    "BodyPart",
    "KEYPOINTS",
    "NodeKind",
    "PSI_NONE",
    "PSI_SELF",
    "PSI_PARENT",
    "PSI_CHILD",
    "SKELETON_FORMAT_VERSION",
]

NodeKind = Literal["base", "revolute", "site"]

#: The 14 semantic key points that build joint maps, in a fixed order.
KEYPOINTS: tuple[str, ...] = (
    "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_toe", "right_toe", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_hand", "right_hand",
)  # fmt: skip

#: ``psi[i, j]`` codes: no relation, self, ``j`` is the parent of ``i``, ``j`` is a child of ``i``.
PSI_NONE, PSI_SELF, PSI_PARENT, PSI_CHILD = 0, 1, 2, 3

#: Bumped whenever :meth:`Skeleton.to_dict` changes incompatibly.
SKELETON_FORMAT_VERSION = 1


@dataclass(frozen=True)
class BodyPart:
    """A chain of key points scaled together (paper: body-part scaling ``alpha_k``).

    ``start`` is ``"base"`` or a key point; ``keypoints`` are the points of the part, each scaled
    about the (already scaled) start point.
    """

    name: str
    start: str
    keypoints: tuple[str, ...]


def _readonly(a: np.ndarray, dtype) -> np.ndarray:
    a = np.array(a, dtype=dtype, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Immutable skeleton graph of one robot (possibly with scaled links).

    Attributes (J = number of nodes):
        name: robot name.
        node_names: (J,) node 0 = root link name, joints = URDF joint names, sites = key point names.
        node_kinds: (J,) ``"base"``, ``"revolute"`` or ``"site"``.
        parents: (J,) int64 parent node, ``-1`` for the base; ``parents[j] < j``.
        axes: (J, 3) unit rotation axis in the root frame at zero pose; zero for base and sites.
        offsets: (J, 3) parent → node vector in the root frame at zero pose [m]; zero for the base.
        lower, upper: (J,) joint limits [rad]; 0 for base and sites; continuous joints get ±pi.
        nominal: (J,) nominal angles [rad] (regulariser target), inside the limits.
        rest_rotations: (J, 3, 3) orientation of each node's URDF link at zero pose (root frame).
        link_names: (J,) URDF link each node stands for (sites: the link that carries them).
        urdf_joint_names: (J,) URDF joint of each node; ``None`` for base and sites.
        mimic_source: (J,) node whose angle drives this one (``q_j = m * q_src + o``), -1 if none.
        mimic_multiplier, mimic_offset: (J,) the mimic relation (1 and 0 where there is none).
        keypoints: key point → node index, or -1 where the robot has none (all 14 present as keys).
        body_parts: chains of key points used for reference scaling.
        locked: URDF joints held at a value, merged into their parents [rad].
        continuous: (J,) True for continuous joints.
    """

    name: str
    node_names: tuple[str, ...]
    node_kinds: tuple[NodeKind, ...]
    parents: np.ndarray
    axes: np.ndarray
    offsets: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    nominal: np.ndarray
    rest_rotations: np.ndarray
    link_names: tuple[str, ...]
    urdf_joint_names: tuple[str | None, ...]
    mimic_source: np.ndarray
    mimic_multiplier: np.ndarray
    mimic_offset: np.ndarray
    keypoints: Mapping[str, int]
    body_parts: tuple[BodyPart, ...] = ()
    locked: Mapping[str, float] = field(default_factory=dict)
    continuous: np.ndarray | None = None

    def __post_init__(self) -> None:
        J = len(self.node_names)
        ro = object.__setattr__
        ro(self, "parents", _readonly(self.parents, np.int64))
        for name in ("axes", "offsets"):
            ro(self, name, _readonly(getattr(self, name), np.float64))
        for name in ("lower", "upper", "nominal", "mimic_multiplier", "mimic_offset"):
            ro(self, name, _readonly(getattr(self, name), np.float64))
        ro(self, "rest_rotations", _readonly(self.rest_rotations, np.float64))
        ro(self, "mimic_source", _readonly(self.mimic_source, np.int64))
        cont = np.zeros(J, bool) if self.continuous is None else self.continuous
        ro(self, "continuous", _readonly(cont, bool))
        ro(self, "keypoints", dict(self.keypoints))
        ro(self, "locked", dict(self.locked))
        ro(self, "node_names", tuple(self.node_names))
        ro(self, "node_kinds", tuple(self.node_kinds))
        ro(self, "link_names", tuple(self.link_names))
        ro(self, "urdf_joint_names", tuple(self.urdf_joint_names))
        ro(self, "body_parts", tuple(self.body_parts))
        self._check()

    def _check(self) -> None:
        J = len(self.node_names)
        shapes = {
            "parents": (J,), "axes": (J, 3), "offsets": (J, 3), "lower": (J,), "upper": (J,),
            "nominal": (J,), "rest_rotations": (J, 3, 3), "mimic_source": (J,),
            "mimic_multiplier": (J,), "mimic_offset": (J,), "continuous": (J,),
        }  # fmt: skip
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"Skeleton.{name} has shape {getattr(self, name).shape}, expected {shape}")
        for name in ("node_kinds", "link_names", "urdf_joint_names"):
            if len(getattr(self, name)) != J:
                raise ValueError(f"Skeleton.{name} has {len(getattr(self, name))} entries, expected {J}")
        if J == 0 or self.parents[0] != -1 or self.node_kinds[0] != "base":
            raise ValueError("node 0 must be the base, with parent -1")
        if np.any(self.parents[1:] < 0) or np.any(self.parents[1:] >= np.arange(1, J)):
            raise ValueError("parents must be in topological order (0 <= parents[j] < j for j > 0)")
        if len(set(self.node_names)) != J:
            raise ValueError("node names must be unique")
        for k, v in self.keypoints.items():
            if not -1 <= v < J:
                raise ValueError(f"key point {k!r} points at node {v}, outside 0..{J - 1}")

    # ---- derived views ----------------------------------------------------------------------
    @property
    def num_nodes(self) -> int:
        """J, the number of nodes including base and sites."""
        return len(self.node_names)

    @property
    def revolute_mask(self) -> np.ndarray:
        """(J,) True for joint nodes (mimic ones included)."""
        return np.array([k == "revolute" for k in self.node_kinds])

    @property
    def dof_mask(self) -> np.ndarray:
        """(J,) True for independently actuated joint nodes (revolute and not mimic)."""
        return self.revolute_mask & (self.mimic_source < 0)

    @property
    def num_dof(self) -> int:
        return int(self.dof_mask.sum())

    @property
    def joint_names(self) -> tuple[str, ...]:
        """URDF names of the actuated joints, in node order."""
        return tuple(n for n, m in zip(self.node_names, self.dof_mask) if m)

    @property
    def depth(self) -> np.ndarray:
        """(J,) number of edges from the base."""
        d = np.zeros(self.num_nodes, np.int64)
        for j in range(1, self.num_nodes):
            d[j] = d[self.parents[j]] + 1
        return d

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    @property
    def psi(self) -> np.ndarray:
        """(J, J) int8 relation matrix: 0 none, 1 self, 2 ``j`` is parent of ``i``, 3 ``j`` is child of ``i``."""
        J = self.num_nodes
        psi = np.zeros((J, J), np.int8)
        psi[np.arange(J), np.arange(J)] = PSI_SELF
        kids = np.arange(1, J)
        psi[kids, self.parents[1:]] = PSI_PARENT
        psi[self.parents[1:], kids] = PSI_CHILD
        return psi

    @property
    def rest_positions(self) -> np.ndarray:
        """(J, 3) node positions at zero pose in the root frame [m] (cumulative offsets)."""
        pos = np.zeros((self.num_nodes, 3))
        for j in range(1, self.num_nodes):
            pos[j] = pos[self.parents[j]] + self.offsets[j]
        return pos

    @property
    def link_lengths(self) -> np.ndarray:
        """(J,) |offsets| [m], the paper's link length of the edge into each node."""
        return np.linalg.norm(self.offsets, axis=-1)

    def node_index(self, name: str) -> int:
        try:
            return self.node_names.index(name)
        except ValueError:
            raise KeyError(f"{self.name} has no node {name!r}") from None

    def path_to_root(self, j: int) -> list[int]:
        """Node indices from ``j`` up to the base, inclusive."""
        out = [j]
        while self.parents[out[-1]] >= 0:
            out.append(int(self.parents[out[-1]]))
        return out

    def rigidly_attached(self, a: int, b: int) -> bool:
        """True if node ``b`` hangs off node ``a`` through fixed nodes only (no joint turns between them)."""
        n = b
        while n != a and n > 0:
            if self.node_kinds[n] == "revolute":
                return False
            n = int(self.parents[n])
        return n == a

    def subtree(self, j: int) -> np.ndarray:
        """(J,) True for ``j`` and every node below it."""
        inside = np.zeros(self.num_nodes, bool)
        inside[j] = True
        for k in range(j + 1, self.num_nodes):
            inside[k] = inside[self.parents[k]]
        return inside

    def keypoint_nodes(self) -> dict[str, int]:
        """The key points this robot has (node index >= 0)."""
        return {k: v for k, v in self.keypoints.items() if v >= 0}

    # ---- modified copies --------------------------------------------------------------------
    def with_link_scales(self, scales: np.ndarray) -> "Skeleton":
        """A copy whose edge into node ``j`` is scaled by ``scales[j]`` ((J,), > 0).

        Scaling edge ``j`` moves exactly the nodes in ``subtree(j)`` at the zero pose.
        """
        scales = np.asarray(scales, dtype=np.float64)
        if scales.shape != (self.num_nodes,) or np.any(scales <= 0) or not np.all(np.isfinite(scales)):
            raise ValueError(f"scales must be ({self.num_nodes},) positive finite numbers")
        return replace(self, offsets=self.offsets * scales[:, None])

    # ---- serialisation ----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict that :meth:`from_dict` turns back into an equal skeleton (bit-exact)."""
        return {
            "format_version": SKELETON_FORMAT_VERSION,
            "name": self.name,
            "node_names": list(self.node_names),
            "node_kinds": list(self.node_kinds),
            "parents": self.parents.tolist(),
            "axes": self.axes.tolist(),
            "offsets": self.offsets.tolist(),
            "lower": self.lower.tolist(),
            "upper": self.upper.tolist(),
            "nominal": self.nominal.tolist(),
            "rest_rotations": self.rest_rotations.tolist(),
            "link_names": list(self.link_names),
            "urdf_joint_names": list(self.urdf_joint_names),
            "mimic_source": self.mimic_source.tolist(),
            "mimic_multiplier": self.mimic_multiplier.tolist(),
            "mimic_offset": self.mimic_offset.tolist(),
            "keypoints": dict(self.keypoints),
            "body_parts": [
                {"name": b.name, "start": b.start, "keypoints": list(b.keypoints)} for b in self.body_parts
            ],
            "locked": dict(self.locked),
            "continuous": self.continuous.tolist(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Skeleton":
        version = d.get("format_version")
        if version != SKELETON_FORMAT_VERSION:
            raise ValueError(
                f"skeleton format version {version!r} is not {SKELETON_FORMAT_VERSION}; rebuild the "
                "artefact with this version of mer"
            )
        kw = {k: v for k, v in d.items() if k != "format_version"}
        kw["body_parts"] = tuple(
            BodyPart(b["name"], b["start"], tuple(b["keypoints"])) for b in d.get("body_parts", ())
        )
        kw["rest_rotations"] = np.asarray(d["rest_rotations"], dtype=np.float64).reshape(-1, 3, 3)
        for k in ("axes", "offsets"):
            kw[k] = np.asarray(d[k], dtype=np.float64).reshape(-1, 3)
        return cls(**kw)

    def to_json(self) -> str:
        """Canonical JSON (sorted keys). Computed once per object: a skeleton is immutable (read-only
        arrays; ``keypoints``/``locked`` are never changed in place), and equality, hashing and
        :attr:`fingerprint` all go through it (collate hashes skeleton pairs for every sample)."""
        text = self.__dict__.get("_json")
        if text is None:
            text = json.dumps(self.to_dict(), sort_keys=True)
            object.__setattr__(self, "_json", text)
        return text

    @classmethod
    def from_json(cls, text: str) -> "Skeleton":
        return cls.from_dict(json.loads(text))

    @property
    def fingerprint(self) -> str:
        """sha256 of the canonical JSON: equal skeletons, equal fingerprints."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Skeleton) and self.to_json() == other.to_json()

    def __hash__(self) -> int:
        return hash(self.fingerprint)

    def __repr__(self) -> str:
        kp = sum(v >= 0 for v in self.keypoints.values())
        return f"Skeleton({self.name!r}, nodes={self.num_nodes}, dof={self.num_dof}, keypoints={kp}/{len(KEYPOINTS)})"


def topological_check(parents: Sequence[int]) -> None:
    """Raise ValueError unless ``parents`` is a valid topologically ordered tree."""
    p = np.asarray(parents)
    if p.ndim != 1 or p[0] != -1 or np.any(p[1:] < 0) or np.any(p[1:] >= np.arange(1, len(p))):
        raise ValueError("parents must be 1-D with parents[0] == -1 and 0 <= parents[j] < j")
