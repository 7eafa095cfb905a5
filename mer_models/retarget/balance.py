"""Balance metrics: could the robot's mass do what the motion shows? (docs/model.md §Balance)

Per frame, from the robot's masses and inertias (:mod:`mer_data.robots.inertia`) and the
dynamics of :mod:`mer_data.kinematics.dynamics` (central differences, the 5-tap binomial filter):
the contact wrench the motion demands, its zero-moment point (ZMP) on the floor z = 0, and the
**support** (:mod:`mer_data.kinematics.support`): every vertex of the robot's collision polytopes
within :data:`CONTACT_HEIGHT` (2 cm) of the floor; the support polygon is the convex hull of their
floor projections. A frame is

* **flight** without any such vertex, else a **contact** frame: **single support** where all of
  them belong to one foot (the collision model's foot shapes), **double** otherwise (both feet, or
  any other body on the floor: knees, hands);
* **ZMP outside** where the ZMP is farther than :data:`ZMP_TOL` (2 cm) outside the support polygon;
* **pulling** where the demanded vertical force is negative (the floor would have to pull);
* **slipping** where the demanded horizontal force exceeds ``MU * f_z`` (mu = 1);
* **off-ballistic** (flight) where the centre of mass accelerates other than by gravity by more than
  :data:`FLIGHT_TOL` [m/s^2];
* **infeasible**: a contact frame with the ZMP outside, pulling or slipping, or an off-ballistic
  flight frame: a demanded wrench no contact can supply.

**Torques over the effort limit**: the joint torques of inverse dynamics with the contact forces
split as favourably as possible: per frame a linear programme over forces at the support's
vertices (each in an 8-sided friction pyramid inscribed in the mu = 1 cone) that first comes as close
to the demanded wrench as it can, then minimises the torques' excess over the URDF effort limits.
A frame counts where some joint's torque still exceeds its limit.

Summary keys (:data:`BALANCE_KEYS`), over the frames that have central differences (the first and
last two are left out): shares of contact frames (``zmp_out``, single and double support apart,
``pull_frames``, ``slip_frames``), of all frames (``balance_infeasible``, ``flight_frames``,
``torque_frames``), ``zmp_out_dist`` the median distance outside over single-support frames [m],
``flight_accel`` the mean ``|c'' - g|`` of flight frames [m/s^2], ``torque_ratio_max``.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch

from mer_data.kinematics import dynamics as dyn
from mer_data.kinematics.collision import shape_points
from mer_data.kinematics.support import CONTACT_HEIGHT, hull_indices, polygon_distance, support_kind

log = logging.getLogger(__name__)

__all__ = ["CONTACT_HEIGHT", "ZMP_TOL", "MU", "FLIGHT_TOL", "BALANCE_KEYS", "balance_frames", "balance_metrics",
           "polygon_distance", "best_contact_torques"]  # fmt: skip

ZMP_TOL = 0.02  # [m] a ZMP this far outside the support polygon is outside
MU = 1.0  # friction coefficient
FLIGHT_TOL = 2.0  # [m/s^2] a flight frame whose |c'' - g| exceeds this is off-ballistic
_PYRAMID = 8  # edges of the friction pyramid
_MASSLESS: set[str] = set()  # robots whose missing masses were logged
_WRENCH_WEIGHT = 1e3  # the LP's price of the wrench residual against the torques' excess
BALANCE_KEYS = (
    "balance_infeasible", "zmp_out", "zmp_out_single", "zmp_out_double", "zmp_out_dist", "pull_frames", "slip_frames",
    "flight_frames", "flight_accel", "torque_frames", "torque_ratio_max",
)  # fmt: skip


# ---- the most favourable contact split ------------------------------------------------------------------
def _pyramid() -> np.ndarray:
    """(E, 3) edges of the friction pyramid inscribed in the cone ``|f_xy| <= MU f_z``."""
    a = np.arange(_PYRAMID) * 2 * np.pi / _PYRAMID
    return np.stack([MU * np.cos(a), MU * np.sin(a), np.ones_like(a)], -1)


def best_contact_torques(tau0: np.ndarray, amap: np.ndarray, points: np.ndarray, com: np.ndarray,
                         force: np.ndarray, moment: np.ndarray, limit: np.ndarray, mass: float) -> np.ndarray:  # fmt: skip
    """Joint torques (D,) [N m] with the contact forces split as favourably as possible (module docstring).

    Args:
        tau0: (D,) torques without contact forces; amap: (D, 3K) their change per contact force
            (``tau = tau0 - amap @ f``); points (K, 3) the contact points; com (3,); the demanded
            ``force`` and ``moment`` about the centre of mass (3,); limit (D,) effort limits (finite).
    """
    from scipy.optimize import linprog

    K, D = len(points), len(tau0)
    if K == 0:
        return tau0
    edges = _pyramid()
    E = len(edges)
    # force of each pyramid weight: (3K, K E)
    emap = np.zeros((3 * K, K * E))
    for k in range(K):
        emap[3 * k : 3 * k + 3, k * E : (k + 1) * E] = edges.T
    arm = points - com
    wrench = np.zeros((6, 3 * K))
    for k in range(K):
        wrench[:3, 3 * k : 3 * k + 3] = np.eye(3)
        x, y, z = arm[k]
        wrench[3:, 3 * k : 3 * k + 3] = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    g_eq = wrench @ emap  # (6, KE)
    t_map = amap @ emap  # (D, KE)
    n_l = K * E
    # variables: weights (KE) >= 0, excess s (D) >= 0, residual r+ (6), r- (6) >= 0
    scale = np.r_[np.full(3, mass * dyn.GRAVITY), np.full(3, mass * dyn.GRAVITY * 0.1)]
    c = np.r_[np.zeros(n_l), 1.0 / limit, np.tile(_WRENCH_WEIGHT / scale, 2)]
    a_eq = np.hstack([g_eq, np.zeros((6, D)), -np.eye(6), np.eye(6)])
    b_eq = np.r_[force, moment]
    a_ub = np.vstack([np.hstack([-t_map, -np.eye(D), np.zeros((D, 12))]), np.hstack([t_map, -np.eye(D), np.zeros((D, 12))])])
    b_ub = np.r_[limit - tau0, limit + tau0]
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=(0, None), method="highs")
    if res.status != 0:  # pragma: no cover - the programme is always feasible (residual and excess are free)
        log.warning("contact split LP failed (%s); torques without contact forces", res.message)
        return tau0
    return tau0 - t_map @ res.x[:n_l]


# ---- per frame ----------------------------------------------------------------------------------------------
def balance_frames(pos: np.ndarray, rot: np.ndarray, fps: float, skel: Any, masses: Any, geometry: Any,
                   torques: bool = True, floor: float = 0.0) -> dict[str, np.ndarray]:  # fmt: skip
    """The per-frame quantities of the module docstring for node frames ``pos`` (F, J, 3) [m] and
    ``rot`` (F, J, 3, 3) of ``skel`` (its :class:`~mer_data.robots.inertia.MassModel` ``masses``,
    :class:`~mer_data.robots.collision.CollisionModel` ``geometry``).

    Returns (F,) arrays (valid where ``valid``): ``zmp`` (F, 2), ``com`` (F, 3), ``force``, ``moment``
    (F, 3), ``support`` (0 flight, 1 single, 2 double), ``zmp_dist`` [m] (NaN where undefined),
    ``pull``, ``slip``, ``flight_accel`` [m/s^2], ``infeasible``; with ``torques``: ``tau`` (F, J)
    [N m] and ``torque_ratio`` (F,) the largest ``|tau| / limit``.
    """
    p = torch.as_tensor(np.asarray(pos, np.float64))
    r = torch.as_tensor(np.asarray(rot, np.float64))
    F = p.shape[0]
    w = dyn.body_wrenches(masses, p, r, fps)
    d = dyn.demand(masses, w)
    zmp = dyn.zmp(d, floor).numpy()
    force, moment, com, mass = d.force.numpy(), d.moment.numpy(), d.com.numpy(), float(d.mass)
    verts = shape_points(geometry, p, r, "vertices").numpy()  # (F, S, V, 3)
    low = verts[..., 2] < floor + CONTACT_HEIGHT  # (F, S, V)
    support = support_kind(np.asarray(geometry.foot), low)
    dist = np.full(F, np.nan)
    for f in np.flatnonzero(support > 0):
        if force[f, 2] > 0:
            dist[f] = polygon_distance(zmp[f], verts[f][low[f]][:, :2])
    valid = np.zeros(F, bool)
    valid[dyn.EDGE : F - dyn.EDGE] = True
    contact = support > 0
    pull = contact & (force[:, 2] <= 0)
    slip = contact & ~pull & (np.linalg.norm(force[:, :2], axis=-1) > MU * force[:, 2])
    accel = np.linalg.norm(force, axis=-1) / mass
    out_zmp = contact & (np.nan_to_num(dist, nan=0.0) > ZMP_TOL)
    infeasible = (contact & (out_zmp | pull | slip)) | (~contact & (accel > FLIGHT_TOL))
    out = {"valid": valid, "zmp": zmp, "com": com, "force": force, "moment": moment, "support": support,
           "zmp_dist": dist, "zmp_out": out_zmp, "pull": pull, "slip": slip, "flight_accel": accel,
           "infeasible": infeasible}  # fmt: skip
    if torques:
        out.update(_torques(skel, masses, geometry, w, p, r, d, verts, low, valid))
    return out


def _torques(skel, masses, geometry, w, p, r, d, verts, low, valid) -> dict[str, np.ndarray]:
    tau0 = dyn.joint_torques(skel, w, p, r).numpy()  # (F, J)
    limit = np.asarray(masses.effort, np.float64)
    act = np.flatnonzero(np.asarray(skel.revolute_mask) & np.isfinite(limit))
    node = np.asarray(geometry.node)
    tau = tau0.copy()
    sub = dyn.subtree_matrix(skel.parents, skel.num_nodes, p)
    for f in np.flatnonzero(valid):
        pts, nodes = [], []
        for n in np.unique(node[low[f].any(-1)]):  # per node: its contact points' hull vertices
            v = verts[f][(node[:, None] == n) & low[f]]
            pts.append(v[hull_indices(v[:, :2])])
            nodes += [n] * len(pts[-1])
        if not pts:
            continue
        pts_a = np.concatenate(pts)
        amap = dyn.contact_torque_map(skel, p[f], r[f], torch.from_numpy(pts_a), torch.as_tensor(nodes), sub).numpy()
        tau[f, act] = best_contact_torques(tau0[f, act], amap[act], pts_a, d.com[f].numpy(), d.force[f].numpy(),
                                           d.moment[f].numpy(), limit[act], float(d.mass))  # fmt: skip
    ratio = np.zeros(len(tau))
    if len(act):
        ratio = (np.abs(tau[:, act]) / limit[act]).max(-1)
    return {"tau": tau, "torque_ratio": ratio, "torque_worst_node": act[np.abs(tau[:, act] / limit[act]).argmax(-1)]
            if len(act) else np.zeros(len(tau), np.int64)}  # fmt: skip


def balance_metrics(pos: np.ndarray, rot: np.ndarray, fps: float, skel: Any, masses: Any, geometry: Any,
                    torques: bool = True) -> dict[str, Any]:  # fmt: skip
    """The summary (:data:`BALANCE_KEYS`, NaN where undefined; ``torque_worst`` the joint most
    often over its limit, or None) of :func:`balance_frames`. A description with no link masses (no
    ``<inertial>``) demands no wrench: every figure is NaN, logged once per robot."""
    if not masses.total_mass > 0:
        if masses.robot not in _MASSLESS:
            _MASSLESS.add(masses.robot)
            log.warning("%s: its description gives no link masses, so the balance metrics are undefined (NaN); "
                        "give its links <inertial> elements to measure them", masses.robot)  # fmt: skip
        return {**{k: float("nan") for k in BALANCE_KEYS}, "torque_worst": None}
    b = balance_frames(pos, rot, fps, skel, masses, geometry, torques=torques)
    v = b["valid"]

    def share(x, among):
        n = (among & v).sum()
        return float((x & among & v).sum() / n) if n else float("nan")

    allf = np.ones_like(v)
    contact, single, double = b["support"] > 0, b["support"] == 1, b["support"] == 2
    flight = ~contact
    d_single = b["zmp_dist"][single & v]
    d_single = d_single[np.isfinite(d_single)]
    out = {
        "balance_infeasible": share(b["infeasible"], allf),
        "zmp_out": share(b["zmp_out"], contact),
        "zmp_out_single": share(b["zmp_out"], single),
        "zmp_out_double": share(b["zmp_out"], double),
        "zmp_out_dist": float(np.median(d_single)) if len(d_single) else float("nan"),
        "pull_frames": share(b["pull"], contact),
        "slip_frames": share(b["slip"], contact),
        "flight_frames": share(flight, allf),
        "flight_accel": float(b["flight_accel"][flight & v].mean()) if (flight & v).any() else float("nan"),
        "torque_frames": float("nan"), "torque_ratio_max": float("nan"), "torque_worst": None,
    }  # fmt: skip
    if torques:
        over = b["torque_ratio"] > 1
        out["torque_frames"] = share(over, allf)
        out["torque_ratio_max"] = float(b["torque_ratio"][v].max()) if v.any() else float("nan")
        worst = b["torque_worst_node"][over & v]
        out["torque_worst"] = skel.urdf_joint_names[int(np.bincount(worst).argmax())] if len(worst) else None
    return out
