"""SMPL-family body models (SMPL, SMPL+H, SMPL-X): where the user's files are, and their joints.

Body-model files are licensed by their authors and never shipped nor downloaded: the user points
mer at theirs. Where mer looks, first found wins:

1. ``--body-model PATH`` (``body_model=``): a model ``.npz`` itself, or a folder;
2. the environment variable ``MER_BODY_MODELS`` (a file or a folder);
3. the user config ``body_models: PATH`` in ``platformdirs.user_config_dir("mer")/config.yaml``.

In a folder (or its ``models/`` subfolder), a model of kind ``smplx`` and gender ``female`` is
``smplx/SMPLX_FEMALE.npz`` (the ``smplx`` package's layout), ``SMPLX_FEMALE.npz``, or
``smplx/female/model.npz`` (AMASS's and MANO's layout); the same for ``smplh`` and ``smpl``.
Files are read with ``allow_pickle=False`` (:mod:`mer_data.motion.arrays`); a ``.pkl`` is refused
with the npz to download instead.

Only the joints are needed (:meth:`BodyModel.joints`): ``J = J_regressor @ (v_template + shapedirs
betas)``. Pose blend shapes move vertices, never the joints, which the regressor reads from the
shaped template at rest.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mer_data.base.errors import MotionFormatError

from .arrays import read_arrays

log = logging.getLogger(__name__)

__all__ = ["BodyModel", "BODY_JOINTS", "KINDS", "JOINT_NAMES", "load_body_model", "find_body_model", "model_roots",
           "BODY_MODEL_ENV"]

BODY_MODEL_ENV = "MER_BODY_MODELS"
#: Joints a model of each kind has (the rows of its joint regressor).
KINDS = {"smpl": 24, "smplh": 52, "smplx": 55}
#: The body's joints, shared by the three kinds (the first 22 of each).
BODY_JOINTS = 22
#: Names of the body joints (SMPL's own), parents first.
JOINT_NAMES = ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
               "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
               "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
#: SMPL's parents of the body joints (the three kinds share them).
PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
#: SMPL-X's shapedirs hold 300 shape then 100 expression directions (v1.1), or 10 and 10 (v1.0).
_SMPLX_DIMS = ((400, 300), (0, 10))
_GENDERS = ("neutral", "male", "female")

_DOWNLOAD = {
    "smplx": "SMPLX_{G}.npz from https://smpl-x.is.tue.mpg.de (\"SMPL-X v1.1 NPZ+PKL\")",
    "smplh": "the AMASS \"Extended SMPL+H model\" ({g}/model.npz) from https://mano.is.tue.mpg.de",
    "smpl": "an npz of SMPL (SMPL_{G}.npz: the SMPL pickle's arrays saved once with numpy.savez in a trusted "
            "environment), or SMPL-X's SMPLX_{G}.npz for SMPL-X motions",
}


def pickle_fix(kind: str | None = None, gender: str = "neutral") -> str:
    """What to download instead of a pickled model."""
    kinds = [kind] if kind in _DOWNLOAD else list(_DOWNLOAD)
    g = gender if gender in _GENDERS else "neutral"
    return "use the npz model instead: " + "; ".join(_DOWNLOAD[k].format(G=g.upper(), g=g) for k in kinds)


@dataclass(frozen=True, eq=False)
class BodyModel:
    """The joint-related arrays of a body model file.

    Attributes:
        path: the file; kind: ``smpl``, ``smplh`` or ``smplx`` (from its joint count).
        v_template: (V, 3) rest vertices [m]; shapedirs: (V, 3, S) shape directions [m];
        J_regressor: (J, V); parents: (J,) parent joint, -1 for the pelvis.
    """

    path: Path
    kind: str
    v_template: np.ndarray
    shapedirs: np.ndarray
    J_regressor: np.ndarray
    parents: np.ndarray

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[-1])

    def joints(self, betas: np.ndarray | None = None) -> np.ndarray:
        """(J, 3) rest joint positions [m] of the body shaped by ``betas`` (S',) (extra betas beyond
        the model's are dropped with a warning where not zero)."""
        b = np.zeros(self.num_betas) if betas is None else np.asarray(betas, np.float64).reshape(-1)
        if len(b) > self.num_betas:
            if np.abs(b[self.num_betas:]).max() > 0:
                log.warning("%s: the motion has %d betas, the model %d: the rest are dropped", self.path, len(b),
                            self.num_betas)  # fmt: skip
            b = b[: self.num_betas]
        v = self.v_template + np.einsum("vcs,s->vc", self.shapedirs[..., : len(b)], b)
        return self.J_regressor @ v


def _array(data: dict, key: str, path: Path, ndim: int) -> np.ndarray:
    if key not in data:
        raise MotionFormatError(f"the body model has no {key!r} array (it has: {', '.join(sorted(data))})", path=path,
                                element=key, fix="give an SMPL, SMPL+H or SMPL-X model .npz as distributed")  # fmt: skip
    a = np.asarray(data[key])
    if a.ndim != ndim or not np.issubdtype(a.dtype, np.number):
        raise MotionFormatError(f"{key!r} has shape {a.shape} ({a.dtype}), expected {ndim} numeric dimensions",
                                path=path, element=key, fix="give an SMPL, SMPL+H or SMPL-X model .npz as distributed")  # fmt: skip
    a = a.astype(np.float64) if key != "kintree_table" else a.astype(np.int64)
    if key != "kintree_table" and not np.isfinite(a).all():
        raise MotionFormatError(f"{key!r} holds NaN or infinite values", path=path, element=key,
                                fix="download the model file again")  # fmt: skip
    return a


def load_body_model(path: str | Path) -> BodyModel:
    """Read the joint-related arrays of a body-model ``.npz`` (module docstring).

    Raises:
        MotionFormatError: a pickle (with the npz to download), missing arrays, shapes that do not
            agree, a joint count of no known kind, a kinematic tree that is not one.
    """
    path = Path(path)
    keys = {"v_template", "shapedirs", "J_regressor", "kintree_table"}
    data = read_arrays(path, pickle_fix=pickle_fix(), keys=keys)
    v = _array(data, "v_template", path, 2)
    sd = _array(data, "shapedirs", path, 3)
    jr = _array(data, "J_regressor", path, 2)
    kt = _array(data, "kintree_table", path, 2)
    V, J = v.shape[0], jr.shape[0]
    fix = "give an SMPL, SMPL+H or SMPL-X model .npz as distributed"
    if v.shape[1] != 3 or sd.shape[:2] != (V, 3) or jr.shape[1] != V or kt.shape != (2, J):
        raise MotionFormatError(f"array shapes disagree: v_template {v.shape}, shapedirs {sd.shape}, J_regressor "
                                f"{jr.shape}, kintree_table {kt.shape}", path=path, fix=fix)  # fmt: skip
    kind = next((k for k, n in KINDS.items() if n == J), None)
    if kind is None:
        raise MotionFormatError(f"the model has {J} joints; SMPL has 24, SMPL+H 52, SMPL-X 55", path=path,
                                element="J_regressor", fix=fix)  # fmt: skip
    parents = kt[0].copy()
    parents[0] = -1
    if any(not 0 <= parents[k] < k for k in range(1, J)) or tuple(parents[:BODY_JOINTS]) != PARENTS:
        raise MotionFormatError("kintree_table is not the SMPL family's kinematic tree", path=path,
                                element="kintree_table", fix=fix)  # fmt: skip
    if kind == "smplx":
        sd = sd[..., : next(n for at_least, n in _SMPLX_DIMS if sd.shape[-1] >= at_least)]
    return BodyModel(path, kind, v, sd, jr, parents)


def _config_root() -> str | None:
    import platformdirs

    from mer_data.base.safe_io import safe_yaml_load

    cfg = Path(platformdirs.user_config_dir("mer", appauthor=False)) / "config.yaml"
    try:
        data = safe_yaml_load(cfg.read_text(encoding="utf-8")) if cfg.is_file() else None
    except Exception:  # an unreadable user config is not this reader's failure: said and ignored
        log.warning("%s: cannot be read; body_models there is ignored", cfg)
        return None
    v = data.get("body_models") if isinstance(data, dict) else None
    return str(Path(v).expanduser()) if isinstance(v, str) and v else None


def model_roots(given: str | Path | None = None) -> list[tuple[Path, str]]:
    """(path, where it came from) of each place to look, in order (module docstring)."""
    out = []
    if given is not None:
        out.append((Path(given).expanduser(), "--body-model"))
    env = os.environ.get(BODY_MODEL_ENV)
    if env:
        out.append((Path(env).expanduser(), BODY_MODEL_ENV))
    cfg = _config_root()
    if cfg:
        out.append((Path(cfg), "body_models in the user config"))
    return out


def _candidates(root: Path, kind: str, gender: str) -> list[Path]:
    K, G = kind.upper(), gender.upper()
    out = []
    for base in (root, root / "models"):
        for name in (f"{kind}/{K}_{G}", f"{K}_{G}", f"{kind}/{gender}/model"):
            out += [base / f"{name}.npz", base / f"{name}.pkl"]
    return out


def find_body_model(kind: str, gender: str, given: str | Path | None = None) -> Path:
    """The model file of ``kind`` and ``gender`` (module docstring).

    Raises:
        MotionFormatError: nowhere to look, no such file (naming where mer looked and what the folder
            has), or only a pickle (naming the npz to download).
    """
    gender = gender if gender in _GENDERS else "neutral"
    roots = model_roots(given)
    if not roots:
        raise MotionFormatError(
            f"an {kind.upper()} motion needs the {kind.upper()} body model, which mer does not ship",
            fix=f"point mer at your model files: --body-model PATH (a model .npz or the smplx package's models folder), "
                f"or set {BODY_MODEL_ENV}=PATH; download {_DOWNLOAD[kind].format(G=gender.upper(), g=gender)}",
        )  # fmt: skip
    looked = []
    for root, where in roots:
        if root.is_file():
            return root
        if not root.is_dir():
            raise MotionFormatError(f"no such file or folder (from {where})", path=root,
                                    fix="give a body-model .npz or the folder holding smplx/, smplh/, smpl/")  # fmt: skip
        cands = _candidates(root, kind, gender)
        for c in cands:
            if c.is_file() and c.suffix == ".npz":
                return c
        pkl = next((c for c in cands if c.is_file()), None)
        if pkl is not None:
            raise MotionFormatError(f"only a pickled {kind.upper()} model was found; mer never unpickles", path=pkl,
                                    fix=pickle_fix(kind, gender))  # fmt: skip
        looked.append(root)
    have = sorted({p.relative_to(r).as_posix() for r in looked for p in list(r.glob("**/*.npz"))[:50]})
    raise MotionFormatError(
        f"no {kind.upper()} model of gender {gender!r} in {', '.join(map(str, looked))} (it has: {', '.join(have) or 'no .npz'})",
        fix=f"add {kind}/{kind.upper()}_{gender.upper()}.npz there (download {_DOWNLOAD[kind].format(G=gender.upper(), g=gender)}), "
            f"or give the file itself: --body-model FILE",
    )  # fmt: skip
