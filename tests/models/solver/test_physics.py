"""The optimiser's physical terms: their analytic Jacobians against finite differences of their cost,
and what each does to a motion built to need it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.collision import collision_model
from mer_data.robots.registry import load_robot
from mer_models.batch import graph_from_batch
from mer_models.config import EnergyConfig
from mer_models.solver.goal_edits import blend as _blend
from mer_models.solver.ik import _Problem
from mer_models.solver.physics import PhysicsConfig, PhysicsInputs


def _problem(name: str, T: int, seed: int):
    r = load_robot(name)
    s = r.skeleton
    eta = joint_map(s, s)
    batch = collate([TrainingSample(np.zeros((3, s.num_nodes, 9), np.float32), s, s, eta)])
    g = graph_from_batch(batch, "tgt", "cpu")
    rng = np.random.default_rng(seed)
    q = torch.from_numpy(rng.uniform(s.lower, s.upper) * 0.5)[None, None].expand(1, T, -1).clone()
    lo, hi = torch.from_numpy(s.lower.copy()), torch.from_numpy(s.upper.copy())
    q = q + torch.from_numpy(rng.normal(size=(1, T, s.num_nodes)) * 0.05)
    q = torch.minimum(torch.maximum(q, lo), hi)
    goal = torch.zeros(1, T, s.num_nodes, 3, dtype=torch.float64)
    P = _Problem(EnergyConfig(), g, torch.from_numpy(eta)[None].double(), goal, q, None, None)
    return r, P, q


@pytest.mark.parametrize("name", ["h1", "talos"])
def test_jacobians_match_finite_differences(name):
    T = 4
    r, P, q = _problem(name, T, 1)
    s = r.skeleton
    rest_low = -s.rest_positions[:, 2].min()
    base_pos = torch.tensor([0.0, 0.0, rest_low - 0.03], dtype=torch.float64).expand(1, T, 3).clone()  # 3 cm into the floor
    base_rot = axis_angle_to_matrix(torch.tensor([[0.05, -0.04, 0.3]], dtype=torch.float64)).expand(1, T, 3, 3).clone()
    contacts = torch.tensor([[[True, False], [True, False], [False, True], [True, True]]])
    cfg = PhysicsConfig(w_floor=3, w_stance=1, w_anchor=1, w_flat=1, w_swing=1, w_self=3, self_margin=0.02)
    phys = PhysicsInputs(collision_model(r), contacts, 30.0, cfg).build(P, 1.0)
    qd = P.columns(q)

    def cost(qd, bp, br, state):
        pos, rot, *_ = P.fit(qd, bp, br)
        return phys.cost(pos, rot, qd, state).sum()

    pos, rot, *_ = P.fit(qd, base_pos, base_rot)
    state = phys.freeze(pos, rot, qd)
    h, g = phys.linearise(pos, rot, qd, state)
    eps = 1e-6
    D = P.D
    num = torch.zeros(1, T, D + 6, dtype=torch.float64)
    rng = np.random.default_rng(0)
    picked = torch.zeros(1, T, D + 6, dtype=torch.bool)
    for t in range(T):
        for d in sorted({*rng.choice(D, 8, replace=False).tolist(), *range(D, D + 6)}):  # 8 joints and the base
            picked[0, t, d] = True
            step = torch.zeros(1, T, D + 6, dtype=torch.float64)
            step[0, t, d] = eps
            vals = []
            for sgn in (1, -1):
                st = step * sgn
                qd2 = qd + st[..., :D] * P.col_mask[:, None]
                bp2 = base_pos + st[..., D : D + 3]
                br2 = axis_angle_to_matrix(st[..., D + 3 :]) @ base_rot
                vals.append(cost(qd2, bp2, br2, state))
            num[0, t, d] = (vals[0] - vals[1]) / (2 * eps)
    mask = torch.cat([P.col_mask[:, None].expand(1, T, D), torch.ones(1, T, 6, dtype=torch.bool)], -1) & picked
    assert float(num.abs().max()) > 1e-3  # the terms are active: the comparison can fail
    torch.testing.assert_close((2 * g)[mask], num[mask], atol=2e-5, rtol=1e-4)


def test_blend_eases_in_and_out():
    down = torch.tensor([[0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0]], dtype=torch.bool)
    w = _blend(down, 3)
    assert w[0, 0] == 0 and w[0, -1] == 0 and w[0, 5] == 1
    assert (w[0, 1:5].diff() > 0).all() and (w[0, 6:10].diff() < 0).all()


def _standing_features(name: str, F: int, sink: float):
    """Features of ``name`` standing still at its zero pose, its soles ``sink`` [m] below the floor."""
    from mer_data.kinematics.collision import shape_points
    from mer_models.retarget.clip import source_features

    r = load_robot(name)
    s = r.skeleton
    m = collision_model(r)
    J = s.num_nodes
    low = float(shape_points(m, torch.from_numpy(s.rest_positions), torch.eye(3, dtype=torch.float64).expand(J, 3, 3))[..., 2].min())
    base = np.zeros((F, 3))
    base[:, 2] = -low - sink
    quat = np.tile([1.0, 0, 0, 0], (F, 1))
    return r, source_features(base, quat, np.zeros((F, J)), s, 30.0)


def test_the_floor_term_keeps_a_sunken_reference_on_the_floor():
    from mer_models.retarget.clip import retarget_features, sequence_metrics

    r, feats = _standing_features("h1", 30, 0.05)
    s, geom = r.skeleton, collision_model(r)
    plain = retarget_features(feats, s, s, method="optimize", fps=30.0)
    phys = retarget_features(feats, s, s, method="optimize", fps=30.0, physics=PhysicsConfig())
    a = sequence_metrics(feats, s, plain.motion, prepared=plain.prepared, geometry=geom)
    b = sequence_metrics(feats, s, phys.motion, prepared=phys.prepared, geometry=geom)
    assert a["floor_frames"] == 1.0 and a["floor_depth_max"] > 0.045  # the goals are 5 cm under: so is the plain solution
    assert b["floor_frames"] == 0.0 and b["floor_depth_max"] < 0.01
    assert b["g_mpbpe"] < 0.06  # it stood up instead: about the 5 cm the goals asked for


@pytest.mark.parametrize("method", ["constraints", "penalty"])
def test_the_repair_takes_feet_the_goals_put_through_each_other_apart(method):
    """TALOS standing, both hips rolled in over frames 6-23 of 30 (its own motion: the goals are
    reachable exactly): the plain optimiser follows the feet through each other, the physical
    terms leave no pair deeper than 1 cm (the metric's sample points: the separating-axis depth
    the repair holds bounds it from above). The constraint method's six rounds leave a pair 2 cm deep
    there; the rounds that go on while a pair is 1 cm short of its margin (``al_extra``) part them."""
    from mer_data.kinematics.collision import shape_points
    from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features

    r = load_robot("talos")
    s, geom = r.skeleton, collision_model(r)
    F, J = 30, s.num_nodes
    q = np.zeros((F, J))
    hip = [s.node_names.index(n) for n in s.node_names if "leg_left_2" in n or "leg_right_2" in n]
    ramp = np.clip(np.minimum(np.arange(F) - 5, 24 - np.arange(F)) / 4, 0, 1)
    q[:, hip[0]], q[:, hip[1]] = -0.3 * ramp, 0.3 * ramp
    low = float(shape_points(geom, torch.from_numpy(s.rest_positions), torch.eye(3, dtype=torch.float64).expand(J, 3, 3))[..., 2].min())
    base = np.zeros((F, 3))
    base[:, 2] = -low
    feats = source_features(base, np.tile([1.0, 0, 0, 0], (F, 1)), q, s, 30.0)
    plain = retarget_features(feats, s, s, method="optimize", fps=30.0)
    phys = retarget_features(feats, s, s, method="optimize", fps=30.0, physics=PhysicsConfig(method=method))
    a = sequence_metrics(feats, s, plain.motion, prepared=plain.prepared, geometry=geom)
    b = sequence_metrics(feats, s, phys.motion, prepared=phys.prepared, geometry=geom)
    assert a["selfpen_1cm_frames"] > 0.3 and a["selfpen_depth_max"] > 0.03, a["selfpen_worst"]
    assert b["selfpen_1cm_frames"] == 0 and b["selfpen_depth_max"] < 0.01, b["selfpen_worst"]


def test_a_later_repair_round_keeps_the_pairs_earlier_ones_found():
    """:meth:`PhysicsInputs.repair` with ``seen``: a pair an earlier round found stays in the self
    term (where it was found), though it is apart now, so the round does not push it back in."""
    from mer_models.batch import batch_fk

    r = load_robot("talos")
    s, m = r.skeleton, collision_model(r)
    T, J = 30, s.num_nodes
    g = graph_from_batch(collate([TrainingSample(np.zeros((3, J, 9), np.float32), s, s, joint_map(s, s))]), "tgt", "cpu")
    q = g.nominal[:, None].expand(1, T, J).clone().double()
    hip = [s.node_names.index(n) for n in s.node_names if "leg_left_2" in n or "leg_right_2" in n]
    q[0, 10:12, hip[0]], q[0, 10:12, hip[1]] = -0.35, 0.35
    eye = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3)
    pos, rot = batch_fk(g, q, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(1, T, 3), eye)
    inputs = PhysicsInputs(m, None, 30.0, PhysicsConfig(repair_reach=2, repair_touch=None))
    rows, first = inputs.repair(pos, rot)
    seen = torch.zeros_like(first.found)
    k = len(m.pairs) - 1  # a pair nowhere near (not hit in any frame)
    assert not bool(first.found[..., k].any())
    seen[0, 25, k] = True
    rows, later = inputs.repair(pos, rot, first=False, seen=seen)
    assert bool(later.found[0, 25, k]) and torch.equal(later.found[..., :k], first.found[..., :k])
    assert later.pairs.shape[0] == first.pairs.shape[0] + 1 and later.pairs[-1].tolist() == m.pairs[k].tolist()
    assert bool(later.pair_mask[0, 25, -1]) and not bool(later.pair_mask[0, :23, -1].any())
    assert (~later.held_frames()[0]).nonzero().flatten().tolist() == list(range(8, 14))  # freed only near today's hit
    # only the frames the last round moved are searched: the hit frames among them, the same result; none, no repair
    moved = torch.zeros(1, T, dtype=torch.bool)
    moved[0, 8:14] = True
    _, same = inputs.repair(pos, rot, first=False, moved=moved)
    assert torch.equal(same.found, first.found) and torch.equal(same.pair_mask, first.pair_mask)
    assert inputs.repair(pos, rot, first=False, moved=torch.zeros_like(moved)) is None


def test_locked_goals_hold_a_stance_foot():
    rng = np.random.default_rng(0)
    goal = torch.from_numpy(rng.normal(size=(1, 20, 5, 3)))
    contacts = torch.zeros(1, 20, 2, dtype=torch.bool)
    contacts[0, 3:15, 0] = True
    inputs = PhysicsInputs(None, contacts, 30.0, PhysicsConfig(lock_blend=2), ((1, 2), ()))
    out = inputs.lock_goals(goal)
    held = out[0, 6:12, 1, :2]
    assert torch.allclose(held, held[:1].expand_as(held))  # planted: one x, y
    assert torch.equal(out[..., 2], goal[..., 2]) and torch.equal(out[:, :, [0, 3, 4]], goal[:, :, [0, 3, 4]])
    assert torch.equal(out[0, 16:], goal[0, 16:])  # after the phase (and its blend): the goals as they were


def test_joint_speed_term_gradient_and_coupling():
    """The joint-speed term's gradient against finite differences of its cost, and its coupling
    block: the cost is a sum of ``(|q_{t+1} - q_t| - limit)^2``, so ``J^T J`` couples t and t + 1
    with minus the diagonal's share."""
    r, P, q = _problem("h1", 5, 3)
    phys = PhysicsInputs(collision_model(r), None, 30.0, PhysicsConfig(w_speed=2.0)).build(P, 1.0)
    qd = P.columns(q).clone()
    lim = phys._step_limit(P.cols, qd)[0, 0]
    j = int(torch.isfinite(lim).nonzero()[0])
    qd[0, :, j] = torch.tensor([0.0, 3.0, 2.5, 6.0, 6.1], dtype=qd.dtype) * lim[j]  # 3x, 0.5x, 3.5x, 0.1x the limit
    diag, off, grad = phys.speed_terms(qd, P.cols)
    eps = 1e-6
    for t in range(5):
        up, down = qd.clone(), qd.clone()
        up[0, t, j] += eps
        down[0, t, j] -= eps
        num = (phys.speed_cost(up, P.cols).sum() - phys.speed_cost(down, P.cols).sum()) / (2 * eps)
        assert float(2 * grad[0, t, j]) == pytest.approx(float(num), rel=1e-4, abs=1e-8)
    active = torch.tensor([1.0, 0.0, 1.0, 0.0]) * 2.0
    assert torch.allclose(off[0, :, j], -active.to(off.dtype)) and torch.allclose(diag[0, 1:-1, j], (active[1:] + active[:-1]).to(diag.dtype))
    assert phys.speed_cost(qd * 0, P.cols).sum() == 0


def test_held_frames_stay_and_the_rest_is_solved():
    """``coupled_lm_ik(hold=...)``: held frames come back bit for bit; the free ones move to the goals."""
    from mer_models.batch import batch_fk
    from mer_models.solver.ik import coupled_lm_ik

    s = load_robot("h1").skeleton
    T, J = 20, s.num_nodes
    eta = torch.from_numpy(joint_map(s, s))[None].float()
    g = graph_from_batch(collate([TrainingSample(np.zeros((3, J, 9), np.float32), s, s, joint_map(s, s))]), "tgt", "cpu")
    rng = np.random.default_rng(1)
    want = torch.from_numpy(rng.uniform(s.lower, s.upper) * 0.3).float()[None, None].expand(1, T, J).clone()
    base_pos = torch.tensor([0.0, 0.0, 1.0]).expand(1, T, 3).clone()
    base_rot = torch.eye(3).expand(1, T, 3, 3).clone()
    goal = batch_fk(g, want, base_pos, base_rot)[0]
    q0 = g.nominal[:, None].expand(1, T, J).clone()
    hold = torch.zeros(1, T, dtype=torch.bool)
    hold[0, :5] = hold[0, 15:] = True
    q, p, r = coupled_lm_ik(EnergyConfig(), g, eta, goal, q0, base_pos, base_rot, iters=5, hold=hold)
    assert torch.equal(q[hold], q0[hold]) and torch.equal(p[hold], base_pos[hold]) and torch.equal(r[hold], base_rot[hold])
    err = lambda x: float((batch_fk(g, x, base_pos, base_rot)[0] - goal)[0, 5:15].norm(dim=-1).mean())  # noqa: E731
    assert err(q) < 0.5 * err(q0)


def test_the_repair_moves_only_frames_near_a_contact():
    """:meth:`PhysicsInputs.repair` on TALOS standing, its feet through each other in frames 10-11
    and its body sunk into the floor in frames 30-31 of 40: the pair it found is looked for, and
    frames are freed, only within ``repair_reach`` of them."""
    from mer_data.kinematics.collision import shape_points
    from mer_models.batch import batch_fk

    r = load_robot("talos")
    s, m = r.skeleton, collision_model(r)
    T, J = 40, s.num_nodes
    g = graph_from_batch(collate([TrainingSample(np.zeros((3, J, 9), np.float32), s, s, joint_map(s, s))]), "tgt", "cpu")
    q = g.nominal[:, None].expand(1, T, J).clone().double()
    hip = [s.node_names.index(n) for n in s.node_names if "leg_left_2" in n or "leg_right_2" in n]  # the hip rolls
    assert len(hip) == 2
    q[0, 10:12, hip[0]] = -0.35  # both legs swung in: the feet through each other
    q[0, 10:12, hip[1]] = 0.35
    eye = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3)
    rest, rrot = batch_fk(g, q[:, :1], torch.zeros(1, 1, 3, dtype=torch.float64), eye[:, :1])
    base = torch.zeros(1, T, 3, dtype=torch.float64)
    base[..., 2] = -float(shape_points(m, rest, rrot)[..., 2].min()) + 0.001  # standing: the soles on the floor
    base[0, 30:32, 2] -= 0.3  # sunk: shins and knees in the floor
    pos, rot = batch_fk(g, q, base, eye)
    for touch, want in ((None, list(range(7, 15))), (0.0, list(range(7, 15)) + list(range(27, 35)))):
        rows, terms = PhysicsInputs(m, None, 30.0, PhysicsConfig(repair_reach=3, repair_touch=touch)).repair(pos, rot)
        assert rows.tolist() == [0]
        assert (~terms.held_frames()[0]).nonzero().flatten().tolist() == want
        mask = terms.pair_mask
        assert mask.shape[:2] == (1, T) and not bool(mask[0, :7].any()) and not bool(mask[0, 15:].any())
