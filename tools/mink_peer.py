"""Benchmark-only peer: mer's per-frame key-point IK solved with mink on MuJoCo.

`mink <https://github.com/kevinzakka/mink>`_ is the differential-IK library GMR is built on. This
module poses the *same* problem as mer's optimiser (every key point of a built-in robot pulled to a
world-frame target, a small regulariser towards the nominal angles, joint limits as hard bounds)
and solves it GMR-style: frames in order, each warm-started from the previous one, a fixed number
of QP steps (``mink.solve_ik`` + ``integrate_inplace``) per frame. ``tools/bench_retarget.py`` uses
it to print mer's frames/s and error next to mink's.

mink and mujoco are **benchmark-only** dependencies, not runtime dependencies of mer::

    pip install mink mujoco daqp      # mink 1.3 pulls qpsolvers[daqp]; "daqp" is the default solver

The MuJoCo model is compiled from the robot's own URDF (``mer_data/robots/<name>/<name>.urdf``) by
MuJoCo's URDF importer, so its kinematics are independent of mer's URDF parser and skeleton
builder (``tests/tools/test_mink_peer.py`` checks that both FKs agree). Before compiling:

* visual and collision geometry, ``<gazebo>``, ``<transmission>`` and ``<mujoco>`` elements are
  stripped (meshes are not shipped); static bodies are kept (``fusestatic="false"``) so that every
  URDF link is a MuJoCo body that a key-point site can hang on;
* a free joint is added on the URDF root link (the floating base);
* the skeleton's ``locked`` joints (card ``locked`` and the mimic joints of locked joints, e.g.
  the TALOS gripper fingers) are removed, their bodies rotated (translated for prismatic joints)
  to the locked value, and MuJoCo's mimic equality constraints on them are dropped. A mimic joint
  that moves with a free master is not supported (no built-in robot has one): ``ValueError``;
* every remaining hinge gets mer's limits (``Skeleton.lower/upper``; continuous joints ±pi);
* one site per key point at ``link + offset`` (offset in the link frame), named ``mer_kp_<key>``.

Units: metres, radians; quaternions are scalar-first (w, x, y, z) like MuJoCo and mer.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

if TYPE_CHECKING:
    import mujoco

    from mer_data.skeleton import Skeleton

log = logging.getLogger(__name__)

__all__ = ["MinkRobot", "build_mink_robot", "solve_keypoints", "keypoints_fk", "SITE_PREFIX", "BASE"]

#: Prefix of the key-point site names in the MuJoCo model.
SITE_PREFIX = "mer_kp_"
#: The key point that stands for the root link's origin.
BASE = "base"
#: Name of the free joint added on the root link.
FREE_JOINT = "mer_floating_base"

_STRIP_TAGS = ("visual", "collision", "gazebo", "transmission", "mujoco")


def _import_mujoco_mink():
    try:
        import mink
        import mujoco
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "tools/mink_peer.py needs the benchmark-only packages mink and mujoco (pip install mink mujoco daqp)"
        ) from exc
    return mujoco, mink


@dataclass(frozen=True, eq=False)
class MinkRobot:
    """A built-in mer robot as a compiled MuJoCo model, ready for mink.

    Attributes:
        name: mer robot name.
        model: the compiled ``mujoco.MjModel`` (free joint first: ``qpos[0:3]`` base position,
            ``qpos[3:7]`` base quaternion wxyz).
        skeleton: mer's :class:`~mer_data.skeleton.Skeleton` of the robot.
        root_body: MuJoCo body of the URDF root link (the ``"base"`` key point).
        joint_names: (n_dof,) mer's joint order, ``skeleton.joint_names``.
        qpos_index: (n_dof,) ``qpos`` address of each joint of ``joint_names``.
        dof_index: (n_dof,) ``qvel`` address of each joint of ``joint_names``.
        keypoint_frames: key point → (MuJoCo frame name, ``"site"`` or ``"body"``), ``"base"`` included.
        nominal_qpos: (nq,) mer's nominal angles (base at the origin, identity orientation).
    """

    name: str
    model: mujoco.MjModel
    skeleton: Skeleton
    root_body: str
    joint_names: tuple[str, ...]
    qpos_index: np.ndarray
    dof_index: np.ndarray
    keypoint_frames: dict[str, tuple[str, str]]
    nominal_qpos: np.ndarray

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def keypoints(self) -> tuple[str, ...]:
        """Key points this robot has: ``"base"`` then the card's, in ``KEYPOINTS`` order."""
        return tuple(self.keypoint_frames)

    def qpos(self, q: np.ndarray, base_pos: np.ndarray, base_quat_wxyz: np.ndarray) -> np.ndarray:
        """(nq,) MuJoCo configuration from mer's (n_dof,) angles and a base pose."""
        out = self.nominal_qpos.copy()
        out[0:3] = base_pos
        quat = np.asarray(base_quat_wxyz, dtype=np.float64)
        out[3:7] = quat / np.linalg.norm(quat)
        out[self.qpos_index] = q
        return out


def _stripped_urdf(path: Path) -> str:
    """URDF text without geometry and simulator extras, plus a MuJoCo compiler element."""
    from lxml import etree

    parser = etree.XMLParser(remove_comments=True, resolve_entities=False, no_network=True)
    root = etree.fromstring(path.read_bytes(), parser)
    for tag in _STRIP_TAGS:
        for el in list(root.iter(tag)):
            el.getparent().remove(el)
    for el in list(root):
        if el.tag == "material":  # top-level materials only colour visuals
            root.remove(el)
    extra = etree.SubElement(root, "mujoco")
    etree.SubElement(extra, "compiler", fusestatic="false", discardvisual="true", balanceinertia="true")
    return etree.tostring(root, encoding="unicode")


def _axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])  # fmt: skip


def build_mink_robot(robot: str) -> MinkRobot:
    """Compile the MuJoCo model of a built-in mer robot (see the module docstring).

    Args:
        robot: a built-in mer robot name (g1, h1, h1_2, atlas, oli, tron1, talos, valkyrie); a
            registered user robot works too.

    Raises:
        ImportError: mink or mujoco is not installed.
        ValueError: the robot has a mimic joint that moves, or its URDF does not compile.
    """
    mujoco, _ = _import_mujoco_mink()
    from mer_data.robots.registry import load_robot
    from mer_data.skeleton import KEYPOINTS

    rob = load_robot(robot)
    skel, card = rob.skeleton, rob.card
    spec = mujoco.MjSpec.from_string(_stripped_urdf(rob.urdf_path))
    spec.compiler.boundmass = 1e-3  # links without <inertial>: kinematics only, any mass will do
    spec.compiler.boundinertia = 1e-6
    if spec.compiler.degree:  # the URDF importer works in radians; ranges below are radians
        raise ValueError("unexpected: MuJoCo's URDF importer left compiler.degree on")

    roots = list(spec.worldbody.bodies)
    root_name = skel.link_names[0]
    if len(roots) != 1 or roots[0].name != root_name:
        raise ValueError(f"{robot}: expected the URDF root link {root_name!r} as the only child of the world")
    roots[0].add_freejoint(name=FREE_JOINT)

    # ---- locked joints: fold the locked value into the body frame, drop the joint -------------
    joints = {j.name: j for b in spec.bodies for j in b.joints}
    removed: set[str] = set()
    for name, value in skel.locked.items():
        j = joints.get(name)
        if j is None:
            raise ValueError(f"{robot}: locked joint {name!r} is not in the MuJoCo model")
        body = j.parent
        if np.linalg.norm(j.pos) > 1e-12:
            raise ValueError(f"{robot}: joint {name!r} is not at its body's origin")
        if j.type == mujoco.mjtJoint.mjJNT_HINGE:
            body.quat = _quat_mul(np.asarray(body.quat), _axis_angle_quat(j.axis, value))
        elif j.type == mujoco.mjtJoint.mjJNT_SLIDE:
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, np.asarray(body.quat, dtype=np.float64))
            body.pos = np.asarray(body.pos) + rot.reshape(3, 3) @ (np.asarray(j.axis) / np.linalg.norm(j.axis) * value)
        else:
            raise ValueError(f"{robot}: cannot lock joint {name!r} of MuJoCo type {j.type}")
        spec.delete(j)
        removed.add(name)
    for eq in list(spec.equalities):
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and (eq.name1 in removed or eq.name2 in removed):
            spec.delete(eq)
    if any(True for _ in spec.equalities):
        raise ValueError(f"{robot}: equality constraints remain (a mimic joint that moves?); not supported")

    # ---- mer's joint limits on every remaining joint ------------------------------------------
    dof_nodes = np.flatnonzero(skel.dof_mask)
    limits = {skel.node_names[j]: (float(skel.lower[j]), float(skel.upper[j])) for j in dof_nodes}
    for b in spec.bodies:
        for j in b.joints:
            if j.name == FREE_JOINT:
                continue
            if j.name not in limits:
                raise ValueError(
                    f"{robot}: MuJoCo joint {j.name!r} is neither a mer degree of freedom nor locked "
                    "(a moving mimic joint?); not supported by the benchmark peer"
                )
            j.range = limits[j.name]
            j.limited = mujoco.mjtLimited.mjLIMITED_TRUE

    # ---- key-point sites ------------------------------------------------------------------------
    frames: dict[str, tuple[str, str]] = {BASE: (root_name, "body")}
    for key in KEYPOINTS:
        kp = card.keypoints.get(key)
        if kp is None or skel.keypoints.get(key, -1) < 0:
            continue
        body = spec.body(kp.link)
        if body is None:
            raise ValueError(f"{robot}: key point {key!r} names link {kp.link!r}, not a MuJoCo body")
        body.add_site(name=SITE_PREFIX + key, pos=np.asarray(kp.offset, dtype=np.float64))
        frames[key] = (SITE_PREFIX + key, "site")

    try:
        model = spec.compile()
    except Exception as exc:  # mujoco raises ValueError with the compiler message
        raise ValueError(f"{robot}: MuJoCo could not compile the URDF: {exc}") from exc

    free = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, FREE_JOINT)
    if model.jnt_qposadr[free] != 0:
        raise ValueError(f"{robot}: the free joint is not at qpos[0:7]")
    names = skel.joint_names
    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    if min(jids, default=0) < 0:
        raise ValueError(f"{robot}: joints missing from the MuJoCo model: {[n for n, i in zip(names, jids) if i < 0]}")
    qpos_index = np.asarray(model.jnt_qposadr[jids], dtype=np.int64)
    dof_index = np.asarray(model.jnt_dofadr[jids], dtype=np.int64)
    nominal = np.zeros(model.nq)
    nominal[3] = 1.0
    nominal[qpos_index] = skel.nominal[dof_nodes]
    log.debug("mink peer %s: nq=%d nv=%d, %d key points", robot, model.nq, model.nv, len(frames))
    return MinkRobot(
        name=robot,
        model=model,
        skeleton=skel,
        root_body=root_name,
        joint_names=names,
        qpos_index=qpos_index,
        dof_index=dof_index,
        keypoint_frames=frames,
        nominal_qpos=nominal,
    )


def _frame_ids(mr: MinkRobot, keypoints: Sequence[str]) -> list[tuple[int, bool]]:
    """(MuJoCo id, is_site) of each key point; ValueError for names the robot does not have."""
    mujoco, _ = _import_mujoco_mink()
    out = []
    for k in keypoints:
        if k not in mr.keypoint_frames:
            raise ValueError(f"{mr.name} has no key point {k!r}; it has {', '.join(mr.keypoints)}")
        name, kind = mr.keypoint_frames[k]
        obj = mujoco.mjtObj.mjOBJ_SITE if kind == "site" else mujoco.mjtObj.mjOBJ_BODY
        out.append((mujoco.mj_name2id(mr.model, obj, name), kind == "site"))
    return out


def _read_frames(data, ids: list[tuple[int, bool]]) -> np.ndarray:
    return np.stack([data.site_xpos[i] if site else data.xpos[i] for i, site in ids])


def keypoints_fk(
    mr: MinkRobot,
    q: np.ndarray,
    base_pos: np.ndarray,
    base_quat_wxyz: np.ndarray,
    keypoints: Sequence[str] | None = None,
) -> np.ndarray:
    """MuJoCo FK of key points: (T, n_dof) angles [rad] in mer's order, (T, 3) base position [m],
    (T, 4) base quaternion wxyz → (T, K, 3) world positions [m] (leading dims may be absent)."""
    mujoco, _ = _import_mujoco_mink()
    keypoints = list(mr.keypoints if keypoints is None else keypoints)
    ids = _frame_ids(mr, keypoints)
    q = np.asarray(q, dtype=np.float64)
    single = q.ndim == 1
    q, bp, bq = np.atleast_2d(q), np.atleast_2d(base_pos), np.atleast_2d(base_quat_wxyz)
    data = mujoco.MjData(mr.model)
    out = np.empty((len(q), len(keypoints), 3))
    for t in range(len(q)):
        data.qpos[:] = mr.qpos(q[t], bp[t], bq[t])
        mujoco.mj_kinematics(mr.model, data)
        out[t] = _read_frames(data, ids)
    return out[0] if single else out


def solve_keypoints(
    mr: MinkRobot,
    targets_w: np.ndarray,
    keypoints: list[str],
    *,
    base_pos0: np.ndarray,
    base_quat0_wxyz: np.ndarray,
    q0: np.ndarray | None = None,
    iters_per_frame: int = 10,
    dt: float = 0.01,
    position_cost: float = 1.0,
    posture_cost: float | None = None,
    damping: float = 1e-3,
    solver: str = "daqp",
    euclidean: bool = True,
) -> dict:
    """Track key-point targets frame by frame with mink (GMR's scheme).

    Per frame: set one ``FrameTask`` target per key point (position cost only, orientation cost
    0; ``"base"`` is a FrameTask on the root body), then ``iters_per_frame`` times
    ``v = mink.solve_ik(conf, tasks, dt, solver, damping, limits=[ConfigurationLimit])`` and
    ``conf.integrate_inplace(v, dt)``. Frame ``t`` starts from frame ``t - 1``'s solution. A
    ``PostureTask`` pulls the angles towards mer's nominal pose (it ignores the free joint).

    The problem is mer's per-frame IK (``mer_models/solver/ik.py``):
    ``w_kp/K * sum_k |p_k - P_k|^2 + w_norm/n_dof * sum_j (q_j - nominal_j)^2`` within the
    limits. mink's task weight ``c`` enters the objective as ``c^2``, so the equivalent costs
    are ``position_cost^2 / posture_cost^2 = (w_kp / K) / (w_norm / n_dof)``; ``posture_cost=None``
    picks that ratio with mer's default weights (``EnergyConfig``: w_kp 1, w_norm 1e-3).

    Args:
        mr: from :func:`build_mink_robot`.
        targets_w: (T, K, 3) world-frame targets [m] of ``keypoints``.
        keypoints: K names: ``"base"`` (the root link origin) and/or names of
            ``mer_data.skeleton.KEYPOINTS`` that the robot has.
        base_pos0: (3,) initial base position [m] (frame 0's warm start).
        base_quat0_wxyz: (4,) initial base orientation.
        q0: (n_dof,) initial angles [rad] in mer's joint order; default mer's nominal pose.
        iters_per_frame: QP steps per frame (GMR: up to 10).
        dt: integration step [s] of mink's velocity; with only position limits it cancels out.
        position_cost: FrameTask position cost of every key point [1/m].
        posture_cost: PostureTask cost [1/rad]; ``None``: mer's relative weight (see above).
        damping: Levenberg-Marquardt damping of ``solve_ik`` (GMR uses 0.5 with larger costs).
        solver: qpsolvers backend ("daqp", "quadprog", "osqp", ...).
        euclidean: before each step, give each target its frame's current orientation, so that the
            position part of mink's SE(3) error is exactly ``R^T (P - p)`` and the least-squares cost
            is mer's Euclidean one. ``False``: identity target orientation, as a plain
            ``SE3.from_translation`` target (the fixed point is the same; the weighting is not).

    Returns:
        ``q`` (T, n_dof) angles [rad] in ``mr.joint_names`` (= ``Skeleton.joint_names``) order,
        ``base_pos`` (T, 3) [m], ``base_quat_wxyz`` (T, 4), ``seconds`` (solve time only; model
        building excluded), ``keypoints_w`` (T, K, 3) achieved key-point positions [m].
    """
    mujoco, mink = _import_mujoco_mink()
    targets = np.asarray(targets_w, dtype=np.float64)
    if targets.ndim != 3 or targets.shape[1:] != (len(keypoints), 3):
        raise ValueError(f"targets_w must be (T, {len(keypoints)}, 3), got {targets.shape}")
    if iters_per_frame < 1:
        raise ValueError("iters_per_frame must be >= 1")
    T, K = targets.shape[:2]
    ids = _frame_ids(mr, keypoints)
    model = mr.model
    if posture_cost is None:
        posture_cost = math.sqrt(1e-3 * K / max(mr.n_dof, 1))  # EnergyConfig w_norm / w_kp

    tasks = []
    for k in keypoints:
        name, kind = mr.keypoint_frames[k]
        tasks.append(mink.FrameTask(name, kind, position_cost=position_cost, orientation_cost=0.0))
    posture = mink.PostureTask(model, cost=posture_cost)
    posture.set_target(mr.nominal_qpos)
    all_tasks = [*tasks, posture]
    limits = [mink.ConfigurationLimit(model)]

    q_init = mr.skeleton.nominal[mr.skeleton.dof_mask] if q0 is None else np.asarray(q0, dtype=np.float64)
    qpos0 = mr.qpos(q_init, np.asarray(base_pos0, dtype=np.float64), np.asarray(base_quat0_wxyz, dtype=np.float64))
    hinge = model.jnt_type != mujoco.mjtJoint.mjJNT_FREE
    adr = model.jnt_qposadr[hinge]
    qpos0[adr] = np.clip(qpos0[adr], model.jnt_range[hinge, 0], model.jnt_range[hinge, 1])
    conf = mink.Configuration(model, qpos0)
    data = conf.data

    qpos_out = np.empty((T, model.nq))
    kp_out = np.empty((T, K, 3))
    wxyz_xyz = np.zeros((K, 7))
    wxyz_xyz[:, 0] = 1.0
    quat = np.empty(4)

    def set_targets(t: int) -> None:
        wxyz_xyz[:, 4:] = targets[t]
        if euclidean:
            for i, (fid, site) in enumerate(ids):
                mujoco.mju_mat2Quat(quat, data.site_xmat[fid] if site else data.xmat[fid])
                wxyz_xyz[i, :4] = quat
        for i, task in enumerate(tasks):
            task.set_target(mink.SE3(wxyz_xyz=wxyz_xyz[i].copy()))

    t0 = time.perf_counter()
    for t in range(T):
        for it in range(iters_per_frame):
            if it == 0 or euclidean:
                set_targets(t)
            v = mink.solve_ik(conf, all_tasks, dt, solver, damping=damping, limits=limits)
            conf.integrate_inplace(v, dt)
        qpos_out[t] = data.qpos
        kp_out[t] = _read_frames(data, ids)
    seconds = time.perf_counter() - t0
    log.info(
        "mink peer %s: %d frames x %d iters in %.3f s (%.1f frames/s), mean key-point error %.2f mm",
        mr.name, T, iters_per_frame, seconds, T / max(seconds, 1e-12),
        1e3 * float(np.linalg.norm(kp_out - targets, axis=-1).mean()),
    )  # fmt: skip
    return {
        "q": qpos_out[:, mr.qpos_index],
        "base_pos": qpos_out[:, 0:3].copy(),
        "base_quat_wxyz": qpos_out[:, 3:7].copy(),
        "seconds": seconds,
        "keypoints_w": kp_out,
    }
