"""Tiny synthetic URDFs built in code: humanoids, bipeds without arms, quadrupeds, mirrors.

Every robot is written as plain XML text; ``Robot`` collects links and joints and ``mirrored()``
reflects it through the x-z plane (y -> -y, left <-> right), which is what the mirror property
tests need. Geometry is in metres, angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace


def _fmt(v) -> str:
    return " ".join(f"{x:.12g}" for x in v)


@dataclass
class J:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)
    axis: tuple | None = (0.0, 0.0, 1.0)
    limit: tuple | None = (-1.5, 1.5)
    mimic: tuple | None = None  # (joint, multiplier, offset)


@dataclass
class L:
    name: str
    boxes: list = field(default_factory=list)  # [(xyz, size)]


@dataclass
class Robot:
    name: str
    links: list = field(default_factory=list)
    joints: list = field(default_factory=list)

    def link(self, name, boxes=()):
        self.links.append(L(name, list(boxes)))
        return name

    def joint(self, name, type, parent, child, **kw):
        if child not in [l.name for l in self.links]:
            self.link(child)
        self.joints.append(J(name, type, parent, child, **kw))

    def xml(self) -> str:
        out = [f'<?xml version="1.0"?>\n<robot name="{self.name}">']
        for l in self.links:
            if l.boxes:
                out.append(f'  <link name="{l.name}">')
                for xyz, size in l.boxes:
                    out.append(
                        f'    <collision><origin xyz="{_fmt(xyz)}" rpy="0 0 0"/>'
                        f'<geometry><box size="{_fmt(size)}"/></geometry></collision>'
                    )
                out.append("  </link>")
            else:
                out.append(f'  <link name="{l.name}"/>')
        for j in self.joints:
            out.append(f'  <joint name="{j.name}" type="{j.type}">')
            out.append(f'    <parent link="{j.parent}"/>\n    <child link="{j.child}"/>')
            out.append(f'    <origin xyz="{_fmt(j.xyz)}" rpy="{_fmt(j.rpy)}"/>')
            if j.axis is not None and j.type != "fixed":
                out.append(f'    <axis xyz="{_fmt(j.axis)}"/>')
            if j.limit is not None and j.type in ("revolute", "prismatic"):
                out.append(f'    <limit lower="{j.limit[0]}" upper="{j.limit[1]}" effort="10" velocity="10"/>')
            if j.mimic is not None:
                out.append(f'    <mimic joint="{j.mimic[0]}" multiplier="{j.mimic[1]}" offset="{j.mimic[2]}"/>')
            out.append("  </joint>")
        out.append("</robot>\n")
        return "\n".join(out)

    def write(self, path) -> str:
        path.write_text(self.xml())
        return str(path)

    def mirrored(self) -> "Robot":
        """Reflection through the x-z plane, left and right names swapped.

        Positions: y -> -y. Rotations R -> M R M with M = diag(1, -1, 1), i.e. rpy (r, p, y) ->
        (-r, p, -y). Joint axes (pseudo-vectors) a -> -M a = (-ax, ay, -az), limits unchanged.
        """

        def swap(s: str) -> str:
            return s.replace("left", "\0").replace("right", "left").replace("\0", "right")

        m = Robot(swap(self.name))
        for l in self.links:
            m.links.append(L(swap(l.name), [((x, -y, z), size) for (x, y, z), size in l.boxes]))
        for j in self.joints:
            x, y, z = j.xyz
            r, p, yw = j.rpy
            axis = None if j.axis is None else (-j.axis[0], j.axis[1], -j.axis[2])
            mimic = None if j.mimic is None else (swap(j.mimic[0]), j.mimic[1], j.mimic[2])
            m.joints.append(
                replace(j, name=swap(j.name), parent=swap(j.parent), child=swap(j.child), xyz=(x, -y, z),
                        rpy=(-r, p, -yw), axis=axis, mimic=mimic)
            )  # fmt: skip
        return m


def humanoid(name="toy_humanoid", *, arms=True, head=True, scale=1.0, asymmetric=False, tilt=0.0) -> Robot:
    """A 3-DoF-hip, knee, 2-DoF-ankle, waist, 3-DoF-shoulder, elbow, wrist humanoid.

    ``asymmetric`` makes the right side differ (for mirror tests); ``tilt`` tilts the hip-pitch
    axes (like Oli) and adds rotated fixed frames (to exercise fixed-joint merging).
    """
    s = scale
    r = Robot(name)
    r.link("pelvis")
    for side, sy in (("left", 1.0), ("right", -1.0)):
        k = 1.0 + (0.1 if (asymmetric and sy < 0) else 0.0)
        r.joint(f"{side}_hip_yaw_joint", "revolute", "pelvis", f"{side}_hip_yaw_link",
                xyz=(0.0, 0.09 * sy * s * k, -0.05 * s), axis=(0, 0, 1), limit=(-0.8, 0.8))
        r.joint(f"{side}_hip_roll_joint", "revolute", f"{side}_hip_yaw_link", f"{side}_hip_roll_link",
                xyz=(0.0, 0.02 * sy * s, -0.06 * s), axis=(1, 0, 0), limit=(-0.5, 0.5))
        r.joint(f"{side}_hip_pitch_joint", "revolute", f"{side}_hip_roll_link", f"{side}_thigh_link",
                xyz=(0.0, 0.0, 0.0), axis=(0.0, 1.0, tilt * sy), limit=(-2.0, 1.5))
        r.joint(f"{side}_knee_joint", "revolute", f"{side}_thigh_link", f"{side}_shin_link",
                xyz=(0.01, 0.0, -0.35 * s * k), axis=(0, 1, 0), limit=(0.0, 2.4))
        r.joint(f"{side}_ankle_pitch_joint", "revolute", f"{side}_shin_link", f"{side}_ankle_link",
                xyz=(0.0, 0.0, -0.34 * s), axis=(0, 1, 0), limit=(-0.8, 0.5))
        r.link(f"{side}_foot_link", boxes=[((0.04 * s, 0.0, -0.03 * s), (0.2 * s, 0.08 * s, 0.02 * s))])
        r.joint(f"{side}_ankle_roll_joint", "revolute", f"{side}_ankle_link", f"{side}_foot_link",
                xyz=(0.0, 0.0, 0.0), axis=(1, 0, 0), limit=(-0.3, 0.3))
    r.joint("waist_yaw_joint", "revolute", "pelvis", "waist_link", xyz=(0, 0, 0.08 * s), axis=(0, 0, 1))
    r.joint("torso_fixed_joint", "fixed", "waist_link", "torso_link", xyz=(0.01, 0, 0.12 * s),
            rpy=(0.0, tilt, 0.0))
    r.joint("imu_joint", "fixed", "torso_link", "imu_link", xyz=(0.0, 0.0, 0.05), rpy=(0.3, -0.2, 0.7))
    if head:
        r.joint("neck_joint", "revolute", "torso_link", "head_link", xyz=(0, 0, 0.3 * s), axis=(0, 0, 1))
    if arms:
        for side, sy in (("left", 1.0), ("right", -1.0)):
            k = 1.0 + (0.15 if (asymmetric and sy < 0) else 0.0)
            r.joint(f"{side}_shoulder_pitch_joint", "revolute", "torso_link", f"{side}_shoulder_pitch_link",
                    xyz=(0.0, 0.15 * sy * s * k, 0.22 * s), axis=(0, 1, 0), limit=(-2.5, 2.5))
            r.joint(f"{side}_shoulder_roll_joint", "revolute", f"{side}_shoulder_pitch_link",
                    f"{side}_shoulder_roll_link", xyz=(0.0, 0.03 * sy * s, 0.0), axis=(1, 0, 0))
            r.joint(f"{side}_shoulder_yaw_joint", "revolute", f"{side}_shoulder_roll_link",
                    f"{side}_upper_arm_link", xyz=(0.0, 0.0, -0.1 * s), axis=(0, 0, 1))
            r.joint(f"{side}_elbow_joint", "revolute", f"{side}_upper_arm_link", f"{side}_forearm_link",
                    xyz=(0.0, 0.0, -0.15 * s * k), axis=(0, 1, 0), limit=(-0.2, 2.3))
            r.joint(f"{side}_wrist_joint", "revolute", f"{side}_forearm_link", f"{side}_wrist_link",
                    xyz=(0.0, 0.0, -0.2 * s), axis=(0, 0, 1))
            r.joint(f"{side}_hand_joint", "fixed", f"{side}_wrist_link", f"{side}_hand_link",
                    xyz=(0.0, 0.0, -0.06 * s))
    return r


def biped(name="toy_biped") -> Robot:
    """Legs only (like Tron1): 2-DoF hip, knee, ankle; no arms, no head."""
    r = Robot(name)
    r.link("base")
    for side, sy in (("left", 1.0), ("right", -1.0)):
        r.joint(f"abad_{side}_joint", "revolute", "base", f"abad_{side}_link", xyz=(0.05, 0.1 * sy, -0.2), axis=(1, 0, 0))
        r.joint(f"hip_{side}_joint", "revolute", f"abad_{side}_link", f"hip_{side}_link", xyz=(-0.07, 0.02 * sy, 0.0), axis=(0, sy, 0))
        r.joint(f"knee_{side}_joint", "revolute", f"hip_{side}_link", f"knee_{side}_link", xyz=(-0.15, 0.0, -0.26), axis=(0, -sy, 0))
        r.link(f"foot_{side}_link", boxes=[((0.03, 0.0, -0.04), (0.16, 0.06, 0.02))])
        r.joint(f"ankle_{side}_joint", "revolute", f"knee_{side}_link", f"foot_{side}_link", xyz=(0.15, 0.0, -0.26), axis=(0, -1, 0))
    return r


def quadruped(name="toy_quadruped") -> Robot:
    """Unitree-style quadruped: hip abduction, thigh, calf, fixed foot frame, per leg."""
    r = Robot(name)
    r.link("trunk")
    for leg, (sx, sy) in {"FL": (1, 1), "FR": (1, -1), "RL": (-1, 1), "RR": (-1, -1)}.items():
        r.joint(f"{leg}_hip_joint", "revolute", "trunk", f"{leg}_hip", xyz=(0.19 * sx, 0.05 * sy, 0.0), axis=(1, 0, 0))
        r.joint(f"{leg}_thigh_joint", "revolute", f"{leg}_hip", f"{leg}_thigh", xyz=(0.0, 0.08 * sy, 0.0), axis=(0, 1, 0))
        r.joint(f"{leg}_calf_joint", "revolute", f"{leg}_thigh", f"{leg}_calf", xyz=(0.0, 0.0, -0.21), axis=(0, 1, 0), limit=(-2.7, -0.9))
        r.joint(f"{leg}_foot_fixed", "fixed", f"{leg}_calf", f"{leg}_foot", xyz=(0.0, 0.0, -0.21))
    return r
