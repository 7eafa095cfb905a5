"""The base states of synthetic motion (issue 42): lying, the floor, sprints, falls and getting up.

Fast and always run (no LAFAN1): a modest set of clips per robot must reach them, inside the limits.
"""

from __future__ import annotations

import numpy as np
import pytest

from mer_data.robots.registry import get_skeleton
from mer_data.synthesis import body_of, clip_seed, ground_heights, synthesize
from mer_data.synthesis.motion import SPRINT_NU
from mer_data.synthesis.quat import qmatrix
from mer_data.synthesis.signals import transition

CLIPS = 30  # of 20 s: 18,030 frames per robot, about half a second to generate


def _tilt(quat: np.ndarray) -> np.ndarray:
    """(F,) angle between the base's z axis and the world's [rad]."""
    return np.arccos(np.clip(qmatrix(quat)[:, 2, 2], -1.0, 1.0))


def _clips(robot: str):
    skel = get_skeleton(robot)
    return skel, [synthesize(skel, 20.0, 30.0, clip_seed(0, robot, i)) for i in range(CLIPS)]


@pytest.mark.parametrize("robot", ["g1", "h1"])
def test_lying_the_floor_and_every_limit(robot):
    skel, clips = _clips(robot)
    standing = -skel.rest_positions[:, 2].min()  # base height of the zero pose [m]
    tilt = np.concatenate([_tilt(c.motion.base_quat) for c in clips])
    z = np.concatenate([c.motion.base_pos[:, 2] for c in clips])
    assert tilt.max() >= 1.6, f"no frame lies down: max tilt {tilt.max():.2f} rad"
    assert z.min() < 0.05 * standing, f"the base never comes down to the floor: {z.min():.3f} m"
    assert 0.6 < np.mean(tilt < 0.5) < 0.95, "most frames upright, not all"  # LAFAN1: 90 % (G1), 78 % (H1)
    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    for c in clips:
        m = c.motion
        assert np.all(m.joints >= lo) and np.all(m.joints <= hi), "a joint left its limits"
        lowest = ground_heights(skel, m).min(axis=1)
        assert np.abs(lowest[c.flight == 0]).max() < 1e-9, "the lowest node must touch the ground outside jumps"


def test_g1_sprints_past_5_m_per_s_and_small_robots_scale_by_leg_length():
    skel, clips = _clips("g1")
    vxy = [np.linalg.norm(np.diff(c.motion.base_pos[:, :2], axis=0), axis=1) * 30 for c in clips]  # m/s
    assert max(v.max() for v in vxy) >= 5.0
    assert sum(c.sprints for c in clips) >= 3
    assert np.median(np.concatenate(vxy)) < 1.0, "sprints are bursts, not the bulk"
    tron1, small = _clips("tron1")  # speeds are in leg lengths per second: a shorter leg, a lower top speed
    top = max((np.linalg.norm(np.diff(c.motion.base_pos[:, :2], axis=0), axis=1) * 30).max() for c in small)
    assert top <= SPRINT_NU[1] * body_of(tron1).leg_length + 0.3  # + the base's wander and a fall's tip-over


@pytest.mark.parametrize("robot", ["g1", "tron1"])
def test_falls_are_fast_and_followed_by_getting_up(robot):
    """A fall: within 1.5 s from an upright posture to the ground, the body turning fastest late
    (slow start, abrupt stop, like a body toppling over), then up again later in the clip."""
    skel, clips = _clips(robot)
    standing = -skel.rest_positions[:, 2].min()
    falls = got_up = 0
    for c in clips:
        m = c.motion
        tilt, z = _tilt(m.base_quat), m.base_pos[:, 2] / standing
        turn = 2 * np.arccos(np.clip(np.abs(np.sum(m.base_quat[1:] * m.base_quat[:-1], axis=1)), 0, 1)) * 30  # rad/s
        for a, b in c.falls:
            i, j = int(np.ceil(a * 30)), min(int(b * 30), m.num_frames - 1)
            if j >= m.num_frames - 1:
                continue  # the clip ends mid-fall
            falls += 1
            assert b - a <= 1.5 and (tilt[j] > 1.2 or z[j] < 0.4), (a, b, tilt[j], z[j])  # down, fast
            w = turn[i:j]
            assert w.max() > 1.5 and np.argmax(w) > 0.55 * len(w), "the body turns fastest late in the fall"
            got_up += bool(((tilt[j:] < 0.4) & (z[j:] > 0.8)).any())
    assert falls >= 4 and got_up >= 2, (falls, got_up)


def test_the_fall_transition_is_c3_and_ends_fast():
    """:func:`transition` is flat to third order at both ends for any warp (x ~ s^4 there), so
    warped falls keep the motion C3; with warp > 1 its speed peaks late."""
    for warp in (1.0, 1.4, 2.1):
        s = np.array([1e-2, 1e-3])
        x0, x1 = transition(s, warp), 1.0 - transition(1.0 - s, warp)  # distance from each end
        for x in (x0, x1):
            assert np.all(x >= 0) and x[1] / s[1] ** 4 <= 1.2 * x[0] / s[0] ** 4 + 1e-9, (warp, x)  # O(s^4), no s^3 term
        grid = np.linspace(0.0, 1.0, 10001)
        y = transition(grid, warp)
        assert y[0] == 0.0 and y[-1] == 1.0 and np.all(np.diff(y) > -1e-12)  # monotone (to rounding)
        peak = grid[np.argmax(np.diff(y))]
        assert abs(peak - 0.5) < 1e-3 if warp == 1.0 else peak > 0.6, (warp, peak)
