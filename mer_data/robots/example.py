"""A small humanoid URDF generated in code: the robot ``mer demo`` registers (no file ships with mer).

:func:`example_humanoid_urdf` returns the URDF text of a ~1 m humanoid with 21 revolute joints:
3-DoF hips, knees, 2-DoF ankles with box feet, a waist, a neck, 3-DoF shoulders, elbows and wrists
with fixed hand frames. Link names follow the common ``left_*``/``right_*`` conventions, so
``mer robots register`` proposes every key point on its own. It is written here, under mer's
Apache-2.0 licence, so a fresh install can walk through registering a robot with no download.
Geometry in metres, angles in radians.
"""

from __future__ import annotations

from pathlib import Path

from mer_data.base.atomic import atomic_write

__all__ = ["EXAMPLE_ROBOT", "example_humanoid_urdf", "write_example_urdf"]

EXAMPLE_ROBOT = "mer_demo_humanoid"


def _v(*xs: float) -> str:
    return " ".join(f"{x:.6g}" for x in xs)


def example_humanoid_urdf(name: str = EXAMPLE_ROBOT, scale: float = 1.0) -> str:
    """URDF text of the example humanoid; ``scale`` multiplies every length (1.0: ~1 m standing)."""
    s = float(scale)
    links: list[str] = []
    joints: list[str] = []

    def link(n: str, box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None) -> None:
        if box is None:
            links.append(f'  <link name="{n}"/>')
        else:
            (x, y, z), (a, b, c) = box
            links.append(f'  <link name="{n}">\n    <collision><origin xyz="{_v(x, y, z)}" rpy="0 0 0"/>'
                         f'<geometry><box size="{_v(a, b, c)}"/></geometry></collision>\n  </link>')

    def joint(n: str, parent: str, child: str, xyz, axis=None, limit=(-1.5, 1.5), box=None) -> None:
        link(child, box)
        kind = "fixed" if axis is None else "revolute"
        body = [f'  <joint name="{n}" type="{kind}">', f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
                f'    <origin xyz="{_v(*xyz)}" rpy="0 0 0"/>']
        if axis is not None:
            body += [f'    <axis xyz="{_v(*axis)}"/>', f'    <limit lower="{limit[0]}" upper="{limit[1]}" effort="50" velocity="10"/>']
        joints.append("\n".join(body + ["  </joint>"]))

    link("pelvis", ((0.0, 0.0, 0.0), (0.12 * s, 0.2 * s, 0.1 * s)))
    for side, sy in (("left", 1.0), ("right", -1.0)):
        joint(f"{side}_hip_yaw_joint", "pelvis", f"{side}_hip_yaw_link", (0.0, 0.08 * sy * s, -0.05 * s), (0, 0, 1), (-0.8, 0.8))
        joint(f"{side}_hip_roll_joint", f"{side}_hip_yaw_link", f"{side}_hip_roll_link", (0.0, 0.0, -0.04 * s), (1, 0, 0), (-0.5, 0.5))
        joint(f"{side}_hip_pitch_joint", f"{side}_hip_roll_link", f"{side}_thigh_link", (0.0, 0.0, 0.0), (0, 1, 0), (-2.0, 1.5))
        joint(f"{side}_knee_joint", f"{side}_thigh_link", f"{side}_shin_link", (0.0, 0.0, -0.3 * s), (0, 1, 0), (0.0, 2.4))
        joint(f"{side}_ankle_pitch_joint", f"{side}_shin_link", f"{side}_ankle_link", (0.0, 0.0, -0.3 * s), (0, 1, 0), (-0.8, 0.5))
        joint(f"{side}_ankle_roll_joint", f"{side}_ankle_link", f"{side}_foot_link", (0.0, 0.0, 0.0), (1, 0, 0), (-0.3, 0.3),
              box=((0.03 * s, 0.0, -0.03 * s), (0.16 * s, 0.06 * s, 0.02 * s)))
    joint("waist_yaw_joint", "pelvis", "torso_link", (0.0, 0.0, 0.08 * s), (0, 0, 1), (-1.0, 1.0),
          box=((0.0, 0.0, 0.15 * s), (0.1 * s, 0.22 * s, 0.25 * s)))
    joint("neck_yaw_joint", "torso_link", "head_link", (0.0, 0.0, 0.32 * s), (0, 0, 1), (-1.0, 1.0),
          box=((0.0, 0.0, 0.06 * s), (0.1 * s, 0.1 * s, 0.12 * s)))
    for side, sy in (("left", 1.0), ("right", -1.0)):
        joint(f"{side}_shoulder_pitch_joint", "torso_link", f"{side}_shoulder_pitch_link", (0.0, 0.13 * sy * s, 0.26 * s), (0, 1, 0), (-2.5, 2.5))
        joint(f"{side}_shoulder_roll_joint", f"{side}_shoulder_pitch_link", f"{side}_shoulder_roll_link", (0.0, 0.03 * sy * s, 0.0), (1, 0, 0),
              (-0.3, 2.0) if sy > 0 else (-2.0, 0.3))
        joint(f"{side}_shoulder_yaw_joint", f"{side}_shoulder_roll_link", f"{side}_upper_arm_link", (0.0, 0.0, -0.08 * s), (0, 0, 1), (-1.5, 1.5))
        joint(f"{side}_elbow_joint", f"{side}_upper_arm_link", f"{side}_forearm_link", (0.0, 0.0, -0.14 * s), (0, 1, 0), (-0.2, 2.3))
        joint(f"{side}_wrist_yaw_joint", f"{side}_forearm_link", f"{side}_wrist_link", (0.0, 0.0, -0.18 * s), (0, 0, 1), (-1.5, 1.5))
        joint(f"{side}_hand_joint", f"{side}_wrist_link", f"{side}_hand_link", (0.0, 0.0, -0.05 * s))
    return "\n".join([f'<?xml version="1.0"?>\n<robot name="{name}">', *links, *joints, "</robot>\n"])


def write_example_urdf(path: str | Path, name: str = EXAMPLE_ROBOT, scale: float = 1.0) -> Path:
    """Write :func:`example_humanoid_urdf` to ``path`` (parents created); returns the path."""
    return atomic_write(path, example_humanoid_urdf(name, scale))
