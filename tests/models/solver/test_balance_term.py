"""The balance term (mer_models.solver.balance_term): its rows are the ZMP's distance past the support
polygon's edges (checked against the dynamics module's ZMP), its ``J^T r`` is half the gradient of its
cost (finite differences), and its rounds move a one-legged stance's ZMP into the foot."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from test_physics import _problem

from mer_data.kinematics import dynamics as dyn
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.kinematics.support import polygon_distance
from mer_data.robots.inertia import mass_model
from mer_models.solver.balance_term import BalanceConfig, BalanceInputs

FPS = 30.0


def _one_legged(T: int, sway: float = 0.0):
    """G1 on its left foot (the right one lifted), feet flat on z = 0, the pelvis swaying sideways."""
    r, P, q = _problem("g1", T, 0)
    s = r.skeleton
    q = torch.zeros_like(q)
    q[..., s.node_index("right_knee_joint")] = 1.0
    q[..., s.node_index("right_hip_pitch_joint")] = -0.5
    from mer_data.kinematics.collision import shape_points
    from mer_data.robots.collision import collision_model

    geo = collision_model(r)
    base_rot = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3).clone()
    base_pos = torch.zeros(1, T, 3, dtype=torch.float64)
    pos, rot, *_ = P.fit(P.columns(q), base_pos, base_rot)
    base_pos[..., 2] = 0.001 - float(shape_points(geo, pos, rot, "vertices")[..., 2].min())
    base_pos[0, :, 1] = sway * torch.sin(torch.arange(T, dtype=torch.float64) / 3)
    return r, P, q, base_pos, base_rot, geo


def _inputs(r, geo, P, q, base_pos, base_rot):
    inp = BalanceInputs.of_robot(r, BalanceConfig(tol=0.0), FPS, geometry=geo)
    pos, rot, *_ = P.fit(P.columns(q), base_pos, base_rot)
    inp.read_support(pos, rot)
    return inp, inp.build(P, 1.0), pos, rot


def test_rows_are_the_zmp_distance_past_the_stance_foot():
    """Where the demanded vertical force is the weight (a still pose), a frame's largest row is its
    ZMP's distance past the nearest violated edge: the dynamics module's ZMP against the same polygon."""
    T = 9
    r, P, q, base_pos, base_rot, geo = _one_legged(T)
    inp, rows, pos, rot = _inputs(r, geo, P, q, base_pos, base_rot)
    assert bool(inp.contact[0, 1:-1].all())
    res, _ = rows._rows_of(rows._x(pos, rot))
    res = res / rows.sw  # unweighted
    mm = mass_model(r)
    J = len(mm.mass)
    d = dyn.demand(mm, dyn.body_wrenches(mm, pos[0, :, :J], rot[0, :, :J], FPS, spin=False))
    z = dyn.zmp(d).numpy()
    corners = rows._x(pos, rot)[0, :, J:, :2].numpy()
    for t in range(3, T - 3):
        out = polygon_distance(z[t], corners[t])
        assert out > 0.02  # the centre of mass sits between the feet, outside the left sole
        # the largest edge excess is at most the distance, and equals it where the ZMP faces one edge
        assert float(res[0, t, :-3].max()) <= out + 1e-9
        assert float(res[0, t, :-3].max()) > 0.7 * out


def test_gradient_matches_finite_differences_and_reaches_seven_frames():
    T = 9
    r, P, q, base_pos, base_rot, geo = _one_legged(T, sway=0.03)
    inp, rows, pos, rot = _inputs(r, geo, P, q, base_pos, base_rot)
    h, c, g = rows.coupled_terms(pos, rot, {})
    qd = P.columns(q)

    def cost(x):
        p, rr, *_ = P.fit(qd + x[..., : P.D] * P.col_mask[:, None], base_pos + x[..., P.D : P.D + 3],
                          axis_angle_to_matrix(x[..., P.D + 3 :]) @ base_rot)  # fmt: skip
        return rows.cost(p, rr, None, {}).sum()

    assert float(cost(torch.zeros(1, T, P.D + 6, dtype=torch.float64))) > 0
    eps, rng = 1e-6, np.random.default_rng(0)
    for t in range(T):
        for d in sorted({*rng.choice(P.D, 5, replace=False).tolist(), *range(P.D, P.D + 6)}):
            if d < P.D and not bool(P.col_mask[0, d]):
                continue
            x = torch.zeros(1, T, P.D + 6, dtype=torch.float64)
            x[0, t, d] = eps
            num = (cost(x) - cost(-x)) / (2 * eps)
            torch.testing.assert_close(2 * g[0, t, d], num, atol=1e-5, rtol=1e-4)
    assert float(c.abs().max()) > 0  # neighbouring frames are coupled


def test_a_solve_moves_the_zmp_into_the_stance_foot():
    """The term's rounds on a one-legged stance whose goals are the stance itself (the centre of mass
    between the feet, the ZMP outside the left sole): the centre of mass moves over the left foot (+y), the ZMP's
    excess falls to a fraction, the stance foot stays where it was."""
    from mer_data.kinematics.jointmap import joint_map
    from mer_models.config import EnergyConfig
    from mer_models.solver.ik import DEFAULT_SMOOTH, DEFAULT_TOL

    T = 15
    r, P, q, base_pos, base_rot, geo = _one_legged(T)
    s = r.skeleton
    pos, rot, *_ = P.fit(P.columns(q), base_pos, base_rot)
    eta = torch.from_numpy(joint_map(s, s))[None].double()
    inp = BalanceInputs.of_robot(r, BalanceConfig(), FPS, geometry=geo)
    cfg = EnergyConfig()

    def excess(q_, bp, br):
        p_, r_, *_ = P.fit(P.columns(q_), bp, br)
        inp.read_support(p_, r_)
        return float(inp.build(P, 1.0).cost(p_, r_, None, {}).sum()), p_

    before, _ = excess(q, base_pos, base_rot)
    f32 = [x.float() for x in (eta, pos, q, base_pos, base_rot)]  # the solver's dtype (the graph's)
    q2, bp2, br2 = (x.double() for x in inp.solve(cfg, P.graph, *f32, smooth=DEFAULT_SMOOTH, tol=DEFAULT_TOL))
    after, pos2 = excess(q2, bp2, br2)
    assert before > 0 and after < 0.3 * before, (before, after)
    mm = mass_model(r)
    J = len(mm.mass)
    com = [dyn.demand(mm, dyn.body_wrenches(mm, p_[0, :, :J], r_[0, :, :J], FPS)).com for p_, r_ in
           (P.fit(P.columns(q), base_pos, base_rot)[:2], P.fit(P.columns(q2), bp2, br2)[:2])]  # fmt: skip
    mid = slice(4, T - 4)
    assert float((com[1][mid, 1] - com[0][mid, 1]).mean()) > 0.01, (
        com[1][mid, 1] - com[0][mid, 1]
    )  # the mass went left, over the stance foot
    # as the balance metric reads it: every single-support frame's ZMP was outside the left sole, now none is
    from mer_models.retarget.balance import balance_frames

    for (p_, r_), want in ((P.fit(P.columns(q), base_pos, base_rot)[:2], True), (P.fit(P.columns(q2), bp2, br2)[:2], False)):
        b = balance_frames(p_[0, :, :J].numpy(), r_[0, :, :J].numpy(), FPS, s, mm, geo, torques=False)
        single = b["valid"] & (b["support"] == 1)
        assert single.sum() >= T - 6 and bool((b["zmp_out"][single] == want).all()), (want, b["zmp_dist"])
    foot = s.node_index("left_ankle_roll_joint")
    rows = slice(3, T - 3)  # the frames with rows (each reaches three frames either side)
    assert float((pos2[0, rows, foot] - pos[0, rows, foot]).norm(dim=-1).max()) < 0.01


def test_a_hovering_stance_is_put_down():
    """The one-legged stance with every goal 2.5 cm up (the sole just above the metric's 2 cm: every frame
    reads flight, the weight held by nothing): the ``path`` rounds' vertical correction puts the sole back
    on the floor (the metric reads contact, not flight), not under it; without it (``hover=None``) the
    frames stay in flight."""
    from mer_data.kinematics.collision import shape_points
    from mer_data.kinematics.jointmap import joint_map
    from mer_models.config import EnergyConfig
    from mer_models.retarget.balance import balance_frames
    from mer_models.solver.ik import DEFAULT_SMOOTH, DEFAULT_TOL

    T = 15
    r, P, q, base_pos, base_rot, geo = _one_legged(T)
    base_pos[..., 2] += 0.025
    s = r.skeleton
    pos, rot, *_ = P.fit(P.columns(q), base_pos, base_rot)
    eta = torch.from_numpy(joint_map(s, s))[None].float()
    mm = mass_model(r)
    J = len(mm.mass)
    f32 = [x.float() for x in (pos, q, base_pos, base_rot)]
    for cfg, flight in ((BalanceConfig(hover=None), True), (BalanceConfig(), False)):
        inp = BalanceInputs.of_robot(r, dataclasses.replace(cfg, rounds=2), FPS, geometry=geo)
        q2, bp2, br2 = (x.double() for x in inp.solve(EnergyConfig(), P.graph, eta, *f32, smooth=DEFAULT_SMOOTH, tol=DEFAULT_TOL))
        p2, r2, *_ = P.fit(P.columns(q2), bp2, br2)
        b = balance_frames(p2[0, :, :J].numpy(), r2[0, :, :J].numpy(), FPS, s, mm, geo, torques=False)
        low = shape_points(geo, p2, r2, "vertices")[0, ..., 2].flatten(1).min(-1).values
        inner = b["valid"]
        assert bool(((b["support"][inner] == 0) == flight).all()), (cfg.hover, b["support"], low)
        assert float(low.min()) > -0.005, low
