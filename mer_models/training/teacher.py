"""``mer shards solve``: the optimiser's solution for every training sample of a set of shards.

For each shard file, every sample (window x target robot x augmentation variant) is retargeted by
the optimiser (:func:`mer_models.retarget.inference.optimize_batch`: the same solver and goals as ``mer
evaluate --methods optimize``) and stored in the shard's teacher file
(:mod:`mer_data.shards.teacher`). Training then reads ``x`` from there.

* **Batched**: samples of one target robot are solved together (same topology, no padding), up
  to ``batch`` windows at a time.
* **Resumable**: results go to ``<teacher>.partial`` and are flushed after every batch; a killed
  run resumes from the samples already solved; the complete file is renamed into place at the
  end, so a teacher file under its final name is always complete.
* **Sharded**: ``shard_index``/``num_shards`` take every N-th shard file, so N jobs cover a set once.
* **Consistent**: the solver configuration is stored; a complete file with another configuration
  (or for another build of the shard) is refused unless ``force``.
* **Contained**: a ``teacher/`` folder that is a symbolic link, and a teacher or ``.partial`` name that
  is one (or not a regular file), are refused before anything is solved; the file's room is claimed
  before HDF5 writes into it, so a full disk is one ``DiskFullError`` line (HDF5 would crash).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import h5py
import numpy as np

from mer_data.base.atomic import disk_full_as_error, real_folder, release_reserve, reserve_space
from mer_data.base.errors import MerError, OutputPathError, ShardFormatError
from mer_data.base.locks import hold_locks
from mer_data.kinematics.rotations import matrix_to_axis_angle
from mer_data.kinematics.scaling import SCALING_VERSION
from mer_data.motion.samples import collate
from mer_data.shards.dataset import ShardDataset
from mer_data.shards.h5safe import attr
from mer_data.shards.teacher import TEACHER_FORMAT, TEACHER_VERSION, TeacherFile, teacher_path, teacher_schema
from mer_models.config import EnergyConfig
from mer_models.retarget.clip import MODEL_FPS, geometry_of
from mer_models.retarget.inference import optimize_batch
from mer_models.solver.ik import DEFAULT_SMOOTH
from mer_models.solver.optimize import DEFAULT_GN_ITERS, FINE_OF_VERSION, OPTIMIZER_VERSION
from mer_models.solver.physics import PhysicsConfig

log = logging.getLogger(__name__)

__all__ = ["SolverConfig", "solve_shards"]


@dataclass(frozen=True)
class SolverConfig:
    """The teacher: the optimiser's settings (defaults: ``mer evaluate --methods optimize``).

    Attributes:
        energy: the energy weights.
        gn_iters: most Levenberg-Marquardt iterations.
        scaling: reference scaling (``segments`` or ``parts``, :mod:`mer_data.kinematics.scaling`).
        smooth: weight of the optimiser's temporal prior (:data:`mer_models.solver.ik.DEFAULT_SMOOTH`).
        scaling_version: :data:`mer_data.kinematics.scaling.SCALING_VERSION` of the goals (a teacher of older
            goals is solved again).
        optimizer_version: the optimiser's schedule (:data:`mer_models.solver.optimize.OPTIMIZER_VERSION`;
            1 solves as the teachers written before version 2 did).
        physics: the optimiser's physical terms (:mod:`mer_models.solver.physics`, as ``mer retarget``
            by default), on the samples whose target is a registered robot as it is (augmented
            variants have no collision geometry of their own and are solved without); None: off.
        human_feet: samples whose reference is a human (BVH, SMPL family, joint positions) get the
            physics ``mer retarget`` gives a human source: the constraint method, which keeps a stance
            sole on the floor and unmoved while the human's foot is down
            (:func:`mer_models.retarget.clip.human_physics`); False: the same physics as a robot's.
        batch: windows solved together.
    """

    energy: EnergyConfig = EnergyConfig()
    gn_iters: int = DEFAULT_GN_ITERS
    scaling: str = "segments"
    smooth: float = DEFAULT_SMOOTH
    scaling_version: int = SCALING_VERSION
    optimizer_version: int = OPTIMIZER_VERSION
    physics: PhysicsConfig | None = PhysicsConfig()
    human_feet: bool = True
    batch: int = 64

    def __post_init__(self) -> None:
        if self.optimizer_version not in FINE_OF_VERSION:
            raise MerError(f"optimizer_version {self.optimizer_version} is not one of {sorted(FINE_OF_VERSION)}",
                           fix=f"leave it at the default ({OPTIMIZER_VERSION})")  # fmt: skip

    def to_json(self) -> str:
        d = dataclasses.asdict(self)
        d.pop("batch")  # does not change the result
        return json.dumps(d, sort_keys=True)


def _plain_file(path: Path) -> bool:
    """Whether ``path`` exists as a plain file mer may write: a symbolic link, anything but a regular
    file, or a file with other hard links is refused (writing it would write somewhere else)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        kind = "a symbolic link" if stat.S_ISLNK(st.st_mode) else "not a regular file" if not stat.S_ISREG(st.st_mode) \
            else f"a file with {st.st_nlink} hard links"  # fmt: skip
        raise MerError(f"is {kind}; mer never writes through it (that would write outside the teacher folder)",
                       path=path, fix="delete it (it is not a file mer wrote) and run again")  # fmt: skip
    return True


def _teacher_bytes(meta, J: int) -> int:
    """An upper bound of a complete teacher file's size: its arrays uncompressed, an index entry per
    chunk and 1 MiB of metadata."""
    R, S, T = meta.num_rows, meta.samples_per_row, meta.window
    return R * S * T * (J + 6) * 4 + R * S * 5 + R * 3 * 64 + (1 << 20)


def _same_file(f: h5py.File, path: Path) -> None:
    """The open file is the one checked at ``path`` (not swapped for a link meanwhile)."""
    st, fst = os.lstat(path), os.fstat(f.id.get_vfd_handle())
    if (st.st_dev, st.st_ino) != (fst.st_dev, fst.st_ino):
        f.close()
        raise MerError("was replaced while being opened", path=path, fix="make sure no other program writes there")


def _create(path: Path, meta, S: int, J: int, solver: SolverConfig) -> h5py.File:
    if _plain_file(path):
        path.unlink()
    try:
        f = h5py.File(path, "x")  # exclusive: fails on anything (a link included) planted under the name meanwhile
    except (FileExistsError, OSError) as exc:
        raise MerError(f"cannot create the teacher file ({exc})", path=path, fix="check the folder and free space") from None
    R, T = meta.num_rows, meta.window
    chunk = (1, S, T)
    f.create_dataset("q", (R, S, T, J), np.float32, chunks=chunk + (J,), fillvalue=0)
    f.create_dataset("base_pos", (R, S, T, 3), np.float32, chunks=chunk + (3,), fillvalue=0)
    f.create_dataset("base_rotvec", (R, S, T, 3), np.float32, chunks=chunk + (3,), fillvalue=0)
    f.create_dataset("energy", (R, S), np.float32, fillvalue=np.nan)
    f.create_dataset("solved", (R, S), bool, fillvalue=False)
    f.attrs.update({
        "format": TEACHER_FORMAT, "format_version": TEACHER_VERSION, "shard_build_id": meta.build_id,
        "rows": R, "samples_per_row": S, "solver": solver.to_json(), "seconds": 0.0, "frames": 0,
    })  # fmt: skip
    return f


def _open_partial(path: Path, meta, S: int, J: int, solver: SolverConfig) -> h5py.File:
    """The partial file to continue, or a new one (a partial of another configuration, or one a
    kill left unreadable, is started over)."""
    if _plain_file(path):
        try:
            f = h5py.File(path, "r+")
            _same_file(f, path)
            a = f.attrs
            shapes = {n: tuple(f[n].shape) if n in f and isinstance(f.get(n, getlink=True), h5py.HardLink) else None
                      for n in ("q", "base_pos", "base_rotvec", "energy", "solved")}  # fmt: skip
            want = {n: shape for n, (_, shape) in teacher_schema(meta).items()}
            if (a.get("shard_build_id"), a.get("solver"), shapes) == (meta.build_id, solver.to_json(), want):
                log.info("resuming %s (%d of %d samples solved)", path.name, int(f["solved"][()].sum()), meta.num_rows * S)
                return f
            f.close()
            log.info("starting %s over: it was begun with another configuration or shard build", path.name)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            log.warning("starting %s over: it cannot be read (%s)", path.name, exc)
    return _create(path, meta, S, J, solver)


def _check_complete(path: Path, meta, solver: SolverConfig, force: bool) -> bool:
    """True when ``path`` already holds this solve; an incompatible file is refused unless ``force``."""
    if not os.path.lexists(path):
        return False
    try:
        tf = TeacherFile(path, meta)
        same = tf.solver == json.loads(solver.to_json()) and bool(tf.solved.all())
        tf.close()
    except ShardFormatError as exc:
        log.info("%s cannot be used (%s)", path, exc.message)
        same = False
    if same:
        return True
    if not force:
        raise MerError(
            "a teacher file of another shard build or solver configuration exists",
            path=path,
            fix="pass --force to solve again (it is replaced when the new one is complete), or --out elsewhere",
        )
    return False


def solve_shards(
    paths: str | Path | Sequence[str | Path],
    *,
    solver: SolverConfig = SolverConfig(),
    out: str | Path | None = None,
    shard_index: int | None = None,
    num_shards: int = 1,
    force: bool = False,
    device: str = "cpu",
    progress: Callable[[int, int, str], None] | None = None,
) -> list[dict]:
    """Solve every sample of the shards at ``paths``; returns one record per shard file.

    Args:
        out: folder of the teacher files (default: ``teacher/`` beside each shard).
        shard_index, num_shards: solve only shard files ``i`` with ``i % num_shards == shard_index``.
        progress: ``progress(samples_done, samples_total, message)`` after every batch.

    Each record: ``shard``, ``teacher`` (path), ``samples``, ``frames``, ``seconds``,
    ``frames_per_s``, ``energy_mean``, ``status`` (``solved``, ``up to date``).
    """
    if num_shards < 1 or (shard_index is not None and not 0 <= shard_index < num_shards):
        raise MerError(f"--shard-index {shard_index} is not in 0..{num_shards - 1}", fix="use 0 <= I < N")
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if out is None and any(str(p).startswith("hf://") for p in items):
        raise MerError("shards read from the Hub live in the read-only Hub cache: the teacher files need a folder of their own",
                       fix="pass --out DIR (and ShardDataset(..., teacher=DIR) when training)")  # fmt: skip
    ds = ShardDataset(paths, teacher=None)
    files = [i for i in range(len(ds.files)) if shard_index is None or i % num_shards == shard_index]
    records = []
    total = sum(ds.files[i].meta.num_rows * ds.files[i].meta.samples_per_row for i in files)
    done_all = 0
    for fi in files:
        shard, meta = ds.paths[fi], ds.files[fi].meta
        final = teacher_path(shard, out)
        if out is None:  # the folder mer chooses beside the shards: a real one, never a link elsewhere
            real_folder(final.parent, shard.parent)
        for name in (final, final.with_name(final.name + ".partial")):
            if os.path.islink(name) or (os.path.lexists(name) and not os.path.isfile(name)):
                raise OutputPathError("is a symbolic link or not a regular file; mer never writes through it (that would "
                                      "write outside the teacher folder)", path=name,
                                      fix="delete it (it is not a file mer wrote) and run again")  # fmt: skip
        S = meta.samples_per_row
        n = meta.num_rows * S
        if _check_complete(final, meta, solver, force):
            tf = TeacherFile(final, meta)
            try:
                frames, seconds = attr(tf._f(), "frames", default=0), attr(tf._f(), "seconds", default=0.0)
                if not (isinstance(frames, (int, float)) and isinstance(seconds, (int, float))):
                    raise ShardFormatError("attributes 'frames' and 'seconds' are not numbers", path=final)
                rec = {"shard": str(shard), "teacher": str(final), "samples": n, "frames": int(frames),
                       "seconds": float(seconds), "energy_mean": float(np.mean(tf.energy)), "status": "up to date"}  # fmt: skip
            finally:
                tf.close()
            rec["frames_per_s"] = rec["frames"] / max(rec["seconds"], 1e-9)
            records.append(rec)
            done_all += n
            if progress:
                progress(done_all, total, f"{shard.name} up to date")
            continue
        final.parent.mkdir(parents=True, exist_ok=True)  # --out: the user's folder, taken as it is
        with hold_locks(final.parent, [final.name], MerError):
            records.append(_solve_file(ds, fi, final, solver, device, progress, done_all, total))
        done_all += n
    ds.close()
    return records


def _solve_samples(samples: list, solver: SolverConfig, device: str) -> tuple[np.ndarray, ...]:
    """The optimiser on samples of one target robot: angles (N, T, J), base positions (N, T, 3),
    base rotation vectors (N, T, 3) and energies (N,). With ``solver.physics``, the samples are
    grouped by reference skeleton and by whether the target has its robot's collision geometry
    (the physical terms need both), and by whether the reference is a human (``solver.human_feet``)."""
    from mer_data.shards.humans import human_kind_of
    from mer_models.retarget.clip import human_physics

    groups: dict[tuple, list[int]] = {}
    geoms: dict[str, object] = {}
    for i, smp in enumerate(samples):
        geo = None
        if solver.physics is not None:
            fp = smp.target_skeleton.fingerprint
            if fp not in geoms:
                geoms[fp] = geometry_of(smp.target_skeleton)
            geo = geoms[fp]
        human = solver.human_feet and human_kind_of(str(smp.provenance.get("robot", ""))) is not None
        groups.setdefault((smp.reference_skeleton.fingerprint, id(geo) if geo is not None else None, human), []).append(i)
    out: list = [None] * 4
    for (_, _, human), idx in groups.items():
        group = [samples[i] for i in idx]
        geo = geoms.get(group[0].target_skeleton.fingerprint) if solver.physics is not None else None
        physics = human_physics(solver.physics) if human and solver.physics is not None else solver.physics
        kw = {"physics": physics, "geometry": geo, "ref_skeleton": group[0].reference_skeleton, "fps": MODEL_FPS,
              "target_skeleton": group[0].target_skeleton} if geo is not None else {}  # fmt: skip
        motion = optimize_batch(solver.energy, collate(group, scaling=solver.scaling), gn_iters=solver.gn_iters,
                                smooth=solver.smooth, fine=FINE_OF_VERSION[solver.optimizer_version], device=device, **kw)  # fmt: skip
        vals = (motion["q"].float().cpu().numpy(), motion["base_pos"].float().cpu().numpy(),
                matrix_to_axis_angle(motion["base_rot"].float()).cpu().numpy(), motion["energy"].float().cpu().numpy())  # fmt: skip
        for k, v in enumerate(vals):  # one target robot: every group has its node count
            if out[k] is None:
                out[k] = np.zeros((len(samples), *v.shape[1:]), v.dtype)
            out[k][idx] = v
    return tuple(out)


def _solve_file(ds: ShardDataset, fi: int, final: Path, solver: SolverConfig, device: str, progress, done_before: int, total: int) -> dict:
    meta = ds.files[fi].meta
    S, T = meta.samples_per_row, meta.window
    J = meta.max_target_nodes
    partial = final.with_name(final.name + ".partial")
    need = _teacher_bytes(meta, J)
    with disk_full_as_error(final, need):
        f = _open_partial(partial, meta, S, J, solver)
        try:  # HDF5 cannot survive ENOSPC: claim the file's whole room before solving into it
            reserve_space(f.id.get_vfd_handle(), need - os.path.getsize(partial), final)
        except BaseException:
            f.close()
            raise
    try:
        solved = f["solved"][()]
        slots = ds.slot_targets(fi)  # (rows, S): target index of each slot
        seconds, frames = float(f.attrs["seconds"]), int(f.attrs["frames"])
        done = done_before + int(solved.sum())
        for t_idx, t_name in enumerate(meta.targets):
            todo = [(r, k) for r in range(meta.num_rows) for k in range(S) if int(slots[r, k]) == t_idx and not solved[r, k]]
            for a in range(0, len(todo), solver.batch):
                part = todo[a : a + solver.batch]
                samples = [ds.slot_sample(fi, r, k) for r, k in part]
                t0 = time.perf_counter()
                q, pos, rv, en = _solve_samples(samples, solver, device)
                dt = time.perf_counter() - t0
                if not (np.isfinite(q).all() and np.isfinite(pos).all() and np.isfinite(rv).all()):
                    raise MerError(f"the optimiser returned non-finite values for target {t_name}", path=ds.paths[fi],
                                   fix="check the shard with mer shards inspect; report it with the shard file")  # fmt: skip
                for i, (r, k) in enumerate(part):
                    jt = q.shape[-1]
                    f["q"][r, k, :, :jt] = q[i]
                    f["base_pos"][r, k] = pos[i]
                    f["base_rotvec"][r, k] = rv[i]
                    f["energy"][r, k] = en[i]
                    f["solved"][r, k] = True
                seconds += dt
                frames += len(part) * T
                f.attrs["seconds"], f.attrs["frames"] = seconds, frames
                f.flush()
                done += len(part)
                if progress:
                    progress(done, total, f"{ds.paths[fi].name} -> {t_name}, {frames / max(seconds, 1e-9):.0f} frames/s")
        energy = f["energy"][()]
        if not f["solved"][()].all():
            raise ShardFormatError("some samples were not solved", path=partial)
        f.attrs["shard_file"] = ds.paths[fi].name
    finally:
        f.close()
    if os.path.islink(final) or (os.path.lexists(final) and not os.path.isfile(final)):
        raise MerError("is not a regular file; mer does not replace it", path=final, fix="delete it and run again")
    fd = os.open(partial, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0))
    try:
        release_reserve(fd)  # the room claimed and not used
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(partial, final)  # replaces the name itself, never what a link there points to
    rec = {"shard": str(ds.paths[fi]), "teacher": str(final), "samples": meta.num_rows * S, "frames": frames,
           "seconds": round(seconds, 3), "frames_per_s": frames / max(seconds, 1e-9),
           "energy_mean": float(np.mean(energy)), "status": "solved"}  # fmt: skip
    log.info("%s: %d samples, %.0f frames/s", final.name, rec["samples"], rec["frames_per_s"])
    return rec
