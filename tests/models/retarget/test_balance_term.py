"""The balance-term prototype: its residual is the ZMP's excess, its Jacobian couples three frames,
and a step along it moves a leaning stance's ZMP back into the foot."""

from __future__ import annotations

import torch

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.collision import collision_model
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import load_robot
from mer_models.retarget.balance_term import balance_jacobian, balance_residual, stance_planes


def test_residual_and_its_three_frame_jacobian():
    r = load_robot("g1")
    skel, mm, geo = r.skeleton, mass_model(r), collision_model(r)
    st = skeleton_tensors(skel, torch.float64)
    F, fps = 9, 30.0
    q = torch.zeros(F, skel.num_nodes, dtype=torch.float64)
    q[:, skel.node_index("right_knee_joint")] = 1.0  # stand on the left foot: the right one lifted
    q[:, skel.node_index("right_hip_pitch_joint")] = -0.5
    rot = torch.eye(3, dtype=torch.float64).expand(F, 3, 3).contiguous()
    from mer_data.kinematics.collision import shape_points

    pos0, rot0 = fk_skeleton(st, q, torch.zeros(F, 3, dtype=torch.float64), base_rot=rot)
    zmin = float(shape_points(geo, pos0, rot0, "vertices")[..., 2].min())
    base = torch.tensor([0.0, 0.0, -zmin + 0.005], dtype=torch.float64).expand(F, 3).contiguous()
    pos, rot_n = fk_skeleton(st, q, base, base_rot=rot)
    planes, single, flight = stance_planes(pos.numpy(), rot_n.numpy(), fps, skel, mm, geo)
    assert single[2:-2].all() and not flight.any()
    args = (st, skel, mm, fps, torch.from_numpy(planes), torch.from_numpy(single), torch.from_numpy(flight))
    res0 = balance_residual(q, base, rot, *args)
    assert float(res0[4].max()) > 0.01  # the CoM sits between the feet, outside the left sole
    # the Jacobian of frame 4 reaches frames 3..5 only
    res, jac = balance_jacobian(q, base, rot, *args)
    torch.testing.assert_close(res, res0)
    reach = jac[4].abs().sum((0, 2)) > 0
    assert reach.tolist() == [False, False, False, True, True, True, False, False, False]
    # a Gauss-Newton step in the base's sideways path alone (mid frames) lowers the excess
    x = torch.zeros(F, dtype=torch.float64, requires_grad=True)

    def moved(x):
        return balance_residual(q, base + torch.stack([torch.zeros_like(x), x, torch.zeros_like(x)], -1), rot, *args)[2:-2].flatten()

    jx = torch.autograd.functional.jacobian(moved, x)
    rr = moved(x).detach()
    step = -torch.linalg.solve(jx.T @ jx + 1e-6 * torch.eye(F, dtype=torch.float64), jx.T @ rr)
    assert float(moved(step).norm()) < 0.5 * float(rr.norm())
