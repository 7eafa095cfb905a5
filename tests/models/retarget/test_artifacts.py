"""The artifact metrics on motions built to have (or not have) each artifact, and on Unitree's own
LAFAN1 retargeting (the figures docs/model.md quotes for it)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mer_data.robots.collision import collision_model
from mer_data.robots.registry import load_robot
from mer_models.retarget.artifacts import artifact_metrics, motion_artifacts


def _standing(name: str, F: int = 60):
    """The zero pose standing on the floor (lowest point at z = 0.003), F frames."""
    r = load_robot(name)
    m = collision_model(r)
    J = r.skeleton.num_nodes
    q = np.zeros((F, J))
    rot = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
    base = np.zeros((F, 3))
    a = motion_artifacts(q[:1], base[:1], rot[:1], 30.0, r.skeleton, m)
    pos = torch.from_numpy(r.skeleton.rest_positions)
    from mer_data.kinematics.collision import shape_points

    z0 = float(shape_points(m, pos, torch.eye(3, dtype=torch.float64).expand(J, 3, 3), "vertices")[..., 2].min())
    base[:, 2] = -z0 + 0.003
    assert a["floor_depth_max"] > 0  # at the origin the robot stands 0.8-1 m into the floor
    return r, m, q, base, rot


@pytest.mark.parametrize("name", ["h1", "g1"])
def test_standing_still_has_no_artifact(name):
    r, m, q, base, rot = _standing(name)
    a = motion_artifacts(q, base, rot, 30.0, r.skeleton, m)
    assert a["floor_frames"] == 0 and a["body_floor_frames"] == 0 and a["floor_depth_max"] == 0
    assert a["skate_median"] == 0 and a["skate_share"] == 0
    assert a["selfpen_frames"] == 0 and a["speed_frames"] == 0 and a["speed_ratio_max"] == 0


def test_sinking_sliding_and_floating_are_measured():
    r, m, q, base, rot = _standing("h1")
    sunk = base.copy()
    sunk[20:40, 2] -= 0.033  # 3 cm into the floor for a third of the frames
    a = motion_artifacts(q, sunk, rot, 30.0, r.skeleton, m)
    assert a["floor_frames"] == pytest.approx(20 / 60) and a["floor_depth_max"] == pytest.approx(0.03, abs=1e-6)
    slide = base.copy()
    slide[:, 0] = np.arange(60) * 0.1 / 30  # 10 cm/s forward, feet on the floor
    a = motion_artifacts(q, slide, rot, 30.0, r.skeleton, m)
    assert a["skate_median"] == pytest.approx(0.1, rel=1e-6) and a["skate_share"] == 1.0
    up = base.copy()
    up[:, 2] += 0.2
    contacts = np.ones((60, 2), bool)
    a = artifact_metrics(q, *_fk(r, q, up, rot), 30.0, m, r.skeleton.urdf_joint_names, contacts)
    assert a["floating_frames"] == 1.0 and np.isnan(a["skate_median"])  # no foot near the floor: no contact


def test_hovering_and_any_body_in_the_floor_are_measured():
    """The source's left foot down all along, the right one for the first half: standing 3 mm up,
    nothing hovers; 2 cm up, every one of those samples hovers; 5 cm into the floor, any body is."""
    r, m, q, base, rot = _standing("h1")
    contacts = np.zeros((60, 2), bool)
    contacts[:, 0] = True
    contacts[:30, 1] = True
    a = artifact_metrics(q, *_fk(r, q, base, rot), 30.0, m, r.skeleton.urdf_joint_names, contacts)
    assert a["hover_frames"] == 0.0 and a["body_floor_frames"] == 0.0 and a["body_floor_depth_max"] == 0.0
    up = base.copy()
    up[:45, 2] += 0.02  # the first 45 frames: 45 left and 30 right of the 90 foot-down samples
    a = artifact_metrics(q, *_fk(r, q, up, rot), 30.0, m, r.skeleton.urdf_joint_names, contacts)
    assert a["hover_frames"] == pytest.approx((45 + 30) / 90)
    down = base.copy()
    down[:, 2] -= 0.053
    a = artifact_metrics(q, *_fk(r, q, down, rot), 30.0, m, r.skeleton.urdf_joint_names, contacts)
    assert a["body_floor_frames"] == 1.0 and a["body_floor_depth_max"] == pytest.approx(0.05, abs=1e-6)
    assert np.isnan(artifact_metrics(q, *_fk(r, q, base, rot), 30.0, m, r.skeleton.urdf_joint_names, None)["hover_frames"])


def _fk(r, q, base, rot):
    from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors

    pos, rr = fk_skeleton(skeleton_tensors(r.skeleton, torch.float64), torch.from_numpy(q), torch.from_numpy(base),
                          base_rot=torch.from_numpy(rot))  # fmt: skip
    return pos.numpy(), rr.numpy()


def test_joint_speed_and_self_penetration_are_measured():
    r, m, q, base, rot = _standing("h1")
    s = r.skeleton
    knee = s.keypoints["left_knee"]
    lim = m.velocity_limit[knee]
    fast = q.copy()
    fast[:, knee] = np.clip(np.arange(60) * 1.5 * lim / 30, s.lower[knee], s.upper[knee])  # 1.5x the limit
    a = motion_artifacts(fast, base, rot, 30.0, s, m)
    assert a["speed_ratio_max"] == pytest.approx(1.5, rel=1e-6) and a["speed_frames"] > 0
    assert a["speed_worst"] == s.urdf_joint_names[knee]
    # the left forearm turned into the torso: shoulder roll fully in, upper arm turned (about 4 cm deep)
    cross = q.copy()
    for joint, at in (("left_shoulder_roll_joint", s.lower), ("left_shoulder_yaw_joint", s.lower)):
        j = s.urdf_joint_names.index(joint)
        cross[30:, j] = at[j]
    a = motion_artifacts(cross, base, rot, 30.0, s, m)
    assert a["selfpen_1cm_frames"] == pytest.approx(0.5) and 0.02 < a["selfpen_depth_max"] < 0.06
    assert a["selfpen_worst"][0]["pair"] == "torso_link|left_elbow_link"


def test_unitree_h1_walk_matches_the_published_figures(lafan1_dir):
    """Unitree's H1 on walk1_subject1 frames 601-1050: never below -1 cm (deepest 0.7 cm), median
    skate about 5 cm/s (design notes: measured independently on the upstream meshes)."""
    from mer_data.kinematics.rotations import quat_to_matrix
    from mer_data.motion.lafan1 import read_lafan1_csv

    h1 = load_robot("h1")
    u = read_lafan1_csv(lafan1_dir / "h1" / "walk1_subject1.csv", h1)
    sl = slice(600, 1050)
    a = motion_artifacts(u.node_angles(h1.skeleton)[sl], u.base_pos[sl], quat_to_matrix(torch.from_numpy(u.base_quat[sl])).numpy(),
                         30.0, h1.skeleton, collision_model(h1))  # fmt: skip
    assert a["floor_frames"] == 0 and a["floor_depth_max"] < 0.01
    assert 0.03 < a["skate_median"] < 0.07
    assert a["selfpen_1cm_frames"] == 0 and a["speed_frames"] == 0


def test_evaluate_reports_artifacts_and_takes_physics(tmp_path):
    """``mer evaluate`` reports the artifact metrics per window, and its optimiser keeps the physical
    terms by default: a source sunk 6 cm into the floor leaves H1's feet under it with
    ``--no-physics``, and none below the floor without it (the feasibility pass)."""
    import json

    from mer_data.motion.lafan1 import write_lafan1_csv
    from mer_data.synthesis.walking import walking_motion
    from mer_models.cli import main

    g1 = load_robot("g1")
    m = walking_motion("g1", 4.0)
    write_lafan1_csv(tmp_path / "in" / "g1" / "walk.csv", m.with_arrays(base_pos=m.base_pos - [0.0, 0.0, 0.06]), robot=g1)
    out = {}
    for name, flag in (("off", ("--no-physics",)), ("on", ())):
        f = tmp_path / f"r_{name}.json"
        assert main(["evaluate", "--input", str(tmp_path / "in"), "--source", "g1", "--targets", "h1", "--split", "all",
                     "--methods", "optimize", "--max-windows", "2", "--save", str(f), *flag]) == 0  # fmt: skip
        report = json.loads(f.read_text())
        out[name] = report["rows"][0]["metrics"]
    assert out["off"]["floor_frames"]["mean"] > 0.3
    assert out["on"]["floor_frames"]["mean"] == 0
    assert out["on"]["floor_depth_max"]["mean"] < 1e-3
    assert out["on"]["speed_frames"]["mean"] == 0
