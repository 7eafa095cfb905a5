"""``ShardDataset``: training samples from shards of either format, for a torch ``DataLoader``.

Index space: every selected sample of every window of every file, file by file, window by window.
A sample is (window, target robot, variant); variant 0 is the target's URDF skeleton, variants
1.. are the stored augmentations (link scales + dropped correspondences). When the target robot
has a window of the same clip and start frame in the given shards (G1 and H1 share the LAFAN1
clips), variant-0 samples carry it as ``target``.

Teacher targets: where a shard has a teacher file (``mer shards solve``,
:mod:`mer_data.shards.teacher`), every sample carries the optimiser's solution as ``teacher``.

Use :func:`mer_data.motion.samples.collate` as the ``collate_fn``; workers are fine (each process opens
its own file handles).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np
import torch

from mer_data.base.errors import ShardFormatError
from mer_data.base.limits import LINK_SCALE_RANGE, MAX_LENGTH_M
from mer_data.motion.samples import TrainingSample
from mer_data.motion.windows import window_features
from mer_data.skeleton import KEYPOINTS, Skeleton

from .augment import augmented_joint_map
from .h5safe import require_values
from .hub import resolve_hub_paths
from .reader import PathsLike, ShardFile, find_shards, open_shard
from .teacher import TeacherFile, teacher_features, teacher_path

__all__ = ["ShardDataset", "WindowRef"]

_SMALL = ("robot", "clip", "start_frame", "source_sha256", "origin_xy", "sample_target", "sample_variant", "link_scales", "dropped")


def check_columns(cols: dict[str, np.ndarray], meta, path: Path) -> None:
    """Refuse per-row columns a reader would hand on wrong: sample slots not in the documented order
    (slot ``k`` is target ``k // variants``, variant ``k % variants``), non-finite origins, link
    scales outside :data:`~mer_data.base.limits.LINK_SCALE_RANGE`, negative start frames."""
    V, K = meta.variants, meta.samples_per_row
    k = np.arange(K)
    for name, want in (("sample_target", k // V), ("sample_variant", k % V)):
        a = np.asarray(cols[name])
        bad = np.argwhere(a != want[None, :])
        if len(bad):
            r, s = (int(i) for i in bad[0])
            raise ShardFormatError(f"{name} is {int(a[r, s])} at row {r}, slot {s}; the shard's layout needs {int(want[s])} "
                                   f"({len(meta.targets)} targets x {V} variants)", path=path, element=f"dataset {name!r}",
                                   fix="the file is damaged or hostile; rebuild it with mer")  # fmt: skip
    require_values(cols["origin_xy"], "origin_xy", path=path, low=-1e9, high=1e9)
    require_values(cols["link_scales"], "link_scales", path=path, low=LINK_SCALE_RANGE[0], high=LINK_SCALE_RANGE[1])
    require_values(cols["start_frame"], "start_frame", path=path, low=0, high=2**53)
    for name in ("robot", "clip", "source_sha256"):
        if any(len(str(v)) > 4096 for v in cols[name]):
            raise ShardFormatError(f"{name} holds a string longer than 4096 characters", path=path, element=f"dataset {name!r}")
    if len(cols["robot"]) and set(map(str, cols["robot"])) != {meta.robot}:
        raise ShardFormatError(f"rows of robots {sorted(set(map(str, cols['robot'])))}, the metadata says {meta.robot!r}",
                               path=path, element="dataset 'robot'")  # fmt: skip


@dataclass(frozen=True)
class WindowRef:
    """One stored window: its id in the dataset, provenance and location."""

    id: int
    robot: str
    clip: str
    start_frame: int
    split: str
    source_sha256: str
    file: int
    row: int


class ShardDataset(torch.utils.data.Dataset):
    """Samples of the shards at ``paths`` (a shard file, a folder of shards, ``hf://datasets/OWNER/NAME[@REV]``,
    or a list of these; a Hub dataset is read through the Hub cache, see :mod:`.hub`).

    Args:
        split: keep the samples of ``"train"`` or ``"eval"`` windows only (default: all).
        targets: keep samples whose target robot is one of these (default: all stored targets).
        augmented: keep augmented variants (False: only the URDF skeletons, as for evaluation).
        teacher: ``"auto"`` (default): read each shard's teacher file where one exists
            (``<shard folder>/teacher/<shard>.h5``); ``True``: require them; a folder: require them
            there; ``None``/``False``: ignore them.
    """

    def __init__(
        self,
        paths: PathsLike,
        *,
        split: str | None = None,
        targets: Iterable[str] | None = None,
        augmented: bool = True,
        teacher: bool | str | Path | None = "auto",
    ) -> None:
        self.paths = find_shards(resolve_hub_paths(paths))
        self.files: list[ShardFile] = [open_shard(p) for p in self.paths]
        self._check_compatible()
        self.teachers: list[TeacherFile | None] = [self._open_teacher(p, f, teacher) for p, f in zip(self.paths, self.files)]
        self._skel_json: dict[str, str] = {}
        for f in self.files:
            for name, text in f.meta.skeletons.items():
                if self._skel_json.setdefault(name, text) != text:
                    raise ShardFormatError(
                        f"the shards hold two different skeletons named {name!r}",
                        path=f.path,
                        fix="load shards built with the same robot descriptions together",
                    )
        self._skels: dict[str, Skeleton] = {}
        self._cols: list[dict[str, np.ndarray]] = [{c: f.column(c) for c in _SMALL} for f in self.files]
        for f, cols in zip(self.files, self._cols):
            check_columns(cols, f.meta, f.path)
        self.windows: list[WindowRef] = []
        self._first: list[int] = []
        self._index: dict[tuple[str, str, int], int] = {}
        for fi, (f, cols) in enumerate(zip(self.files, self._cols)):
            self._first.append(len(self.windows))
            for row in range(f.num_rows):
                w = WindowRef(
                    len(self.windows), str(cols["robot"][row]), str(cols["clip"][row]), int(cols["start_frame"][row]),
                    f.meta.split, str(cols["source_sha256"][row]), fi, row,
                )  # fmt: skip
                self.windows.append(w)
                self._index.setdefault((w.robot, w.clip, w.start_frame), w.id)
        want = None if targets is None else set(targets)
        self._split = split
        self._blocks: list[tuple[int, list[int]]] = []
        self._starts: list[int] = []
        total = 0
        for fi, f in enumerate(self.files):
            m = f.meta
            if split is not None and m.split != split:
                continue
            V = m.variants
            ks = [
                k
                for k in range(m.samples_per_row)
                if (want is None or m.targets[k // V] in want) and (augmented or k % V == 0)
            ]
            if not ks or f.num_rows == 0:
                continue
            self._blocks.append((fi, ks))
            self._starts.append(total)
            total += f.num_rows * len(ks)
        self._len = total

    @staticmethod
    def _open_teacher(path: Path, f: ShardFile, teacher: bool | str | Path | None) -> TeacherFile | None:
        if teacher is None or teacher is False:
            return None
        folder = None if teacher in (True, "auto") else Path(teacher)
        tp = teacher_path(path, folder)
        if not tp.is_file():
            if teacher == "auto":
                return None
            raise ShardFormatError(f"no teacher file for this shard (looked for {tp})", path=path,
                                   fix=f"run: mer shards solve {path.parent}")  # fmt: skip
        return TeacherFile(tp, f.meta)

    @property
    def has_teacher(self) -> bool:
        """True when every shard file has a teacher file."""
        return all(t is not None for t in self.teachers)

    # ---- metadata ---------------------------------------------------------------------------
    def _check_compatible(self) -> None:
        m0 = self.files[0].meta
        for f in self.files[1:]:
            if (f.meta.window, f.meta.fps) != (m0.window, m0.fps):
                raise ShardFormatError(
                    f"windows of {f.meta.window} frames at {f.meta.fps:g} Hz do not mix with "
                    f"{m0.window} frames at {m0.fps:g} Hz ({self.files[0].path})",
                    path=f.path,
                )

    @property
    def robots(self) -> list[str]:
        """Source (reference) robots with windows."""
        return sorted({f.meta.robot for f in self.files})

    @property
    def targets(self) -> list[str]:
        return sorted({t for f in self.files for t in f.meta.targets})

    @property
    def config(self) -> dict:
        """The resolved build configuration (of the first file; see :attr:`configs`)."""
        return self.files[0].meta.config

    @property
    def configs(self) -> dict[str, dict]:
        """build id -> resolved build configuration."""
        return {f.meta.build_id: f.meta.config for f in self.files}

    @property
    def window_length(self) -> int:
        return self.files[0].meta.window

    @property
    def fps(self) -> float:
        return self.files[0].meta.fps

    def skeleton(self, name: str) -> Skeleton:
        """The (URDF) skeleton stored in the shards under ``name``."""
        if name not in self._skels:
            try:
                self._skels[name] = Skeleton.from_json(self._skel_json[name])
            except KeyError:
                raise KeyError(f"no skeleton {name!r} in these shards ({', '.join(sorted(self._skel_json))})") from None
        return self._skels[name]

    def clips(self, robot: str | None = None, split: str | None = None) -> dict[tuple[str, str], list[WindowRef]]:
        """(robot, clip) -> its windows in start order, for evaluation loops over whole clips."""
        out: dict[tuple[str, str], list[WindowRef]] = {}
        for w in self.windows:
            if (robot is None or w.robot == robot) and (split is None or w.split == split):
                out.setdefault((w.robot, w.clip), []).append(w)
        for ws in out.values():
            ws.sort(key=lambda w: w.start_frame)
        return dict(sorted(out.items()))

    def find_window(self, robot: str, clip: str, start_frame: int) -> WindowRef | None:
        wid = self._index.get((robot, clip, int(start_frame)))
        return None if wid is None else self.windows[wid]

    # ---- data -------------------------------------------------------------------------------
    def window_features(self, window: WindowRef | int) -> np.ndarray:
        """(T, J, 9) float32 features of a stored window (see :func:`mer_data.motion.windows.window_features`)."""
        w = self.windows[window] if isinstance(window, int) else window
        f = self.files[w.file]
        a = [require_values(f.row(c, w.row), c, path=f.path, row=w.row, low=-MAX_LENGTH_M, high=MAX_LENGTH_M)
             for c in ("pos", "q", "base_rotvec")]  # fmt: skip
        return window_features(a[0], a[1], a[2], f.meta.fps)

    def sample(self, window: WindowRef | int, target: str, variant: int = 0) -> TrainingSample:
        """The sample of ``window`` for ``target`` (by name) and ``variant`` (0: URDF skeleton)."""
        w = self.windows[window] if isinstance(window, int) else window
        m = self.files[w.file].meta
        if target not in m.targets or not 0 <= variant < m.variants:
            raise KeyError(f"{self.paths[w.file].name} has no sample for target {target!r} variant {variant}")
        return self._sample(w, m.targets.index(target) * m.variants + variant)

    def slot_targets(self, file: int) -> np.ndarray:
        """(rows, S) index into ``files[file].meta.targets`` of every sample slot of that shard file."""
        return self._cols[file]["sample_target"]

    def slot_sample(self, file: int, row: int, slot: int) -> TrainingSample:
        """The sample in ``slot`` of ``row`` of shard file ``file`` (what a teacher file is indexed by)."""
        return self._sample(self.windows[self._first[file] + row], slot)

    def _sample(self, w: WindowRef, k: int) -> TrainingSample:
        f, cols = self.files[w.file], self._cols[w.file]
        m = f.meta
        ref = self.skeleton(w.robot)
        t_name = m.targets[int(cols["sample_target"][w.row, k])]
        variant = int(cols["sample_variant"][w.row, k])
        tgt = self.skeleton(t_name)
        if variant > 0:
            tgt = tgt.with_link_scales(cols["link_scales"][w.row, k, : tgt.num_nodes].astype(np.float64))
        dropped = cols["dropped"][w.row, k]
        target = None
        if variant == 0:
            tw = self.find_window(t_name, w.clip, w.start_frame)
            if tw is not None:
                target = self.window_features(tw)
        taught = None
        tf = self.teachers[w.file]
        if tf is not None:
            sol = tf.solution(w.row, k)
            if sol is not None:
                taught = teacher_features(tgt, *sol, m.fps)
        provenance = {
            "robot": w.robot, "clip": w.clip, "start_frame": w.start_frame, "source_sha256": w.source_sha256,
            "split": w.split, "target": t_name, "variant": variant, "augmented": variant > 0,
            "dropped": [KEYPOINTS[x] for x in np.flatnonzero(dropped)], "origin_xy": cols["origin_xy"][w.row].tolist(),
            "file": Path(self.paths[w.file]).name, "row": w.row, "window": w.id, "slot": k,
        }  # fmt: skip
        if taught is not None:
            provenance["teacher_energy"] = float(tf.energy[w.row, k])
        return TrainingSample(
            reference=self.window_features(w),
            reference_skeleton=ref,
            target_skeleton=tgt,
            joint_map=augmented_joint_map(tgt, ref, dropped),
            target=target,
            provenance=provenance,
            teacher=taught,
        )

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, i: int) -> TrainingSample:
        if not -self._len <= i < self._len:
            raise IndexError(f"sample {i} out of range ({self._len} samples)")
        i %= self._len
        b = bisect.bisect_right(self._starts, i) - 1
        fi, ks = self._blocks[b]
        j = i - self._starts[b]
        row, k = divmod(j, len(ks))
        return self._sample(self.windows[self._first[fi] + row], ks[k])

    def reference_groups(self) -> list[np.ndarray]:
        """The sample indices of each window (every target and augmentation of one reference
        motion), one int64 array per window with samples, in index order; the arrays partition
        ``range(len(self))``. Samples of one group share their reference features and skeleton."""
        out = []
        for (fi, ks), start in zip(self._blocks, self._starts):
            n = len(ks)
            out += [np.arange(start + row * n, start + (row + 1) * n, dtype=np.int64) for row in range(self.files[fi].num_rows)]
        return out

    def locate(self, i: int) -> tuple[WindowRef, int]:
        """(window, sample slot ``k``) of sample ``i``."""
        b = bisect.bisect_right(self._starts, i) - 1
        fi, ks = self._blocks[b]
        row, k = divmod(i - self._starts[b], len(ks))
        return self.windows[self._first[fi] + row], ks[k]

    def __repr__(self) -> str:
        """The files, windows and samples of this selection (``split``, ``targets``), not every window loaded
        (``windows`` also holds the other split's, for pairing and lookups)."""
        used = [fi for fi, _ in self._blocks]
        windows = sum(self.files[fi].num_rows for fi in used)
        split = f" {self._split}" if self._split is not None else ""
        return (f"ShardDataset({len(used)} of {len(self.files)} files, {windows}{split} windows, {self._len} samples, "
                f"robots={self.robots})")  # fmt: skip

    def close(self) -> None:
        for f in self.files:
            f.close()
        for t in self.teachers:
            if t is not None:
                t.close()
