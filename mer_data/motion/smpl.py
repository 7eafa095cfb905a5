"""SMPL-family motion files (SMPL, SMPL+H, SMPL-X parameters) as a human the BVH route reads.

Layouts read (``.npz``, ``allow_pickle=False``), the first whose keys are present:

* **AMASS**: ``poses`` (T, 156) SMPL+H or (T, 165) SMPL-X (also (T, 72) SMPL, (T, 66) body only):
  root axis-angle, then the 21 body joints', then hands (and SMPL-X's jaw and eyes, before the
  hands); ``trans`` (T, 3) [m]; ``betas``; ``gender``; ``mocap_framerate`` or ``mocap_frame_rate``
  [Hz]. Z up.
* **AMASS SMPL-X "N" / OMOMO**: ``root_orient`` (T, 3), ``pose_body`` (T, 63), ``trans``,
  ``betas``, ``gender``, ``mocap_frame_rate``; ``surface_model_type`` names the kind. Z up.
* **video estimators** (GVHMR, WHAM, PromptHMR...): ``global_orient`` (T, 3), ``body_pose`` (T, 69)
  SMPL or (T, 63) SMPL-X (also (T, 23 | 21, 3) or rotation matrices (T, J, 3, 3)), ``betas`` (10,)
  or (T, 10) (their median), ``transl`` (T, 3) (zeros if absent). No frame rate in the file:
  ``fps`` (default 30 Hz). Up axis detected (the head's side of the feet), a camera frame included.

The kind (``smpl``, ``smplh``, ``smplx``) is the layout's; the body model (its file found by
:func:`~mer_data.motion.body_model.find_body_model` for the kind and the file's ``gender``) must be
of that kind. The skeleton is the model's 22 body joints (pelvis to wrists: hands, jaw and eyes do
not move any key point) at their rest positions for the motion's ``betas``; each joint's local
rotation is its axis-angle, the pelvis's its global orientation, the pelvis's position ``trans +
J_pelvis`` (the model's own kinematics). :func:`~mer_data.motion.rig.rig_motion` then writes it as
the hierarchy the BVH route takes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mer_data.base.errors import MotionFormatError
from mer_data.base.limits import limit, too_big

from .arrays import read_arrays
from .body_model import BODY_JOINTS, JOINT_NAMES, PARENTS, BodyModel, find_body_model, load_body_model, pickle_fix
from .bvh import BvhMotion
from .rig import rig_motion

__all__ = ["read_smpl", "smpl_layout", "SmplParams", "up_rotation", "detect_up", "check_frames"]

_FPS_KEYS = ("mocap_framerate", "mocap_frame_rate", "fps", "frame_rate", "framerate")
_POSES_KIND = {72: "smpl", 156: "smplh", 165: "smplx", 66: None}
_KIND_NAMES = {"smpl": "SMPL", "smplh": "SMPL+H", "smplx": "SMPL-X"}
MAX_FPS = 10_000.0
MAX_TRANS_M = 1e4


class SmplParams:
    """What a motion file says: ``kind`` (None: any), ``gender``, ``fps`` (None: not said),
    ``betas`` (S,), ``root`` (T, 3, 3), ``body`` (T, 21, 3, 3), ``trans`` (T, 3) [m], ``up``
    (``"z"`` or None: detect), ``layout``."""

    def __init__(self, kind, gender, fps, betas, root, body, trans, up, layout):
        self.kind, self.gender, self.fps, self.betas = kind, gender, fps, betas
        self.root, self.body, self.trans, self.up, self.layout = root, body, trans, up, layout


def check_frames(T: int, path: Path, key: str) -> None:
    """Refuse no frames or more than ``MER_MAX_ARRAY_FRAMES``."""
    if T < 1:
        raise MotionFormatError(f"{key!r} has no frames", path=path, element=key, fix="give a motion of at least one frame")
    if T > limit("MER_MAX_ARRAY_FRAMES"):
        msg, how = too_big("MER_MAX_ARRAY_FRAMES", T)
        raise MotionFormatError(msg, path=path, element=key, fix=how)


def _numeric(data: dict, key: str, path: Path) -> np.ndarray:
    a = np.asarray(data[key])
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise MotionFormatError(f"{key!r} is {a.dtype}, not numbers", path=path, element=key,
                                fix="store the parameters as float arrays")  # fmt: skip
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        raise MotionFormatError(f"{key!r} holds NaN or infinite values (first at index {tuple(int(i) for i in bad)})",
                                path=path, element=key, fix="drop or repair the broken frames")  # fmt: skip
    return a


def _rotations(a: np.ndarray, T: int, J: int, key: str, path: Path) -> np.ndarray:
    """(T, J, 3, 3) from axis-angle (T, 3J) / (T, J, 3) or matrices (T, J, 3, 3)."""
    fix = f"{key} is T x {3 * J} axis-angle (or T x {J} x 3, or T x {J} x 3 x 3 rotation matrices)"
    if a.shape in ((T, 3 * J), (T, J, 3)):
        aa = a.reshape(T * J, 3)
        if np.abs(aa).max(initial=0.0) > 1e3:
            raise MotionFormatError(f"{key!r} has axis-angles over 1000 rad", path=path, element=key, fix=fix)
        return Rotation.from_rotvec(aa).as_matrix().reshape(T, J, 3, 3)
    if a.shape == (T, J, 3, 3) or (J == 1 and a.shape == (T, 3, 3)):
        m = a.reshape(T, J, 3, 3)
        err = np.abs(m @ np.swapaxes(m, -1, -2) - np.eye(3)).max(initial=0.0)
        if err > 1e-3 or (np.linalg.det(m) <= 0).any():
            raise MotionFormatError(f"{key!r} holds matrices that are not rotations (|R R^T - I| up to {err:.3g})",
                                    path=path, element=key, fix=fix)  # fmt: skip
        return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_matrix().reshape(T, J, 3, 3)
    raise MotionFormatError(f"{key!r} has shape {a.shape}", path=path, element=key, fix=fix)


def _gender(data: dict, path: Path) -> str:
    if "gender" not in data:
        return "neutral"
    g = np.asarray(data["gender"])
    if g.dtype.kind not in "US" or g.size != 1:
        raise MotionFormatError(f"'gender' is {g.dtype} of shape {g.shape}, expected one string", path=path,
                                element="gender", fix="store gender as a string: neutral, male or female")  # fmt: skip
    v = g.reshape(()).item()
    v = (v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)).strip().lower()
    if v not in ("neutral", "male", "female"):
        raise MotionFormatError(f"'gender' is {v[:40]!r}", path=path, element="gender",
                                fix="store gender as neutral, male or female")  # fmt: skip
    return v


def _fps(data: dict, path: Path) -> float | None:
    for k in _FPS_KEYS:
        if k in data:
            a = _numeric(data, k, path).reshape(-1)
            if a.size != 1 or not 0 < a[0] <= MAX_FPS:
                raise MotionFormatError(f"{k!r} is {a[:3].tolist()}, not a frame rate in (0, {MAX_FPS:g}] Hz", path=path,
                                        element=k, fix="store the capture's frame rate in Hz")  # fmt: skip
            return float(a[0])
    return None


def _kind_of(data: dict, path: Path) -> str | None:
    for k in ("surface_model_type", "model_type"):
        if k in data:
            v = np.asarray(data[k])
            s = str(v.reshape(-1)[0].decode() if v.dtype.kind == "S" else v.reshape(-1)[0]).lower().replace("+", "").replace("-", "")
            if s in _KIND_NAMES:
                return s
    return None


def smpl_layout(keys) -> str | None:
    """``amass``, ``amass_n``, ``video`` or None: which layout (module docstring) a file's keys are."""
    keys = set(keys)
    if "poses" in keys:
        return "amass"
    if {"root_orient", "pose_body"} <= keys:
        return "amass_n"
    if {"global_orient", "body_pose"} <= keys:
        return "video"
    return None


def _params(data: dict, path: Path) -> SmplParams:
    layout = smpl_layout(data)
    if layout is None:
        raise MotionFormatError(f"is not an SMPL-family motion: it has none of poses, root_orient + pose_body, "
                                f"global_orient + body_pose (it has: {', '.join(sorted(data)[:30])})", path=path,
                                fix="give an AMASS / SMPL-X / video-estimator parameter npz, or a joint-position "
                                    "array with --source joints")  # fmt: skip
    gender, fps, kind = _gender(data, path), _fps(data, path), _kind_of(data, path)
    if layout == "amass":
        poses = _numeric(data, "poses", path)
        if poses.ndim != 2 or poses.shape[1] not in _POSES_KIND:
            raise MotionFormatError(f"'poses' has shape {poses.shape}", path=path, element="poses",
                                    fix="poses is T x 156 (SMPL+H), T x 165 (SMPL-X), T x 72 (SMPL) or T x 66 axis-angle")  # fmt: skip
        T = poses.shape[0]
        check_frames(T, path, "poses")
        kind = kind or _POSES_KIND[poses.shape[1]]
        root, body = poses[:, :3], poses[:, 3:66]
        trans_key, up = "trans", "z"
    elif layout == "amass_n":
        root, body = _numeric(data, "root_orient", path), _numeric(data, "pose_body", path)
        T = root.shape[0] if root.ndim else 0
        check_frames(T, path, "root_orient")
        kind, trans_key, up = kind or "smplx", "trans", "z"
    else:
        root, body = _numeric(data, "global_orient", path), _numeric(data, "body_pose", path)
        T = root.shape[0] if root.ndim else 0
        check_frames(T, path, "global_orient")
        nb = body.shape[1] if body.ndim >= 2 else 0
        kind = kind or {69: "smpl", 23: "smpl", 63: None, 21: None}.get(nb)
        body = body.reshape(T, -1, 3)[:, :21] if body.ndim in (2, 3) and body.size in (T * 69, T * 63) else body
        body = body[:, :21] if body.ndim == 4 and body.shape[1] == 23 else body
        trans_key, up = "transl", None
    Rroot = _rotations(root, T, 1, "global_orient" if layout == "video" else ("root_orient" if layout == "amass_n" else "poses"), path)
    Rbody = _rotations(body, T, 21, {"amass": "poses", "amass_n": "pose_body", "video": "body_pose"}[layout], path)
    if trans_key in data:
        trans = _numeric(data, trans_key, path)
        if trans.shape != (T, 3):
            raise MotionFormatError(f"{trans_key!r} has shape {trans.shape}, expected ({T}, 3) like the poses", path=path,
                                    element=trans_key, fix=f"{trans_key} is one root translation [m] per frame")  # fmt: skip
        if np.abs(trans).max(initial=0.0) > MAX_TRANS_M:
            raise MotionFormatError(f"{trans_key!r} reaches {np.abs(trans).max():.3g} m", path=path, element=trans_key,
                                    fix="translations are in metres")  # fmt: skip
    elif layout == "video":
        trans = np.zeros((T, 3))
    else:
        raise MotionFormatError(f"no {trans_key!r} (the root translation)", path=path, element=trans_key,
                                fix=f"store {trans_key}: T x 3 [m]")  # fmt: skip
    betas = _numeric(data, "betas", path) if "betas" in data else np.zeros(10)
    if betas.ndim == 2 and betas.shape[0] == T:
        betas = np.median(betas, axis=0)
    if betas.ndim != 1 or betas.size > 400 or np.abs(betas).max(initial=0.0) > 100:
        raise MotionFormatError(f"'betas' has shape {betas.shape} (values up to {np.abs(betas).max(initial=0):.3g})",
                                path=path, element="betas", fix="betas is one shape vector (10 to 300 numbers, about -5..5)")  # fmt: skip
    return SmplParams(kind, gender, fps, betas, Rroot[:, 0], Rbody, trans, up, layout)


def up_rotation(up: str) -> np.ndarray:
    """(3, 3) proper rotation taking the file's ``up`` (``x|y|z|-x|-y|-z``) to +z."""
    rows = {"z": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "y": [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
            "x": [[0, 1, 0], [0, 0, 1], [1, 0, 0]], "-z": [[1, 0, 0], [0, -1, 0], [0, 0, -1]],
            "-y": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "-x": [[0, 1, 0], [0, 0, -1], [-1, 0, 0]]}  # fmt: skip
    return np.asarray(rows[up], np.float64)


def detect_up(head_minus_feet: np.ndarray) -> tuple[str, str]:
    """The file axis (``x|y|z|-x|-y|-z``) the head lies along from the feet: (F, 3) per frame."""
    d = np.asarray(head_minus_feet).mean(0)
    i = int(np.argmax(np.abs(d)))
    up = ("-" if d[i] < 0 else "") + "xyz"[i]
    return up, f"up axis {up}: the head lies along {up} from the feet"


def _world_joints(rest: np.ndarray, root: np.ndarray, body: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(T, 22, 3) body joint positions in the file's axes (the model's own kinematics)."""
    T = root.shape[0]
    G = np.zeros((T, BODY_JOINTS, 3, 3))
    P = np.zeros((T, BODY_JOINTS, 3))
    G[:, 0], P[:, 0] = root, trans + rest[0]
    for k in range(1, BODY_JOINTS):
        p = PARENTS[k]
        G[:, k] = G[:, p] @ body[:, k - 1]
        P[:, k] = P[:, p] + G[:, p] @ (rest[k] - rest[p])
    return P


def read_smpl(path: str | Path, *, body_model: str | Path | None = None, fps: float | None = None,
              up: str | None = None) -> BvhMotion:  # fmt: skip
    """An SMPL-family motion file (module docstring) as a :class:`BvhMotion` (metres, z up).

    Args:
        path: the motion ``.npz``; body_model: a model file or folder (else ``MER_BODY_MODELS``, the
            user config); fps: the rate [Hz] where the file says none (video estimators; default 30);
        up: the file's up axis (``y``, ``z``, ``-y``...; default: the layout's, else detected).

    Raises:
        MotionFormatError: the file's problem (naming the field), a body model that is missing, of
            another kind, pickled or broken.
    """
    path = Path(path)
    data = read_arrays(path, pickle_fix="mer reads .npz parameter files; save the arrays with numpy.savez (AMASS's "
                       "npz files are read as they are)")  # fmt: skip
    p = _params(data, path)
    model_path = find_body_model(p.kind or "smplx", p.gender, body_model)
    model = load_body_model(model_path)
    if p.kind is not None and model.kind != p.kind:
        raise MotionFormatError(
            f"the motion is {_KIND_NAMES[p.kind]} ({p.layout} layout) but the body model {model_path} is "
            f"{_KIND_NAMES[model.kind]} ({len(model.parents)} joints)", path=path,
            fix=f"give the {_KIND_NAMES[p.kind]} model: --body-model PATH/{p.kind}/{p.kind.upper()}_{p.gender.upper()}.npz",
        )  # fmt: skip
    rest = model.joints(p.betas)[:BODY_JOINTS]
    notes = [f"{_KIND_NAMES[model.kind]} body model {model_path} ({p.gender}), {p.layout} layout"]
    rate = p.fps if p.fps is not None else (fps if fps is not None else 30.0)
    if p.fps is None:
        notes.append(f"frame rate {rate:g} Hz ({'given' if fps is not None else 'the file says none: the default'})")
    up = up or p.up
    if up is None:
        P = _world_joints(rest, p.root[:: max(1, len(p.root) // 64)], p.body[:: max(1, len(p.root) // 64)],
                          p.trans[:: max(1, len(p.root) // 64)])  # fmt: skip
        up, note = detect_up(P[:, 15] - P[:, [7, 8, 10, 11]].mean(1))
        notes.append(note)
    offsets = rest - rest[list((0, *PARENTS[1:]))]
    rot = np.concatenate([p.root[:, None], p.body], axis=1)
    return rig_motion(str(path), JOINT_NAMES, PARENTS, offsets, rot, p.trans + rest[0], rate, up_rotation(up), notes)


def body_model_for(path: str | Path, body_model: str | Path | None = None) -> BodyModel:
    """The body model an SMPL motion file would be read with (for tools and tests)."""
    p = _params(read_arrays(Path(path), pickle_fix=pickle_fix()), Path(path))
    return load_body_model(find_body_model(p.kind or "smplx", p.gender, body_model))
