"""The dynamics (mer_data.kinematics.dynamics) against MuJoCo: mass, centre of mass, centroidal
momentum (mj_subtreeVel) and inverse dynamics (mj_inverse) of G1 on a smooth random trajectory, and
the zero-moment point of a robot pushed forward."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mer_data.kinematics import dynamics as dyn
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.articulation import articulation
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import load_robot
from mer_models.export.mjcf import mjcf_model


def _rotvec(v: np.ndarray) -> np.ndarray:
    k = torch.tensor([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]], dtype=torch.float64)
    return torch.linalg.matrix_exp(k).numpy()


@pytest.fixture(scope="module")
def g1():
    r = load_robot("g1")
    m = mujoco.MjModel.from_xml_string(mjcf_model(r))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return r, m


def test_mass_model_matches_mujoco(g1):
    r, m = g1
    mm = mass_model(r)
    assert mm.total_mass == pytest.approx(m.body_subtreemass[1], rel=1e-9)
    assert np.isfinite(mm.effort[r.skeleton.dof_mask]).all()  # every G1 joint has a <limit effort>
    assert mm.effort[r.skeleton.node_index("left_knee_joint")] == pytest.approx(139.0)


def test_momentum_and_inverse_dynamics_match_mujoco(g1):
    r, m = g1
    skel, art, mm = r.skeleton, articulation(r), mass_model(r)
    rng = np.random.default_rng(0)
    dof = skel.dof_mask
    q0 = np.where(dof, rng.uniform(skel.lower, skel.upper) * 0.5, 0)
    qv, qa = np.where(dof, rng.normal(size=skel.num_nodes), 0), np.where(dof, rng.normal(size=skel.num_nodes) * 3, 0)
    b0, bv, ba = np.array([0.1, -0.2, 0.8]), np.array([0.3, 0.1, -0.2]), np.array([1.0, -0.5, 2.0])
    w0, wv, wa = np.array([0.2, -0.1, 0.4]), np.array([0.5, 0.8, -0.3]), np.array([1.0, 2.0, -1.0])
    h = 1e-3
    ts = np.arange(-3, 4) * h
    Q = np.array([q0 + qv * t + qa * t * t / 2 for t in ts])
    P = np.array([b0 + bv * t + ba * t * t / 2 for t in ts])
    R = np.array([_rotvec(w0 + wv * t + wa * t * t / 2) for t in ts])
    pos, rot = fk_skeleton(skeleton_tensors(skel, torch.float64), torch.from_numpy(Q), torch.from_numpy(P), base_rot=torch.from_numpy(R))
    w = dyn.body_wrenches(mm, pos, rot, 1 / h, filtered=False)
    dem = dyn.demand(mm, w)
    tau = dyn.joint_torques(skel, w, pos, rot)
    c, lin, ang = dyn.centroidal_momentum(mm, pos, rot, 1 / h)

    def qpos(i):
        out = np.zeros(m.nq)
        out[:3] = P[i]
        mujoco.mju_mat2Quat(out[3:7], R[i].reshape(-1))
        out[7:] = art.joint_values(Q[i : i + 1])[0]
        return out

    def diff(a, b, dt):
        v = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, v, dt, a, b)
        return v

    k, qp = 3, [qpos(i) for i in range(len(ts))]
    d = mujoco.MjData(m)
    d.qpos[:] = qp[k]
    d.qvel[:] = diff(qp[k - 1], qp[k + 1], 2 * h)
    d.qacc[:] = (diff(qp[k], qp[k + 1], h) - diff(qp[k - 1], qp[k], h)) / h
    mujoco.mj_inverse(m, d)
    mujoco.mj_subtreeVel(m, d)
    np.testing.assert_allclose(c[k].numpy(), d.subtree_com[1], atol=1e-9)
    np.testing.assert_allclose(lin[k].numpy(), d.subtree_linvel[1] * m.body_subtreemass[1], atol=1e-3)
    np.testing.assert_allclose(ang[k].numpy(), d.subtree_angmom[1], atol=1e-3)  # O(h^2) of differences
    np.testing.assert_allclose(dem.force[k].numpy(), d.qfrc_inverse[:3], atol=1e-3)  # world force on the free joint
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    for j in np.flatnonzero(dof):
        dof_adr = m.jnt_dofadr[names.index(skel.urdf_joint_names[j])]
        assert float(tau[k, j]) == pytest.approx(d.qfrc_inverse[dof_adr], abs=1e-3), skel.urdf_joint_names[j]
    assert np.abs(d.qfrc_inverse[6:]).max() > 5  # the check is not vacuous: torques of several N m


def test_zmp_of_a_robot_pushed_forward_moves_back_by_the_known_amount(g1):
    """A standing pose carried with constant forward acceleration a: the ZMP lies c_z a / g behind
    the centre of mass, and with a = 0 right under it (binomial filter and central differences
    are exact on a quadratic path)."""
    r, _ = g1
    skel, mm = r.skeleton, mass_model(r)
    F, fps = 20, 30.0
    t = np.arange(F) / fps
    st = skeleton_tensors(skel, torch.float64)
    q = torch.zeros(F, skel.num_nodes, dtype=torch.float64)
    rot0 = torch.eye(3, dtype=torch.float64).expand(F, 3, 3)
    for a in (0.0, 1.5):
        base = torch.from_numpy(np.stack([0.5 * a * t**2, np.zeros(F), np.full(F, 0.78)], -1))
        pos, rot = fk_skeleton(st, q, base, base_rot=rot0)
        dem = dyn.demand(mm, dyn.body_wrenches(mm, pos, rot, fps))
        p = dyn.zmp(dem).numpy()
        c = dem.com.numpy()
        np.testing.assert_allclose(p[:, 0], c[:, 0] - c[:, 2] * a / dyn.GRAVITY, atol=1e-9)
        np.testing.assert_allclose(p[:, 1], c[:, 1], atol=1e-9)
    assert c[0, 2] * 1.5 / dyn.GRAVITY > 0.08  # the shift is large enough to tell


def test_torch_dynamics_are_differentiable(g1):
    r, _ = g1
    skel, mm = r.skeleton, mass_model(r)
    F = 7
    q = torch.zeros(F, skel.num_nodes, dtype=torch.float64, requires_grad=True)
    base = torch.tensor([0.0, 0.0, 0.78], dtype=torch.float64).expand(F, 3) + torch.linspace(0, 0.1, F, dtype=torch.float64)[:, None]
    pos, rot = fk_skeleton(skeleton_tensors(skel, torch.float64), q, base, base_rot=torch.eye(3, dtype=torch.float64).expand(F, 3, 3))
    dyn.zmp(dyn.demand(mm, dyn.body_wrenches(mm, pos, rot, 30.0)))[3].sum().backward()
    assert torch.isfinite(q.grad).all() and q.grad.abs().sum() > 0
