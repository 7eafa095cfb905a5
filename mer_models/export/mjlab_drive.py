"""The drive of each joint of a robot exported for mjlab (``mer robots export NAME --mjlab DIR``):
position-actuator gains, effort limit and armature, from the description where it gives them, else
from the rule below (docs/trackers.md §5 lists what the user still decides).

**Given** (used as they are): a URDF's ``<limit effort>`` and ``<dynamics damping friction>``; an
MJCF's joint ``armature``, ``damping``, ``frictionloss``, ``actuatorfrcrange``, and a ``<position>``
actuator's ``kp`` / ``kv`` / ``forcerange`` (a ``<motor>``'s ``ctrlrange`` x ``gear`` as the effort).

**The rule** (the kind mjlab's own G1 / Go1 configurations use): a joint is a second-order system
around its motor's reflected inertia (the armature ``a``), with natural frequency ``w`` =
2 pi x 10 Hz and damping ratio ``zeta`` = 2 (mjlab's G1 values), so ``kp = a w^2`` and
``kd = 2 zeta a w``. Where the description gives no armature (URDFs never do), it is estimated from
the joint's effort limit ``e`` [N m]: ``a = 1.33e-3 sqrt(e)`` [kg m^2], fitted (least squares in
log space) to the four actuator types of mjlab's G1 (Unitree's rotor inertias and gear ratios:
5020 at 25 N m, 7520-14 at 88, 7520-22 at 139, 4010 at 5), which it matches within a factor
0.63 -- 1.85. Where the effort is not given either, it is twice the static torque the joint
holds at the zero pose: a leg joint (one above a foot) half the robot's weight at the sole's centre,
any other its subtree's weight at the subtree's centre of mass (lever: the distance from the joint's
axis), at least 5 N m (slide joints: twice the weight they carry, at least 50 N).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mer_data.robots.articulation import Articulation, urdf_joint_drives

__all__ = ["NATURAL_FREQ", "DAMPING_RATIO", "ARMATURE_PER_SQRT_EFFORT", "Drive", "joint_drives", "given_drives"]

#: Natural frequency of the rule's joint [rad/s] (mjlab's G1: 10 Hz).
NATURAL_FREQ = 2 * math.pi * 10.0
#: Damping ratio of the rule's joint (mjlab's G1).
DAMPING_RATIO = 2.0
#: Armature per square root of the effort limit [kg m^2 / sqrt(N m)], fitted to mjlab's G1 actuators.
ARMATURE_PER_SQRT_EFFORT = 1.334e-3
_G = 9.81
_MIN_EFFORT = (5.0, 50.0)  # [N m] hinge, [N] slide


@dataclass(frozen=True)
class Drive:
    """One joint's position actuator.

    Attributes:
        joint: its name; kp [N m/rad or N/m], kd [N m s/rad or N s/m], effort [N m or N],
        armature [kg m^2 or kg]; damping, frictionloss: passive joint terms (0 where none given).
        source: per quantity, ``"given"`` or ``"rule"``.
    """

    joint: str
    kp: float
    kd: float
    effort: float
    armature: float
    damping: float
    frictionloss: float
    source: dict[str, str]


def given_drives(path: str | Path, source: str) -> dict[str, dict[str, float]]:
    """Joint → the drive values the description gives (keys ``effort``, ``armature``, ``damping``,
    ``frictionloss``, ``kp``, ``kd``; only those it gives)."""
    if source == "urdf":
        out = {}
        for name, v in urdf_joint_drives(path).items():
            out[name] = {
                k2: v[k] for k, k2 in (("effort", "effort"), ("damping", "damping"), ("friction", "frictionloss")) if k in v
            }
        return out
    import mujoco

    from mer_data.robots.mjcf import compile_mjcf

    m = compile_mjcf(path, geometry=False).model
    out: dict[str, dict[str, float]] = {}
    for j in range(m.njnt):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        if name is None or int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE):
            continue
        d, v = int(m.jnt_dofadr[j]), {}
        for key, val in (("armature", m.dof_armature[d]), ("damping", m.dof_damping[d]), ("frictionloss", m.dof_frictionloss[d])):
            if val > 0:
                v[key] = float(val)
        if m.jnt_actfrclimited[j]:
            v["effort"] = float(np.abs(m.jnt_actfrcrange[j]).max())
        out[name] = v
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))
        v = out.setdefault(name, {})
        gain, bias = m.actuator_gainprm[a], m.actuator_biasprm[a]
        gear = abs(float(m.actuator_gear[a, 0])) or 1.0
        if int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE) and gain[0] > 0 and bias[1] == -gain[0]:
            v["kp"], v["kd"] = float(gain[0]), float(max(-bias[2], 0.0))
            if m.actuator_forcelimited[a]:
                v["effort"] = float(np.abs(m.actuator_forcerange[a]).max())
        elif int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_NONE) and m.actuator_ctrllimited[a] and "effort" not in v:
            v["effort"] = float(np.abs(m.actuator_ctrlrange[a]).max()) * gear
    return out


def _static_effort(art: Articulation, j: int, world: np.ndarray, subtree: list[list[int]], soles: dict[int, np.ndarray],
                   mass: float) -> float:  # fmt: skip
    """The rule's effort of joint ``j`` (module docstring) [N m or N]."""
    jt = art.joints[j]
    t = world[jt.body]
    axis, anchor = t[:3, :3] @ jt.axis, t[:3, :3] @ jt.pos + t[:3, 3]
    below = subtree[jt.body]
    feet = [soles[b] for b in below if b in soles]
    if feet:
        load, point = mass / 2, np.mean(feet, axis=0)
    else:
        ms = np.array([art.bodies[b].mass for b in below])
        if ms.sum() <= 0:
            return _MIN_EFFORT[jt.type == "slide"]
        coms = np.array([world[b][:3, :3] @ art.bodies[b].com + world[b][:3, 3] for b in below])
        load, point = float(ms.sum()), (ms[:, None] * coms).sum(0) / ms.sum()
    if jt.type == "slide":
        return max(2 * load * _G, _MIN_EFFORT[1])
    r = point - anchor
    lever = float(np.linalg.norm(r - (r @ axis) * axis))
    return max(2 * load * _G * lever, _MIN_EFFORT[0])


def joint_drives(
    art: Articulation, given: dict[str, dict[str, float]], world: np.ndarray, soles: dict[int, np.ndarray]
) -> list[Drive]:
    """A :class:`Drive` per joint of ``art`` that is not a mimic joint, in its order.

    Args:
        given: :func:`given_drives` of its description.
        world: (B, 4, 4) world <- body at the zero pose [m].
        soles: foot body index -> (3,) the centre of its sole in the world [m] at the zero pose.
    """
    subtree: list[list[int]] = [[b] for b in range(len(art.bodies))]
    for b in range(len(art.bodies) - 1, 0, -1):
        subtree[art.bodies[b].parent].extend(subtree[b])
    mass = sum(b.mass for b in art.bodies)
    out = []
    for j, jt in enumerate(art.joints):
        if jt.mimic is not None:
            continue
        g = given.get(jt.name, {})
        src = {}
        effort = g.get("effort")
        src["effort"] = "given" if effort else "rule"
        if not effort:
            effort = _static_effort(art, j, world, subtree, soles, mass)
        armature = g.get("armature")
        src["armature"] = "given" if armature else "rule"
        if not armature:
            armature = ARMATURE_PER_SQRT_EFFORT * math.sqrt(effort)
        if "kp" in g:
            kp, kd, src["gains"] = g["kp"], g.get("kd", 0.0), "given"
        else:
            kp, kd, src["gains"] = armature * NATURAL_FREQ**2, 2 * DAMPING_RATIO * armature * NATURAL_FREQ, "rule"
        out.append(Drive(jt.name, float(kp), float(kd), float(effort), float(armature), g.get("damping", 0.0),
                         g.get("frictionloss", 0.0), src))  # fmt: skip
    return out
