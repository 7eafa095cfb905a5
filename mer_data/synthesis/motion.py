"""Synthetic whole-body motion of any robot, from its skeleton alone (no motion data needed).

A clip mixes behaviours drawn by a seeded generator:

* **postures** (:mod:`.postures`): standing, bending, crouching, kneeling on one or both knees,
  balancing on one leg, sitting, lying on the back, side or front, on all fours, handstands, with
  eased (C3) transitions between them: lying down and getting up pass through the intermediate ones;
* **falls**: from standing, one leg, bending, crouching or kneeling on one knee straight onto the
  back, side or front in 0.9-1.5 s, accelerating like a body toppling over and stopping abruptly
  (still C3), the base carried over the feet as it tips, the arms reaching out; getting up follows
  through the intermediate postures;
* **free joint motion** per group (left/right arm, left/right leg, torso), independent: each joint
  swings about a drawn centre anywhere in its range with multi-scale noise (0.2-3 Hz), scaled by a
  slowly varying activity per group (and, for the legs, by how much the posture frees them);
* **gait**: hip/knee cycles whose frequency and amplitude follow the travel speed, arms swinging
  with the legs (and moving less on their own the faster the travel);
* **travel**: a cruising speed profile (standing still to running, up to 0.4-4.5 leg lengths per
  second) with sprints (eased up to 6.5-10 leg lengths per second, held, eased down), scaled by
  the posture's mobility, in any direction relative to the body, with yaw turning, a forward lean
  with speed and acceleration and a small wander of the base;
* **jumps**: eased flights (sin^4 height pulses, knees tucked) from standing postures.

Clips are of two families: locomotion (85 %: start and mostly stay upright, half of them with
sprints, rare falls) and floor work (15 %: may start on the ground, get up less readily, fall
often), so the set covers lying, falling and getting up while most frames stay upright, as in
human motion capture. Speeds are in leg lengths per second, so a small robot moves as fast for its
size, not in m/s: G1 (leg length 0.66 m) sprints at up to 6.6 m/s, TRON1 (0.58 m) at 5.8 m/s.

Every joint passes through :func:`.signals.soft_clamp` (never past a limit, C3); the base height
puts the lowest node on the ground (z = 0) in every frame except during jumps. The result is a
:class:`~mer_data.motion.lafan1.Motion` with one column per actuated joint (``skel.joint_names``), so it
works for every robot, with or without a LAFAN1 column layout. Same seed, same bytes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from mer_data.motion.lafan1 import Motion
from mer_data.skeleton import Skeleton

from .body import GROUPS, SIDES, Body, body_of
from .postures import Chain, Posture, posture_chain
from .quat import qangle, qaxis, qcontinuous, qmatrix, qmul, qrotvec, qslerp
from .signals import bump, hold_and_blend, plateau, smooth_noise, soft_clamp, transition

__all__ = ["SyntheticClip", "synthesize", "clip_seed", "ground_heights", "SYNTHESIS_VERSION"]

#: Bumped whenever the same seed would give different motion.
SYNTHESIS_VERSION = 2
#: Typical peak speed of the wide free joint swings [rad/s] (their frequency is chosen from it).
JOINT_SPEED = 5.0
#: Share of floor-work clips (the rest are locomotion clips).
FLOOR_SHARE = 0.15
#: Range of a clip's top cruising speed and of a sprint's peak speed [leg lengths per second].
CRUISE_NU = (0.4, 4.5)
SPRINT_NU = (6.5, 10.0)


@dataclass(frozen=True)
class SyntheticClip:
    """A generated clip: the motion and what it contains (for reports and tests)."""

    motion: Motion
    postures: tuple[str, ...]
    jumps: int
    flight: np.ndarray  # (F,) height of the base above its grounded height [m] (jumps)
    falls: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (n, 2) start, end of each fall [s]
    sprints: int = 0


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


def _orientation(chain: Chain, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(F, 4) posture orientation in the heading frame, slerped (eased) between the posture keys.

    Each key may be turned by a multiple of 90 degrees about the vertical (the heading is arbitrary)
    to the variant nearest the previous key, so no transition turns by more than needed.
    """
    postures, times = chain.postures, chain.times
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
        out[inside] = qslerp(keys[k - 1], keys[k], transition((t[inside] - a) / max(b - a, 1e-9), chain.warp[k]))
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

    # --- clip style ----------------------------------------------------------------------------
    floor = rng.random() < FLOOR_SHARE
    lying = rng.uniform(0.0, 0.6) if floor else 0.0
    stand_w = float(np.exp(rng.uniform(np.log(0.5), np.log(6.0)) if floor else rng.uniform(np.log(2.0), np.log(12.0))))
    fall_p = rng.uniform(0.1, 0.5) if floor else rng.uniform(0.0, 0.06)
    nu_top = float(np.exp(rng.uniform(*np.log(CRUISE_NU))))  # leg lengths per second
    sprint_rate = 0.0 if floor or rng.random() < 0.5 else rng.uniform(0.02, 0.05)  # sprints/s
    turn = rng.uniform(0.0, 2.5) * (rng.random() < 0.8)  # rad/s
    sideways = rng.uniform(0.0, np.pi) * (rng.random() < 0.4)
    arm_swing = rng.uniform(0.0, 1.0)
    jump_rate = rng.uniform(0.0, 0.5) * (rng.random() < 0.5)  # jumps/s while standing

    chain = posture_chain(rng, seconds, lying=lying, stand=stand_w, fall=fall_p)
    postures, times = chain.postures, chain.times
    blend = lambda v: hold_and_blend(t, times, v, np.sqrt(chain.warp))  # noqa: E731  (joints topple less abruptly than the body)
    scal = lambda f: blend(np.array([getattr(p, f) for p in postures], float))  # noqa: E731
    beta, mobility, gait_w, jump_ok = scal("beta"), scal("mobility"), scal("gait"), scal("jump")
    leg_free = blend(np.array([p.leg_free for p in postures], float))  # (F, 2)
    flat = blend(np.array([p.flat for p in postures], float))
    targets = {f: blend(_keys(postures, f)) for f in ("hip", "knee", "ankle", "shoulder", "elbow")}
    weights = {f: blend(_defined(postures, f)) for f in ("hip", "knee", "ankle", "shoulder", "elbow")}

    # --- travel, heading, gait ----------------------------------------------------------------
    slow = smooth_noise(rng, t, 4, f_lo=0.04, f_hi=0.4, components=4, slope=1.0)
    cruise = nu_top * 0.5 * (1 + np.tanh(2 * slow[:, 0] + rng.uniform(-0.5, 1.5)))
    sprint, sprints = _sprints(rng, t, seconds, sprint_rate)
    nu = mobility * (cruise * (1 - sprint[0]) + sprint[1])  # leg lengths per second
    speed = body.leg_length * nu  # m/s
    heading = rng.uniform(-np.pi, np.pi) + np.cumsum(turn * 2 * slow[:, 1]) / fps
    course = heading + sideways * 2 * slow[:, 2]
    vel = speed[:, None] * np.stack([np.cos(course), np.sin(course)], -1)
    wander = body.leg_length * rng.uniform(0.01, 0.05) * (rng.random() < 0.7)  # [m]; none in 30 % of clips
    wander = wander * smooth_noise(rng, t, 2, f_lo=0.2, f_hi=1.5, components=3)  # (F, 2) the base shifting its weight
    xy = rng.uniform(-3, 3, 2) + wander + np.concatenate([[[0.0, 0.0]], np.cumsum((vel[1:] + vel[:-1]) / 2, 0) / fps])
    phase = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.cumsum(0.55 + 0.2 * np.minimum(nu, 6.0)) / fps
    amp = np.minimum(0.9, 0.12 + 0.13 * nu) * gait_w * np.minimum(1.0, nu / 0.3)
    rel = course - heading  # travel direction in the heading frame
    accel = np.gradient(speed) * fps
    lean_v = 0.02 * nu  # rad: leaning into the travel, more the faster
    lean = lean_v + 0.25 * np.tanh(accel / (0.25 * 9.81))  # and into an acceleration (about a / g, below 0.25)
    lean_rv = lean[:, None] * np.stack([-np.sin(rel), np.cos(rel), np.zeros(F)], -1)  # heading frame

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
            elif name.endswith("_arm"):  # the faster the travel, the more the arms follow the gait alone
                side = SIDES.index(name.split("_")[0])
                activity[:, j] = act[:, g] * (1 - 0.85 * weights["shoulder"][:, side]) * (1 - 0.6 * np.tanh(nu / 3))
            else:
                activity[:, j] = act[:, g]
    q = nom[None] + activity * dev

    # --- pitch roles: posture + gait, then the feet levelled ------------------------------------------
    sway = 0.05 * smooth_noise(rng, t, 3, f_lo=0.2, f_hi=2.0, components=4) * rng.uniform(0, 2, 3)
    sway[:, 2] = 0.0
    brace = _brace(rng, t, chain)  # (F,) r added to both shoulders: the arms reach out in a fall
    clamp = lambda j, x: soft_clamp(x, lo[j], hi[j], body.margin[j])  # noqa: E731
    done = np.zeros(J, bool)
    for s, side in enumerate(SIDES):
        g = phase + s * np.pi
        extra = {
            "hip": amp * np.sin(g) * 0.8,
            "knee": amp * 1.4 * ((1 + np.sin(g + np.pi / 2)) / 2) ** 2 + tuck,
            "shoulder": -arm_swing * amp * np.sin(g) * (1 - weights["shoulder"][:, s]) + brace,
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
            level = -(beta + sway[:, 1] + lean_v * np.cos(rel) + r_h + r_k)
            free_r = targets["ankle"][:, s]
            f = flat[:, s]
            q[:, j] = q[:, j] + body.sign[j] * (f * level + (1 - f) * free_r) * (1 - 0.5 * leg_free[:, s])
    for j in body.dof[~done[body.dof]]:
        q[:, j] = clamp(j, q[:, j])
    q[:, ~skel.dof_mask] = 0.0

    # --- base orientation and height ------------------------------------------------------------
    post = _orientation(chain, t, rng)
    xy = xy + _fall_shift(rng, t, chain, post, heading, body)
    quat = qcontinuous(qmul(qmul(qmul(qaxis(2, heading), qrotvec(lean_rv)), post), qrotvec(sway)))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    heights = _fk_heights(skel, q, qmatrix(quat))
    z = -heights.min(axis=1) + flight
    motion = Motion(
        robot=skel.name, fps=float(fps), base_pos=np.column_stack([xy, z]), base_quat=quat,
        joints=np.ascontiguousarray(q[:, body.dof]), columns=skel.joint_names,
    )  # fmt: skip
    falls = np.array([(a, b) for a, b, _ in _fall_intervals(chain)]).reshape(-1, 2)
    return SyntheticClip(motion, tuple(p.kind for p in postures), jumps, flight, falls, sprints)


def _sprints(rng: np.random.Generator, t: np.ndarray, seconds: float, rate: float) -> tuple[np.ndarray, int]:
    """Sprints at ``rate`` per second: (2, F) [envelope in [0, 1], envelope * peak speed [leg lengths/s]]
    and their number. Each eases up over 1-2.5 s, holds 0.5-2.5 s, eases down over 1-2.5 s; none overlap."""
    out = np.zeros((2, len(t)))
    n = 0
    for _ in range(rng.poisson(rate * seconds)):
        rise, hold, down = rng.uniform(1.0, 2.5), rng.uniform(0.5, 2.5), rng.uniform(1.0, 2.5)
        t0 = rng.uniform(-rise, max(seconds - rise - hold, 0.0))
        e = plateau(t, t0, rise, hold, down)
        peak = rng.uniform(*SPRINT_NU)
        if (out[0] * e).max() == 0.0:
            out += np.stack([e, peak * e])
            n += 1
    return out, n


def _fall_intervals(chain: Chain) -> list[tuple[float, float, float]]:
    """(start, end, end of the hold after it) [s] of every fall."""
    return [(chain.times[k - 1, 1], chain.times[k, 0], chain.times[k, 1]) for k in np.flatnonzero(chain.falls)]


def _brace(rng: np.random.Generator, t: np.ndarray, chain: Chain) -> np.ndarray:
    """(F,) shoulder ``r`` of the arms reaching out during each fall (forward: negative), sin^4 pulses."""
    out = np.zeros(len(t))
    for a, b, _ in _fall_intervals(chain):
        out -= rng.uniform(0.5, 1.4) * bump(t, a + 0.3 * (b - a), 1.2 * (b - a))
    return out


def _fall_shift(
    rng: np.random.Generator, t: np.ndarray, chain: Chain, post: np.ndarray, heading: np.ndarray, body: Body
) -> np.ndarray:
    """(F, 2) base displacement of the falls [m]: the base tips over the feet with the body.

    During a fall from ``a`` to ``b`` the base moves by ``c * leg_length`` times the change of the
    horizontal part of its z axis (``c`` in [0.4, 0.9]: the knees give way too), held afterwards;
    C3 like the posture orientation it follows (which holds still before and after the fall).
    """
    out = np.zeros((len(t), 2))
    up = qmatrix(post)[:, :2, 2]  # (F, 2) horizontal part of the base's z axis, heading frame
    last = len(t) - 1
    for a, b, held in _fall_intervals(chain):
        i0, mid = min(np.searchsorted(t, a), last), min(np.searchsorted(t, (a + b) / 2), last)
        d = (up - up[i0]) * (t >= a)[:, None]
        d[t > held] = d[t <= held][-1]
        c, h = np.cos(heading[mid]), np.sin(heading[mid])
        out += rng.uniform(0.4, 0.9) * body.leg_length * d @ np.array([[c, h], [-h, c]])
    return out
