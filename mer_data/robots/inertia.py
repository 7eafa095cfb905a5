"""The mass model of a robot on its skeleton: each node's mass, centre of mass and inertia, and each
joint's effort limit, which the dynamics (:mod:`mer_data.kinematics.dynamics`) compute with.

Masses and inertias are the description's (URDF ``<inertial>``, MJCF compiled bodies), read once
by the robot's articulation (:mod:`.articulation`, which a simulator's model and mer's MuJoCo export
share) and lumped per skeleton node: a node carries every body that moves with it (fixed links and
locked joints merged), expressed in the node frame (root-aligned at the zero pose, origin at the
node). Site nodes and nodes without bodies carry nothing. The skeleton itself stays kinematic:
human sources have no masses, and skeleton fingerprints do not change.

Effort limits: a URDF joint's ``<limit effort>`` [N m]; an MJCF joint's ``actuatorfrcrange`` where
limited, else the force range of the actuator that drives it times its gear; ``inf`` where the
description gives none (never counted as exceeded).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .articulation import _combine, _yourdfpy_model, articulation
from .mjcf import compile_mjcf, description_format

if TYPE_CHECKING:  # pragma: no cover
    from .registry import Robot

__all__ = ["MassModel", "build_mass_model", "mass_model", "effort_limits"]


@dataclass(frozen=True, eq=False)
class MassModel:
    """Per skeleton node (J nodes): what moves with it and what its joint can push.

    Attributes:
        robot: robot name; skeleton_fingerprint: the skeleton whose nodes it indexes.
        mass: (J,) [kg]; com: (J, 3) centre of mass in the node frame [m] (the origin where massless);
        inertia: (J, 3, 3) about the centre of mass, node axes [kg m^2].
        effort: (J,) effort limit of each node's joint [N m] (``inf`` where none; base and sites ``inf``).
    """

    robot: str
    skeleton_fingerprint: str
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    effort: np.ndarray

    @property
    def total_mass(self) -> float:
        return float(self.mass.sum())


def effort_limits(robot: "Robot") -> dict[str, float]:
    """Joint name → effort limit [N m] of the registered description (joints without one left out)."""
    out: dict[str, float] = {}
    if description_format(robot.urdf_path) == "mjcf":
        import mujoco

        m = compile_mjcf(robot.urdf_path, geometry=False).model
        for j in range(m.njnt):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
            if name and m.jnt_actfrclimited[j]:
                out[name] = float(np.abs(m.jnt_actfrcrange[j]).max())
        for a in range(m.nu):
            j = int(m.actuator_trnid[a, 0])
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) if j >= 0 else None
            if (name and name not in out and int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                    and m.actuator_forcelimited[a]):  # fmt: skip
                out[name] = float(np.abs(m.actuator_forcerange[a]).max() * abs(m.actuator_gear[a, 0]))
        return {k: v for k, v in out.items() if math.isfinite(v) and v > 0}
    for j in _yourdfpy_model(robot.urdf_path).robot.joints:
        e = getattr(j.limit, "effort", None) if j.limit is not None else None
        try:
            e = None if e is None else float(e)
        except (TypeError, ValueError):
            e = None
        if e is not None and math.isfinite(e) and e > 0:
            out[j.name] = e
    return out


def build_mass_model(robot: "Robot") -> MassModel:
    """The :class:`MassModel` of ``robot`` (uncached; :func:`mass_model` caches it)."""
    skel = robot.skeleton
    art = articulation(robot)
    J = skel.num_nodes
    parts: list[list[tuple[float, np.ndarray, np.ndarray]]] = [[] for _ in range(J)]
    for b in art.bodies:
        if b.mass <= 0:
            continue
        r, t = b.in_node[:3, :3], b.in_node[:3, 3]
        parts[b.node].append((b.mass, r @ b.com + t, r @ b.inertia @ r.T))
    mass, com, inertia = np.zeros(J), np.zeros((J, 3)), np.zeros((J, 3, 3))
    for j, p in enumerate(parts):
        mass[j], com[j], inertia[j] = _combine(p) if p else (0.0, np.zeros(3), np.zeros((3, 3)))
    limits = effort_limits(robot)
    effort = np.array([limits.get(n, np.inf) if n else np.inf for n in skel.urdf_joint_names], np.float64)
    for a in (mass, com, inertia, effort):
        a.setflags(write=False)
    return MassModel(robot.name, skel.fingerprint, mass, com, inertia, effort)


_cache: dict[tuple, MassModel] = {}
_lock = threading.Lock()


def mass_model(robot: "Robot") -> MassModel:
    """The :class:`MassModel` of a registered robot, cached per description file and skeleton."""
    p = Path(robot.urdf_path)
    key = (str(p), p.stat().st_mtime_ns, robot.skeleton.fingerprint)
    with _lock:
        hit = _cache.get(key)
    if hit is None:
        hit = build_mass_model(robot)
        with _lock:
            _cache[key] = hit
    return hit
