"""npz joint/body order: mjlab (URDF, MuJoCo's; default) or isaaclab (breadth-first, BeyondMimic's).

BeyondMimic's ``csv_to_npz`` logs ``robot.data.joint_pos`` / ``body_pos_w``: the whole articulation
in Isaac Lab's order. PhysX parses an articulation breadth-first (Isaac Lab issue #37), and the
G1 lists below are the order that public Isaac Lab G1 projects read from ``robot.joint_names`` /
``robot.body_names`` at run time (fixed-joint links merged: 30 bodies).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from model_helpers import synthetic_csv

from mer_data.base.errors import OutputError
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.registry import get_skeleton
from mer_models.cli import main
from mer_models.export.writers import TargetMotion, isaaclab_order, write_npz
from mer_models.training.synthetic import synthetic_motion

ISAACLAB_G1_JOINTS = [
    "left_hip_pitch_joint", "right_hip_pitch_joint", "waist_yaw_joint",
    "left_hip_roll_joint", "right_hip_roll_joint", "waist_roll_joint",
    "left_hip_yaw_joint", "right_hip_yaw_joint", "waist_pitch_joint",
    "left_knee_joint", "right_knee_joint", "left_shoulder_pitch_joint", "right_shoulder_pitch_joint",
    "left_ankle_pitch_joint", "right_ankle_pitch_joint", "left_shoulder_roll_joint", "right_shoulder_roll_joint",
    "left_ankle_roll_joint", "right_ankle_roll_joint", "left_shoulder_yaw_joint", "right_shoulder_yaw_joint",
    "left_elbow_joint", "right_elbow_joint", "left_wrist_roll_joint", "right_wrist_roll_joint",
    "left_wrist_pitch_joint", "right_wrist_pitch_joint", "left_wrist_yaw_joint", "right_wrist_yaw_joint",
]  # fmt: skip
ISAACLAB_G1_BODIES = [
    "pelvis", "left_hip_pitch_link", "right_hip_pitch_link", "waist_yaw_link",
    "left_hip_roll_link", "right_hip_roll_link", "waist_roll_link", "left_hip_yaw_link", "right_hip_yaw_link", "torso_link",
    "left_knee_link", "right_knee_link", "left_shoulder_pitch_link", "right_shoulder_pitch_link",
    "left_ankle_pitch_link", "right_ankle_pitch_link", "left_shoulder_roll_link", "right_shoulder_roll_link",
    "left_ankle_roll_link", "right_ankle_roll_link", "left_shoulder_yaw_link", "right_shoulder_yaw_link",
    "left_elbow_link", "right_elbow_link", "left_wrist_roll_link", "right_wrist_roll_link",
    "left_wrist_pitch_link", "right_wrist_pitch_link", "left_wrist_yaw_link", "right_wrist_yaw_link",
]  # fmt: skip


def _motion(name: str, frames: int = 30) -> TargetMotion:
    s = get_skeleton(name)
    m = synthetic_motion(s, frames, seed=2)
    return TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())


def test_breadth_first_order_of_g1_is_isaac_labs():
    s = get_skeleton("g1")
    joints, bodies = isaaclab_order(s)
    assert list(joints) == ISAACLAB_G1_JOINTS
    assert [s.link_names[j] for j in bodies] == ISAACLAB_G1_BODIES


def test_isaaclab_npz_is_the_mjlab_npz_reordered_by_name(tmp_path):
    m = _motion("g1")
    a = np.load(write_npz(tmp_path / "mjlab.npz", m))
    b = np.load(write_npz(tmp_path / "isaac.npz", m, order="isaaclab"))
    assert list(b["joint_names"]) == ISAACLAB_G1_JOINTS and list(b["body_names"]) == ISAACLAB_G1_BODIES
    assert list(a["joint_names"]) != ISAACLAB_G1_JOINTS  # the default really is another order
    ji = [list(a["joint_names"]).index(n) for n in b["joint_names"]]
    bi = [list(a["body_names"]).index(n) for n in b["body_names"]]
    for k in ("joint_pos", "joint_vel"):
        np.testing.assert_array_equal(b[k], a[k][:, ji])
    for k in ("body_pos_w", "body_quat_w", "body_lin_vel_w", "body_ang_vel_w"):
        np.testing.assert_array_equal(b[k], a[k][:, bi])
    assert float(b["fps"]) == 50.0 and b["body_pos_w"].shape[1] == 30


def test_isaaclab_order_is_refused_for_unverified_robots(tmp_path):
    with pytest.raises(OutputError, match="verified only for g1, not for 'h1'") as e:
        write_npz(tmp_path / "h1.npz", _motion("h1"), order="isaaclab")
    assert "--npz-order mjlab" in str(e.value) and not (tmp_path / "h1.npz").exists()
    with pytest.raises(OutputError, match="unknown npz order 'urdf'"):
        write_npz(tmp_path / "h1.npz", _motion("h1"), order="urdf")


def test_cli_npz_order(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=20)
    argv = ["retarget", str(src), "--source", "g1", "--method", "optimize"]
    assert main(argv + ["--target", "g1", "--npz", str(tmp_path / "g1.npz"), "--npz-order", "isaaclab"]) == 0
    assert list(np.load(tmp_path / "g1.npz")["joint_names"]) == ISAACLAB_G1_JOINTS
    capsys.readouterr()
    assert main(argv + ["--target", "h1", "--npz", str(tmp_path / "h1.npz"), "--npz-order", "isaaclab"]) == 1
    err = capsys.readouterr().err
    assert "verified only for g1" in err and "fix:" in err and not (tmp_path / "h1.npz").exists()
    code = main(["retarget", "--input", str(tmp_path), "--source", "g1", "--targets", "g1", "--out", str(tmp_path / "o"),
                 "--formats", "npz", "--npz-order", "isaaclab"])  # fmt: skip
    assert code == 1 and "single-file runs" in capsys.readouterr().err
