"""The build configuration of a shard set: one frozen, validated dataclass, written into every shard."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from mer_data.motion.lafan1 import QUAT_TOLERANCE

from .augment import AugmentConfig
from .schema import FORMAT_VERSION

__all__ = ["BuildConfig", "PAPER_TARGETS", "FORMATS"]

#: The target robots of the paper's experiments (Experiment Setup).
PAPER_TARGETS: tuple[str, ...] = ("g1", "h1", "oli", "tron1", "atlas", "talos", "valkyrie")
FORMATS = ("hdf5", "mcap")
#: fields that do not change the content of the shards (left out of the build id)
_NOT_CONTENT = ("input", "body_model")
_SYNTHETIC = ("synthetic", "synthetic_seconds", "synthetic_seed")
_HUMAN = ("body_model", "up", "human_fps")  # kept only where given (builds without them keep their build id)


@dataclass(frozen=True)
class BuildConfig:
    """What ``mer shards build`` builds.

    Attributes:
        input: a folder holding ``<robot>/<clip>.csv[.gz]``, or ``hf://REPO_ID[@REVISION]``; human
            files: a folder of them (``<kind>/*`` or ``*``, :func:`mer_data.motion.sources.human_files`).
        robots: source robots (each needs ``lafan1_columns`` in its card), or one human kind alone:
            ``("bvh",)``, ``("smpl",)``, ``("joints",)`` (one reference per body, :mod:`mer_data.shards.humans`).
        format: ``"hdf5"`` or ``"mcap"``.
        window: frames per window (at ``out_fps``).
        stride: frames between window starts, 1..window; ``None`` = ``window`` (non-overlapping
            windows, plus a last one ending at the clip's last frame: every frame is in a window).
        fps: frame rate of the input files [Hz] (LAFAN1: 30).
        out_fps: frame rate of the windows [Hz] (paper: 30).
        split: ``"paper"``, ``"all"`` or the path of a split file (:mod:`mer_data.motion.splits`);
            ``mer shards build`` defaults to ``"all"`` (every clip trains), this dataclass to ``"paper"``.
        targets: target robots of the samples; ``("all",)`` = every registered robot.
        augment: augmented target skeletons per (training window, target), besides the URDF one.
        seed: seed of the augmentation draws.
        augmentation: ranges and drop probability (:class:`mer_data.shards.augment.AugmentConfig`).
        num_shards: how many disjoint shards the clips are dealt into (by clip name).
        compression: HDF5 filter: ``"lzf"`` (fast), ``"gzip"`` (portable, smaller) or ``"none"``.
        quat_tolerance: root quaternions within this of unit norm are renormalized, others refused.
        mcap_preview: windows per clip animated for Foxglove in MCAP shards (-1: all).
        synthetic: clips of synthetic motion per robot (:mod:`mer_data.synthesis`) instead of
            ``input``'s files (0: read ``input``); any registered robot works, LAFAN1 layout or not.
        synthetic_seconds: length of each synthetic clip [s] (generated at ``fps``).
        synthetic_seed: seed of the synthetic motion (clip ``i`` of robot ``R`` depends on it, ``R``, ``i``).
        body_model, up, human_fps: how to read human clips (``robots`` ``("smpl",)`` or ``("joints",)``:
            :class:`~mer_data.motion.sources.HumanOptions`): the SMPL-family model file or folder, the
            up axis, the rate of files that say none [Hz]; None: the reader's defaults.
    """

    input: str
    robots: tuple[str, ...]
    format: str = "hdf5"
    window: int = 60
    stride: int | None = None
    fps: float = 30.0
    out_fps: float = 30.0
    split: str = "paper"
    targets: tuple[str, ...] = PAPER_TARGETS
    augment: int = 4
    seed: int = 0
    augmentation: AugmentConfig = field(default_factory=AugmentConfig)
    num_shards: int = 1
    compression: str = "lzf"
    quat_tolerance: float = QUAT_TOLERANCE
    mcap_preview: int = 1
    synthetic: int = 0
    synthetic_seconds: float = 20.0
    synthetic_seed: int = 0
    body_model: str | None = None
    up: str | None = None
    human_fps: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "robots", tuple(self.robots))
        object.__setattr__(self, "targets", tuple(self.targets))
        if isinstance(self.augmentation, dict):
            aug = self.augmentation
            object.__setattr__(
                self,
                "augmentation",
                AugmentConfig(tuple(aug["key_scale"]), tuple(aug["other_scale"]), float(aug["drop_prob"])),
            )
        if self.stride is None:
            object.__setattr__(self, "stride", self.window)
        problems = []
        if not self.robots or len(set(self.robots)) != len(self.robots):
            problems.append(f"robots must be a non-empty list without repeats, got {list(self.robots)}")
        if not self.targets or len(set(self.targets)) != len(self.targets):
            problems.append(f"targets must be a non-empty list without repeats, got {list(self.targets)}")
        if self.format not in FORMATS:
            problems.append(f"format must be one of {', '.join(FORMATS)}, got {self.format!r}")
        if not (isinstance(self.window, int) and self.window >= 3):
            problems.append(f"window must be an integer >= 3 frames, got {self.window!r}")
        if not (isinstance(self.stride, int) and 1 <= self.stride <= max(self.window, 1)):
            problems.append(f"stride must be an integer in 1..window (every frame in a window), got {self.stride!r}")
        if not (self.fps > 0 and self.out_fps > 0):
            problems.append(f"frame rates must be positive, got fps={self.fps}, out_fps={self.out_fps}")
        if not (isinstance(self.augment, int) and self.augment >= 0):
            problems.append(f"augment must be an integer >= 0, got {self.augment!r}")
        if not (isinstance(self.num_shards, int) and self.num_shards >= 1):
            problems.append(f"num_shards must be an integer >= 1, got {self.num_shards!r}")
        if self.compression not in ("lzf", "gzip", "none"):
            problems.append(f"compression must be lzf, gzip or none, got {self.compression!r}")
        if not 0 < self.quat_tolerance < 1:
            problems.append(f"quat_tolerance must be in (0, 1), got {self.quat_tolerance}")
        if not (isinstance(self.synthetic, int) and self.synthetic >= 0):
            problems.append(f"synthetic must be an integer >= 0 (clips per robot), got {self.synthetic!r}")
        if not self.synthetic_seconds > 0:
            problems.append(f"synthetic_seconds must be positive, got {self.synthetic_seconds!r}")
        if not isinstance(self.synthetic_seed, int):
            problems.append(f"synthetic_seed must be an integer, got {self.synthetic_seed!r}")
        if self.human_fps is not None and not self.human_fps > 0:
            problems.append(f"human_fps must be positive, got {self.human_fps!r}")
        if problems:
            raise ValueError("; ".join(problems))

    def human_options(self):
        """How the build reads human clips (:class:`~mer_data.motion.sources.HumanOptions`)."""
        from mer_data.motion.sources import HumanOptions

        return HumanOptions(body_model=self.body_model, up=self.up, fps=self.human_fps)

    def variants(self, split: str) -> int:
        """Target skeletons per (window, target): 1 + ``augment`` for training windows, 1 for evaluation."""
        return 1 + self.augment if split == "train" else 1

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["robots"], d["targets"] = list(self.robots), list(self.targets)
        d["augmentation"] = self.augmentation.to_dict()
        if not self.synthetic:  # builds from files keep the configuration (and build id) they always had
            for k in _SYNTHETIC:
                d.pop(k)
        for k in _HUMAN:
            if d[k] is None:
                d.pop(k)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "BuildConfig":
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def with_(self, **kw) -> "BuildConfig":
        return replace(self, **kw)

    def build_id(self, resolved: dict[str, Any]) -> str:
        """sha256 of everything that determines the shards' content.

        ``resolved`` adds what the configuration only names: the clip -> split assignment and the
        skeleton fingerprints of every robot used.
        """
        content = {k: v for k, v in self.to_dict().items() if k not in _NOT_CONTENT}
        blob = json.dumps({"config": content, "resolved": resolved, "format_version": FORMAT_VERSION}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()
