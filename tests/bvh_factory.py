"""Human figures written as BVH, for tests: an independent writer (scipy's Euler angles) and an
independent forward kinematics (plain rotation matrices), in any convention (channel order, 3 or 6
channels, Y- or Z-up, units, frame rate). Used by the BVH reader's, the human skeleton's and the
BVH-source retargeting tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from mer_data.motion.bvh import UNITS

# ---- an independent writer: a figure defined in mer's frame (metres, z up, x forward) ------------


@dataclass
class Figure:
    """A hierarchy and motion in mer's frame: ``offsets`` (N, 3) [m], ``local`` (F, N, 3, 3) rotations
    of each joint relative to its parent, ``root_pos`` (F, 3) [m]; ``moving`` joint -> (F, 3)
    translations that replace its offset (written as position channels). End Sites have ``end[k]``."""

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    end: list[bool]
    local: np.ndarray
    root_pos: np.ndarray
    moving: dict[int, np.ndarray] = field(default_factory=dict)


# file axes from mer axes: Y-up files have x_f = y, y_f = z, z_f = x (forward +z, left +x, up +y)
FILE_FROM_MER = {"z": np.eye(3), "y": np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])}

LAFAN_NAMES = {
    "hips": "Hips", "spine": ["Spine", "Spine1", "Spine2"], "neck": "Neck", "head": "Head",
    "clavicle": "{S}Shoulder", "upperarm": "{S}Arm", "forearm": "{S}ForeArm", "hand": "{S}Hand",
    "thigh": "{S}UpLeg", "shin": "{S}Leg", "foot": "{S}Foot", "toe": "{S}Toe", "left": "Left", "right": "Right",
}  # fmt: skip


def human_definition(rng: np.random.Generator, frames: int, names: dict = LAFAN_NAMES, *, spine: int = 2,
                     toe: bool = True, angle: float = 25.0, yaw: float = 60.0) -> Figure:  # fmt: skip
    """A random human (T-pose rest, facing +x, ~1.7 m) with random motion: joints turned by up to
    ``angle`` degrees, the root by a yaw up to ``yaw`` degrees and a small tilt, walking along x.

    ``names``: the joint names (LAFAN_NAMES' keys; ``{S}`` is the side's word, ``{s}`` its first
    letter); optional ``root`` (a joint on the floor above
    the hips, whose translation then moves, as Bandai's), ``hipjoint`` (CMU's pelvis-to-hip bone),
    ``handend`` (a joint after the wrist, as SMPL's)."""
    out_n, out_p, out_o, out_e = [], [], [], []

    def add(name, parent, offset, end=False) -> int:
        out_n.append(name)
        out_p.append(parent)
        out_o.append(np.asarray(offset, float) * rng.uniform(0.85, 1.15))
        out_e.append(end)
        return len(out_n) - 1

    floor = add(names["root"], -1, [0, 0, 0]) if "root" in names else None
    hips = add(names["hips"], -1 if floor is None else floor, [0, 0, 0 if floor is None else 0.95])
    k = hips
    for i in range(spine):
        k = add(names["spine"][i], k, [0, 0, 0.12])
    chest = k
    k = add(names["head"], add(names["neck"], chest, [0, 0, 0.18]), [0, 0, 0.1])
    add(f"{names['head']}_End", k, [0, 0, 0.15], end=True)
    for side, s in (("left", 1.0), ("right", -1.0)):
        nm = {key: v.format(S=names[side], s=names[side][0]) for key, v in names.items() if isinstance(v, str)}
        k = add(nm["clavicle"], chest, [0, 0.04 * s, 0.14])
        k = add(nm["upperarm"], k, [0, 0.13 * s, 0])
        k = add(nm["forearm"], k, [0, 0.28 * s, 0])
        k = add(nm["hand"], k, [0, 0.25 * s, 0])
        if "handend" in names:
            k = add(nm["handend"], k, [0, 0.06 * s, 0])
        add("", k, [0, 0.08 * s, 0], end=True)
    for side, s in (("left", 1.0), ("right", -1.0)):
        nm = {key: v.format(S=names[side], s=names[side][0]) for key, v in names.items() if isinstance(v, str)}
        k = hips
        if "hipjoint" in names:
            k = add(nm["hipjoint"], k, [0, 0.05 * s, -0.01])
        k = add(nm["thigh"], k, [0, (0.04 if "hipjoint" in names else 0.09) * s, -0.02])
        k = add(nm["shin"], k, [0, 0, -0.42])
        k = add(nm["foot"], k, [0, 0, -0.42])
        if toe:
            k = add(nm["toe"], k, [0.13, 0, -0.06])
        add("", k, [0.05, 0, 0], end=True)
    N = len(out_n)
    rot = Rotation.from_rotvec(_random_rotvecs(rng, (frames, N), math.radians(angle))).as_matrix()
    rot[:, out_e] = np.eye(3)  # End Sites do not turn
    t = np.arange(frames) / 30.0
    yaws = np.radians(rng.uniform(-yaw, yaw)) + 0.3 * np.sin(t)
    tilt = Rotation.from_rotvec(_random_rotvecs(rng, (frames,), math.radians(8))).as_matrix()
    turn = Rotation.from_euler("z", yaws[:, None]).as_matrix()
    root = np.column_stack([1.2 * t + rng.uniform(-1, 1), 0.3 * t, 0.95 + 0.03 * np.sin(5 * t)])
    if floor is None:
        rot[:, hips] = turn @ tilt
        return Figure(out_n, out_p, np.array(out_o), out_e, rot, root)
    rot[:, floor], rot[:, hips] = turn, tilt  # the floor joint slides and turns, the hips bob and tilt on it
    offsets = np.array(out_o)
    bob = offsets[hips] + np.column_stack([0.02 * np.sin(3 * t), 0.01 * t, 0.03 * np.sin(5 * t)])
    root[:, 2] = 0.0
    return Figure(out_n, out_p, offsets, out_e, rot, root, {hips: bob})


def _random_rotvecs(rng: np.random.Generator, shape: tuple, max_angle: float) -> np.ndarray:
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=shape + (1,))


def canonical_fk(fig: Figure, *, rotations: bool = False):
    """(F, N, 3) positions [m] of the figure, from its matrices (no Euler angles anywhere), and with
    ``rotations`` the (F, N, 3, 3) world rotations of the joint frames."""
    F, N = fig.local.shape[:2]
    pos, rot = np.zeros((F, N, 3)), np.zeros((F, N, 3, 3))
    for k, p in enumerate(fig.parents):
        if p < 0:
            pos[:, k], rot[:, k] = fig.root_pos, fig.local[:, k]
        else:
            t = np.broadcast_to(fig.moving.get(k, fig.offsets[k]), (F, 3))
            pos[:, k] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], t)
            rot[:, k] = rot[:, p] @ fig.local[:, k]
    return (pos, rot) if rotations else pos


def write_bvh(fig: Figure, *, order: str = "ZXY", six: bool = False, up: str = "y", units: str = "cm",
              fps: float = 30.0, root_order: str | None = None, root_rotation_only: bool = False,
              fixed: frozenset[str] = frozenset()) -> str:  # fmt: skip
    """BVH text of ``fig``: rotation channels in ``order`` (intrinsic, as BVH), ``six``: 6 channels
    on every joint (rotations first, then positions repeating the offset), else 3 (6 on the root).
    ``root_rotation_only``: the root has 3 rotation channels, its OFFSET is ``root_pos[0]``;
    ``fixed``: joints written without channels (their rotations must be the identity)."""
    P, inv = FILE_FROM_MER[up], 1.0 / UNITS[units]
    F, N = fig.local.shape[:2]
    rot_ch = [f"{a}rotation" for a in order]
    pos_ch = ["Xposition", "Yposition", "Zposition"]
    kids = {k: [c for c, p in enumerate(fig.parents) if p == k] for k in range(N)}
    columns: list[np.ndarray] = []
    lines = ["HIERARCHY"]

    def joint(k: int, depth: int) -> None:
        ind = "  " * depth
        off = P @ fig.offsets[k] * inv
        if fig.end[k]:
            lines.extend([f"{ind}End Site", f"{ind}{{", f"{ind}  OFFSET {_fmt(off)}", f"{ind}}}"])
            return
        if k == 0 and root_rotation_only:
            off = P @ fig.root_pos[0] * inv
        lines.extend([f"{ind}{'ROOT' if k == 0 else 'JOINT'} {fig.names[k]}", f"{ind}{{", f"{ind}  OFFSET {_fmt(off)}"])
        order_k = root_order if (k == 0 and root_order) else order
        eul = Rotation.from_matrix(P @ fig.local[:, k] @ P.T).as_euler(order_k.upper(), degrees=True)
        if fig.names[k] in fixed:
            chans = []
        elif k == 0 and root_rotation_only:
            chans = [f"{a}rotation" for a in order_k]
            columns.extend(eul[:, i] for i in range(3))
        elif k == 0:
            chans = pos_ch + [f"{a}rotation" for a in order_k]
            columns.extend([(fig.root_pos @ P.T * inv)[:, i] for i in range(3)] + [eul[:, i] for i in range(3)])
        elif k in fig.moving:
            chans = rot_ch + pos_ch
            columns.extend([eul[:, i] for i in range(3)] + [(fig.moving[k] @ P.T * inv)[:, i] for i in range(3)])
        elif six:
            chans = rot_ch + pos_ch
            columns.extend([eul[:, i] for i in range(3)] + [np.full(F, off[i]) for i in range(3)])
        else:
            chans = rot_ch
            columns.extend(eul[:, i] for i in range(3))
        lines.append(f"{ind}  CHANNELS {len(chans)} {' '.join(chans)}")
        for c in kids[k]:
            joint(c, depth + 1)
        lines.append(f"{ind}}}")

    joint(0, 0)
    table = np.column_stack(columns)
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / fps:.7f}"]
    lines += [_fmt(row) for row in table]
    return "\n".join(lines) + "\n"


def _fmt(values) -> str:
    return " ".join(f"{v:.9f}" for v in values)


BANDAI_NAMES = {
    "root": "joint_Root", "hips": "Hips", "spine": ["Spine", "Chest", "Chest2"], "neck": "Neck", "head": "Head",
    "clavicle": "Shoulder_{s}", "upperarm": "UpperArm_{s}", "forearm": "LowerArm_{s}", "hand": "Hand_{s}",
    "thigh": "UpperLeg_{s}", "shin": "LowerLeg_{s}", "foot": "Foot_{s}", "toe": "Toes_{s}", "left": "L", "right": "R",
}  # fmt: skip


def smooth_motion(fig: Figure, rng: np.random.Generator, fps: float = 30.0, max_angle: float = 25.0) -> Figure:
    """``fig`` with its joints turning smoothly (each about a random axis, a sine of up to
    ``max_angle`` degrees at 0.5-1.5 Hz) instead of ``human_definition``'s independent frames."""
    F, N = fig.local.shape[:2]
    t = np.arange(F) / fps
    local = fig.local.copy()
    for k in range(N):
        if fig.end[k] or fig.parents[k] < 0:
            continue
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        amp = math.radians(rng.uniform(5, max_angle))
        ang = amp * np.sin(2 * math.pi * rng.uniform(0.5, 1.5) * t + rng.uniform(0, 2 * math.pi))
        local[:, k] = Rotation.from_rotvec(ang[:, None] * axis).as_matrix()
    return Figure(fig.names, fig.parents, fig.offsets, fig.end, local, fig.root_pos, fig.moving)


def fold_root(fig: Figure, names: dict[str, str]) -> Figure:
    """The same motion without the figure's floor joint (Bandai's ``joint_Root``): its child (the
    hips) becomes the ROOT, carrying its world pose; joints renamed by ``names`` (old -> new)."""
    pos, rot = canonical_fk(fig, rotations=True)
    hips = fig.parents.index(0)
    keep = [k for k in range(len(fig.names)) if k != 0]
    new = {k: i for i, k in enumerate(keep)}
    local = fig.local[:, keep].copy()
    local[:, new[hips]] = rot[:, hips]
    parents = [-1 if k == hips else new[fig.parents[k]] for k in keep]
    return Figure([names.get(fig.names[k], fig.names[k]) for k in keep], parents, fig.offsets[keep],
                  [fig.end[k] for k in keep], local, pos[:, hips], {})  # fmt: skip


def upsample(fig: Figure, factor: int) -> Figure:
    """``fig`` at ``factor`` times its frame rate: the root's path linear, every joint's rotation
    slerped; the original frames are every ``factor``-th."""
    from scipy.spatial.transform import Slerp

    F, N = fig.local.shape[:2]
    t = np.arange(F, dtype=float)
    tt = np.arange((F - 1) * factor + 1) / factor
    local = np.empty((len(tt), N, 3, 3))
    for k in range(N):
        local[:, k] = Slerp(t, Rotation.from_matrix(fig.local[:, k]))(tt).as_matrix()
        local[::factor, k] = fig.local[:, k]
    root = np.stack([np.interp(tt, t, fig.root_pos[:, i]) for i in range(3)], -1)
    moving = {k: np.stack([np.interp(tt, t, v[:, i]) for i in range(3)], -1) for k, v in fig.moving.items()}
    return Figure(fig.names, fig.parents, fig.offsets, fig.end, local, root, moving)
