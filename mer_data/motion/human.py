"""Human motion capture (BVH) as a source :class:`~mer_data.skeleton.Skeleton` and its motion.

A human read by :mod:`mer_data.motion.bvh` becomes a skeleton like a robot's, so what takes a source
skeleton (features, key-point joint maps, foot contacts) takes a human. :func:`human_skeleton`
builds it, :func:`human_motion` gives the clip as ``base_pos`` (F, 3) [m], ``base_quat`` (F, 4) wxyz
and ``q`` (F, J) [rad], whose forward kinematics
(:func:`mer_data.kinematics.fk.fk_skeleton`) reproduces the file's own (:meth:`BvhMotion.positions`,
metres, z up, x forward) to rounding. The choices:

* **Floating base** (node 0, named after its joint): the first joint from the ROOT with more than
  one child, the hips (LAFAN1, CMU, Mixamo: the ROOT ``Hips``; Bandai: ``Hips`` under
  ``joint_Root``). The joints above it have one child each, so their transforms fold into the base
  pose exactly; they are not nodes (Bandai's ``joint_Root`` slides along the floor in some clips).
* **Ball joints**: each rotation channel of a joint below the base is one revolute node named
  ``"<joint>:<channel>"`` (``"LeftUpLeg:Zrotation"``), in the channel order, about the x, y or z
  axis of the joint's frame: three nodes compose ``Rz @ Rx @ Ry`` exactly as the file does. Euler
  angles wrap, so the nodes are ``continuous`` with limits +-pi and nominal 0; angles are wrapped to
  (-pi, pi].
* **Translation channels** below the base (Bandai writes 6 channels on every joint, repeating the
  bone lengths) are folded into the offsets when constant over the clip (within
  :data:`TRANSLATION_TOL` of the first frame); one that changes is refused (BVHError naming the
  joint, the channel and the frame), never dropped.
* **Sites**: End Sites (named ``<parent>_End`` by the reader) and joints without rotation channels
  become site nodes, named as in the file and appended after the revolute nodes, as the URDF
  builder does; the children of a joint without rotations hang off its nearest rotating ancestor
  with composed offsets (like a fixed URDF joint).
* **Zero pose**: by default the BVH rest pose (every rotation channel 0), turned to z up. It is
  clip independent, and standing for files whose rest pose is a T-pose (CMU, LAFAN1, Mixamo); it
  is not for Bandai's, whose rest pose lays every bone along +x (a warning says so).
  ``rest_frame=t`` makes the pose of frame ``t``, turned to face +x, the zero pose instead (angles
  are then measured from it: node ``n`` gets ``channel - channel(t)``, with the axes re-expressed,
  as the URDF builder does for joints behind fixed rotations).
* **Key points** (:func:`assign_keypoints`): by name, after :func:`~mer_data.motion.bvh.split_joint_name`
  strips namespaces and the side: hip = thigh root (``UpLeg``, ``UpperLeg``, ``Thigh``, ``femur``,
  ``Hip``), knee = shin root (``Leg``, ``LowerLeg``, ``Shin``, ``Calf``, ``Knee``, ``tibia``),
  ankle = ``Ankle``, else ``Foot``; toe = ``Toe``/``Toes``/``ToeBase``/``Toe0`` below the ankle,
  else the ankle's first child (joint, else End Site); shoulder = upper-arm root (``Arm``,
  ``UpperArm``, ``humerus``), else ``Shoulder`` (SMPL; Bandai's and Mixamo's ``Shoulder`` is the
  clavicle); elbow = forearm root (``ForeArm``, ``LowerArm``, ``Elbow``, ``radius``); hand =
  ``Wrist``, else ``Hand`` (the human "hand" key point is the wrist, docs/decisions.md). This covers
  Bandai, LAFAN1, CMU, Mixamo, SMPL, CMU-ASF (``lfemur``) and 3ds Max biped (``Bip01 L Thigh``)
  names. A mapping (key point -> joint name), possibly partial, overrides; each limb must run down
  the hierarchy (hip above knee above ankle above toe...). A key point sits on its joint's last
  rotation node (or its site), whose frame is the joint's whole frame (what orientation goals of
  feet and hands compare), at the joint's position, so :func:`mer_data.motion.contacts.sole_points` finds the ankle and
  toe of each foot as on a robot.
* **Other fields**: ``link_names`` the BVH joint each node moves with (sites: the joint carrying
  them, as for robots); ``urdf_joint_names`` the node name of revolute nodes, None for base and
  sites; ``rest_rotations`` the orientation of the BVH joint frame (after the node's rotation) at the
  zero pose; ``body_parts`` the standard humanoid plan (:data:`~mer_data.robots.card.DEFAULT_BODY_PARTS`);
  no mimic joints, nothing locked. The fingerprint follows from these as for any skeleton, so it
  changes with the bone lengths (Bandai's clips come from several performers).
* **Frames**: the skeleton's root frame is the BVH base joint's frame turned by the file's up
  rotation; the world is the reader's (metres, z up, the clip starting to face +x).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np
import torch

from mer_data.base.errors import BVHError
from mer_data.kinematics.rotations import matrix_to_quat
from mer_data.skeleton import KEYPOINTS, Skeleton

from .bvh import BvhMotion, axis_rotation, branch_joint, fk
from .human_keypoints import KEYPOINT_NAMES, KeypointChoice, assign_keypoints, keypoint_table, standing_frame
from .human_keypoints import is_below as _below

log = logging.getLogger(__name__)

__all__ = [
    "TRANSLATION_TOL",
    "KEYPOINT_NAMES",
    "KeypointChoice",
    "assign_keypoints",
    "keypoint_table",
    "base_joint",
    "standing_frame",
    "folded_translations",
    "human_skeleton",
    "human_motion",
    "bvh_nodes",
]

#: A translation channel below the base that stays this close to its first frame is a constant [m].
TRANSLATION_TOL = 1e-6
_MATCH_TOL = 1e-6
_MIXED = ("this clip's skeleton differs from the one it is read with (another performer's or studio's"
          " hierarchy): read each clip with its own skeleton (mer retarget and mer evaluate do), or put clips of one hierarchy in a folder")

# ---- the hierarchy ----------------------------------------------------------------------------


def base_joint(bvh: BvhMotion) -> int:
    """Index of the floating base: the first joint from the ROOT with other than one child joint."""
    return branch_joint(bvh.joints)


def folded_translations(bvh: BvhMotion, base: int) -> np.ndarray:
    """(N, 3) translation of each joint below ``base`` from its parent [file units]: the OFFSET, with
    constant position channels folded in (their first frame).

    Raises:
        BVHError: a position channel below the base changes by more than :data:`TRANSLATION_TOL`.
    """
    out = np.array([j.offset for j in bvh.joints], np.float64).reshape(-1, 3)
    for k, j in enumerate(bvh.joints):
        if not j.position_channels or not _below(bvh, k, base):
            continue
        for col, comp in j.position_channels:
            v = bvh.values[:, col]
            dev = np.abs(v - v[0]) * bvh.scale
            f = int(np.argmax(dev))
            if dev[f] > TRANSLATION_TOL:
                ch = j.channels[col - j.column]
                raise BVHError(
                    f"joint {j.name!r}: its {ch} channel changes during the clip ({dev[f] * 1000:.3g} mm away from "
                    f"frame 1 at frame {f + 1}); mer represents a human below the hips by rotations only",
                    path=bvh.path,
                    line=bvh.first_data_line + f,
                    element=f"joint {j.name!r}",
                    fix="re-export the BVH with translation only on the root (stretching bones are not supported)",
                )
            out[k, comp] = v[0]
    return out


# ---- the skeleton -----------------------------------------------------------------------------


def _rest(bvh: BvhMotion, choice: dict[str, KeypointChoice], base: int, rest_frame: int | None):
    """(C,) channel angles [rad] of the zero pose and the base frame's orientation (3, 3) in it."""
    C = bvh.values.shape[1]
    if rest_frame is None:
        return np.zeros(C), bvh.up_rotation
    if not 0 <= rest_frame < bvh.num_frames:
        raise BVHError(f"rest_frame {rest_frame} is outside the clip's frames 0..{bvh.num_frames - 1}", path=bvh.path,
                       fix="pass a frame index of the clip (0 = the first)")  # fmt: skip
    sel = slice(rest_frame, rest_frame + 1)
    rot = bvh.rotations(sel)[0]
    pos = bvh.positions(sel)[0]
    v = pos[bvh.index(choice["left_hip"].joint)] - pos[bvh.index(choice["right_hip"].joint)]
    heading = math.atan2(v[1], v[0]) - math.pi / 2
    return np.deg2rad(bvh.values[rest_frame]), axis_rotation("z", -heading) @ rot[base]


@dataclass
class _Nodes:
    names: list
    kinds: list
    parents: list
    axes: list
    pos: list
    rest: list
    links: list

    def add(self, name, kind, parent, axis, pos, rest, link) -> int:
        for lst, v in zip((self.names, self.kinds, self.parents, self.axes, self.pos, self.rest, self.links),
                          (name, kind, parent, axis, pos, rest, link)):  # fmt: skip
            lst.append(v)
        return len(self.names) - 1


def human_skeleton(
    bvh: BvhMotion,
    *,
    keypoints: Mapping[str, str] | None = None,
    name: str = "bvh",
    rest_frame: int | None = None,
) -> Skeleton:
    """The skeleton of the human in ``bvh`` (module docstring).

    Args:
        bvh: a parsed file (:func:`mer_data.motion.bvh.read_bvh`).
        keypoints: key point -> joint name overrides (partial is fine).
        name: the skeleton's name.
        rest_frame: None: the BVH rest pose is the zero pose; a frame index: that frame's pose is.

    Raises:
        BVHError: missing key points, key points at or above the base, changing translations below
            the base.
    """
    choice = assign_keypoints(bvh, keypoints)
    base = base_joint(bvh)
    for c in choice.values():
        if not _below(bvh, bvh.index(c.joint), base):
            raise BVHError(f"key point {c.key!r} is {c.joint!r}, which is not below the floating base "
                           f"{bvh.joints[base].name!r}", path=bvh.path, element=f"key point {c.key}",
                           fix="name a joint of the legs or arms in keypoints=")  # fmt: skip
    trans = folded_translations(bvh, base) * bvh.scale
    q0, q_base = _rest(bvh, choice, base, rest_frame)
    nodes = _Nodes([], [], [], [], [], [], [])
    nodes.add(bvh.joints[base].name, "base", -1, np.zeros(3), np.zeros(3), q_base, bvh.joints[base].name)
    frame_node, orient, where, at = {base: 0}, {base: q_base}, {base: np.zeros(3)}, {base: 0}
    sites = []
    for k in range(base + 1, len(bvh.joints)):
        j = bvh.joints[k]
        if j.parent not in frame_node:  # not below the base
            continue
        p, Q, node = j.parent, orient[j.parent], frame_node[j.parent]
        where[k] = where[p] + Q @ trans[k]
        for i, (col, axis) in enumerate(j.rotation_channels):
            Q_next = Q @ axis_rotation(axis, q0[col])
            node = nodes.add(f"{j.name}:{j.channels[col - j.column]}", "revolute", node, Q[:, "xyz".index(axis)],
                             where[k], Q_next, j.name)  # fmt: skip
            at[k] = node  # a key point sits on its joint's last rotation node: the joint's whole frame (orientation goals)
            Q = Q_next
        if not j.rotation_channels:
            sites.append((k, node, Q))
        frame_node[k], orient[k] = node, Q
    for k, carrier, Q in sites:
        at[k] = nodes.add(bvh.joints[k].name, "site", carrier, np.zeros(3), where[k], Q, nodes.links[carrier])
    if len(set(nodes.names)) != len(nodes.names):
        dup = next(n for n in nodes.names if nodes.names.count(n) > 1)
        raise BVHError(f"node name {dup!r} would be used twice (a joint is named like another joint's channel)",
                       path=bvh.path, fix="rename the joint in the file")  # fmt: skip
    skel = _assemble(nodes, {c.key: at[bvh.index(c.joint)] for c in choice.values()}, name)
    _warn_if_not_standing(bvh, skel, rest_frame)
    return skel


def _assemble(nodes: _Nodes, keypoints: dict[str, int], name: str) -> Skeleton:
    from mer_data.robots.card import DEFAULT_BODY_PARTS

    J = len(nodes.names)
    pos, par = np.asarray(nodes.pos), np.asarray(nodes.parents)
    offsets = np.zeros((J, 3))
    offsets[1:] = pos[1:] - pos[par[1:]]
    rev = np.array([k == "revolute" for k in nodes.kinds])
    return Skeleton(
        name=name,
        node_names=tuple(nodes.names),
        node_kinds=tuple(nodes.kinds),
        parents=par,
        axes=np.asarray(nodes.axes),
        offsets=offsets,
        lower=np.where(rev, -math.pi, 0.0),
        upper=np.where(rev, math.pi, 0.0),
        nominal=np.zeros(J),
        rest_rotations=np.asarray(nodes.rest),
        link_names=tuple(nodes.links),
        urdf_joint_names=tuple(n if r else None for n, r in zip(nodes.names, rev)),
        mimic_source=np.full(J, -1),
        mimic_multiplier=np.ones(J),
        mimic_offset=np.zeros(J),
        keypoints={k: keypoints[k] for k in KEYPOINTS},
        body_parts=DEFAULT_BODY_PARTS,
        continuous=rev,
    )


def _warn_if_not_standing(bvh: BvhMotion, skel: Skeleton, rest_frame: int | None) -> None:
    """Log when the zero pose's head is not well above its feet (Bandai's rest pose)."""
    rest = skel.rest_positions
    kp = skel.keypoints
    feet = rest[[kp["left_ankle"], kp["right_ankle"]], 2].mean()
    legs = np.linalg.norm(rest[kp["left_hip"]] - rest[kp["left_ankle"]])
    if rest[0, 2] - feet < 0.5 * legs:
        log.warning("%s: in the zero pose (%s) the hips are not above the feet: it is not a standing pose; "
                    "pass rest_frame=N to use a standing frame's pose", bvh.path,
                    "the BVH rest pose" if rest_frame is None else f"frame {rest_frame}")  # fmt: skip


# ---- the motion -------------------------------------------------------------------------------


def bvh_nodes(skel: Skeleton) -> dict[str, int]:
    """BVH joint / End Site name -> its node (base, last rotation node: the joint's whole frame, or site)."""
    out = {skel.node_names[0]: 0}
    for n in range(1, skel.num_nodes):
        out[skel.node_names[n] if skel.node_kinds[n] == "site" else skel.link_names[n]] = n
    return out


def _node_columns(bvh: BvhMotion, skel: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Revolute nodes, their channel columns and zero-pose angles [rad], checked against ``bvh``."""
    fix = _MIXED
    per_joint: dict[str, list[tuple[int, str, float]]] = {}
    for n in np.flatnonzero(skel.revolute_mask):
        Qp, axis = skel.rest_rotations[skel.parents[n]], skel.axes[n]
        local = Qp.T @ axis
        a = int(np.argmax(np.abs(local)))
        M = Qp.T @ skel.rest_rotations[n]
        i1, i2 = (a + 1) % 3, (a + 2) % 3
        angle = math.atan2(M[i2, i1], M[i1, i1])
        if local[a] < 1 - _MATCH_TOL or np.abs(M - axis_rotation("xyz"[a], angle)).max() > _MATCH_TOL:
            raise BVHError(f"skeleton node {skel.node_names[n]!r} does not turn about an axis of its joint's frame",
                           path=bvh.path, fix=_MIXED)  # fmt: skip
        per_joint.setdefault(skel.link_names[n], []).append((int(n), "xyz"[a], angle))
    nodes, cols, q0 = [], [], []
    base = base_joint(bvh)
    for k, j in enumerate(bvh.joints):
        if not j.rotation_channels or not _below(bvh, k, base):
            continue
        have = per_joint.pop(j.name, [])
        if [ax for _, ax, _ in have] != [ax for _, ax in j.rotation_channels]:
            raise BVHError(f"joint {j.name!r} has rotation channels {list(j.channels)} but the skeleton's nodes "
                           f"turn about {[ax for _, ax, _ in have]}", path=bvh.path, line=j.line, fix=fix)  # fmt: skip
        for (n, _, a0), (col, _) in zip(have, j.rotation_channels):
            nodes.append(n)
            cols.append(col)
            q0.append(a0)
    if per_joint:
        raise BVHError(f"the skeleton moves joints this file does not rotate below its base: {sorted(per_joint)}",
                       path=bvh.path, fix=fix)  # fmt: skip
    return np.array(nodes, np.int64), np.array(cols, np.int64), np.array(q0)


def _check_bones(bvh: BvhMotion, skel: Skeleton, base: int, trans: np.ndarray) -> None:
    at = bvh_nodes(skel)
    rest = skel.rest_positions
    worst, joint = 0.0, ""
    for k, j in enumerate(bvh.joints):
        if not _below(bvh, k, base):
            continue
        if j.name not in at or bvh.joints[j.parent].name not in at:
            raise BVHError(f"joint {j.name!r} of the file is not in the skeleton {skel.name!r}", path=bvh.path,
                           line=j.line, fix=_MIXED)  # fmt: skip
        got = np.linalg.norm(rest[at[j.name]] - rest[at[bvh.joints[j.parent].name]])
        diff = abs(got - np.linalg.norm(trans[k]) * bvh.scale)
        if diff > worst:
            worst, joint = diff, j.name
    if worst > _MATCH_TOL:
        log.warning("%s: the skeleton's bones differ from this clip's by up to %.3g m (at %s): its motion will not "
                    "reproduce the clip exactly", bvh.path, worst, joint)  # fmt: skip


def human_motion(bvh: BvhMotion, skel: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clip as a motion of ``skel`` (built by :func:`human_skeleton` from this file or one with the
    same hierarchy).

    Returns:
        base_pos: (F, 3) float64 base position in the world [m] (z up, x forward).
        base_quat: (F, 4) float64 unit base orientation, wxyz, world <- base.
        q: (F, J) float64 angle per node [rad], in (-pi, pi]; 0 at the base and sites.

    Raises:
        BVHError: ``skel`` does not fit the file, or a translation below the base changes.
    """
    base = base_joint(bvh)
    if skel.node_names[0] != bvh.joints[base].name:
        raise BVHError(f"the skeleton's base is {skel.node_names[0]!r}, this file's is {bvh.joints[base].name!r}",
                       path=bvh.path, fix=_MIXED)  # fmt: skip
    nodes, cols, q0 = _node_columns(bvh, skel)
    _check_bones(bvh, skel, base, folded_translations(bvh, base))
    pos, rot = fk(bvh.joints[: base + 1], bvh.values)
    T = bvh.to_world
    base_pos = bvh.scale * pos[:, base] @ T.T
    base_rot = T @ rot[:, base] @ skel.rest_rotations[0].T
    base_quat = matrix_to_quat(torch.from_numpy(np.ascontiguousarray(base_rot))).numpy()
    q = np.zeros((bvh.num_frames, skel.num_nodes))
    d = np.deg2rad(bvh.values[:, cols]) - q0
    q[:, nodes] = np.arctan2(np.sin(d), np.cos(d))
    return np.ascontiguousarray(base_pos), base_quat, q
