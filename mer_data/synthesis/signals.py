"""Smooth scalar signals for synthetic motion: multi-scale noise, C3 easing, C3 saturation.

All functions are pure numpy and deterministic given their generator (same seed, same bytes).
Time ``t`` is in seconds; angles in radians.
"""

from __future__ import annotations

import numpy as np

__all__ = ["smooth_noise", "ease", "soft_clamp", "bump", "plateau", "transition", "hold_and_blend"]


def smooth_noise(
    rng: np.random.Generator,
    t: np.ndarray,
    n: int,
    *,
    f_lo: float | np.ndarray = 0.2,
    f_hi: float | np.ndarray = 3.0,
    components: int = 6,
    slope: float = 1.5,
) -> np.ndarray:
    """(F, n) sums of ``components`` sinusoids per channel, one per time scale.

    The band [f_lo, f_hi] Hz is cut into ``components`` equal log-width sub-bands and each channel
    draws one frequency log-uniformly in each, so every channel moves on every time scale.
    Amplitudes fall as ``f**-slope`` (low frequencies dominate, as in human motion); each channel is
    scaled so its peak magnitude bound is 1 (the sum of its amplitudes): values stay in [-1, 1] and
    are typically within +-0.5. C-infinity. ``f_lo``, ``f_hi`` may be (n,) arrays: a band per channel.
    """
    lo = np.broadcast_to(np.log(f_lo), (n,))[:, None]
    hi = np.broadcast_to(np.log(f_hi), (n,))[:, None]
    edges = lo + (hi - lo) * np.linspace(0.0, 1.0, components + 1)[None]  # (n, C + 1)
    f = np.exp(rng.uniform(edges[:, :-1], edges[:, 1:]))
    a = f ** (-slope) * rng.uniform(0.5, 1.0, size=(n, components))
    a /= a.sum(axis=1, keepdims=True)
    phase = rng.uniform(0.0, 2 * np.pi, size=(n, components))
    arg = 2 * np.pi * t[:, None, None] * f[None] + phase[None]  # (F, n, C)
    return np.einsum("fnc,nc->fn", np.sin(arg), a)


def ease(s: np.ndarray) -> np.ndarray:
    """Septic smoothstep on [0, 1]: 0 -> 1 with zero velocity, acceleration and jerk at both ends (C3)."""
    s = np.clip(s, 0.0, 1.0)
    return s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)


def _saturate(u: np.ndarray) -> np.ndarray:
    """h(u) = u - 2.5 u^4 + 3 u^5 - u^6 on [0, 1], 1/2 beyond: h' = 1 - smoothstep5, so C3 at both ends."""
    v = np.clip(u, 0.0, 1.0)
    return np.where(u >= 1.0, 0.5, v - 2.5 * v**4 + 3.0 * v**5 - v**6)


def soft_clamp(x: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float, margin: np.ndarray | float) -> np.ndarray:
    """Map ``x`` into [lo, hi] smoothly (C3), never beyond.

    Identity inside ``[lo + margin, hi - margin]``; within ``2 * margin`` beyond those points it bends
    monotonically onto the limit, reaching it with zero slope, curvature and third derivative; past
    that it stays at the limit. ``margin`` must not exceed ``(hi - lo) / 2``.
    """
    lo, hi, m = np.asarray(lo, float), np.asarray(hi, float), np.maximum(np.asarray(margin, float), 1e-12)
    a, b = lo + m, hi - m
    up = b + 2 * m * _saturate((x - b) / (2 * m))
    down = a - 2 * m * _saturate((a - x) / (2 * m))
    y = np.where(x > b, up, np.where(x < a, down, x))
    return np.clip(y, lo, hi)  # rounding only: y is mathematically inside already


def bump(t: np.ndarray, t0: float, duration: float) -> np.ndarray:
    """sin^4 pulse: 0 outside [t0, t0 + duration], 1 at its middle; C3 everywhere."""
    s = (t - t0) / duration
    inside = (s > 0) & (s < 1)
    return np.where(inside, np.sin(np.pi * np.clip(s, 0, 1)) ** 4, 0.0)


def plateau(t: np.ndarray, t0: float, rise: float, hold: float, fall: float) -> np.ndarray:
    """0 before ``t0``, eased up to 1 over ``rise`` [s], 1 for ``hold`` [s], eased down over ``fall``; C3."""
    return ease((t - t0) / rise) - ease((t - t0 - rise - hold) / fall)


def transition(s: np.ndarray, warp: float = 1.0) -> np.ndarray:
    """Eased 0 -> 1 over s in [0, 1]: :func:`ease` of ``s ** warp``.

    ``warp`` = 1 is symmetric; ``warp`` > 1 starts slowly and ends fast, like a body toppling
    over (a fall): the speed peaks late (at s = 0.73 for warp 2) and stops abruptly. Still C3
    at both ends (``s ** warp`` is smooth on (0, 1] and ``ease`` is flat to third order there).
    """
    return ease(np.clip(s, 0.0, 1.0) ** warp)


def hold_and_blend(t: np.ndarray, times: np.ndarray, values: np.ndarray, warp: np.ndarray | None = None) -> np.ndarray:
    """Piecewise hold/transition curve: key ``k`` holds ``values[k]`` from ``times[k, 1]`` ... until the
    transition to key ``k + 1`` over ``[times[k, 1], times[k + 1, 0]]`` eased with :func:`transition`.

    Args:
        times: (K, 2) per key, [start of its hold, end of its hold] [s], increasing.
        values: (K, ...) key values.
        warp: (K,) the :func:`transition` warp into each key (1: plain ease; default all 1).
    Returns:
        (F, ...) the curve (C3: velocity, acceleration and jerk vanish at every key boundary).
    """
    out = np.broadcast_to(values[0], (len(t),) + values.shape[1:]).copy()
    for k in range(1, len(times)):
        s = (t - times[k - 1, 1]) / max(times[k, 0] - times[k - 1, 1], 1e-9)
        w = transition(s, 1.0 if warp is None else float(warp[k]))
        w = w.reshape((-1,) + (1,) * (values.ndim - 1))
        out = out + w * (values[k] - values[k - 1])
    return out
