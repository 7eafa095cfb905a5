"""The balance term's path correction (mer_models.solver.balance_path): its acceleration operator is the
balance metric's (mer_data.kinematics.dynamics), its correction puts a cart-table's ZMP inside the support
with the least change, and the two-stage solve moves a one-legged stance's ZMP into the foot as the metric
(mer_models.retarget.balance) measures it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from mer_data.kinematics import dynamics as dyn
from mer_models.solver.balance_path import accel_operator, flight_phases, path_correction, polygon_rows, vertical_correction

FPS = 30.0


def test_the_operator_is_the_metrics_filtered_acceleration_to_the_end_frames():
    rng = np.random.default_rng(0)
    T = 23
    x = np.cumsum(rng.normal(size=(T, 3)), 0) * 0.01
    point = SimpleNamespace(mass=np.ones(1), com=np.zeros((1, 3)), inertia=np.zeros((1, 3, 3)))
    w = dyn.body_wrenches(point, torch.from_numpy(x)[:, None], torch.eye(3, dtype=torch.float64).expand(T, 1, 3, 3), FPS)
    want = w.force[:, 0].numpy() + np.array([0.0, 0.0, -dyn.GRAVITY])  # m (a - g) with m = 1, g = (0, 0, -9.81)
    np.testing.assert_allclose(accel_operator(T, FPS) @ x, want, atol=1e-9)


def test_polygon_rows_are_the_hull_and_a_strip_around_a_segment():
    n, d = polygon_rows(np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.04], [0.0, 0.04], [0.05, 0.02]]))
    assert len(n) == 4
    assert (n @ np.array([0.05, 0.02]) + d < 0).all() and (n @ np.array([0.05, 0.06]) + d > 0).any()
    n, d = polygon_rows(np.array([[0.0, 0.0], [0.1, 0.0]]))
    assert np.max(n @ np.array([0.05, 0.0]) + d) <= 1e-12 and np.isclose(np.max(n @ np.array([0.05, 0.03]) + d), 0.03)


def _zmp_after(zmp, cz, dc):
    A = accel_operator(len(zmp), FPS)
    return zmp + dc - (cz / dyn.GRAVITY)[:, None] * (A @ dc)


def test_a_static_offset_is_corrected_by_the_least_shift():
    """A still centre of mass 8 cm beside a 4 cm wide foot (the ZMP is its projection): the correction puts
    every frame's ZMP on the foot, moving the centre of mass toward it by less than the 6 cm a still one
    would need (a slow sway whose acceleration carries the ZMP the rest of the way), nothing along the foot."""
    T = 40
    zmp = np.tile([0.0, 0.08], (T, 1))
    cz = np.full(T, 0.7)
    foot = np.array([[-0.1, -0.02], [0.1, -0.02], [0.1, 0.02], [-0.1, 0.02]])
    polys = [polygon_rows(foot) if 2 <= t < T - 2 else None for t in range(T)]
    dc = path_correction(zmp, cz, np.full(T, dyn.GRAVITY), polys, np.zeros(T, bool), np.zeros((T, 2)), FPS)
    assert (dc[2:-2, 1] < 0).all() and dc[:, 1].min() > -0.06 and dc[T // 2, 1] < -0.04
    np.testing.assert_allclose(dc[:, 0], 0.0, atol=1e-6)
    p = _zmp_after(zmp, cz, dc)
    assert np.abs(p[2 : T - 2, 1]).max() < 0.02 + 1e-3


def test_alternating_stances_are_met_with_less_sway_than_statics_need():
    """Steps every 12 frames on feet 10 cm either side of a still centre of mass: every single-support frame's
    ZMP ends inside its foot, and the centre of mass sways less than the 8 cm a still stance would need
    (the dynamics carry the rest: the ZMP is ahead of the centre of mass's swing)."""
    T = 96
    cz = np.full(T, 0.7)
    zmp = np.zeros((T, 2))
    side = np.where((np.arange(T) // 12) % 2 == 0, 1.0, -1.0)
    polys = [polygon_rows(np.array([[-0.1, s * 0.1 - 0.02], [0.1, s * 0.1 - 0.02], [0.1, s * 0.1 + 0.02], [-0.1, s * 0.1 + 0.02]]))
             if 2 <= t < T - 2 else None for t, s in enumerate(side)]  # fmt: skip
    dc = path_correction(zmp, cz, np.full(T, dyn.GRAVITY), polys, np.zeros(T, bool), np.zeros((T, 2)), FPS, smooth=0.1)
    p = _zmp_after(zmp, cz, dc)
    out = np.abs(p[:, 1] - side * 0.1) - 0.02
    assert out[2 : T - 2].max() < 5e-3, out.max()
    assert np.abs(dc[12:-12, 1]).max() < 0.075


def test_flight_frames_are_pulled_to_ballistic():
    """A flight phase whose centre of mass accelerates sideways at 3 m/s^2 (no contact): the correction
    cancels that acceleration (the filtered one, as the metric reads it)."""
    T = 40
    acc = np.zeros((T, 2))
    acc[10:30, 0] = 3.0
    flight = np.zeros(T, bool)
    flight[10:30] = True
    dc = path_correction(np.zeros((T, 2)), np.full(T, 0.7), np.zeros(T), [None] * T, flight, acc, FPS, smooth=0.01,
                         flight_weight=100.0)  # fmt: skip
    a = acc + accel_operator(T, FPS) @ dc
    assert np.abs(a[12:28, 0]).max() < 0.3, a[10:30, 0]


def test_a_jump_is_made_ballistic_and_the_contacts_stay_on_the_floor():
    """A 10-frame flight whose centre of mass stays level (the goals' jump: the feet lift, the body does not
    fall): the vertical correction gives the flight's interior the metric's free fall (``f_z / M`` within its
    2 m/s^2 of 0), and every contact frame's lowest point stays on the floor, not under it."""
    T = 60
    t = np.arange(T)
    flight = (t >= 25) & (t < 35)
    low = np.where(flight, 0.08 * np.sin(np.pi * (t - 24) / 11), 0.0)
    fz = np.full(T, dyn.GRAVITY)  # level: c'' = 0, so the floor would carry the weight
    hover, jump = flight_phases(flight, low, 0.03)
    assert not hover.any() and (jump == flight).all()
    dz = vertical_correction(low, fz, ~flight, hover, jump, 0.7, FPS, top=0.012, flight_weight=3.0)
    a = fz + accel_operator(T, FPS) @ dz
    assert np.abs(a[27:33]).max() < 2.0, a[25:35]
    still = np.r_[a[:15], a[45:]] - dyn.GRAVITY  # far from the jump: standing still
    assert np.abs(still).max() < 1.0
    lo = low + dz
    assert lo[~flight].min() > -1e-3 and lo[~flight].max() < 0.012 + 1e-3, lo[~flight]


def test_a_hover_is_put_down():
    """Flight frames whose lowest point stays 2.5 cm up with the body held (a foot held just above the metric's
    2 cm): a hover, lowered to ``top``; a hop elsewhere that reaches 6 cm is a jump, not lowered to the floor;
    so is the low flight where the body falls (a run's short flight)."""
    T = 60
    t = np.arange(T)
    flight = ((t >= 10) & (t < 20)) | ((t >= 40) & (t < 46))
    low = np.where((t >= 10) & (t < 20), 0.025, 0.0) + np.where((t >= 40) & (t < 46), 0.06, 0.0)
    hover, jump = flight_phases(flight, low, 0.03, np.full(T, dyn.GRAVITY))
    assert (hover == ((t >= 10) & (t < 20))).all() and (jump == ((t >= 40) & (t < 46))).all()
    assert not flight_phases(flight, low, 0.03, np.full(T, 2.0))[0].any()  # falling at 7.8 m/s^2: a jump
    dz = vertical_correction(low, np.full(T, dyn.GRAVITY), ~flight, hover, np.zeros(T, bool), 0.7, FPS, top=0.012)
    lo = low + dz
    assert lo[hover].max() < 0.012 + 1e-3 and lo.min() > -1e-3, lo
    assert lo[40:46].min() > 0.03  # the hop (no ballistic rows here) stays in the air
