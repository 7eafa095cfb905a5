"""Whole-body postures and the seeded chain of postures a synthetic clip moves through.

A posture is a base orientation in the heading frame (pitch ``beta`` forward, then a roll ``gamma``
about the body's long axis: lying on the back is ``beta = -pi/2``, on the side ``gamma = +-pi/2``,
face down ``gamma = pi``), pitch-joint targets ``r`` (rotation about the root's +y, see
:mod:`.body`) for hips, knees, ankles, shoulders and elbows (NaN: left to the free motion layer),
how flat the feet are kept (1: the ankle levels the sole), and how much the posture allows:
travelling (``mobility``), a gait, jumps, free leg motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Posture", "POSTURES", "NEXT", "draw_posture", "posture_chain", "LYING"]

NAN = float("nan")


@dataclass(frozen=True)
class Posture:
    """One drawn posture. Leg/arm fields are (left, right) pairs of ``r`` targets [rad]."""

    kind: str
    beta: float
    gamma: float
    hip: tuple[float, float]
    knee: tuple[float, float]
    ankle: tuple[float, float]  # relative ankle r where the foot is not kept flat
    shoulder: tuple[float, float]
    elbow: tuple[float, float]
    flat: tuple[float, float]  # 1: sole levelled on the ground, 0: ankle free
    mobility: float  # share of the clip's travel speed
    gait: float  # share of the gait amplitude
    jump: float  # 1 where jumps may start
    leg_free: tuple[float, float]  # amplitude of the free motion of each leg (share of its range)


#: Which postures may follow which (getting down and getting up pass through the intermediate ones).
NEXT: dict[str, tuple[str, ...]] = {
    "stand": ("stand", "stand", "bend", "crouch", "kneel_one", "balance", "sit"),
    "bend": ("stand", "crouch", "all_fours", "handstand"),
    "crouch": ("stand", "kneel", "kneel_one", "sit", "all_fours", "bend"),
    "kneel": ("kneel_one", "crouch", "all_fours", "sit"),
    "kneel_one": ("stand", "kneel", "crouch"),
    "balance": ("stand",),
    "sit": ("crouch", "supine", "kneel", "side"),
    "supine": ("side", "sit", "supine"),
    "side": ("supine", "prone", "sit"),
    "prone": ("side", "all_fours", "prone"),
    "all_fours": ("prone", "kneel", "crouch", "bend"),
    "handstand": ("bend", "all_fours"),
}
POSTURES = tuple(NEXT)
LYING = ("supine", "side", "prone")


def _u(rng: np.random.Generator, a: float, b: float) -> float:
    return float(rng.uniform(a, b))


def draw_posture(kind: str, rng: np.random.Generator) -> Posture:
    """A posture of ``kind`` with its parameters drawn from ``rng``."""
    u = lambda a, b: _u(rng, a, b)  # noqa: E731
    pair = lambda a, b, spread=0.15: (u(a, b), u(a, b)) if rng.random() < 0.5 else ((v := u(a, b)), v + u(-spread, spread))  # noqa: E731
    free, none = (NAN, NAN), (NAN, NAN)
    if kind == "stand":
        beta = u(-0.12, 0.2)
        return Posture(kind, beta, 0.0, pair(-0.25, 0.1), pair(0.0, 0.35), none, free, free, (1, 1), 1.0, 1.0, 1.0, (0.12, 0.12))
    if kind == "bend":
        beta = u(0.5, 1.4)
        return Posture(kind, beta, 0.0, pair(-beta - 0.2, -beta + 0.25), pair(0.0, 0.5), none, free, free, (1, 1), 0.25, 0.3, 0.0, (0.08, 0.08))
    if kind == "crouch":
        beta = u(0.15, 0.8)
        return Posture(kind, beta, 0.0, pair(-2.4, -1.1), pair(1.3, 3.0), none, free, free, (1, 1), 0.45, 0.5, 0.4, (0.08, 0.08))
    if kind == "kneel":
        beta = u(-0.1, 0.45)
        return Posture(kind, beta, 0.0, pair(-beta - 0.35, -beta + 0.3), pair(1.6, 3.0), pair(0.0, 0.7), free, free, (0, 0), 0.05, 0.0, 0.0, (0.1, 0.1))
    if kind == "kneel_one":
        beta, k = u(-0.05, 0.35), int(rng.integers(2))
        hip = [u(-beta - 0.3, -beta + 0.2), u(-1.9, -1.2)]
        knee = [u(1.4, 2.2), u(1.2, 2.0)]
        ankle = [u(0.0, 0.7), NAN]
        flat = [0, 1]
        if k:
            hip, knee, ankle, flat = hip[::-1], knee[::-1], ankle[::-1], flat[::-1]
        return Posture(kind, beta, 0.0, tuple(hip), tuple(knee), tuple(ankle), free, free, tuple(flat), 0.03, 0.0, 0.0, (0.08, 0.08))
    if kind == "balance":  # one leg lifted and free: kicks, steps, one-leg stands
        k = int(rng.integers(2))
        lf = [0.1, 0.1]
        lf[k] = u(0.5, 1.0)
        hip, knee = [u(-0.2, 0.1), u(-0.2, 0.1)], [u(0.0, 0.3), u(0.0, 0.3)]
        hip[k], knee[k] = u(-2.2, 0.4), u(0.0, 2.0)
        flat = [1, 1]
        flat[k] = 0
        return Posture(kind, u(-0.15, 0.3), 0.0, tuple(hip), tuple(knee), none, free, free, tuple(flat), 0.2, 0.0, 0.0, tuple(lf))
    if kind == "sit":
        return Posture(kind, u(-0.7, 0.15), 0.0, pair(-1.9, -1.1), pair(0.0, 2.0), pair(-0.3, 0.6), free, free, (0, 0), 0.02, 0.0, 0.0, (0.25, 0.25))
    if kind in LYING:
        gamma = {"supine": 0.0, "prone": np.pi, "side": float(rng.choice([-0.5, 0.5])) * np.pi}[kind]
        return Posture(kind, -np.pi / 2 + u(-0.15, 0.15), gamma + u(-0.2, 0.2), pair(-0.7, 0.2), pair(0.0, 1.2),
                       pair(-0.3, 0.8), free, free, (0, 0), 0.02, 0.0, 0.0, (u(0.3, 1.0), u(0.3, 1.0)))  # fmt: skip
    if kind == "all_fours":
        beta = u(1.25, 1.75)
        return Posture(kind, beta, 0.0, pair(-beta - 0.25, -beta + 0.25), pair(1.3, 1.9), pair(0.0, 0.7),
                       pair(-beta - 0.25, -beta + 0.25), pair(0.0, 0.4), (0, 0), 0.25, 0.6, 0.0, (0.1, 0.1))  # fmt: skip
    if kind == "handstand":
        return Posture(kind, np.pi + u(-0.2, 0.2), 0.0, pair(-0.4, 0.4), pair(0.0, 0.6), pair(-0.3, 0.7),
                       (-np.pi, -np.pi), (0.0, 0.0), (0, 0), 0.0, 0.0, 0.0, (0.3, 0.3))  # fmt: skip
    raise ValueError(f"unknown posture {kind!r} (known: {', '.join(POSTURES)})")


def posture_chain(rng: np.random.Generator, seconds: float, *, lying: float, stand: float) -> tuple[list[Posture], np.ndarray]:
    """Postures and their (start, end) hold times [s] covering ``seconds``.

    Args:
        lying: how likely the clip starts on the ground; ``stand``: weight of returning to standing
            (a locomotion clip stands most of the time, an acrobatic one seldom).
    Returns:
        the postures and a (K, 2) array of hold intervals; transitions fill the gaps between them.
    """
    if rng.random() < lying:
        kind = str(rng.choice(["supine", "prone", "side", "sit", "all_fours", "kneel"]))
    else:
        kind = str(rng.choice(["stand", "stand", "crouch", "bend", "balance"]))
    out, times, t = [], [], 0.0
    while True:
        hold = _u(rng, 1.5, 6.0) if kind == "stand" else _u(rng, 0.3, 3.0)
        out.append(draw_posture(kind, rng))
        times.append((t, t + hold))
        t += hold
        if t >= seconds:
            break
        options = list(NEXT[kind])
        w = np.array([stand if o == "stand" else 1.0 for o in options])
        kind = str(rng.choice(options, p=w / w.sum()))
        slow = kind in LYING or out[-1].kind in LYING or "handstand" in (kind, out[-1].kind)
        t += _u(rng, 0.8, 2.2) if slow else _u(rng, 0.5, 1.6)
    return out, np.array(times)
