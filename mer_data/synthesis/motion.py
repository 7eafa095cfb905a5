"""Synthetic whole-body motion of any robot, from its skeleton alone (no motion data needed).

A clip mixes behaviours drawn by a seeded generator:

* **postures** (:mod:`.postures`): standing, bending, crouching, kneeling on one or both knees,
  balancing on one leg, sitting, lying on the back, side or front, on all fours, handstands, with
  eased (C3) transitions between them: lying down and getting up pass through the intermediate ones;
* **free joint motion** per group (left/right arm, left/right leg, torso), independent: each joint
  swings about a drawn centre anywhere in its range with multi-scale noise (0.2-3 Hz), scaled by a
  slowly varying activity per group (and, for the legs, by how much the posture frees them);
* **gait**: hip/knee cycles whose frequency and amplitude follow the travel speed, arms swinging;
* **travel**: a speed profile (standing still to sprinting, in leg lengths per second, scaled by
  the posture's mobility), walking in any direction relative to the body, yaw turning;
* **jumps**: eased flights (sin^4 height pulses, knees tucked) from standing postures.

Every joint passes through :func:`.signals.soft_clamp` (never past a limit, C3); the base height
puts the lowest node on the ground (z = 0) in every frame except during jumps. The result is a
:class:`~mer_data.motion.lafan1.Motion` with one column per actuated joint (``skel.joint_names``), so it
works for every robot, with or without a LAFAN1 column layout. Same seed, same bytes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from mer_data.motion.lafan1 import Motion
from mer_data.skeleton import Skeleton

from .body import GROUPS, SIDES, body_of
from .postures import Posture, posture_chain
from .quat import qangle, qaxis, qcontinuous, qmatrix, qmul, qrotvec, qslerp
from .signals import bump, ease, hold_and_blend, smooth_noise, soft_clamp

__all__ = ["SyntheticClip", "synthesize", "clip_seed", "ground_heights", "SYNTHESIS_VERSION"]

#: Bumped whenever the same seed would give different motion.
SYNTHESIS_VERSION = 1
#: Typical peak speed of the wide free joint swings [rad/s] (their frequency is chosen from it).
JOINT_SPEED = 5.0


@dataclass(frozen=True)
class SyntheticClip:
    """A generated clip: the motion and what it contains (for reports and tests)."""

    motion: Motion
    postures: tuple[str, ...]
    jumps: int
    flight: np.ndarray  # (F,) height of the base above its grounded height [m] (jumps)


def clip_seed(seed: int, robot: str, index: int) -> list[int]:
    """Entropy of clip ``index`` of ``robot``: independent of other clips, robots and processes."""
    h = hashlib.sha256(f"mer-synthesis/{SYNTHESIS_VERSION}/{robot}".encode()).digest()
    return [int(seed), int(index), *(int.from_bytes(h[4 * i : 4 * i + 4], "little") for i in range(4))]


def _fk_heights(skel: Skeleton, q: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(F, J) node heights with the base at the origin, orientation ``rot`` (F, 3, 3); float64 numpy."""
    F, J = q.shape
    q = q.copy()
    for j in np.flatnonzero(skel.mimic_source >= 0):
        q[:, j] = skel.mimic_multiplier[j] * q[:, skel.mimic_source[j]] + skel.mimic_offset[j]
    R = np.empty((F, J, 3, 3))
    p = np.zeros((F, J, 3))
    R[:, 0] = rot
    for j in range(1, J):
        par = skel.parents[j]
        p[:, j] = p[:, par] + R[:, par] @ skel.offsets[j]
        a = skel.axes[j]
        if not np.any(a):
            R[:, j] = R[:, par]
            continue
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        s, c = np.sin(q[:, j])[:, None, None], np.cos(q[:, j])[:, None, None]
        R[:, j] = R[:, par] @ (np.eye(3) + s * K + (1 - c) * (K @ K))
    return p[..., 2]


def ground_heights(skel: Skeleton, motion: Motion) -> np.ndarray:
    """(F, J) world heights of every node of ``motion`` [m] (numpy FK, float64)."""
    q = motion.node_angles(skel)
    return _fk_heights(skel, q, qmatrix(motion.base_quat)) + motion.base_pos[:, 2:3]


def _keys(postures: list[Posture], field: str) -> np.ndarray:
    """(K, 2) values of a paired posture field, NaN (free) filled from the nearest defined key."""
    v = np.array([getattr(p, field) for p in postures], float)
    for s in range(v.shape[1]):
        col = v[:, s]
        ok = np.flatnonzero(~np.isnan(col))
        if len(ok) == 0:
            col[:] = 0.0
            continue
        idx = np.arange(len(col))
        nearest = ok[np.abs(idx[:, None] - ok[None, :]).argmin(axis=1)]
        col[:] = col[nearest]
    return v


def _defined(postures: list[Posture], field: str) -> np.ndarray:
    return np.array([[0.0 if np.isnan(x) else 1.0 for x in getattr(p, field)] for p in postures])


def _orientation(postures: list[Posture], times: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(F, 4) posture orientation in the heading frame, slerped (eased) between the posture keys.

    Each key may be turned by a multiple of 90 degrees about the vertical (the heading is arbitrary)
    to the variant nearest the previous key, so no transition turns by more than needed.
    """
    keys = []
    for k, p in enumerate(postures):
        base = qmul(qaxis(1, p.beta), qaxis(2, p.gamma))
        if not keys:
            keys.append(base)
            continue
        cands = [qmul(qaxis(2, m * np.pi / 2 + rng.uniform(-0.3, 0.3)), base) for m in range(4)]
        keys.append(min(cands, key=lambda c: float(qangle(c, keys[-1]))))
    out = np.broadcast_to(keys[0], (len(t), 4)).copy()
    for k in range(1, len(keys)):
        a, b = times[k - 1, 1], times[k, 0]
        inside = (t > a) & (t < b)
        out[inside] = qslerp(keys[k - 1], keys[k], ease((t[inside] - a) / max(b - a, 1e-9)))
        out[t >= b] = keys[k] if np.dot(keys[k], out[inside][-1] if inside.any() else keys[k]) >= 0 else -keys[k]
    return qcontinuous(out)


def synthesize(skel: Skeleton, seconds: float = 20.0, fps: float = 30.0, seed: int | list[int] = 0) -> SyntheticClip:
    """One synthetic clip of ``skel``: ``round(seconds * fps) + 1`` frames at ``fps`` [Hz].

    ``seed`` is anything :func:`numpy.random.default_rng` takes (see :func:`clip_seed`).
    """
    if not (seconds > 0 and fps > 0):
        raise ValueError(f"seconds and fps must be positive, got {seconds} and {fps}")
    rng = np.random.default_rng(seed)
    body = body_of(skel)
    F = int(round(seconds * fps)) + 1
    t = np.arange(F) / fps
    J = skel.num_nodes
    lo, hi, nom = skel.lower, skel.upper, skel.nominal
    span = np.maximum(hi - lo, 0.0)

    # --- clip style --------------------------------------------------------------------------
    lying = rng.uniform(0.0, 0.7)
    stand_w = float(np.exp(rng.uniform(np.log(0.3), np.log(5.0))))
    vmax = body.leg_length * float(np.exp(rng.uniform(np.log(0.3), np.log(6.5))))  # m/s
    turn = rng.uniform(0.0, 2.5) * (rng.random() < 0.8)  # rad/s
    sideways = rng.uniform(0.0, np.pi) * (rng.random() < 0.4)
    arm_swing = rng.uniform(0.0, 1.0)
    jump_rate = rng.uniform(0.0, 0.5) * (rng.random() < 0.5)  # jumps/s while standing

    postures, times = posture_chain(rng, seconds, lying=lying, stand=stand_w)
    blend = lambda v: hold_and_blend(t, times, v)  # noqa: E731
    scal = lambda f: blend(np.array([getattr(p, f) for p in postures], float))  # noqa: E731
    beta, mobility, gait_w, jump_ok = scal("beta"), scal("mobility"), scal("gait"), scal("jump")
    leg_free = blend(np.array([p.leg_free for p in postures], float))  # (F, 2)
    flat = blend(np.array([p.flat for p in postures], float))
    targets = {f: blend(_keys(postures, f)) for f in ("hip", "knee", "ankle", "shoulder", "elbow")}
    weights = {f: blend(_defined(postures, f)) for f in ("hip", "knee", "ankle", "shoulder", "elbow")}

    # --- travel, heading, gait ----------------------------------------------------------------
    slow = smooth_noise(rng, t, 4, f_lo=0.04, f_hi=0.4, components=4, slope=1.0)
    speed = vmax * mobility * 0.5 * (1 + np.tanh(3 * slow[:, 0] + rng.uniform(-1, 1.5)))
    heading = rng.uniform(-np.pi, np.pi) + np.cumsum(turn * 2 * slow[:, 1]) / fps
    course = heading + sideways * 2 * slow[:, 2]
    vel = speed[:, None] * np.stack([np.cos(course), np.sin(course)], -1)
    xy = rng.uniform(-3, 3, 2) + np.concatenate([[[0.0, 0.0]], np.cumsum((vel[1:] + vel[:-1]) / 2, 0) / fps])
    nu = speed / body.leg_length  # leg lengths per second
    phase = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(0.55 + 0.2 * np.minimum(nu, 6.0)) / fps
    amp = np.minimum(0.9, 0.12 + 0.13 * nu) * gait_w * np.minimum(1.0, nu / 0.3)

    # --- jumps ---------------------------------------------------------------------------------
    flight = np.zeros(F)
    tuck = np.zeros(F)
    jumps = 0
    for _ in range(rng.poisson(jump_rate * seconds)):
        h = body.leg_length * rng.uniform(0.08, 0.45)
        dur = 2 * np.sqrt(2 * h / 9.81) * rng.uniform(1.0, 1.4) + 0.1
        t0 = rng.uniform(0, max(seconds - dur, 1e-3))
        span_t = (t >= t0) & (t <= t0 + dur)
        if span_t.any() and jump_ok[span_t].min() > 0.999 and flight[span_t].max() == 0:
            b = bump(t, t0, dur)
            flight += h * b
            tuck += rng.uniform(0.2, 1.2) * b
            jumps += 1

    # --- free joint motion, per group ------------------------------------------------------------
    act = 0.1 + 0.9 * (0.5 + 0.5 * np.tanh(2.5 * smooth_noise(rng, t, len(GROUPS), f_lo=0.03, f_hi=0.2, components=3, slope=1.0)))
    act = act * rng.uniform(0.2, 1.0, len(GROUPS))
    centre = lo + span * rng.uniform(0, 1, J)
    A = span * rng.uniform(0.25, 0.75, J)  # wide, slow swings: their speed stays below JOINT_SPEED
    f_hi = np.clip(JOINT_SPEED / (2 * np.pi * np.maximum(A, 1e-6)), 0.1, 0.6)
    wide = smooth_noise(rng, t, J, f_lo=f_hi / 3, f_hi=f_hi, components=2, slope=1.0)
    fine = smooth_noise(rng, t, J, f_lo=0.6, f_hi=3.0, components=4, slope=1.0)
    dev = (centre - nom)[None] + 2 * A[None] * wide + rng.uniform(0.05, 1.2, J)[None] * fine  # (F, J) rad
    activity = np.zeros((F, J))
    for g, name in enumerate(GROUPS):
        for j in body.members(name):
            if name.endswith("_leg"):
                activity[:, j] = leg_free[:, SIDES.index(name.split("_")[0])]
            elif name.endswith("_arm"):
                side = SIDES.index(name.split("_")[0])
                activity[:, j] = act[:, g] * (1 - 0.85 * weights["shoulder"][:, side])
            else:
                activity[:, j] = act[:, g]
    q = nom[None] + activity * dev

    # --- pitch roles: posture + gait, then the feet levelled ------------------------------------------
    sway = 0.05 * smooth_noise(rng, t, 3, f_lo=0.2, f_hi=2.0, components=4) * rng.uniform(0, 2, 3)
    sway[:, 2] = 0.0
    clamp = lambda j, x: soft_clamp(x, lo[j], hi[j], body.margin[j])  # noqa: E731
    done = np.zeros(J, bool)
    for s, side in enumerate(SIDES):
        g = phase + s * np.pi
        extra = {
            "hip": amp * np.sin(g) * 0.8,
            "knee": amp * 1.4 * ((1 + np.sin(g + np.pi / 2)) / 2) ** 2 + tuck,
            "shoulder": -arm_swing * amp * np.sin(g) * (1 - weights["shoulder"][:, s]),
            "elbow": arm_swing * amp * 0.5 * (1 + np.sin(g)),
        }
        for role in ("hip", "knee", "shoulder", "elbow"):
            j = getattr(body, role)[side]
            if j < 0:
                continue
            w = weights[role][:, s]
            posed = body.sign[j] * (targets[role][:, s] + extra[role])
            q[:, j] = clamp(j, q[:, j] + w * (posed - nom[j]) + (1 - w) * body.sign[j] * extra[role] * (role == "shoulder"))
            done[j] = True  # soft_clamp is not idempotent: every joint is clamped exactly once
        j = body.ankle[side]
        if j >= 0:
            r_h = body.sign[body.hip[side]] * q[:, body.hip[side]] if body.hip[side] >= 0 else 0.0
            r_k = body.sign[body.knee[side]] * q[:, body.knee[side]] if body.knee[side] >= 0 else 0.0
            level = -(beta + sway[:, 1] + r_h + r_k)
            free_r = targets["ankle"][:, s]
            f = flat[:, s]
            q[:, j] = q[:, j] + body.sign[j] * (f * level + (1 - f) * free_r) * (1 - 0.5 * leg_free[:, s])
    for j in body.dof[~done[body.dof]]:
        q[:, j] = clamp(j, q[:, j])
    q[:, ~skel.dof_mask] = 0.0

    # --- base orientation and height ------------------------------------------------------------
    post = _orientation(postures, times, t, rng)
    quat = qcontinuous(qmul(qmul(qaxis(2, heading), post), qrotvec(sway)))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    heights = _fk_heights(skel, q, qmatrix(quat))
    z = -heights.min(axis=1) + flight
    motion = Motion(
        robot=skel.name, fps=float(fps), base_pos=np.column_stack([xy, z]), base_quat=quat,
        joints=np.ascontiguousarray(q[:, body.dof]), columns=skel.joint_names,
    )  # fmt: skip
    return SyntheticClip(motion, tuple(p.kind for p in postures), jumps, flight)
