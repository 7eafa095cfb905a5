"""The LM solvers' normal equations (``_Problem.linearise``) against autograd's Jacobian of the residuals,
on a mixed batch (padding, two robots) with mimic joints, and the block-tridiagonal solve's first level."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from model_helpers import mixed_batch

from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_models.batch import graph_from_batch
from mer_models.config import EnergyConfig
from mer_models.solver.ik import _Problem


def _double(g):
    return type(g)(**{f.name: (getattr(g, f.name).double() if getattr(g, f.name).is_floating_point() else getattr(g, f.name))
                      for f in dataclasses.fields(g)})  # fmt: skip


def _with_mimics(g):
    """G1's graph (sample 0) with two joints made to follow others (``q_j = m q_k + o``): the wrists
    follow the elbows, as a URDF ``<mimic>`` does; tron1 (sample 1) keeps its own."""
    src, mult, off = g.mimic_source.clone(), g.mimic_multiplier.clone(), g.mimic_offset.clone()
    pairs = [
        (j, int(g.parents[0, j]))
        for j in range(1, g.parents.shape[1])
        if bool(g.revolute[0, j]) and bool(g.revolute[0, int(g.parents[0, j])])
    ]
    for (j, k), m in zip(pairs[-2:], (0.5, -1.25)):
        src[0, j], mult[0, j], off[0, j] = k, m, 0.1
    return dataclasses.replace(g, mimic_source=src, mimic_multiplier=mult, mimic_offset=off)


@pytest.mark.parametrize("mimic", [False, True])
def test_normal_equations_are_the_residual_jacobians(mimic):
    b = mixed_batch(("g1", "tron1"), frames=6)
    g = _double(graph_from_batch(b, "tgt"))
    if mimic:
        g = _with_mimics(g)
    B, T, J = 2, 2, g.parents.shape[1]  # two frames: the cost is one backward pass per residual row of every frame
    torch.manual_seed(0)
    lo, hi = g.lower[:, None], g.upper[:, None]
    q = (lo + (hi - lo) * (0.25 + 0.5 * torch.rand(B, T, J, dtype=torch.float64))) * g.revolute[:, None]
    bp = torch.randn(B, T, 3, dtype=torch.float64) * 0.1
    br = axis_angle_to_matrix(torch.randn(B, T, 3, dtype=torch.float64) * 0.3)
    goal = b["ref_scaled_pos"][:, :T].double()
    grot = axis_angle_to_matrix(torch.randn(goal.shape[:-1] + (3,), dtype=torch.float64) * 0.5)
    rmask = torch.zeros(B, goal.shape[2], dtype=torch.bool)
    rmask[:, :4] = True
    P = _Problem(EnergyConfig(), g, b["joint_map"].double(), goal, q, grot, rmask)
    assert P.M > 0 and (P.ent_fold is not None) == mimic
    qd = P.columns(q)
    pos, rot, kp, ocols, _ = P.fit(qd, bp, br)
    h, grad = P.linearise(pos, rot, kp, ocols)

    def residuals(step):  # the weighted residuals after a step (B, T, n): key points, then rotation columns
        pos, rot, kp, ocols, _ = P.fit(*P.candidate(qd, bp, br, step))
        return torch.cat(
            [((kp - P.goals) * P.w_kp[..., None].sqrt()).flatten(2), ((ocols - P.gcols) * P.w_o[..., None].sqrt()).flatten(2)], 2
        )

    step0 = torch.zeros(B, T, P.n, dtype=torch.float64, requires_grad=True)
    r = residuals(step0)
    # frames and samples are independent, so one backward pass per row index gives that row of every
    # (sample, frame) block at once: (B, T, rows, n); a coupling between frames would show as a mismatch
    jac = torch.stack([torch.autograd.grad(r[..., k].sum(), step0, retain_graph=True)[0] for k in range(r.shape[-1])], 2)
    r = r.detach()
    for bi in range(B):
        for t in range(T):
            jj = jac[bi, t]  # (rows, n)
            torch.testing.assert_close(h[bi, t], jj.T @ jj, rtol=1e-9, atol=1e-10)
            torch.testing.assert_close(grad[bi, t], jj.T @ r[bi, t], rtol=1e-9, atol=1e-10)
