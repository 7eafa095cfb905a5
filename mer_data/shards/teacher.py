"""Teacher files: the optimiser's solution for every training sample of a shard.

A shard stores windows of a source robot and, per window, the samples (target robot x variant);
its teacher file stores, for each of those samples, the optimiser's solution on that window
(``mer shards solve``, :mod:`mer_models.training.teacher`): the target's joint angles and base pose in the
window's frame, the residual energy, and the solver configuration. Training reads ``x`` from here
(features by FK at load time, :func:`teacher_features`), so every target, augmented or not, is
taught by one consistent solver.

Layout (HDF5, one file per shard, ``<shard folder>/teacher/<shard file stem>.h5`` by default; a
subfolder, so the shard folder's ``*.h5`` glob never mistakes it for a shard):

* ``q`` (rows, S, T, J) float32 [rad]: source-joint angles of the target (padding: 0), as the
  optimiser returns them (mimic joints are applied at load).
* ``base_pos`` (rows, S, T, 3) float32 [m] and ``base_rotvec`` (rows, S, T, 3) float32: the base,
  window frame (world ← base rotation vector).
* ``energy`` (rows, S) float32: the final weighted energy of the sample.
* ``solved`` (rows, S) bool: which samples hold a solution (a partial file is resumed from it).
* root attributes: ``format`` (``mer-teacher``), ``format_version``, ``shard_build_id``,
  ``shard_file``, ``rows``, ``samples_per_row``, ``solver`` (JSON: energy weights, iterations,
  scaling, prior weight, ``scaling_version``, ``optimizer_version``) and, when complete, ``seconds`` and ``frames`` (solver throughput).

``S`` is the shard's ``samples_per_row`` (targets x variants) and ``J`` its largest target.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from mer_data.base.errors import ShardFormatError
from mer_data.base.limits import MAX_LENGTH_M
from mer_data.kinematics.fk import apply_mimic, fk_skeleton, skeleton_tensors
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.windows import window_features
from mer_data.skeleton import Skeleton

from .h5safe import attr, require_values
from .hdf5_io import ProcessLocalH5
from .schema import ShardMeta

__all__ = ["TEACHER_FORMAT", "TEACHER_VERSION", "TEACHER_DIR", "teacher_path", "teacher_schema", "TeacherFile", "teacher_features"]

TEACHER_FORMAT = "mer-teacher"
TEACHER_VERSION = 1
TEACHER_DIR = "teacher"


def teacher_path(shard: str | Path, folder: str | Path | None = None) -> Path:
    """Where the teacher file of ``shard`` lives: ``folder`` (default ``<shard's folder>/teacher``)."""
    shard = Path(shard)
    return Path(folder if folder is not None else shard.parent / TEACHER_DIR) / f"{shard.stem}.h5"


def teacher_schema(meta: ShardMeta) -> dict[str, tuple[str, tuple[int, ...]]]:
    """name -> (dtype, shape) of the datasets of the teacher file of a shard with metadata ``meta``."""
    R, S, T, J = meta.num_rows, meta.samples_per_row, meta.window, meta.max_target_nodes
    return {"q": ("<f4", (R, S, T, J)), "base_pos": ("<f4", (R, S, T, 3)), "base_rotvec": ("<f4", (R, S, T, 3)),
            "energy": ("<f4", (R, S)), "solved": ("|b1", (R, S))}  # fmt: skip


class TeacherFile(ProcessLocalH5):
    """Read access to a complete teacher file, checked against its shard's metadata (one handle per process).

    Opened and read through :mod:`.h5safe`; every solution handed on is finite."""

    what = "teacher file"

    def __init__(self, path: str | Path, meta: ShardMeta) -> None:
        self.path = Path(path)
        fix = "solve again: mer shards solve SHARDS --force"
        f = self._f()
        try:
            if attr(f, "format", path=self.path, default=None) != TEACHER_FORMAT:
                raise ShardFormatError("not a mer teacher file", path=self.path, fix=fix)
            version = attr(f, "format_version", path=self.path, default=-1)
            if version != TEACHER_VERSION:
                raise ShardFormatError(f"teacher format version {version!r} is not {TEACHER_VERSION}",
                                       path=self.path, fix="solve again with this version of mer")  # fmt: skip
            build = attr(f, "shard_build_id", path=self.path, default=None)
            if build != meta.build_id:
                raise ShardFormatError(
                    "the teacher file was solved for another build of this shard "
                    f"(build {build}, the shard is {meta.build_id})",
                    path=self.path,
                    fix=fix,
                )
            self.schema = teacher_schema(meta)
            try:
                for name in self.schema:
                    self._ds(name)
            except ShardFormatError as exc:
                S = meta.samples_per_row
                raise ShardFormatError(f"{exc.message}: the teacher file does not fit the shard ({meta.num_rows} rows x "
                                       f"{S} samples x {meta.window} frames)", path=self.path, element=exc.element,
                                       fix=fix) from None  # fmt: skip
            self.solved = self._read("solved")
            self.energy = self._read("energy")
            require_values(self.energy[self.solved], "energy", path=self.path)
            try:
                self.solver = json.loads(attr(f, "solver", path=self.path))
            except (ValueError, TypeError, RecursionError) as exc:
                raise ShardFormatError(f"attribute 'solver' is not JSON ({type(exc).__name__})", path=self.path, fix=fix) from None
        except BaseException:
            self.close()
            raise

    def solution(self, row: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(q (T, J), base_pos (T, 3), base_rotvec (T, 3)) of sample ``k`` of ``row``; None if unsolved."""
        if not self.solved[row, k]:
            return None
        out = tuple(self._read(name, (row, k)) for name in ("q", "base_pos", "base_rotvec"))
        for name, a in zip(("q", "base_pos", "base_rotvec"), out):
            require_values(a, name, path=self.path, row=row, low=-MAX_LENGTH_M, high=MAX_LENGTH_M)
        return out  # type: ignore[return-value]


def teacher_features(skel: Skeleton, q: np.ndarray, base_pos: np.ndarray, base_rotvec: np.ndarray, fps: float) -> np.ndarray:
    """A stored solution → (T, J, 9) float32 features on ``skel`` (mimic joints applied, by FK).

    ``q`` may be padded beyond the skeleton's nodes; ``skel`` is the sample's (possibly link-scaled)
    target skeleton.
    """
    J = skel.num_nodes
    st = skeleton_tensors(skel, torch.float64)
    qt = torch.from_numpy(np.asarray(q[:, :J], np.float64))
    rv = torch.from_numpy(np.asarray(base_rotvec, np.float64))
    pos, _ = fk_skeleton(st, qt, torch.from_numpy(np.asarray(base_pos, np.float64)), base_rot=axis_angle_to_matrix(rv))
    revolute = (st.axes.abs().sum(-1) > 0).to(qt.dtype)
    q_eff = apply_mimic(qt, st.mimic_source, st.mimic_multiplier, st.mimic_offset) * revolute
    q_eff[..., 0] = 0
    return window_features(pos.float().numpy(), q_eff.float().numpy(), rv.float().numpy(), fps)
