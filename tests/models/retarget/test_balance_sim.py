"""The balance metric against MuJoCo simulating a stepping G1 (issue 54, deliverable 1).

MuJoCo simulates G1 on a floor, PD-held to a scripted step in place: the weight shifted over the
left foot, the right foot lifted (single support), put down again. Its body poses,
sampled at 30 frames/s, go through mer's metric, which knows nothing of the simulation's contacts:

* the motion reads feasible (no frame infeasible, the single-support ZMP inside the stance foot);
* mer's ZMP (from the motion alone) lies where MuJoCo's contact forces put their centre of pressure
  (median 1 mm apart);
* the same motion carried forward with a constant acceleration ``a`` moves the ZMP back, relative
  to the body, by ``c_z M a / f_z`` (``c_z a / g`` at rest): the known amount.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mer_data.kinematics import dynamics as dyn
from mer_data.kinematics.collision import shape_points
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.articulation import articulation
from mer_data.robots.collision import collision_model
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import load_robot
from mer_models.export.mjcf import mjcf_model
from mer_models.retarget.balance import balance_frames, balance_metrics

FPS = 30.0
SWAY = 0.2  # [rad] hip roll carrying the pelvis over the left foot
# the script, in seconds: sway over (0-1.5), lift the right foot (1.7-2.0), hold, lower it (2.2-2.5), stand
LIFT, LOWER, END = (1.7, 2.0), (2.2, 2.5), 3.0


def _ease(t: float, a: float, b: float) -> float:
    s = np.clip((t - a) / (b - a), 0, 1)
    return 0.5 - 0.5 * np.cos(np.pi * s)


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _reference(skel, t: float) -> np.ndarray:
    """The PD target (J,) at time ``t`` [s]: knees bent; sway over the left foot; the right foot up and
    down; each ankle's pitch and roll keeping its sole parallel to the pelvis (G1's chain: hip pitch,
    roll, yaw, knee, ankle pitch, roll; all four sole spheres on the floor)."""
    q = np.zeros(skel.num_nodes)
    sway = SWAY * _ease(t, 0.0, 1.5)
    lift = _ease(t, *LIFT) - _ease(t, *LOWER)
    for side in ("left", "right"):
        up = lift if side == "right" else 0.0
        hp, hr, k = -0.2 - 0.2 * up, -sway, 0.4 + 0.4 * up  # negative hip roll: the pelvis to +y, over the left foot
        u = (_ry(hp) @ _rx(hr) @ _ry(k)).T[:, 2]  # the pelvis' z axis in the shin's frame
        q[skel.node_index(f"{side}_hip_pitch_joint")] = hp
        q[skel.node_index(f"{side}_hip_roll_joint")] = hr
        q[skel.node_index(f"{side}_knee_joint")] = k
        q[skel.node_index(f"{side}_ankle_pitch_joint")] = np.arctan2(u[0], u[2])
        q[skel.node_index(f"{side}_ankle_roll_joint")] = -np.arcsin(u[1])
    return q


@pytest.fixture(scope="module")
def stepping():
    """Node frames (F, J, 3), (F, J, 3, 3) of the simulated step at 30 frames/s, and MuJoCo's contact
    wrench per frame: force (F, 3) [N] and moment about the world origin (F, 3) [N m], each the mean over
    the frame's 1/30 s (the first 0.5 s, settling, dropped)."""
    r = load_robot("g1")
    skel, art, geo = r.skeleton, articulation(r), collision_model(r)
    spec = mujoco.MjSpec.from_string(mjcf_model(r))
    for g in spec.geoms:
        g.contype, g.conaffinity = 2, 0  # the robot touches the floor only
    floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1])
    floor.contype, floor.conaffinity = 0, 2
    m = spec.compile()
    m.opt.timestep = 0.002
    m.opt.integrator = int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
    m.opt.cone = int(mujoco.mjtCone.mjCONE_ELLIPTIC)
    d = mujoco.MjData(m)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    nodes = np.flatnonzero(skel.dof_mask)
    qadr = np.array([m.jnt_qposadr[names.index(skel.urdf_joint_names[j])] for j in nodes])
    vadr = np.array([m.jnt_dofadr[names.index(skel.urdf_joint_names[j])] for j in nodes])
    m.dof_damping[vadr] = 20.0
    st = skeleton_tensors(skel, torch.float64)
    q0 = _reference(skel, 0.0)
    eye = torch.eye(3, dtype=torch.float64)[None]
    p, rt = fk_skeleton(st, torch.from_numpy(q0)[None], torch.zeros(1, 3, dtype=torch.float64), base_rot=eye)
    d.qpos[:3] = [0, 0, 0.002 - float(shape_points(geo, p, rt, "vertices")[..., 2].min())]
    d.qpos[3:7] = [1, 0, 0, 0]
    d.qpos[7:] = art.joint_values(q0[None])[0]
    every = int(round(1 / FPS / m.opt.timestep))
    frames, wrench = [], []
    acc, c6 = np.zeros(6), np.zeros(6)
    for i in range(int(round(END / m.opt.timestep))):
        d.qfrc_applied[vadr] = 1500.0 * (_reference(skel, i * m.opt.timestep)[nodes] - d.qpos[qadr])
        mujoco.mj_step(m, d)
        w = np.zeros(6)
        for k in range(d.ncon):  # every contact's force in the world, and its moment about the origin
            mujoco.mj_contactForce(m, d, k, c6)
            frame = d.contact[k].frame.reshape(3, 3)  # rows: the contact normal and tangents
            f = frame.T @ c6[:3]
            w += np.r_[f, np.cross(d.contact[k].pos, f)]
        acc += w
        if (i + 1) % every == every // 2:  # the frame at the middle of its interval of steps
            frames.append(d.qpos.copy())
        if (i + 1) % every == 0:
            wrench.append(acc / every)
            acc = np.zeros(6)
    n = min(len(frames), len(wrench))
    Q, W = np.array(frames[:n])[15:], np.array(wrench[:n])[15:]
    q = np.zeros((len(Q), skel.num_nodes))
    q[:, nodes] = Q[:, qadr]
    pos, rot = fk_skeleton(st, torch.from_numpy(q), torch.from_numpy(Q[:, :3]), base_quat=torch.from_numpy(Q[:, 3:7]))
    return r, pos.numpy(), rot.numpy(), W[:, :3], W[:, 3:]


def test_simulated_step_reads_feasible(stepping):
    r, pos, rot, _, _ = stepping
    mm, geo = mass_model(r), collision_model(r)
    b = balance_frames(pos, rot, FPS, r.skeleton, mm, geo, torques=False)
    single = (b["support"] == 1) & b["valid"]
    assert single.sum() >= 8  # it really stood on one foot (> 0.25 s)
    assert (b["support"][b["valid"]] > 0).all()  # and never fell or jumped
    out = balance_metrics(pos, rot, FPS, r.skeleton, mm, geo, torques=False)
    assert out["balance_infeasible"] <= 0.02
    assert out["zmp_out_single"] == 0.0
    assert out["pull_frames"] == 0 and out["slip_frames"] == 0


def test_zmp_is_where_mujoco_puts_the_centre_of_pressure(stepping):
    """mer's ZMP (motion only) against the centre of pressure of MuJoCo's contact forces, both through the
    metric's one smoothing filter: a few mm apart (median), 1.5 cm at most (the swing foot's touchdown, an
    impact within one frame)."""
    r, pos, rot, force, moment = stepping
    mm = mass_model(r)
    p = torch.from_numpy(pos)
    d = dyn.demand(mm, dyn.body_wrenches(mm, p, torch.from_numpy(rot), FPS))
    ours = dyn.zmp(d).numpy()
    f, n = dyn.smooth(torch.from_numpy(force)).numpy(), dyn.smooth(torch.from_numpy(moment)).numpy()
    cop = np.stack([-n[:, 1] / f[:, 2], n[:, 0] / f[:, 2]], -1)  # the floor point (z = 0) with no moment about x, y
    v = slice(dyn.EDGE + 2, len(pos) - dyn.EDGE - 2)
    err = np.linalg.norm(ours[v] - cop[v], axis=-1)
    assert np.median(err) < 0.003 and err.max() < 0.015, (np.median(err), err.max())
    np.testing.assert_allclose(d.force.numpy()[v], f[v], atol=0.03 * float(d.mass) * dyn.GRAVITY)
    assert np.ptp(cop[v, 1]) > 0.1  # not vacuous: the centre of pressure crossed from between the feet to the left one


def test_a_push_forward_moves_the_zmp_back_by_the_known_amount(stepping):
    r, pos, rot, _, _ = stepping
    mm = mass_model(r)
    F, a = len(pos), 1.2  # [m/s^2]
    t = np.arange(F) / FPS
    shift = np.zeros((F, 1, 3))
    shift[:, 0, 0] = 0.5 * a * t**2
    rr = torch.from_numpy(rot)
    d0 = dyn.demand(mm, dyn.body_wrenches(mm, torch.from_numpy(pos), rr, FPS))
    d1 = dyn.demand(mm, dyn.body_wrenches(mm, torch.from_numpy(pos + shift), rr, FPS))
    z0, z1 = dyn.zmp(d0).numpy(), dyn.zmp(d1).numpy()
    back = d0.com[:, 2].numpy() * float(d0.mass) * a / d0.force[:, 2].numpy()  # c_z M a / f_z
    np.testing.assert_allclose((z1[:, 0] - shift[:, 0, 0]) - z0[:, 0], -back, atol=1e-9)
    np.testing.assert_allclose(z1[:, 1], z0[:, 1], atol=1e-9)
    assert (
        np.median(np.abs(back - d0.com[:, 2].numpy() * a / dyn.GRAVITY)) < 0.005
    )  # ~ c_z a / g: this motion is mostly near rest
    assert np.median(back) > 0.08  # the shift is large enough to tell
