"""The constraint method of the physical terms (``PhysicsConfig.method="constraints"``): the dense
two-frame coupling of the block-tridiagonal solve, the stance no-slip term's gradient against finite
differences of its cost, and a solve that must lift a sunken reference out of the floor."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_physics import _problem, _standing_features

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.robots.collision import collision_model
from mer_data.robots.registry import load_robot
from mer_models.retarget.clip import source_features
from mer_models.solver.physics import PhysicsConfig, PhysicsInputs
from mer_models.solver.stance import lowest_foot_points, slip_cost
from mer_models.solver.tridiagonal import block_tridiagonal_solve


def test_the_block_tridiagonal_solve_takes_dense_couplings():
    """Sums of random two-frame least-squares rows (each over x_t and x_{t+1}) plus the identity: an SPD
    block-tridiagonal system with dense off-diagonal blocks, solved as numpy solves the assembled matrix."""
    gen = torch.Generator().manual_seed(3)
    for T in (1, 2, 5, 16):
        B, n, m = 2, 4, 3
        full = torch.eye(T * n, dtype=torch.float64).expand(B, T * n, T * n).clone()
        for t in range(T - 1):
            j = torch.randn(B, m, 2 * n, generator=gen, dtype=torch.float64)
            full[:, t * n : (t + 2) * n, t * n : (t + 2) * n] += j.transpose(-1, -2) @ j
        a = torch.stack([full[:, t * n : (t + 1) * n, t * n : (t + 1) * n] for t in range(T)], 1)
        c = torch.stack([full[:, (t + 1) * n : (t + 2) * n, t * n : (t + 1) * n] for t in range(T - 1)], 1) if T > 1 else torch.zeros(B, 0, n, n, dtype=torch.float64)
        rhs = torch.randn(B, T, n, generator=gen, dtype=torch.float64)
        x, ok = block_tridiagonal_solve(a, c, rhs)
        ref = torch.from_numpy(np.linalg.solve(full.numpy(), rhs.reshape(B, -1, 1).numpy())).reshape(B, T, n)
        assert ok.all()
        torch.testing.assert_close(x, ref, atol=1e-10, rtol=1e-10)


def test_the_no_slip_gradient_matches_finite_differences():
    """:func:`mer_models.solver.stance.slip_terms`' ``J^T r`` is half the gradient of its cost, on H1
    with both feet down over 4 frames of a moving pose (the rows couple neighbouring frames)."""
    T = 4
    r, P, q = _problem("h1", T, 2)
    rest_low = -r.skeleton.rest_positions[:, 2].min()
    base_pos = torch.tensor([0.0, 0.0, rest_low], dtype=torch.float64).expand(1, T, 3).clone()
    base_pos[0, :, 0] = torch.arange(T, dtype=torch.float64) * 0.03  # sliding forward
    base_rot = axis_angle_to_matrix(torch.tensor([[0.02, -0.03, 0.2]], dtype=torch.float64)).expand(1, T, 3, 3).clone()
    model = collision_model(r)
    feet = [torch.nonzero(torch.as_tensor(model.foot) == s).flatten() for s in (1, 2)]
    qd = P.columns(q)
    pos, rot, *_ = P.fit(qd, base_pos, base_rot)
    shape, vert = lowest_foot_points(model, pos, rot, feet)
    slip = {"shape": shape, "vert": vert, "mask": torch.ones(1, T - 1, 2, dtype=torch.bool), "w": 2.0}
    phys = PhysicsInputs(model, None, 30.0, PhysicsConfig()).build(P, 1.0)
    _, c, g = phys.coupled_terms(pos, rot, {"slip": slip})
    assert float(c.abs().max()) > 0  # the rows couple frames

    def cost(x):
        p, rr, *_ = P.fit(qd + x[..., : P.D] * P.col_mask[:, None], base_pos + x[..., P.D : P.D + 3], axis_angle_to_matrix(x[..., P.D + 3 :]) @ base_rot)
        return slip_cost(phys, p, rr, slip).sum()

    eps, rng = 1e-6, np.random.default_rng(0)
    for t in range(T):
        for d in sorted({*rng.choice(P.D, 6, replace=False).tolist(), *range(P.D, P.D + 6)}):
            if d < P.D and not bool(P.col_mask[0, d]):
                continue
            x = torch.zeros(1, T, P.D + 6, dtype=torch.float64)
            x[0, t, d] = eps
            num = (cost(x) - cost(-x)) / (2 * eps)
            torch.testing.assert_close(2 * g[0, t, d], num, atol=2e-6, rtol=1e-4)


def test_the_constraints_lift_a_sunken_reference_out_of_the_floor():
    """H1 standing 5 cm into the floor: the least change that meets the floor constraint stands it up
    (about the 5 cm the goals asked for), with the feet on the floor (no hovering)."""
    from mer_models.retarget.clip import retarget_features, sequence_metrics

    r, feats = _standing_features("h1", 30, 0.05)
    s, geom = r.skeleton, collision_model(r)
    res = retarget_features(feats, s, s, method="optimize", fps=30.0, physics=PhysicsConfig(method="constraints"))
    m = sequence_metrics(feats, s, res.motion, prepared=res.prepared, geometry=geom)
    assert m["body_floor_frames"] == 0.0 and m["floor_depth_max"] < 0.01
    assert m["hover_frames"] == 0.0
    assert m["g_mpbpe"] < 0.06


def _displacement(feats, s, cfg, eps: float) -> float:
    """Largest body displacement [m] between the constraint method's results for ``feats`` and for
    ``feats`` with ``eps`` [m] of noise on the base path (tools/bench_sensitivity.py)."""
    from mer_models.retarget.clip import retarget_features

    g = feats.copy()
    g[:, 0, 3:6] += eps * np.random.default_rng(0).standard_normal((len(feats), 3))
    a, b = (retarget_features(f, s, s, method="optimize", fps=30.0, physics=cfg).motion.forward_kinematics()[0] for f in (feats, g))
    return float(np.linalg.norm(a - b, axis=-1).max())


def test_a_rounding_level_change_of_the_input_moves_the_result_by_as_little():
    """The constraint method is continuous where its decisions tie: H1 standing 5 cm in the floor (the first
    lift puts every corner of both flat soles on the floor at once: rows exactly at their bound, which
    rounding switched on or off, moved bodies by centimetres) and TALOS's feet pushed into each other (parallel
    faces: which vertex is deepest flipped with rounding, and with it the self row's direction)."""
    cfg = PhysicsConfig(method="constraints")
    r, feats = _standing_features("h1", 30, 0.05)
    assert _displacement(feats, r.skeleton, cfg, 1e-7) < 1e-4
    t = load_robot("talos")
    s = t.skeleton
    F, J = 30, s.num_nodes
    q = np.zeros((F, J))
    hip = [s.node_names.index(n) for n in s.node_names if "leg_left_2" in n or "leg_right_2" in n]
    ramp = np.clip(np.minimum(np.arange(F) - 5, 24 - np.arange(F)) / 4, 0, 1)
    q[:, hip[0]], q[:, hip[1]] = -0.3 * ramp, 0.3 * ramp
    _, sunk = _standing_features("talos", F, 0.0)
    feats = source_features(sunk[:, 0, 3:6], np.tile([1.0, 0, 0, 0], (F, 1)), q, s, 30.0)
    assert _displacement(feats, s, cfg, 1e-7) < 1e-4


def _talos_posed(T: int):
    """TALOS (hulls) in ``T`` random poses at the origin: its problem, collision model, the angles, base
    pose and node frames."""
    from mer_models.batch import batch_fk

    r, P, q = _problem("talos", T, 5)
    base_pos = torch.zeros(1, T, 3, dtype=torch.float64)
    base_rot = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3).clone()
    return P, collision_model(r), q, base_pos, base_rot, *batch_fk(P.graph, q, base_pos, base_rot)


def test_fixed_faces_give_the_separating_axis_depth_and_bound_it_after_a_move():
    """:mod:`mer_models.solver.faces` on TALOS (hulls) in random poses: at the pose where the faces are
    fixed, each entry's depth, point and normal are :func:`contact_points`' separating-axis ones; after
    the pose moves, the depth along the fixed face is never below the separating-axis depth (the least
    overlap over every face), so holding it under a margin holds the metric's bound too."""
    from mer_data.kinematics.collision import contact_points, pair_contacts
    from mer_models.batch import batch_fk
    from mer_models.solver.faces import face_points, fix_faces

    P, model, q, base_pos, base_rot, pos, rot = _talos_posed(6)
    found = pair_contacts(model, pos, rot, margin=0.05, top=8, which="sat")
    assert found is not None
    entries, (depth, point, normal, na, nb) = found
    K = depth.shape[-1]
    faces = fix_faces(model, pos, rot, entries, K)
    fd, fp, fn, fa, fb = face_points(model, pos, rot, faces)
    bi, ti, ki = entries[:3]
    assert len(bi) >= 10 and bool((depth[bi, ti, ki] > 0).any())  # some pairs overlap, some do not
    torch.testing.assert_close(fd[bi, ti, ki], depth[bi, ti, ki], atol=1e-9, rtol=0)
    torch.testing.assert_close(fn[bi, ti, ki], normal[bi, ti, ki], atol=1e-9, rtol=0)
    from mer_models.solver.faces import POINT_SOFTNESS_M

    # the row's point: the deepest vertex where it stands alone, else weighted towards the vertices as deep
    off = ((fp - point)[bi, ti, ki] * fn[bi, ti, ki]).sum(-1)  # how much shallower along the face's normal
    assert bool((off > -1e-9).all()) and bool((off < 5 * POINT_SOFTNESS_M).all())
    alone = (fp - point)[bi, ti, ki].norm(dim=-1) < 1e-4
    assert bool(alone.any()) and bool((~alone).any())  # a vertex alone at its depth, or the face's vertices as deep
    assert torch.equal(fa[bi, ti, ki], na[bi, ti, ki]) and torch.equal(fb[bi, ti, ki], nb[bi, ti, ki])
    gen = torch.Generator().manual_seed(1)
    moved = q + 0.05 * torch.randn(q.shape, generator=gen, dtype=torch.float64)
    pos2, rot2 = batch_fk(P.graph, moved, base_pos, base_rot)
    sat = contact_points(model, pos2, rot2, entries, K, "sat")[0][bi, ti, ki]
    along = face_points(model, pos2, rot2, faces)[0][bi, ti, ki]
    assert bool((along >= sat - 1e-9).all()) and bool((along > sat + 1e-4).any())  # a bound, not the same


def test_a_round_solves_runs_of_free_frames_with_a_held_frame_each_side():
    """:func:`mer_models.solver.constrained._segments`: runs of frames free in any sample, one held
    frame either side, close runs joined, the whole window once the runs cover most of it."""
    from mer_models.solver.constrained import _segments

    free = torch.zeros(2, 100, dtype=torch.bool)
    assert _segments(free, 8) == []
    free[0, 10:20] = True
    free[1, 24:30] = True  # 4 frames after the first run: joined
    free[0, 60:62] = True
    free[1, 99] = True  # the last frame: no held frame after it
    assert _segments(free, 8) == [(9, 31), (59, 63), (98, 100)]
    assert _segments(free, 0) == [(9, 21), (23, 31), (59, 63), (98, 100)]
    free[0, 5:90] = True
    assert _segments(free, 8) == [(0, 100)]


def test_deep_entries_keep_the_exact_separating_axis_depth():
    """``fix_faces(exact_over=0)``: the entries overlapping at the fixing pose are measured by the
    separating-axis depth itself at any later pose; the others along their fixed faces."""
    from mer_data.kinematics.collision import contact_points, pair_contacts
    from mer_models.batch import batch_fk
    from mer_models.solver.faces import face_points, fix_faces

    T = 6
    r, P, q = _problem("talos", T, 5)
    model = collision_model(r)
    base_pos, base_rot = torch.zeros(1, T, 3, dtype=torch.float64), torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3).clone()
    pos, rot = batch_fk(P.graph, q, base_pos, base_rot)
    entries, (depth, *_) = pair_contacts(model, pos, rot, margin=0.05, top=8, which="sat")
    K = depth.shape[-1]
    faces = fix_faces(model, pos, rot, entries, K, exact_over=0.0)
    bi, ti, ki = entries[:3]
    deep = depth[bi, ti, ki] > 0
    assert bool(deep.any()) and not bool(deep.all())
    moved = q + 0.05 * torch.randn(q.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    pos2, rot2 = batch_fk(P.graph, moved, base_pos, base_rot)
    sat = contact_points(model, pos2, rot2, entries, K, "sat")[0][bi, ti, ki]
    along = face_points(model, pos2, rot2, faces)[0][bi, ti, ki]
    torch.testing.assert_close(along[deep], sat[deep], atol=1e-12, rtol=0)
    assert bool((along[~deep] >= sat[~deep] - 1e-9).all())


def test_without_the_lift_the_rounds_take_a_shallow_sink_out_by_less_than_a_rigid_raise():
    """``al_lift=False``: the rounds start from the plain solution of H1 standing 2 cm into the floor
    and still end with no body in it and the soles down; the least change bends rather than raising
    the whole robot, so g-mpbpe ends under the 2 cm a rigid raise (the lift, ``al_lift=True``) costs."""
    from mer_models.retarget.clip import retarget_features, sequence_metrics

    r, feats = _standing_features("h1", 30, 0.02)
    s, geom = r.skeleton, collision_model(r)
    out = {}
    for lift in (True, False):
        res = retarget_features(feats, s, s, method="optimize", fps=30.0, physics=PhysicsConfig(method="constraints", al_lift=lift))
        out[lift] = m = sequence_metrics(feats, s, res.motion, prepared=res.prepared, geometry=geom)
        assert m["body_floor_frames"] == 0.0 and m["floor_depth_max"] < 0.01 and m["hover_frames"] == 0.0
    assert abs(out[True]["g_mpbpe"] - 0.02) < 0.002  # the lift: every body 2 cm above its goal
    assert out[False]["g_mpbpe"] < out[True]["g_mpbpe"] - 0.001


def _h1_window(T: int):
    """H1 with its own skeleton as reference, ``T`` random poses standing 1 m up: the double-precision
    graph, joint map, angles, base pose, the goals (the poses' node positions) and a clamp into the
    joint limits."""
    import dataclasses

    from test_physics import TrainingSample, collate, graph_from_batch, joint_map

    from mer_models.batch import batch_fk

    r, _, q = _problem("h1", T, 4)
    s = r.skeleton
    eta = torch.from_numpy(joint_map(s, s))[None].double()
    g = graph_from_batch(collate([TrainingSample(np.zeros((3, s.num_nodes, 9), np.float32), s, s, joint_map(s, s))]), "tgt", "cpu")
    g = dataclasses.replace(g, **{f.name: getattr(g, f.name).double() for f in dataclasses.fields(g) if getattr(g, f.name).is_floating_point()})
    base_pos = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(1, T, 3).clone()
    base_rot = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3).clone()
    goal = batch_fk(g, q, base_pos, base_rot)[0]

    def clamp(x: torch.Tensor) -> torch.Tensor:
        return torch.minimum(torch.maximum(x, torch.from_numpy(s.lower.copy())), torch.from_numpy(s.upper.copy()))

    return s, g, eta, q, base_pos, base_rot, goal, clamp


def test_grouped_ranges_solve_as_each_range_alone():
    """``coupled_lm_ik(groups=...)``: ranges of frames put side by side, each bounded by held frames, with
    their own damping and step test, end where a solve of each range alone ends, though one range starts
    far from its goals and the other near (one shared step test does not: the check can fail)."""
    from mer_models.config import EnergyConfig
    from mer_models.solver.ik import coupled_lm_ik

    s, g, eta, q, base_pos, base_rot, goal, clamp = _h1_window(16)
    start = q.clone()
    start[:, :8] += 0.02 * torch.cos(torch.arange(s.num_nodes, dtype=torch.float64))
    start[:, 8:] += 1.2 * torch.sin(torch.arange(s.num_nodes, dtype=torch.float64))  # the second range far from its goals
    start = clamp(start)
    hold = torch.zeros(1, 16, dtype=torch.bool)
    hold[:, [0, 7, 8, 15]] = True  # ranges 0-7 and 8-15, a held frame at each end
    kw = dict(iters=6, smooth=0.05, tol=1e-4, change_of=q, change_smooth=0.5)
    cfg = EnergyConfig()
    alone = [coupled_lm_ik(cfg, g, eta, goal[:, a:b], start[:, a:b], base_pos[:, a:b], base_rot[:, a:b], hold=hold[:, a:b], **{**kw, "change_of": q[:, a:b]})
             for a, b in ((0, 8), (8, 16))]  # fmt: skip
    groups = torch.tensor([0] * 8 + [1] * 8)
    together = coupled_lm_ik(cfg, g, eta, goal, start, base_pos, base_rot, hold=hold, groups=groups, **kw)
    for i, x in enumerate(together):
        torch.testing.assert_close(x, torch.cat([alone[0][i], alone[1][i]], 1), atol=1e-9, rtol=1e-9)
    shared = coupled_lm_ik(cfg, g, eta, goal, start, base_pos, base_rot, hold=hold, **kw)[0]
    assert not torch.allclose(shared, together[0], atol=1e-9, rtol=1e-9)


def test_face_points_reuse_the_last_two_poses_and_only_those():
    """:func:`mer_models.solver.faces.face_points` keeps its last two poses' results (an LM measures each
    accepted candidate again as its next iterate): the same pose (another tensor of the same values)
    gives the same tensors back, exact entries included; a new pose, a fresh result equal to a copy's."""
    from mer_data.kinematics.collision import pair_contacts
    from mer_models.batch import batch_fk
    from mer_models.solver.faces import face_points, fix_faces

    P, model, q, base_pos, base_rot, pos, rot = _talos_posed(4)
    entries, (depth, *_) = pair_contacts(model, pos, rot, margin=0.05, top=8, which="sat")
    faces = fix_faces(model, pos, rot, entries, depth.shape[-1], exact_over=0.0)
    assert faces["exact"] is not None  # some entries measured exactly at every pose
    first = face_points(model, pos, rot, faces)
    moved = batch_fk(P.graph, q + 0.05, base_pos, base_rot)
    second = face_points(model, *moved, faces)
    assert all(a is b for a, b in zip(face_points(model, pos.clone(), rot.clone(), faces), first))
    assert all(a is b for a, b in zip(face_points(model, *moved, faces), second))
    fresh = face_points(model, *moved, {**faces, "memo": []})
    assert all(torch.equal(a, b) for a, b in zip(fresh, second)) and not torch.equal(first[0], second[0])
    third = face_points(model, *batch_fk(P.graph, q - 0.05, base_pos, base_rot), faces)  # the first pose is now forgotten
    assert not any(a is b for a, b in zip(face_points(model, pos, rot, faces), first)) and third is not None


def test_a_refused_step_reuses_its_linearisation(monkeypatch):
    """``coupled_lm_ik``: after a step no group accepts, the iterate is the same, so the next iteration
    solves the same system (only the damping grows): the Jacobian is built once for both. H1 far from
    its goals with almost no damping, so the first full Gauss-Newton steps overshoot and are refused."""
    from mer_models.batch import batch_fk
    from mer_models.config import EnergyConfig
    from mer_models.solver import ik

    s, g, eta, q, base_pos, base_rot, goal, clamp = _h1_window(8)
    start = clamp(q + 1.5 * torch.sin(torch.arange(s.num_nodes, dtype=torch.float64)))
    calls = []
    real = ik._Problem.linearise
    monkeypatch.setattr(ik._Problem, "linearise", lambda self, *a: calls.append(1) or real(self, *a))
    stats: dict = {}
    out = ik.coupled_lm_ik(EnergyConfig(), g, eta, goal, start, base_pos, base_rot, iters=12, damping=1e-7, tol=0.0, stats=stats)
    assert stats["iterations"] == 12 and len(calls) < 12  # some steps refused, their systems not built again
    assert float((batch_fk(g, out[0], *out[1:])[0] - goal).norm(dim=-1).mean()) < float((batch_fk(g, start, base_pos, base_rot)[0] - goal).norm(dim=-1).mean())


def test_with_tries_a_refused_step_does_not_use_up_an_iteration():
    """``coupled_lm_ik(tries=...)``: H1 far from its goals with almost no damping (full Gauss-Newton
    steps overshoot and are refused): with ``tries`` = ``iters`` some of the iterations are refused
    steps; with more tries the solve takes more steps (at most ``iters``), using at most ``tries``
    linearisations, and ends no higher in cost."""
    from mer_models.config import EnergyConfig
    from mer_models.solver import ik

    s, g, eta, q, base_pos, base_rot, goal, clamp = _h1_window(8)
    start = clamp(q + 1.5 * torch.sin(torch.arange(s.num_nodes, dtype=torch.float64)))
    kw = dict(iters=12, damping=1e-7, tol=0.0)
    few, many = {}, {}
    ik.coupled_lm_ik(EnergyConfig(), g, eta, goal, start, base_pos, base_rot, stats=few, **kw)
    ik.coupled_lm_ik(EnergyConfig(), g, eta, goal, start, base_pos, base_rot, stats=many, tries=24, **kw)
    assert few["iterations"] == 12 and int(few["accepted"].min()) < 12
    assert int(few["accepted"].min()) < int(many["accepted"].min()) <= 12 and 12 < many["iterations"] <= 24
    assert float(many["cost"].sum()) <= float(few["cost"].sum())  # each step taken lowers the cost


def test_pair_depths_exact_near_contact_and_a_bound_beyond():
    """:func:`pair_depths` (separating-axis depth) on TALOS in random poses: every entry within the margin
    is each pair's separating-axis depth (:func:`contact_points`, both ways), the cheaper face bounds
    notwithstanding; with ``exact``, the entries within it still are, the rest up to the margin keep a
    bound: never below the exact depth, so "within the margin" finds every entry that is."""
    from mer_data.kinematics.collision import contact_points, pair_depths

    P, model, q, base_pos, base_rot, pos, rot = _talos_posed(8)
    pairs = torch.as_tensor(model.pairs)
    margin, near = 0.04, 0.007
    full = pair_depths(model, pos, rot, margin=margin, which="sat")  # (1, T, K)
    bound = pair_depths(model, pos, rot, margin=margin, which="sat", exact=near)
    bi, ti, ki = (full > -margin).nonzero(as_tuple=True)
    assert len(bi) > 50 and bool((full[bi, ti, ki] > 0).any())
    sat = contact_points(model, pos, rot, (bi, ti, ki, pairs[ki, 0], pairs[ki, 1]), len(pairs), "sat")[0][bi, ti, ki]
    torch.testing.assert_close(full[bi, ti, ki], sat, atol=1e-9, rtol=0)
    close = full > -near
    torch.testing.assert_close(bound[close], full[close], atol=0, rtol=0)
    assert bool((bound >= full - 1e-12).all()) and bool(((bound > -margin) >= (full > -margin)).all())
    assert bool((bound[~close & (full > -margin)] > full[~close & (full > -margin)] + 1e-4).any())  # a bound, not the depth


def test_a_round_measures_again_only_the_frames_its_solve_moved(monkeypatch):
    """The constraint rounds: frames the last round's solve did not take (held away from every unmet
    constraint) keep their measures; H1 standing on the floor, 6 of 60 frames' goals 3 cm under it,
    rounds on unmet constraints only from the first (``al_focus=0``): after the first round's measure
    of every frame, only the few frames near the dip are measured again, and the dip is taken out."""
    from mer_data.kinematics.collision import shape_points
    from mer_data.motion.features import source_features
    from mer_data.robots.registry import load_robot
    from mer_models.retarget.clip import retarget_features, sequence_metrics
    from mer_models.solver import constrained

    r = load_robot("h1")
    s, geom = r.skeleton, collision_model(r)
    J = s.num_nodes
    low = float(shape_points(geom, torch.from_numpy(s.rest_positions), torch.eye(3, dtype=torch.float64).expand(J, 3, 3))[..., 2].min())
    base = np.zeros((60, 3))
    base[:, 2] = -low
    base[27:33, 2] -= 0.03  # 6 frames 3 cm down
    feats = source_features(base, np.tile([1.0, 0, 0, 0], (60, 1)), np.zeros((60, J)), s, 30.0)
    seen = []
    real = constrained._lows
    monkeypatch.setattr(constrained, "_lows", lambda m, p, *a: seen.append(p.shape[1]) or real(m, p, *a))
    res = retarget_features(feats, s, s, method="optimize", fps=30.0, physics=PhysicsConfig(method="constraints", al_focus=0, al_lift=False))
    assert seen[0] == 60 and len(seen) > 1 and max(seen[1:]) < 30, seen  # round 0, then the moved frames
    m = sequence_metrics(feats, s, res.motion, prepared=res.prepared, geometry=geom)
    assert m["body_floor_frames"] == 0.0


def test_round_lows_exact_where_the_floor_shift_reaches_and_a_bound_above():
    """``constrained._lows`` on TALOS in random poses, half a metre up or down: each shape's lowest
    vertex exactly (as :func:`lowest_points`) where its bounding sphere reaches down to its floor shift
    or the shape is a foot; elsewhere a lower bound still above the shift, so the multiplier update and
    the floor violation come out the same."""
    from mer_data.kinematics.collision import lowest_points
    from mer_models.solver.constrained import _lows

    P, model, q, base_pos, base_rot, pos, rot = _talos_posed(6)
    pos = pos + torch.tensor([0.0, 0.0, 0.5]) * torch.tensor([1.0, -1.0, 0.3, 0.8, 1.1, 0.6], dtype=torch.float64)[None, :, None, None]
    exact = lowest_points(model, pos, rot)[0]
    shift = torch.rand(exact.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 0.3
    foot = torch.as_tensor(model.foot) > 0
    low = _lows(model, pos, rot, shift, foot)
    same = (low <= shift) | foot
    assert bool(same.any()) and not bool(same.all())
    torch.testing.assert_close(low[same], exact[same], atol=1e-12, rtol=0)
    assert bool((low[~same] <= exact[~same] + 1e-12).all()) and bool((low[~same] > shift[~same]).all())
    torch.testing.assert_close((shift - low).clamp_min(0), (shift - exact).clamp_min(0), atol=1e-12, rtol=0)


def test_a_real_walk_is_as_continuous(lafan1_dir):
    """TALOS walking from Unitree's G1 (frames 601-690 of walk1): the plain solution's soles are in the floor
    (TALOS's feet are longer), so the first lift stands them on it; lifted exactly onto the floor, every
    corner of a flat sole sat at its bound and a rounding-level change of the input moved bodies by
    2 cm (tools/bench_sensitivity.py). The lift now stops LIFT_MARGIN_M short: the rows start active."""
    from mer_data.motion.lafan1 import read_lafan1_csv

    g1, talos = load_robot("g1"), load_robot("talos")
    m = read_lafan1_csv(lafan1_dir / "g1" / "walk1_subject1.csv", g1)
    src = source_features(m.base_pos, m.base_quat, m.node_angles(g1.skeleton), g1.skeleton, 30.0)[600:690]
    cfg = PhysicsConfig(method="constraints")

    def bodies(f):
        from mer_models.retarget.clip import retarget_features

        return retarget_features(f, g1.skeleton, talos.skeleton, method="optimize", fps=30.0, physics=cfg).motion.forward_kinematics()[0]

    g = src.copy()
    g[:, 0, 3:6] += 1e-7 * np.random.default_rng(0).standard_normal((len(src), 3))
    assert float(np.linalg.norm(bodies(src) - bodies(g), axis=-1).max()) < 1e-4


def test_a_flat_face_on_the_plane_gives_its_centre_as_the_row_point():
    """A square lying flat 1 cm into the other body's face plane: its four corners are equally deep, so
    the self row's point is their centre (not whichever corner rounding makes deepest, and not pulled
    towards corner 0, which the shape's padding repeats)."""
    from types import SimpleNamespace

    from mer_models.solver.faces import face_points

    square = np.array([[0.0, 0, 0], [0.2, 0, 0], [0.2, 0.1, 0], [0, 0.1, 0]])
    verts = np.stack([np.concatenate([square, np.repeat(square[:1], 4, 0)]), np.zeros((8, 3))])  # padded as collision_model pads
    model = SimpleNamespace(node=np.array([0, 1]), vertices=verts)
    pos = torch.tensor([[[[0.0, 0.0, -0.01], [0.0, 0.0, 0.0]]]], dtype=torch.float64)  # (B, T, J, 3)
    rot = torch.eye(3, dtype=torch.float64).expand(1, 1, 2, 3, 3)
    one = torch.zeros(1, dtype=torch.long)
    faces = {"entries": (one, one, one, one, one + 1), "K": 1, "reach": one, "other": one + 1,
             "n": torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), "d": torch.zeros(1, dtype=torch.float64), "exact": None}  # fmt: skip
    depth, point, normal, reach, other = face_points(model, pos, rot, faces)
    assert float(depth[0, 0, 0]) == pytest.approx(0.01)
    torch.testing.assert_close(point[0, 0, 0], torch.tensor([0.1, 0.05, -0.01], dtype=torch.float64), atol=1e-9, rtol=0)


def test_a_floor_shift_under_a_body_high_above_it_makes_no_row():
    """A shape whose bounding sphere is above its floor shift (the multiplier of a constraint no longer
    acting) has no floor row: its vertices are not looked at and it reads as its sphere's bottom. (A
    shape not looked at had read 0, so ``0 - shift < 0`` made an acting row at the world origin.)"""
    T = 2
    r, P, q = _problem("h1", T, 3)
    model = collision_model(r)
    base_pos = torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64).expand(1, T, 3).clone()  # every body far above the floor
    base_rot = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3).clone()
    shift = torch.full((1, T, len(model.node)), 0.05, dtype=torch.float64)
    al = {"floor": shift, "entries": None, "anchor": [None, None]}
    phys = PhysicsInputs(model, None, 30.0, PhysicsConfig(w_self=0.0), al=al).build(P, 1.0)
    qd = P.columns(q)
    pos, rot, *_ = P.fit(qd, base_pos, base_rot)
    h, g, cost = phys.linearise(pos, rot, qd, phys.freeze(pos, rot, qd), with_cost=True)
    assert float(cost.abs().max()) == 0.0 and float(g.abs().max()) == 0.0 and float(h.abs().max()) == 0.0
    base_pos[..., 2] = 0.02  # lowered until its feet reach below the shift: rows there, and only from real vertices
    pos, rot, *_ = P.fit(qd, base_pos, base_rot)
    h, g, cost = phys.linearise(pos, rot, qd, phys.freeze(pos, rot, qd), with_cost=True)
    assert float(cost.max()) > 0


def test_no_extra_round_after_a_round_that_left_the_deep_pair_as_deep(monkeypatch):
    """The rounds after ``al_rounds`` (``al_extra``) run only while the last one brought the worst pair
    ``PROGRESS_M`` nearer its margin: with solves that move nothing (TALOS's feet through each other,
    hips rolled in, stay so) the rounds stop at ``al_rounds``; the crossed-feet test in test_physics is
    the case where they go on and part the feet."""
    import mer_models.solver.constrained as constrained
    from mer_data.kinematics.collision import shape_points
    from mer_models.retarget.clip import retarget_features

    r = load_robot("talos")
    s, geom = r.skeleton, collision_model(r)
    F, J = 12, r.skeleton.num_nodes
    q = np.zeros((F, J))
    hip = [s.node_names.index(n) for n in s.node_names if "leg_left_2" in n or "leg_right_2" in n]
    q[:, hip[0]], q[:, hip[1]] = -0.3, 0.3
    low = float(shape_points(geom, torch.from_numpy(s.rest_positions), torch.eye(3, dtype=torch.float64).expand(J, 3, 3))[..., 2].min())
    base = np.zeros((F, 3))
    base[:, 2] = -low
    feats = source_features(base, np.tile([1.0, 0, 0, 0], (F, 1)), q, s, 30.0)
    calls = []

    def still(cfg, graph, eta, goal, q, base_pos, base_rot, **kw):
        calls.append(q.shape[1])
        return q, base_pos, base_rot

    monkeypatch.setattr(constrained, "coupled_lm_ik", still)
    cfg = PhysicsConfig()
    retarget_features(feats, s, s, method="optimize", fps=30.0, physics=cfg)
    assert cfg.al_extra > 0 and len(calls) == cfg.al_rounds, calls
