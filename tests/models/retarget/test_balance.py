"""The balance metrics (mer_models.retarget.balance) on motions MuJoCo simulated (a standing G1 and
one that sways its weight over one foot and back: both physically consistent, so ~0 infeasible
frames), on a kinematic motion no contact can hold, and the support polygon's distance."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mer_data.kinematics.collision import shape_points
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.robots.articulation import articulation
from mer_data.robots.collision import collision_model
from mer_data.robots.inertia import mass_model
from mer_data.robots.registry import load_robot
from mer_models.export.mjcf import mjcf_model
from mer_models.retarget.balance import balance_frames, balance_metrics, best_contact_torques, polygon_distance

FPS = 30.0


def test_polygon_distance():
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], float)
    assert polygon_distance(np.array([0.5, 0.2]), square) == 0.0
    assert polygon_distance(np.array([1.5, 0.5]), square) == pytest.approx(0.5)
    assert polygon_distance(np.array([2.0, 2.0]), square) == pytest.approx(np.sqrt(2))
    seg = np.array([[0, 0], [1, 0], [0.5, 0]], float)  # collinear: a segment
    assert polygon_distance(np.array([0.5, 0.3]), seg) == pytest.approx(0.3)
    assert polygon_distance(np.array([3.0, 4.0]), np.array([[0.0, 0.0]] * 3)) == pytest.approx(5.0)


def test_best_contact_split_carries_a_load_within_the_limit():
    """A unit mass on one contact point under a joint: without contact force the joint holds the
    whole weight (over its limit); the split lets the floor carry it."""
    points, com = np.array([[0.0, 0.0, 0.0]]), np.array([0.0, 0.0, 0.5])
    force, moment = np.array([0.0, 0.0, 9.81]), np.zeros(3)
    amap = np.array([[0.0, 0.0, 1.0]])  # the joint's torque falls by 1 N m per newton up at the point
    tau = best_contact_torques(np.array([9.81]), amap, points, com, force, moment, np.array([1.0]), 1.0)
    assert abs(tau[0]) <= 1.0 + 1e-6


def _simulate(sway: bool, seconds: float = 4.0):
    """G1 on a floor in MuJoCo, PD-held at a knees-bent stance; ``sway``: hip and ankle rolls carry the
    pelvis over the left foot and back (feet flat). Node frames at 30 frames/s, the first 0.5 s dropped."""
    r = load_robot("g1")
    skel, art, geo = r.skeleton, articulation(r), collision_model(r)
    spec = mujoco.MjSpec.from_string(mjcf_model(r))
    for g in spec.geoms:
        g.contype, g.conaffinity = 2, 0  # the robot touches the floor only
    floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1])
    floor.contype, floor.conaffinity = 0, 2
    m = spec.compile()
    m.opt.timestep = 0.001
    m.opt.integrator = int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
    d = mujoco.MjData(m)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    nodes = np.flatnonzero(skel.dof_mask)
    qadr = np.array([m.jnt_qposadr[names.index(skel.urdf_joint_names[j])] for j in nodes])
    vadr = np.array([m.jnt_dofadr[names.index(skel.urdf_joint_names[j])] for j in nodes])
    m.dof_damping[vadr] = 20.0
    st = skeleton_tensors(skel, torch.float64)

    def ref(t):
        q = np.zeros(skel.num_nodes)
        for side in ("left", "right"):
            q[skel.node_index(f"{side}_hip_pitch_joint")] = -0.2
            q[skel.node_index(f"{side}_knee_joint")] = 0.4
            q[skel.node_index(f"{side}_ankle_pitch_joint")] = -0.2
            if sway:  # negative hip roll (positive ankle roll) carries G1's pelvis to +y, over the left foot
                s = np.clip(t / 1.5, 0, 1) - np.clip((t - 2.0) / 1.5, 0, 1)
                th = 0.2 * (0.5 - 0.5 * np.cos(np.pi * s))
                q[skel.node_index(f"{side}_hip_roll_joint")] -= th
                q[skel.node_index(f"{side}_ankle_roll_joint")] += th
        return q

    q0 = ref(0.0)
    eye = torch.eye(3, dtype=torch.float64)[None]
    p, rt = fk_skeleton(st, torch.from_numpy(q0)[None], torch.zeros(1, 3, dtype=torch.float64), base_rot=eye)
    d.qpos[:3] = [0, 0, 0.002 - float(shape_points(geo, p, rt, "vertices")[..., 2].min())]
    d.qpos[3:7] = [1, 0, 0, 0]
    d.qpos[7:] = art.joint_values(q0[None])[0]
    every, frames = int(round(1 / FPS / m.opt.timestep)), []
    for i in range(int(round(seconds / m.opt.timestep))):
        d.qfrc_applied[vadr] = 1500.0 * (ref(i * m.opt.timestep)[nodes] - d.qpos[qadr])
        mujoco.mj_step(m, d)
        if i % every == 0:
            frames.append(d.qpos.copy())
    Q = np.array(frames)[15:]
    q = np.zeros((len(Q), skel.num_nodes))
    q[:, nodes] = Q[:, qadr]
    pos, rot = fk_skeleton(st, torch.from_numpy(q), torch.from_numpy(Q[:, :3]), base_quat=torch.from_numpy(Q[:, 3:7]))
    return r, pos.numpy(), rot.numpy()


@pytest.mark.parametrize("sway", [False, True], ids=["standing", "swaying"])
def test_simulated_motion_reads_feasible(sway):
    r, pos, rot = _simulate(sway)
    mm, geo = mass_model(r), collision_model(r)
    b = balance_frames(pos, rot, FPS, r.skeleton, mm, geo, torques=False)
    assert (b["support"] > 0).all()  # it stood
    if sway:  # the centre of mass really went over the left foot, near the edge of the support
        assert b["com"][:, 1].max() > 0.1
    out = balance_metrics(pos, rot, FPS, r.skeleton, mm, geo)
    assert out["balance_infeasible"] <= 0.02
    assert out["pull_frames"] == 0 and out["slip_frames"] == 0 and out["flight_frames"] == 0
    assert out["torque_frames"] == 0


def test_kinematic_lunge_reads_infeasible():
    """The simulated stance carried sideways and back (up to 8 m/s^2): the ZMP leaves the feet."""
    r, pos, rot = _simulate(False, seconds=1.5)
    F = len(pos)
    t = np.arange(F) / FPS
    shift = np.stack([np.zeros(F), 4.0 * np.sin(np.pi * t / t[-1]) * (t[-1] / np.pi) ** 2 * 2, np.zeros(F)], -1)
    out = balance_metrics(pos + shift[:, None], rot, FPS, r.skeleton, mass_model(r), collision_model(r), torques=False)
    assert out["zmp_out"] > 0.5 and out["balance_infeasible"] > 0.5


def test_a_description_without_masses_reads_nan_with_one_warning(caplog):
    """A robot whose links carry no ``<inertial>`` demands no wrench: every figure NaN, no division by
    zero (the dataset summaries' RuntimeWarning before), one log line naming the robot and the fix."""
    import dataclasses
    import warnings

    r = load_robot("g1")
    mm = mass_model(r)
    bare = dataclasses.replace(mm, robot="g1-bare", mass=np.zeros_like(mm.mass))
    F = 12
    q = torch.zeros(F, r.skeleton.num_nodes, dtype=torch.float64)
    pos, rot = fk_skeleton(skeleton_tensors(r.skeleton, torch.float64), q, torch.tensor([[0.0, 0.0, 0.8]] * F, dtype=torch.float64),
                           base_rot=torch.eye(3, dtype=torch.float64).expand(F, 3, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        outs = [balance_metrics(pos.numpy(), rot.numpy(), FPS, r.skeleton, bare, collision_model(r)) for _ in range(2)]
    assert all(np.isnan(v) for k, v in outs[0].items() if k != "torque_worst") and outs[0]["torque_worst"] is None
    assert sum("g1-bare" in m and "<inertial>" in m for m in caplog.messages) == 1
