"""Artifact metrics: what makes a retargeted motion hard for a tracking policy to learn from.

Per motion (docs/model.md §Evaluation), on the robot's collision polytopes
(:mod:`mer_data.robots.collision`), floor at z = 0:

* **floor**: ``floor_frames`` the share of frames in which a foot's lowest point is below
  -:data:`FLOOR_TOL` (1 cm); ``floor_depth_mean`` / ``floor_depth_max`` the mean (over those frames)
  and largest depth [m]; ``body_floor_frames`` the same share for any body and
  ``body_floor_depth_max`` its largest depth [m].
* **skating**: the horizontal speed of each foot's lowest body-fixed point (the vertex lowest at
  frame t, followed to t + 1) over the frame pairs in which the foot is in contact (lowest point
  within :data:`CONTACT_BAND` = 2.5 cm of the floor at both frames): ``skate_median``,
  ``skate_p95`` [m/s], ``skate_share`` (share above 5 cm/s).
* **hovering**: ``hover_frames`` the share of the source's foot-down samples (frame, foot) in which
  the target's same foot has its lowest point higher than :data:`HOVER_TOL` (1 cm): a stance foot
  that does not reach the floor.
* **floating**: ``floating_frames`` the share of the frames in which the *source* has a foot down
  (:func:`mer_data.motion.contacts.foot_contacts`) where no body of the target is within 5 cm of
  the floor.
* **self-penetration**: ``selfpen_frames`` / ``selfpen_1cm_frames`` the share of frames in which
  two checked bodies (not the same body, not parent and child, not touching at the zero pose)
  interpenetrate by more than 1 mm / 1 cm; ``selfpen_depth_max`` [m]; ``selfpen_worst`` the pairs
  deeper than 1 cm most often.
* **joint speed**: ``speed_frames`` the share of frame pairs in which some joint turns faster than
  its URDF velocity limit; ``speed_ratio_max`` the largest speed / limit and ``speed_worst`` its joint.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from mer_data.kinematics.collision import pair_depths, shape_points

__all__ = ["FLOOR_TOL", "CONTACT_BAND", "HOVER_TOL", "SKATE_TOL", "FLOAT_HEIGHT", "ARTIFACT_KEYS", "artifact_metrics"]

FLOOR_TOL = 0.01  # [m] below the floor by more than this: penetration
CONTACT_BAND = 0.025  # [m] a foot this close to the floor is in contact
HOVER_TOL = 0.01  # [m] a stance foot's lowest point higher than this: hovering
SKATE_TOL = 0.05  # [m/s] a contact foot faster than this skates
FLOAT_HEIGHT = 0.05  # [m] no body this close to the floor: floating
SELFPEN_TOL = 0.001  # [m] interpenetrating
SELFPEN_DEEP = 0.01  # [m] deeply
ARTIFACT_KEYS = (
    "floor_frames", "floor_depth_mean", "floor_depth_max", "body_floor_frames", "skate_median", "skate_p95",
    "skate_share", "hover_frames", "body_floor_depth_max", "floating_frames", "selfpen_frames", "selfpen_1cm_frames", "selfpen_depth_max", "speed_frames",
    "speed_ratio_max",
)  # fmt: skip


def _nan() -> float:
    return float("nan")


def artifact_metrics(
    q: np.ndarray,
    node_pos: np.ndarray,
    node_rot: np.ndarray,
    fps: float,
    model: Any,
    joint_names: tuple[str | None, ...],
    source_contacts: np.ndarray | None = None,
) -> dict[str, Any]:
    """The artifact metrics of one motion (see the module docstring).

    Args:
        q: (F, J) node angles [rad]; node_pos (F, J, 3) [m] and node_rot (F, J, 3, 3): node frames
            from FK (:meth:`mer_models.export.writers.TargetMotion.forward_kinematics`).
        model: the robot's :class:`~mer_data.robots.collision.CollisionModel`.
        joint_names: (J,) URDF joint of each node (for ``speed_worst``).
        source_contacts: (F, 2) bool, the source's feet down (:func:`mer_data.motion.contacts.foot_contacts`).

    Returns:
        metric → value; floats (NaN where undefined: no contact frame, no source contacts), plus
        ``selfpen_worst`` (list of ``{pair, frames, depth_max}``) and ``speed_worst`` (joint or None).
    """
    pos = torch.from_numpy(np.asarray(node_pos, np.float64))
    rot = torch.from_numpy(np.asarray(node_rot, np.float64))
    F = pos.shape[0]
    out: dict[str, Any] = {}
    verts = shape_points(model, pos, rot, "vertices")  # (F, S, V, 3)
    z = verts[..., 2]
    low_z, low_v = z.min(-1)  # (F, S)
    body_low = low_z.min(-1).values
    foot = torch.as_tensor(model.foot)
    feet = [torch.nonzero(foot == side).flatten() for side in (1, 2)]
    feet = [f for f in feet if len(f)]
    # floor
    if feet:
        foot_low = torch.stack([low_z[:, f].min(-1).values for f in feet], -1)  # (F, feet)
        deepest = (-foot_low.min(-1).values).clamp_min(0)
        bad = foot_low.min(-1).values < -FLOOR_TOL
        out["floor_frames"] = float(bad.double().mean())
        out["floor_depth_mean"] = float(deepest[bad].mean()) if bool(bad.any()) else 0.0
        out["floor_depth_max"] = float(deepest.max())
    else:
        out.update(floor_frames=_nan(), floor_depth_mean=_nan(), floor_depth_max=_nan())
    out["body_floor_frames"] = float((body_low < -FLOOR_TOL).double().mean())
    out["body_floor_depth_max"] = float((-body_low).clamp_min(0).max())
    # skating: each foot's lowest body-fixed point, followed one frame
    speeds = []
    for f in feet:
        lz, which = low_z[:, f].min(-1)  # (F,)
        s_idx = f[which]  # shape of the lowest point per frame
        v_idx = low_v[torch.arange(F), s_idx]
        p_now = verts[torch.arange(F - 1), s_idx[:-1], v_idx[:-1]]
        p_next = verts[torch.arange(1, F), s_idx[:-1], v_idx[:-1]]
        contact = (lz[:-1] < CONTACT_BAND) & (lz[1:] < CONTACT_BAND)
        sp = (p_next[:, :2] - p_now[:, :2]).norm(dim=-1) * fps
        speeds.append(sp[contact])
    sp_all = torch.cat(speeds) if speeds else torch.zeros(0, dtype=torch.float64)
    if len(sp_all):
        out["skate_median"] = float(sp_all.median())
        out["skate_p95"] = float(torch.quantile(sp_all, 0.95))
        out["skate_share"] = float((sp_all > SKATE_TOL).double().mean())
    else:
        out.update(skate_median=_nan(), skate_p95=_nan(), skate_share=_nan())
    # hovering: the source's foot down, the target's same foot up
    sides = [torch.nonzero(foot == side).flatten() for side in (1, 2)]
    out["hover_frames"] = _nan()
    if source_contacts is not None and len(source_contacts) == F and all(len(f) for f in sides):
        sc = torch.from_numpy(np.asarray(source_contacts, bool))
        if bool(sc.any()):
            lows = torch.stack([low_z[:, f].min(-1).values for f in sides], -1)  # (F, 2)
            out["hover_frames"] = float((lows[sc] > HOVER_TOL).double().mean())
    # floating
    if source_contacts is not None and len(source_contacts) == F and bool(np.asarray(source_contacts).any()):
        down = torch.from_numpy(np.asarray(source_contacts, bool).any(1))
        out["floating_frames"] = float((body_low[down] > FLOAT_HEIGHT).double().mean())
    else:
        out["floating_frames"] = _nan()
    # self-penetration
    if len(model.pairs):
        d = pair_depths(model, pos, rot)  # (F, K)
        worst = d.max(-1).values
        out["selfpen_frames"] = float((worst > SELFPEN_TOL).double().mean())
        out["selfpen_1cm_frames"] = float((worst > SELFPEN_DEEP).double().mean())
        out["selfpen_depth_max"] = float(worst.clamp_min(0).max())
        deep = (d > SELFPEN_DEEP).sum(0)
        order = torch.argsort(deep, descending=True)[:3]
        out["selfpen_worst"] = [
            {"pair": f"{model.link[int(model.pairs[k, 0])]}|{model.link[int(model.pairs[k, 1])]}",
             "frames": round(float(deep[k]) / F, 4), "depth_max": round(float(d[:, k].max()), 4)}
            for k in order.tolist() if int(deep[k]) > 0
        ]  # fmt: skip
    else:
        out.update(selfpen_frames=0.0, selfpen_1cm_frames=0.0, selfpen_depth_max=0.0, selfpen_worst=[])
    # joint speed against the URDF velocity limit
    lim = np.asarray(model.velocity_limit, np.float64)
    has = np.isfinite(lim) & (lim > 0)
    if F > 1 and has.any():
        vel = np.abs(np.diff(np.asarray(q, np.float64), axis=0)) * fps  # (F-1, J)
        ratio = vel[:, has] / lim[has]
        out["speed_frames"] = float((ratio > 1).any(1).mean())
        out["speed_ratio_max"] = float(ratio.max())
        j = np.flatnonzero(has)[int(ratio.max(0).argmax())]
        out["speed_worst"] = joint_names[j] if ratio.max() > 1 else None
    else:
        out.update(speed_frames=_nan(), speed_ratio_max=_nan(), speed_worst=None)
    return out


def motion_artifacts(
    q: np.ndarray,
    base_pos: np.ndarray,
    base_rot: np.ndarray,
    fps: float,
    skel: Any,
    model: Any,
    reference: np.ndarray | None = None,
    ref_skel: Any = None,
    masses: Any = None,
    torques: bool = False,
) -> dict[str, Any]:
    """:func:`artifact_metrics` of a motion given as angles and base pose (FK done here).

    Args:
        q: (F, J) node angles [rad] of ``skel`` (extra padded columns are dropped); base_pos (F, 3)
            [m]; base_rot (F, 3, 3).
        reference: (F, Jr, 9) source features of ``ref_skel`` (world frame), for the source's contacts.
        masses: the robot's :class:`~mer_data.robots.inertia.MassModel`: adds the balance metrics
            (:func:`mer_models.retarget.balance.balance_metrics`; the joint torques with ``torques``).
    """
    from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
    from mer_data.motion.contacts import foot_contacts
    from mer_data.motion.features import split_features

    J = skel.num_nodes
    qq = torch.from_numpy(np.asarray(q, np.float64)[:, :J])
    pos, rot = fk_skeleton(skeleton_tensors(skel, torch.float64), qq, torch.from_numpy(np.asarray(base_pos, np.float64)),
                           base_rot=torch.from_numpy(np.asarray(base_rot, np.float64)))  # fmt: skip
    contacts = None
    if reference is not None and ref_skel is not None:
        ref_pos = split_features(torch.from_numpy(np.asarray(reference, np.float64)))["pos"].numpy()
        contacts = foot_contacts(ref_pos, ref_skel, fps)
    out = artifact_metrics(qq.numpy(), pos.numpy(), rot.numpy(), fps, model, skel.urdf_joint_names, contacts)
    if masses is not None and len(qq) >= 5:
        from .balance import balance_metrics

        out.update(balance_metrics(pos.numpy(), rot.numpy(), fps, skel, masses, model, torques=torques))
    return out
