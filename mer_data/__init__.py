"""mer_data: robots, their kinematics, source motion and training shards. Depends on no part of
:mod:`mer_models`.

* :mod:`.skeleton` - the central type, :class:`Skeleton` (the paper's skeleton graph);
* :mod:`.robots` - URDF + robot card -> a registered robot and its skeleton; the registry;
* :mod:`.kinematics` - FK, rotations, joint maps, the scaled goals;
* :mod:`.motion` - source-motion readers, windows, features, splits, training samples;
* :mod:`.shards` - ``mer shards``: HDF5 / MCAP training shards and :class:`~.shards.ShardDataset`;
* :mod:`.synthesis` - synthetic motion of any robot; :mod:`.base` - errors, limits, safe I/O.

The names below are imported lazily (PEP 562), so ``import mer_data.base.errors`` (or the model zoo's
registry) does not pay for importing torch; ``from mer_data import Skeleton`` works as before.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "MerError": ".base.errors",
    "Skeleton": ".skeleton",
    "KEYPOINTS": ".skeleton",
    "BUILTIN_ROBOTS": ".robots.registry",
    "get_skeleton": ".robots.registry",
    "load_robot": ".robots.registry",
    "list_robots": ".robots.registry",
    "forward_kinematics": ".kinematics.fk",
    "skeleton_tensors": ".kinematics.fk",
    "joint_map": ".kinematics.jointmap",
    "keypoint_pairs": ".kinematics.jointmap",
}

__all__ = list(_EXPORTS)
__version__ = "0.1.0"


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mer_data' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
