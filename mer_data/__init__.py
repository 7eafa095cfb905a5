"""mer_data: robot skeleton graphs from URDF, the robot registry, forward kinematics, joint maps,
and the LAFAN1 training-shard tooling. Depends on no part of :mod:`mer_models`."""

from .errors import MerError
from .fk import forward_kinematics, skeleton_tensors
from .jointmap import joint_map, keypoint_pairs
from .registry import BUILTIN_ROBOTS, get_skeleton, list_robots, load_robot
from .skeleton import KEYPOINTS, Skeleton

__all__ = [
    "MerError",
    "Skeleton",
    "KEYPOINTS",
    "BUILTIN_ROBOTS",
    "get_skeleton",
    "load_robot",
    "list_robots",
    "forward_kinematics",
    "skeleton_tensors",
    "joint_map",
    "keypoint_pairs",
]
__version__ = "0.1.0"
