"""Output files: LAFAN1-style CSV, a tracker's npz, Foxglove MCAP, PNG."""

from __future__ import annotations

import json

import numpy as np
import torch

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.robots.registry import get_skeleton, load_robot
from mer_models.batch import rot_z
from mer_models.export.plot import plot_motion
from mer_models.export.writers import TargetMotion, csv_columns, write_csv, write_mcap, write_npz
from mer_models.training.synthetic import synthetic_motion


def _motion(name="g1", frames=40, seed=0) -> TargetMotion:
    s = get_skeleton(name)
    m = synthetic_motion(s, frames, seed=seed)
    return TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())


def test_csv_in_the_lafan1_layout_reads_back(tmp_path):
    m = _motion("g1")
    path = write_csv(tmp_path / "out.csv", m)
    text = path.read_text().splitlines()
    assert len(text) == 40 and len(text[0].split(",")) == 7 + 29  # no header
    back = read_lafan1_csv(path, "g1")
    np.testing.assert_allclose(back.node_angles(m.skeleton), m.q, atol=1e-6)
    np.testing.assert_allclose(back.base_pos, m.base_pos, atol=1e-6)
    assert csv_columns(m.skeleton) == tuple(load_robot("g1").card.lafan1_columns)


def test_csv_of_a_robot_without_a_layout_uses_node_order(tmp_path):
    m = _motion("atlas")
    assert load_robot("atlas").card.lafan1_columns is None
    assert csv_columns(m.skeleton) == m.skeleton.joint_names
    a = np.loadtxt(write_csv(tmp_path / "atlas.csv", m), delimiter=",")
    assert a.shape == (40, 7 + m.skeleton.num_dof)
    idx = [m.skeleton.node_index(n) for n in m.skeleton.joint_names]
    np.testing.assert_allclose(a[:, 7:], m.q[:, idx], atol=1e-6)
    quat_xyzw = a[:, 3:7]
    np.testing.assert_allclose(np.linalg.norm(quat_xyzw, axis=1), 1.0, atol=1e-5)


def test_npz_has_the_converters_keys_and_consistent_bodies(tmp_path):
    m = _motion("h1")
    z = np.load(write_npz(tmp_path / "m.npz", m, tracker="mjlab", fps=None))
    keys = {"fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w", "body_lin_vel_w", "body_ang_vel_w", "joint_names", "body_names"}
    assert keys <= set(z.files)
    F, D = z["joint_pos"].shape
    L = len(z["body_names"])
    assert (F, D) == (40, 19) and list(z["joint_names"]) == list(csv_columns(m.skeleton))
    assert z["body_pos_w"].shape == (F, L, 3) and z["body_quat_w"].shape == (F, L, 4)
    np.testing.assert_allclose(np.linalg.norm(z["body_quat_w"], axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(z["body_pos_w"][:, 0], m.base_pos, atol=1e-5)  # body 0 is the base link
    assert z["fps"].shape == (1,) and z["fps"].dtype == np.float64 and z["fps"][0] == 30  # as mjlab's csv_to_npz writes it


def test_npz_angular_velocity_of_a_steady_spin(tmp_path):
    s = get_skeleton("tron1")
    F, rate = 30, 1.5  # rad/s about z
    rot = rot_z(torch.arange(F, dtype=torch.float64) * rate / 30.0).numpy()
    m = TargetMotion(s, 30.0, np.zeros((F, s.num_nodes)), np.zeros((F, 3)), rot)
    z = np.load(write_npz(tmp_path / "spin.npz", m, tracker="beyondmimic"))  # at 50 Hz: the spin rate stays 1.5 rad/s
    np.testing.assert_allclose(z["body_ang_vel_w"][:, :, 2], rate, atol=1e-4)
    np.testing.assert_allclose(z["body_ang_vel_w"][:, :, :2], 0.0, atol=1e-5)


def test_mcap_has_foxglove_channels(tmp_path):
    from mcap.reader import make_reader

    m = _motion("tron1", frames=12)
    pts = np.zeros((12, 3, 3))
    path = write_mcap(tmp_path / "m.mcap", m, reference_points=pts)
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        schemas = {s.name for s in summary.schemas.values()}
        topics = {c.topic: c.message_encoding for c in summary.channels.values()}
        counts = {}
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            json.loads(message.data)
    assert schemas == {"foxglove.FrameTransforms", "foxglove.SceneUpdate", "std_msgs/String"}
    assert topics == {"/tf": "json", "/skeleton": "json", "/reference": "json", "/robot": "json", "/robot_description": "json"}
    assert counts == {"/tf": 12, "/skeleton": 1, "/reference": 12, "/robot": 1, "/robot_description": 1}


def test_png_is_written(tmp_path):
    m = _motion("g1", frames=20)
    path = plot_motion(tmp_path / "m.png", m, reference_points=np.zeros((20, 2, 3)), panels=4)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_npz_is_written_at_the_trackers_rate_by_lerp_and_slerp(tmp_path):
    """Default 50 Hz (mjlab / BeyondMimic control rate), like csv_to_npz: a 30 Hz motion would play 1.67x too fast."""
    from mer_models.export.writers import resample_motion

    m = _motion("h1")  # 40 frames at 30 Hz: 1.3 s
    z = np.load(write_npz(tmp_path / "m.npz", m, tracker="mjlab"))
    assert int(z["fps"][0]) == 50 and z["joint_pos"].shape[0] == 66  # frames at 0, 1/50, ... 1.3 s
    r = resample_motion(m, 50.0)
    np.testing.assert_allclose(r.q[::5], m.q[::3], atol=1e-12)  # every 0.1 s both have a frame
    np.testing.assert_allclose(r.base_rot[::5], m.base_rot[::3], atol=1e-9)
    half = resample_motion(TargetMotion(m.skeleton, 30.0, m.q[:2], m.base_pos[:2], m.base_rot[:2]), 60.0)
    np.testing.assert_allclose(half.q[1], (m.q[0] + m.q[1]) / 2, atol=1e-12)
    np.testing.assert_allclose(half.base_pos[1], (m.base_pos[0] + m.base_pos[1]) / 2, atol=1e-12)
    from mer_data.kinematics.rotations import rotation_angle_between

    a = float(rotation_angle_between(torch.from_numpy(half.base_rot[1]), torch.from_numpy(m.base_rot[0])))
    b = float(rotation_angle_between(torch.from_numpy(m.base_rot[1]), torch.from_numpy(m.base_rot[0])))
    assert abs(a - b / 2) < 1e-9  # slerp: half the turn
