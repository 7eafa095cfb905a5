"""The G1 npz replays in MuJoCo: qpos from the npz (base pose, joint_pos by joint_names), MuJoCo's
own forward kinematics (mj_kinematics) puts every body where the npz's body_pos_w / body_quat_w say.

The model is mer's built-in G1 URDF compiled by MuJoCo's URDF compiler (an FK implementation
independent of mer's): mjlab's G1 MJCF is not available offline, and the URDF is the description
the npz is computed from. Visual/collision meshes are not shipped, so they are removed (FK needs
none), and a free joint is added at the pelvis for the floating base. MuJoCo fuses the fixed-joint
links (``fusestatic``), which leaves exactly the npz's bodies: the pelvis and one link per joint.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lxml import etree

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.robots.registry import get_skeleton, load_robot
from mer_models.export.writers import TargetMotion, write_npz
from mer_models.training.synthetic import synthetic_motion

mujoco = pytest.importorskip("mujoco", reason="MuJoCo replays the npz (pip install -e '.[dev]')")


def g1_model():
    """MuJoCo model of the built-in G1 URDF with a free base (meshes stripped)."""
    root = etree.parse(str(load_robot("g1").urdf_path)).getroot()
    for el in root.xpath("//visual|//collision|//mujoco"):
        el.getparent().remove(el)
    spec = mujoco.MjSpec.from_string(etree.tostring(root).decode())
    spec.worldbody.first_body().add_freejoint()
    return spec.compile()


def replay_errors(npz_path) -> tuple[float, float]:
    """Max body position error [m] and max rotation error (~angle) [rad] of MuJoCo's FK of the npz's
    qpos against its body_pos_w / body_quat_w, over all frames and bodies."""
    z = np.load(npz_path)
    model = g1_model()
    data = mujoco.MjData(model)
    bodies = [str(n) for n in z["body_names"]]
    assert [model.body(i).name for i in range(1, model.nbody)] == bodies  # MuJoCo's (mjlab's) body order
    body_id = [model.body(n).id for n in bodies]
    qadr = [int(model.joint(str(n)).qposadr[0]) for n in z["joint_names"]]
    assert len(set(qadr)) == model.njnt - 1 == z["joint_pos"].shape[1]  # every hinge once
    pos_err = rot_err = 0.0
    for f in range(z["joint_pos"].shape[0]):
        data.qpos[:] = 0.0
        data.qpos[0:3] = z["body_pos_w"][f, 0]  # body 0 is the pelvis: the base
        data.qpos[3:7] = z["body_quat_w"][f, 0]  # wxyz, as MuJoCo
        data.qpos[qadr] = z["joint_pos"][f]
        mujoco.mj_kinematics(model, data)
        pos_err = max(pos_err, float(np.abs(data.xpos[body_id] - z["body_pos_w"][f]).max()))
        a, b = data.xquat[body_id], z["body_quat_w"][f]  # q and -q are the same rotation
        d = np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))
        rot_err = max(rot_err, float(2 * d.max()))  # ~ the rotation angle between them, for small d
    return pos_err, rot_err


def test_a_synthetic_g1_npz_replays_in_mujoco(tmp_path):
    s = get_skeleton("g1")
    m = synthetic_motion(s, 45, seed=3)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    assert np.ptp(motion.q, axis=0).max() > 0.3  # the joints move
    pos_err, rot_err = replay_errors(write_npz(tmp_path / "g1.npz", motion, tracker="mjlab"))
    assert pos_err < 1e-5 and rot_err < 1e-4, (pos_err, rot_err)


def test_the_replay_catches_a_wrong_joint_order(tmp_path):
    """The check can fail: swapping two joints' columns moves bodies by centimetres."""
    s = get_skeleton("g1")
    m = synthetic_motion(s, 10, seed=1)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    z = dict(np.load(write_npz(tmp_path / "g1.npz", motion, tracker="mjlab", fps=None)))
    z["joint_pos"] = z["joint_pos"][:, [1, 0, *range(2, z["joint_pos"].shape[1])]]
    np.savez(tmp_path / "bad.npz", **z)
    assert replay_errors(tmp_path / "bad.npz")[0] > 1e-3


def test_a_real_lafan1_g1_clip_replays_in_mujoco(lafan1_dir, tmp_path):
    """Real G1 data (../shared, skipped where absent; nothing derived is kept): 4 s of walk1_subject1."""
    lines = (lafan1_dir / "g1" / "walk1_subject1.csv").read_text().splitlines()[300:420]
    (tmp_path / "walk.csv").write_text("\n".join(lines) + "\n")
    s = get_skeleton("g1")
    mo = read_lafan1_csv(tmp_path / "walk.csv", "g1")
    motion = TargetMotion(s, 30.0, mo.node_angles(s), mo.base_pos, quat_to_matrix(torch.from_numpy(mo.base_quat)).numpy())
    pos_err, rot_err = replay_errors(write_npz(tmp_path / "g1.npz", motion, tracker="mjlab"))
    assert pos_err < 1e-5 and rot_err < 1e-4, (pos_err, rot_err)
