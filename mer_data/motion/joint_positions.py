"""Joint-position arrays (text-to-motion outputs: HumanML3D, MDM, MoMask, T2M-GPT) as a human the
BVH route reads.

Read: ``.npy`` / ``.npz`` arrays (``allow_pickle=False``) of T x J x 3 positions [m] (or T x 3J),
J = 22 (HumanML3D / SMPL's 22 body joints) or 24 (SMPL's 24: the hands after the wrists), in
SMPL's joint order (:data:`~mer_data.motion.body_model.JOINT_NAMES`). An npz's array is its only
3-D one, or the one under ``joints`` / ``positions``. Defaults: 20 Hz (HumanML3D's rate; ``fps``
otherwise) and y up (HumanML3D's; ``up`` otherwise).

Positions carry no orientations, but the energy wants the pelvis's, the feet's and the hands'
(orientation goals), and the human skeleton is a tree of rotations. :func:`joint_rotations`
derives a rotation per joint and frame:

* **rest pose** = the first frame: each bone's offset is its vector there, every joint frame
  aligned with the world (the zero pose used afterwards is the clip's most neutral standing frame,
  as for any human: :func:`~mer_data.motion.human.standing_frame`);
* **joints with several children** (pelvis: hips and spine; spine3: neck and collars): the
  rotation that best carries their rest offsets onto the frame's (Kabsch); this is the pelvis's
  orientation;
* **joints with one child**: the parent's rotation, then the smallest rotation that turns the child
  bone (as the parent carries it) onto the frame's: no twist of its own (the foot's orientation
  is the shin's carried onto the ankle-to-toe line; a hand's, with 24 joints, the forearm's carried
  onto the wrist-to-hand line);
* **leaves** (toes, head, wrists with 22 joints): the parent's rotation (a wrist's orientation is
  its forearm's).

Forward kinematics of these rotations reproduces the positions exactly where bone lengths do not
change over the clip (HumanML3D's skeleton is fixed), and to the change in length otherwise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mer_data.base.errors import MotionFormatError

from .arrays import read_arrays
from .body_model import JOINT_NAMES, PARENTS
from .bvh import BvhMotion
from .rig import rig_motion
from .smpl import MAX_FPS, check_frames, detect_up, up_rotation

__all__ = ["read_joint_positions", "joint_rotations", "LAYOUTS", "DEFAULT_FPS"]

#: Joint count -> (names, parents).
LAYOUTS = {
    22: (JOINT_NAMES, PARENTS),
    24: ((*JOINT_NAMES, "left_hand", "right_hand"), (*PARENTS, 20, 21)),
}
#: HumanML3D's rate [Hz].
DEFAULT_FPS = 20.0
_MAX_M = 1e4
_PICKLE_FIX = ("save the T x J x 3 positions as a plain array, e.g. for MDM's results.npy: "
               "np.save('walk.npy', results['motion'][0].transpose(2, 0, 1))")


def _minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 3, 3) smallest rotations turning directions a (N, 3) onto b (N, 3)."""
    a = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-12)
    v = np.cross(a, b)
    c = (a * b).sum(-1)
    K = np.zeros(a.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    R = np.eye(3) + K + K @ K / np.maximum(1.0 + c, 1e-12)[..., None, None]
    opp = c < -1 + 1e-9  # opposite: a half turn about any axis normal to a
    if opp.any():
        n = np.cross(a[opp], np.eye(3)[np.argmin(np.abs(a[opp]), axis=-1)])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        R[opp] = 2 * n[:, :, None] * n[:, None, :] - np.eye(3)
    return R


def _kabsch(rest: np.ndarray, now: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations R minimising sum |R rest_i - now_i|^2: rest (C, 3), now (T, C, 3)."""
    H = np.einsum("ci,tcj->tij", rest, now)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros_like(H)
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2] = 1, 1, d
    return np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)


def joint_rotations(pos: np.ndarray, parents) -> tuple[np.ndarray, np.ndarray]:
    """Rotations of positions (module docstring).

    Args:
        pos: (T, J, 3) joint positions [m]; parents: (J,) parent index, -1 for joint 0.

    Returns:
        offsets (J, 3) [m] (the rest pose: frame 1), local rotations (T, J, 3, 3) (joint 0's global).
    """
    T, J = pos.shape[:2]
    offsets = np.zeros((J, 3))
    kids: list[list[int]] = [[] for _ in range(J)]
    for k in range(1, J):
        offsets[k] = pos[0, k] - pos[0, parents[k]]
        kids[parents[k]].append(k)
    G = np.zeros((T, J, 3, 3))
    for k in range(J):
        p = parents[k]
        Gp = np.broadcast_to(np.eye(3), (T, 3, 3)) if p < 0 else G[:, p]
        ch = kids[k]
        if len(ch) >= 2:
            G[:, k] = _kabsch(offsets[ch], pos[:, ch] - pos[:, k : k + 1])
        elif len(ch) == 1:
            pred = np.einsum("tij,j->ti", Gp, offsets[ch[0]])
            G[:, k] = _minimal_rotation(pred, pos[:, ch[0]] - pos[:, k]) @ Gp
        else:
            G[:, k] = Gp
    local = G.copy()
    for k in range(1, J):
        local[:, k] = np.swapaxes(G[:, parents[k]], -1, -2) @ G[:, k]
    return offsets, local


def _positions(data: dict, path: Path) -> tuple[np.ndarray, str]:
    keys = [k for k in ("joints", "positions", "motion", "arr_0") if k in data]
    cands = [k for k in data if np.asarray(data[k]).ndim in (2, 3)]
    key = keys[0] if keys else (cands[0] if len(cands) == 1 else None)
    if key is None:
        raise MotionFormatError(f"no joint-position array: expected one T x J x 3 array, or one named joints "
                                f"(it has: {', '.join(sorted(data)[:30])})", path=path,
                                fix="save the positions alone: np.save('motion.npy', joints)")  # fmt: skip
    a = np.asarray(data[key])
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise MotionFormatError(f"{key!r} is {a.dtype}, not numbers", path=path, element=key, fix=_PICKLE_FIX)
    a = a.astype(np.float64)
    if a.ndim == 2 and a.shape[1] in (66, 72):
        a = a.reshape(a.shape[0], -1, 3)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[1] not in LAYOUTS:
        raise MotionFormatError(f"{key!r} has shape {a.shape}; expected T x 22 x 3 (HumanML3D, SMPL's 22 body joints) "
                                f"or T x 24 x 3 (SMPL's 24)", path=path, element=key,
                                fix="give frames x joints x xyz positions in SMPL's joint order "
                                    "(MDM's (joints, xyz, frames) is transposed: .transpose(2, 0, 1))")  # fmt: skip
    check_frames(a.shape[0], path, key)
    if not np.isfinite(a).all():
        t = int(np.argwhere(~np.isfinite(a))[0][0])
        raise MotionFormatError(f"{key!r} holds NaN or infinite values (first at frame {t + 1})", path=path,
                                element=key, fix="drop or repair the broken frames")  # fmt: skip
    if np.abs(a).max(initial=0.0) > _MAX_M:
        raise MotionFormatError(f"{key!r} reaches {np.abs(a).max():.3g}: positions are metres", path=path, element=key,
                                fix="convert the positions to metres")  # fmt: skip
    return a, key


def read_joint_positions(path: str | Path, *, fps: float | None = None, up: str | None = None) -> BvhMotion:
    """A joint-position array file (module docstring) as a :class:`BvhMotion` (metres, z up).

    Raises:
        MotionFormatError: not an array file, a pickle, a shape of no known layout, NaN, absurd
            values or frame counts, a rate outside (0, 10 kHz].
    """
    path = Path(path)
    pos, key = _positions(read_arrays(path, pickle_fix=_PICKLE_FIX), path)
    rate = DEFAULT_FPS if fps is None else float(fps)
    if not 0 < rate <= MAX_FPS:
        raise MotionFormatError(f"frame rate {rate:g} Hz", path=path, fix=f"give --fps in (0, {MAX_FPS:g}] Hz")
    names, parents = LAYOUTS[pos.shape[1]]
    notes = [f"joint positions {pos.shape[1]} x 3 ({key!r}) at {rate:g} Hz ({'given' if fps is not None else 'HumanML3D default'})"]
    if up is None:
        up, note = detect_up(pos[:, 15] - pos[:, [7, 8, 10, 11]].mean(1))
        notes.append(note)
    bones = np.linalg.norm(pos[:, 1:] - pos[:, list(parents[1:])], axis=-1)
    if bones.min() < 1e-6:
        j = int(np.argmin(bones.min(0))) + 1
        raise MotionFormatError(f"joint {names[j]!r} sits on its parent {names[parents[j]]!r} (a bone of length 0)",
                                path=path, element=names[j], fix="give the joints in SMPL's order (docs/kinematics.md)")  # fmt: skip
    offsets, local = joint_rotations(pos, parents)
    return rig_motion(str(path), names, parents, offsets, local, pos[:, 0], rate, up_rotation(up), notes)
