"""The humans of a shard build from human motion (``--robots bvh|smpl|joints``): which reference each
clip's windows have.

Shards store one skeleton per reference (``ShardMeta.skeletons``, one ``robot`` per shard file), so
the clips of a folder are grouped by their *body*: the hierarchy (joint names and parents) and every
bone's offset to 1 cm, as the source reader gives them (:func:`mer_data.motion.sources.read_human`:
a BVH's header, the SMPL-family model's joints for the motion's shape and gender, a joint-position
layout's bones). Each group is one reference: named the kind (``bvh``, ``smpl``, ``joints``) for the
group of the first clip by name, ``KIND-2``, ``KIND-3``... for the next ones in the order of their
first clip; its skeleton is that first clip's (zero pose its most neutral standing frame,
:func:`~mer_data.motion.sources.human_source_skeleton`). So a folder mixing hierarchies, performers
or genders is built per body, never refused, and every clip's windows are on its own body's bones
(bones within 1 cm of it: the clip's angles measured on its group's first clip's skeleton).

A clip that cannot be read joins the first group, where its worker reads it again and records why
(``--keep-going``) or stops the build naming the file.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from mer_data.base.errors import MerError
from mer_data.motion.sources import HUMAN_SOURCES, HumanOptions, human_source_skeleton, read_human
from mer_data.skeleton import Skeleton

log = logging.getLogger(__name__)

__all__ = ["human_kind_of", "human_groups", "BODY_TOLERANCE_M"]

#: Bones within this of each other [m] are one body.
BODY_TOLERANCE_M = 0.01


def human_kind_of(name: str) -> str | None:
    """The human kind of a reference name (``smpl``, ``smpl-2`` -> ``smpl``), None for a robot's."""
    head, _, tail = name.partition("-")
    return head if head in HUMAN_SOURCES and (not tail or tail.isdigit()) else None


def _body(clip: Any) -> tuple:
    """The hierarchy and bone offsets [cm, rounded] of a read human (:class:`~mer_data.motion.bvh.BvhMotion`)."""
    scale = float(clip.scale) / BODY_TOLERANCE_M
    return tuple((j.name, j.parent, tuple(np.round(np.asarray(j.offset, np.float64) * scale).astype(int).tolist()) if k else ())
                 for k, j in enumerate(clip.joints))  # fmt: skip


def human_groups(files: dict[str, Path], kind: str, opts: HumanOptions) -> tuple[dict[str, dict[str, Path]], dict[str, Skeleton]]:
    """Reference name -> clip -> file, and reference name -> skeleton, of the human ``files``
    (clip -> file, of one ``kind``) read with ``opts`` (module docstring)."""
    bodies: dict[tuple, str] = {}
    groups: dict[str, dict[str, Path]] = {}
    skeletons: dict[str, Skeleton] = {}
    unread: dict[str, Path] = {}
    for clip, path in sorted(files.items()):
        try:
            human = read_human(path, kind, opts)
        except MerError as exc:
            log.warning("%s: %s", path, exc)
            unread[clip] = path
            continue
        body = _body(human)
        if body not in bodies:
            name = kind if not bodies else f"{kind}-{len(bodies) + 1}"
            bodies[body] = name
            skeletons[name] = human_source_skeleton(human, opts.keypoints, name=name)
            groups[name] = {}
        groups[bodies[body]][clip] = path
    if not groups:
        first = next(iter(sorted(unread.items())), None)
        if first is None:
            raise MerError(f"no {kind} clips to build from", fix="point --input at a folder of human motion files")
        read_human(first[1], kind, opts)  # raises: the first clip's problem, naming the file
    groups[kind].update(unread)
    if len(groups) > 1:
        log.info("%d bodies among the %s clips: %s", len(groups), kind, ", ".join(f"{n} ({len(c)} clips)" for n, c in groups.items()))
    return {n: dict(sorted(c.items())) for n, c in groups.items()}, skeletons
