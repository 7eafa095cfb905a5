"""f_kin through the foundation FK, the LM IK's Jacobian, and the optimisation baseline."""

from __future__ import annotations

import torch
from model_helpers import MICRO, mixed_batch

from mer_data.robots.registry import get_skeleton
from mer_models.batch import batch_fk, graph_from_batch
from mer_models.config import EnergyConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.solver.energy import energy_terms, f_kin, split_motion
from mer_models.solver.ik import ancestors
from mer_models.solver.optimize import optimize_motion

CFG = EnergyConfig()


def _truth(b):
    q, bp, br = split_motion(b["target"])
    return q, bp, br


def test_the_reference_itself_has_no_tracking_energy():
    b = mixed_batch(("g1",))  # G1 -> G1: the scaled reference is the reference
    g = graph_from_batch(b, "tgt")
    e = f_kin(CFG, g, b["target"], b["joint_map"], b["ref_scaled_pos"])
    assert float(e["kp"]) < 1e-9 and float(e["cst"]) < 1e-9 and float(e["vel"]) < 1e-8
    assert float(e["norm"]) > 0


def test_mixed_batch_energy_equals_per_sample_energy():
    names = ("tron1", "g1", "h1")
    b = mixed_batch(names)
    g = graph_from_batch(b, "tgt")
    torch.manual_seed(0)
    J = b["tgt_mask"].shape[1]
    q = torch.randn(3, 60, J) * 0.3
    bp = torch.randn(3, 60, 3)
    br = torch.eye(3).expand(3, 60, 3, 3)
    mixed = energy_terms(CFG, g, q, bp, br, b["joint_map"], b["ref_scaled_pos"])["total"]
    for k, n in enumerate(names):
        one = mixed_batch((n,), seed=k)
        g1 = graph_from_batch(one, "tgt")
        Jk = one["tgt_mask"].shape[1]
        e = energy_terms(CFG, g1, q[k : k + 1, :, :Jk], bp[k : k + 1], br[k : k + 1], one["joint_map"], one["ref_scaled_pos"])
        torch.testing.assert_close(e["total"], mixed[k : k + 1], rtol=1e-5, atol=1e-7)


def test_energy_gradient_is_correct():
    b = mixed_batch(("tron1",))
    g = graph_from_batch(b, "tgt")
    g = type(g)(**{k: (v.double() if v.is_floating_point() else v) for k, v in g.__dict__.items()})
    T = 5
    goal = b["ref_scaled_pos"][:, :T].double()
    eta = b["joint_map"].double()
    torch.manual_seed(0)
    J = g.parents.shape[1]
    q = (torch.rand(1, T, J, dtype=torch.float64) - 0.5).requires_grad_()
    bp = torch.randn(1, T, 3, dtype=torch.float64, requires_grad=True)
    br = torch.eye(3, dtype=torch.float64).expand(1, T, 3, 3)
    assert torch.autograd.gradcheck(lambda q, bp: energy_terms(CFG, g, q, bp, br, eta, goal)["total"], (q, bp))


def test_ancestors_match_the_skeleton():
    b = mixed_batch(("g1", "tron1"))
    anc = ancestors(b["tgt_parents"])
    for k, name in enumerate(("g1", "tron1")):
        s = get_skeleton(name)
        for j in range(s.num_nodes):
            expect = set(s.path_to_root(j)[1:])
            assert set(torch.nonzero(anc[k, j]).flatten().tolist()) == expect


def test_optimisation_recovers_a_reachable_motion_within_limits():
    """G1 -> G1: the scaled reference is exactly reachable; the baseline must get there."""
    b = mixed_batch(("g1", "h1"))
    g = graph_from_batch(b, "tgt")
    from mer_data.kinematics.rotations import axis_angle_to_matrix

    ref_rot = axis_angle_to_matrix(b["reference"][:, :, 0, 0:3])
    out = optimize_motion(CFG, g, b["joint_map"], b["ref_scaled_pos"], ref_rot, iters=30, gn_iters=15)
    init = optimize_motion(CFG, g, b["joint_map"], b["ref_scaled_pos"], ref_rot, iters=0, gn_iters=0)
    assert (out["energy"] < init["energy"]).all()
    pos, _ = batch_fk(g, out["q"], out["base_pos"], out["base_rot"])
    kp = b["joint_map"][0].sum(-1) > 0
    err = (pos[0][:, kp] - b["ref_scaled_pos"][0][:, b["joint_map"][0].argmax(-1)[kp]]).norm(dim=-1)
    assert float(err.mean()) < 0.01  # metres (the regulariser keeps it from 0)
    q = out["q"]
    assert ((q >= g.lower[:, None] - 1e-6) & (q <= g.upper[:, None] + 1e-6)).all()


def _double(g):
    return type(g)(**{k: (v.double() if v.is_floating_point() else v) for k, v in g.__dict__.items()})


def test_optimisation_of_a_sample_does_not_depend_on_the_batch():
    """Nothing couples samples (per-frame damping, acceptance and solve; per-sample stopping; the
    Adam loss is a sum), so a sample's result is the same alone or next to another robot.

    In float64: differently padded systems round differently, and in float32 an accept/reject
    decision near a tie can amplify that rounding (8.7e-5 rad once seen on a loaded machine)."""
    b = mixed_batch(("h1", "tron1"))
    one = mixed_batch(("h1",))
    from mer_data.kinematics.rotations import axis_angle_to_matrix

    def run(bb):
        g = _double(graph_from_batch(bb, "tgt"))
        r = axis_angle_to_matrix(bb["reference"][:, :, 0, 0:3].double())
        return optimize_motion(CFG, g, bb["joint_map"].double(), bb["ref_scaled_pos"].double(), r, iters=5, gn_iters=8,
                               goal_rot=bb["ref_goal_rot"].double(), rot_mask=bb["ref_rot_mask"])  # fmt: skip

    a, c = run(b), run(one)
    J = one["tgt_mask"].shape[1]
    torch.testing.assert_close(a["q"][:1, :, :J], c["q"], atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(a["base_pos"][:1], c["base_pos"], atol=1e-9, rtol=1e-9)


def test_model_energy_uses_physical_units():
    m = RetargetModel(MICRO)
    b = mixed_batch(("g1",))
    cond = m.conditions(b)
    x = m.target_sample(b["target"], cond)
    e = m.energy(x, cond, CFG)
    assert float(e["kp"]) < 1e-8 and float(e["cst"]) < 1e-8
