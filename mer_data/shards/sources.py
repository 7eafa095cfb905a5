"""Where the motions come from: a local folder or a Hugging Face dataset (``hf://REPO_ID[@REV]``).

The layout is the one of ``lvhaidong/LAFAN1_Retargeting_Dataset``: one folder per robot, one file
per clip (``g1/dance1_subject1.csv``); ``.csv.gz`` files are read as well.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path
from typing import Sequence

from mer_data.base.errors import ShardBuildError
from mer_data.base.safe_io import check_regular_file
from mer_data.motion.lafan1 import motion_suffixes

log = logging.getLogger(__name__)

__all__ = ["HF_PREFIX", "LAFAN1_REPO", "resolve_input", "discover_clips", "clip_name", "sha256_bytes", "stable_words"]

HF_PREFIX = "hf://"
#: The public LAFAN1 robot dataset (Unitree's retargeting; folders g1/, h1/, h1_2/).
LAFAN1_REPO = "lvhaidong/LAFAN1_Retargeting_Dataset"


def clip_name(path: Path) -> str | None:
    """Clip name of a motion file (its name without ``.csv``/``.csv.gz``), None for other files."""
    for suffix in sorted(motion_suffixes(), key=len, reverse=True):
        if path.name.endswith(suffix) and len(path.name) > len(suffix):
            return path.name[: -len(suffix)]
    return None


def resolve_input(spec: str, robots: Sequence[str]) -> Path:
    """A local folder for ``spec``: the folder itself, or the snapshot of ``hf://REPO_ID[@REVISION]``.

    Only the robots' ``*.csv``/``*.csv.gz`` files are downloaded, each checked and capped at
    ``MER_MAX_MOTION_BYTES`` (:func:`mer_data.base.hub_files.checked_snapshot`). ``HF_HUB_OFFLINE=1``
    is honoured (the cached snapshot is used, and it is an error if there is none).
    """
    if not spec.startswith(HF_PREFIX):
        root = Path(spec).expanduser()
        if not root.is_dir():
            raise ShardBuildError(
                "the input folder does not exist" if not root.exists() else "the input is not a folder",
                path=root,
                fix=f"pass a folder holding one sub-folder per robot ({'/, '.join(robots)}/), or hf://{LAFAN1_REPO}",
            )
        return root
    repo, _, revision = spec[len(HF_PREFIX) :].partition("@")
    if repo.count("/") != 1 or not all(repo.split("/")):
        raise ShardBuildError(f"cannot read the Hub dataset id {repo!r}", fix=f"use hf://OWNER/NAME, e.g. hf://{LAFAN1_REPO}")
    from mer_data.base.hub_files import checked_snapshot

    patterns = [f"{r}/*{s}" for r in robots for s in motion_suffixes()]
    path = checked_snapshot(repo, revision or None, repo_type="dataset", patterns=patterns,
                            size_limit=lambda name: "MER_MAX_MOTION_BYTES", error=ShardBuildError,
                            offline_fix="connect to the network (and unset HF_HUB_OFFLINE) once to download it, or pass "
                            "a local folder")  # fmt: skip
    log.info("using %s from %s", spec, path)
    return Path(path)


def discover_clips(root: Path, robots: Sequence[str]) -> dict[str, dict[str, Path]]:
    """robot -> clip name -> file, for the given robots (sorted by clip name).

    A ``.csv``/``.csv.gz`` entry that is not a regular file (a directory, a FIFO, a dangling link,
    a link loop) is refused here, before anything is read, with the same message as everywhere.
    """
    out: dict[str, dict[str, Path]] = {}
    for robot in robots:
        folder = root / robot
        if not folder.is_dir():
            present = sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
            human = _human_kind_in(root)
            raise ShardBuildError(
                f"no folder for robot {robot!r} in the input (it has: {', '.join(present) or 'nothing'})"
                + (f"; it holds human motion ({human} files)" if human else ""),
                path=root,
                fix=f"for human motion give --robots {human} (alone; the targets are --targets)" if human
                else f"put the robot's clips in {folder}/ (one .csv or .csv.gz per clip)",
            )  # fmt: skip
        clips: dict[str, Path] = {}
        for p in sorted(folder.iterdir()):
            name = clip_name(p)
            if name is None:
                continue
            check_regular_file(
                p, ShardBuildError, fix="remove it or replace it with the clip's .csv/.csv.gz file; mer reads only regular files"
            )
            if name in clips:
                raise ShardBuildError(
                    f"clip {name!r} is there twice ({clips[name].name} and {p.name})",
                    path=folder,
                    fix="keep one file per clip",
                )
            clips[name] = p
        if not clips:
            human = _human_kind_in(folder)
            raise ShardBuildError(f"no .csv or .csv.gz files for robot {robot!r}" + (f"; the folder holds {human} files" if human else ""),
                                  path=folder, fix=f"for human motion give --robots {human} --input {folder}" if human else None)  # fmt: skip
        out[robot] = dict(sorted(clips.items()))
    return out


def _human_kind_in(folder: Path) -> str | None:
    """The human kind (bvh, smpl, joints) whose files ``folder`` holds (:func:`~mer_data.motion.sources.human_files`), else None."""
    from mer_data.base.errors import MerError
    from mer_data.motion.sources import HUMAN_SOURCES, human_files, human_kind

    for kind in HUMAN_SOURCES:
        try:
            first = next(iter(human_files(folder, kind).values())) if folder.is_dir() else None
        except MerError:
            continue
        try:  # an .npz of SMPL parameters or of joint positions: its content says
            return human_kind(first, None) or kind
        except MerError:
            return kind
    return None


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def stable_words(text: str, n: int = 4) -> list[int]:
    """``n`` 32-bit words from sha256(text): a platform-independent seed component for a name."""
    h = hashlib.sha256(text.encode()).digest()
    return [int.from_bytes(h[4 * i : 4 * i + 4], "little") for i in range(n)]
