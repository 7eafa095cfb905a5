"""One exception hierarchy for everything mer refuses.

Every error says *what* was wrong, *where* (file, line, element) and *how to fix it*. The command
line prints ``str(error)`` and exits non-zero; library callers can catch the class they care about.

    MerError
    ├── URDFError
    │   ├── MalformedURDFError      XML syntax, missing or non-numeric attributes
    │   ├── UnsafeURDFError         DTDs / XML entities (never resolved)
    │   ├── BrokenReferenceError    a joint, mimic or key point names a link/joint that is not there
    │   ├── KinematicTreeError      cycles, several roots, a link with two parents
    │   └── UnsupportedJointError   prismatic/planar/floating joints, zero axes, missing limits
    ├── RobotCardError              robot card (YAML) problems
    ├── RegistryError
    │   ├── UnknownRobotError       lists the known robots
    │   └── RobotExistsError
    ├── MotionFormatError           motion files (CSV) that do not match the robot
    ├── OutputError                 a computed output that is not finite: refused, never written
    ├── OutputPathError             an output name mer will not write through (a link, not a regular file)
    ├── DiskFullError               no space left for an output: the path and the space it needs
    ├── SplitError                  a train/eval split that does not fit the clips
    ├── ShardError                  training shards
    │   ├── ShardFormatError        not a shard, a damaged one, or an unsupported format version
    │   └── ShardBuildError         a build that cannot start or finish (input, output folder)
    ├── ConfigError                 a configuration (or checkpoint config.json) the code does not match
    ├── CheckpointError             missing, corrupt or mismatched model checkpoints
    │   └── UnseenRobotError        a checkpoint asked to retarget to a robot it never saw
    └── ModelZooError               model registry (cards), Hub downloads and publishing
        ├── UnknownModelError       lists the known models
        ├── ModelNotAvailableError  weights not published yet, or offline and not cached
        ├── ChecksumError           a file whose size or sha256 differs from its card
        └── PublishError            a checkpoint or card that cannot be published
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "MerError",
    "URDFError",
    "MalformedURDFError",
    "UnsafeURDFError",
    "BrokenReferenceError",
    "KinematicTreeError",
    "UnsupportedJointError",
    "RobotCardError",
    "RegistryError",
    "UnknownRobotError",
    "RobotExistsError",
    "MotionFormatError",
    "OutputError",
    "OutputPathError",
    "DiskFullError",
    "ConfigError",
    "CheckpointError",
    "UnseenRobotError",
    "SplitError",
    "ShardError",
    "ShardFormatError",
    "ShardBuildError",
    "ModelZooError",
    "UnknownModelError",
    "ModelNotAvailableError",
    "ChecksumError",
    "PublishError",
]


class MerError(Exception):
    """Base class: a message plus where it happened and how to fix it.

    Args:
        message: what is wrong.
        path: the file concerned, if any.
        line: 1-based line in ``path``, if known.
        element: the element concerned (e.g. ``joint 'left_knee'``).
        fix: one sentence telling the user what to do.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        element: str | None = None,
        fix: str | None = None,
    ) -> None:
        self.message = message
        self.path = str(path) if path is not None else None
        self.line = line
        self.element = element
        self.fix = fix
        super().__init__(self._format())

    def _format(self) -> str:
        where = ""
        if self.path:
            where = self.path + (f":{self.line}" if self.line else "")
        parts = []
        if where:
            parts.append(where)
        if self.element:
            parts.append(self.element)
        head = ": ".join(parts)
        text = f"{head}: {self.message}" if head else self.message
        if self.fix:
            text += f"\n  fix: {self.fix}"
        return text


class URDFError(MerError):
    """A URDF that mer cannot turn into a skeleton."""


class MalformedURDFError(URDFError):
    """Not well-formed XML, or an element misses a required or numeric attribute."""


class UnsafeURDFError(URDFError):
    """The file declares a DTD or XML entities; mer never resolves them."""


class BrokenReferenceError(URDFError):
    """A joint, mimic tag or key point refers to a link or joint that does not exist."""


class KinematicTreeError(URDFError):
    """The links and joints do not form a single tree (cycle, several roots, two parents)."""


class UnsupportedJointError(URDFError):
    """A joint type or joint definition the skeleton graph cannot represent."""


class RobotCardError(MerError):
    """A robot card (YAML) that is malformed or does not match its URDF."""


class RegistryError(MerError):
    """Robot registry problems."""


class UnknownRobotError(RegistryError, KeyError):
    """A robot name that is neither built in nor registered."""

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return self._format()


class RobotExistsError(RegistryError):
    """Registering a name that is already taken."""


class MotionFormatError(MerError):
    """A motion file (CSV) that does not match its robot's layout."""


class OutputError(MerError):
    """A computed output (motion, shard, skeleton) with NaN or infinite values; nothing is written."""


class OutputPathError(MerError):
    """An output path mer will not write through: a symbolic link (or a folder that is one) where mer
    chooses the name, or something that is not a regular file or folder."""


class DiskFullError(MerError):
    """The file system has no room for an output (ENOSPC, or the quota): one line naming the path,
    the space the write needs and the space free; nothing is left under the final name."""


class ConfigError(MerError):
    """A configuration, or a checkpoint's ``config.json``, that does not match the code."""


class CheckpointError(MerError):
    """A model checkpoint that is missing, corrupt, or does not match the model."""


class UnseenRobotError(CheckpointError):
    """A checkpoint asked to retarget to (or from) a robot it was never trained on."""


class SplitError(MerError):
    """A train/eval split that cannot be applied to the clips at hand."""


class ShardError(MerError):
    """Training shard problems."""


class ShardFormatError(ShardError):
    """A file that is not a mer shard, is damaged, or has an unsupported format version."""


class ShardBuildError(ShardError):
    """A shard build that cannot start or finish (input folder, output folder, failed clips)."""


class ModelZooError(MerError):
    """Model registry (cards), Hub download and publishing problems."""


class UnknownModelError(ModelZooError, KeyError):
    """A model name that has no card; the message lists the known names."""

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return self._format()


class ModelNotAvailableError(ModelZooError):
    """The weights are not published yet, or they are not cached and the network is off."""


class ChecksumError(ModelZooError):
    """A downloaded or cached file whose size or sha256 differs from what its card records."""


class PublishError(ModelZooError):
    """A checkpoint or card that cannot be published (missing files, unknown licence, name taken)."""


class BVHError(MotionFormatError):
    """A BVH motion capture file that mer cannot read, or cannot turn into a human skeleton."""


__all__.append("BVHError")
