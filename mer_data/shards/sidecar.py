"""``mer_meta.json``: the shards' metadata as one JSON file, for readers that ignore HDF5 attributes.

A shard's file-level metadata (:class:`~.schema.ShardMeta`: the target names that
``sample_target`` indexes, the skeletons, the build configuration...) are HDF5 root attributes or
MCAP metadata records. ``datasets.load_dataset("hdf5", ...)`` reads the datasets (columns) only, so
a row's ``sample_target`` (an index) cannot be turned into a robot name, nor a name into a
skeleton, from what it returns. The side file carries exactly what is lost::

    {
      "format": "mer-shards-meta", "format_version": 1,
      "skeletons": {NAME: <Skeleton.to_json() as a JSON object>, ...},   # once per name
      "shards": {FILE NAME: <ShardMeta without its skeletons, + "skeleton_names">, ...}
    }

It is written next to the shards by ``mer shards build`` and ``mer shards push`` (and pushed with
them). :func:`read_sidecar` gives a :class:`Sidecar` that resolves a ``load_dataset`` row's samples
(:meth:`Sidecar.sample_info`).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping

from mer_data.base.atomic import atomic_write
from mer_data.base.errors import ShardFormatError
from mer_data.skeleton import Skeleton

from .reader import PathsLike, find_shards, open_shard
from .schema import ShardMeta

__all__ = ["META_FILE", "SIDECAR_FORMAT", "SIDECAR_VERSION", "Sidecar", "SampleInfo", "sidecar_dict", "write_sidecar", "read_sidecar"]

META_FILE = "mer_meta.json"
SIDECAR_FORMAT = "mer-shards-meta"
SIDECAR_VERSION = 1


def sidecar_dict(paths: PathsLike) -> dict[str, Any]:
    """The side file's content for the shards at ``paths`` (files or folders)."""
    skeletons: dict[str, Any] = {}
    shards: dict[str, Any] = {}
    for p in find_shards(paths):
        f = open_shard(p)
        try:
            meta = f.meta
        finally:
            f.close()
        for name, text in meta.skeletons.items():
            obj = json.loads(text)
            if skeletons.setdefault(name, obj) != obj:
                raise ShardFormatError(f"the shards hold two different skeletons named {name!r}", path=p,
                                       fix="write one side file per build (shards built with the same robot descriptions)")
        if p.name in shards:
            raise ShardFormatError(f"two shards are named {p.name}", path=p, fix="keep one build per folder")
        entry = asdict(meta)
        entry.pop("skeletons")
        entry["skeleton_names"] = sorted(meta.skeletons)
        shards[p.name] = entry
    return {"format": SIDECAR_FORMAT, "format_version": SIDECAR_VERSION, "skeletons": dict(sorted(skeletons.items())),
            "shards": shards}


def write_sidecar(folder: str | Path) -> Path:
    """Write ``folder/mer_meta.json`` for the shards in ``folder``, atomically; returns its path."""
    folder = Path(folder)
    return atomic_write(folder / META_FILE, json.dumps(sidecar_dict(folder), indent=1, sort_keys=True) + "\n")


@dataclass(frozen=True)
class SampleInfo:
    """What sample ``k`` of a stored window is: its target robot, variant and target skeleton."""

    target: str
    variant: int
    skeleton: Skeleton  # the target's URDF skeleton, with the row's link scales for variants > 0
    dropped: list[str]  # dropped key point correspondences (KEYPOINTS names)


class Sidecar:
    """A parsed ``mer_meta.json``: per-shard metadata and the skeletons."""

    def __init__(self, data: Mapping[str, Any], path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else None
        if not isinstance(data, Mapping) or data.get("format") != SIDECAR_FORMAT:
            raise ShardFormatError(f"not a mer shard side file (format {data.get('format') if isinstance(data, Mapping) else None!r})",
                                   path=path, fix=f"pass the {META_FILE} written by `mer shards build` or `mer shards push`")
        if data.get("format_version") != SIDECAR_VERSION:
            raise ShardFormatError(f"side file version {data.get('format_version')!r}; this mer reads {SIDECAR_VERSION}",
                                   path=path, fix="upgrade mer, or rewrite the file with `mer shards card DIR`")
        try:
            self.skeleton_json: dict[str, str] = {n: json.dumps(obj) for n, obj in data["skeletons"].items()}
            self.shards: dict[str, ShardMeta] = {}
            for name, entry in data["shards"].items():
                kw = {k: v for k, v in entry.items() if k != "skeleton_names"}
                kw["skeletons"] = {n: self.skeleton_json[n] for n in entry["skeleton_names"]}
                self.shards[name] = ShardMeta(**kw)
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise ShardFormatError(f"damaged side file ({type(exc).__name__}: {exc})", path=path,
                                   fix="rewrite it from the shards (`mer shards card DIR`) or download it again") from None
        self._skels: dict[str, Skeleton] = {}

    def skeleton(self, name: str) -> Skeleton:
        """The URDF skeleton stored under ``name``."""
        if name not in self._skels:
            if name not in self.skeleton_json:
                raise KeyError(f"no skeleton {name!r} in {self.path or META_FILE} ({', '.join(sorted(self.skeleton_json))})")
            self._skels[name] = Skeleton.from_json(self.skeleton_json[name])
        return self._skels[name]

    def meta(self, robot: str, split: str) -> ShardMeta:
        """The metadata of the shards of ``robot`` and ``split`` (a ``datasets`` config ``ROBOT_SPLIT``).

        Every shard of one robot and split of a build has the same targets and variants."""
        found = [m for m in self.shards.values() if m.robot == robot and m.split == split]
        if not found:
            have = sorted({f"{m.robot}/{m.split}" for m in self.shards.values()})
            raise KeyError(f"no shard of robot {robot!r}, split {split!r} in {self.path or META_FILE} (it has {', '.join(have)})")
        if any((m.targets, m.variants) != (found[0].targets, found[0].variants) for m in found[1:]):
            raise ShardFormatError(f"the {robot}/{split} shards disagree on their targets", path=self.path,
                                   fix="the folder mixes builds; keep one build per folder")
        return found[0]

    def sample_info(self, row: Mapping[str, Any], k: int, split: str) -> SampleInfo:
        """Sample ``k`` of a row as ``load_dataset("hdf5")`` returns it (``robot``, ``sample_target``,
        ``sample_variant``, ``link_scales``, ``dropped``), for a row of split ``split``."""
        import numpy as np

        from mer_data.skeleton import KEYPOINTS

        m = self.meta(str(row["robot"]), split)
        t = int(np.asarray(row["sample_target"])[k])
        if not 0 <= t < len(m.targets):
            raise ShardFormatError(f"sample_target {t} is out of range for the {len(m.targets)} targets of {m.robot}/{split}",
                                   path=self.path)
        name = m.targets[t]
        variant = int(np.asarray(row["sample_variant"])[k])
        skel = self.skeleton(name)
        if variant > 0:
            scales = np.asarray(row["link_scales"], dtype=np.float64)[k, : skel.num_nodes]
            skel = skel.with_link_scales(scales)
        dropped = [KEYPOINTS[i] for i in np.flatnonzero(np.asarray(row["dropped"])[k])]
        return SampleInfo(name, variant, skel, dropped)


def read_sidecar(path: str | Path) -> Sidecar:
    """Read ``mer_meta.json`` (a file, or a folder holding one): a regular file of at most
    ``MER_MAX_SIDECAR_BYTES``, JSON of bounded depth."""
    from mer_data.base.safe_io import decode_utf8, read_regular_file

    p = Path(path)
    if p.is_dir():
        p = p / META_FILE
    if not os.path.lexists(p):
        raise ShardFormatError(f"no {META_FILE} here", path=p, fix="write it with `mer shards card DIR` (or rebuild the shards)")
    raw = read_regular_file(p, ShardFormatError, "MER_MAX_SIDECAR_BYTES")
    try:
        data = json.loads(decode_utf8(raw, p, ShardFormatError))
    except (ValueError, RecursionError) as exc:
        raise ShardFormatError(f"cannot read the side file: {type(exc).__name__}: {str(exc)[:200]}", path=p) from None
    return Sidecar(data, p)
