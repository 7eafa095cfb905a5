"""Whole-body postures and the seeded chain of postures a synthetic clip moves through.

A posture is a base orientation in the heading frame (pitch ``beta`` forward, then a roll ``gamma``
about the body's long axis: lying on the back is ``beta = -pi/2``, on the side ``gamma = +-pi/2``,
face down ``gamma = pi``), pitch-joint targets ``r`` (rotation about the root's +y, see
:mod:`.body`) for hips, knees, ankles, shoulders and elbows (NaN: left to the free motion layer),
how flat the feet are kept (1: the ankle levels the sole), and how much the posture allows:
travelling (``mobility``), a gait, jumps, free leg motion.

The chain moves between postures along :data:`NEXT` with eased transitions, except for **falls**:
from an upright posture (:data:`FALL_FROM`) a clip may drop straight onto the back, side or front
in 0.9-1.5 s along a warped transition that starts slowly and ends fast
(:func:`.signals.transition`), then gets up again through the intermediate postures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Posture", "POSTURES", "NEXT", "draw_posture", "posture_chain", "LYING", "FALL_FROM", "FALL_TO", "Chain"]

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
#: Postures a fall may start from, and where it may land (bent forward: not onto the back).
FALL_FROM = ("stand", "balance", "bend", "crouch", "kneel_one")
FALL_TO = LYING
_FALL_TO_BENT = ("side", "prone")
#: Fall transitions: duration [s] and the warp of :func:`.signals.transition` (slow start, fast end).
FALL_SECONDS = (0.9, 1.5)
FALL_WARP = (1.4, 2.1)


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
        return Posture(kind, beta, 0.0, pair(-beta - 0.2, -beta + 0.25), pair(0.0, 0.5), none, free, free, (1, 1), 0.25, 0.3, 0.0, (0.08, 0.08))  # fmt: skip
    if kind == "crouch":
        beta = u(0.15, 0.8)
        return Posture(kind, beta, 0.0, pair(-2.4, -1.1), pair(1.3, 3.0), none, free, free, (1, 1), 0.45, 0.5, 0.4, (0.08, 0.08))
    if kind == "kneel":
        beta = u(-0.1, 0.45)
        return Posture(kind, beta, 0.0, pair(-beta - 0.35, -beta + 0.3), pair(1.6, 3.0), pair(0.0, 0.7), free, free, (0, 0), 0.05, 0.0, 0.0, (0.1, 0.1))  # fmt: skip
    if kind == "kneel_one":
        beta, k = u(-0.05, 0.35), int(rng.integers(2))
        hip = [u(-beta - 0.3, -beta + 0.2), u(-1.9, -1.2)]
        knee = [u(1.4, 2.2), u(1.2, 2.0)]
        ankle = [u(0.0, 0.7), NAN]
        flat = [0, 1]
        if k:
            hip, knee, ankle, flat = hip[::-1], knee[::-1], ankle[::-1], flat[::-1]
        return Posture(kind, beta, 0.0, tuple(hip), tuple(knee), tuple(ankle), free, free, tuple(flat), 0.03, 0.0, 0.0, (0.08, 0.08))  # fmt: skip
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
        return Posture(kind, u(-0.7, 0.15), 0.0, pair(-1.9, -1.1), pair(0.0, 2.0), pair(-0.3, 0.6), free, free, (0, 0), 0.02, 0.0, 0.0, (0.25, 0.25))  # fmt: skip
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


@dataclass(frozen=True)
class Chain:
    """A clip's postures: ``times`` (K, 2) hold intervals [s] (transitions fill the gaps), ``warp``
    (K,) the transition warp into each key (1: eased, > 1: a fall) and ``falls`` (K,) bool."""

    postures: list[Posture]
    times: np.ndarray
    warp: np.ndarray
    falls: np.ndarray


def posture_chain(rng: np.random.Generator, seconds: float, *, lying: float, stand: float, fall: float = 0.0) -> Chain:
    """Postures and their hold times covering ``seconds``.

    Args:
        lying: how likely the clip starts on the ground; ``stand``: weight of standing, at the start and
            on return, and of getting up from lying (a locomotion clip stands most of the time, an acrobatic
            one seldom); ``fall``: chance
            that a posture of :data:`FALL_FROM` is left by a fall.
    """
    if rng.random() < lying:
        kind = str(rng.choice(["supine", "prone", "side", "sit", "all_fours", "kneel"]))
    else:
        options = ["stand", "crouch", "bend", "balance"]
        w = np.array([2 * stand, 1.0, 1.0, 1.0])
        kind = str(rng.choice(options, p=w / w.sum()))
    out, times, warp, falls, t = [], [], [1.0], [False], 0.0
    while True:
        hold = _u(rng, 1.5, 6.0) if kind == "stand" else _u(rng, 0.3, 3.0)
        out.append(draw_posture(kind, rng))
        times.append((t, t + hold))
        t += hold
        if t >= seconds:
            break
        if kind in FALL_FROM and rng.random() < fall:
            kind = str(rng.choice(_FALL_TO_BENT if kind == "bend" else FALL_TO))
            t += _u(rng, *FALL_SECONDS)
            warp.append(_u(rng, *FALL_WARP))
            falls.append(True)
            continue
        options = list(NEXT[kind])
        w = np.array([stand if o == "stand" or (kind in LYING and o not in LYING) else 1.0 for o in options])
        kind = str(rng.choice(options, p=w / w.sum()))
        slow = kind in LYING or out[-1].kind in LYING or "handstand" in (kind, out[-1].kind)
        t += _u(rng, 0.8, 2.2) if slow else _u(rng, 0.5, 1.6)
        warp.append(1.0)
        falls.append(False)
    return Chain(out, np.array(times), np.array(warp), np.array(falls, bool))
