"""The pieces of `mer demo`'s walk: the example robot, whole-motion metrics, the results table."""

from __future__ import annotations

import numpy as np
import torch

from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.robots.example import EXAMPLE_ROBOT, example_humanoid_urdf
from mer_data.robots.registry import get_skeleton, load_robot
from mer_data.skeleton import KEYPOINTS
from mer_models.cli.demo_walk import RobotResult, format_results, register_example_robot
from mer_models.export.writers import TargetMotion
from mer_models.retarget.clip import sequence_metrics, source_features
from mer_models.training.synthetic import synthetic_motion


def test_the_example_robot_registers_with_every_key_point(tmp_path):
    rep = register_example_robot(tmp_path)
    s = get_skeleton(EXAMPLE_ROBOT)
    assert load_robot(EXAMPLE_ROBOT).urdf_path.name == f"{EXAMPLE_ROBOT}.urdf"
    assert all(s.keypoints[k] >= 0 for k in KEYPOINTS) and s.num_dof == 24
    assert rep.proposals is not None and not [k for k, p in rep.proposals.items() if p.confidence in ("low", "absent")]
    register_example_robot(tmp_path)  # again: replaces the demo's earlier copy
    assert 'robot name="small"' in example_humanoid_urdf("small", scale=0.5)


def test_sequence_metrics_of_the_source_motion_itself_are_zero_errors():
    """Retargeting G1 to G1 perfectly = the source motion: no position, velocity or orientation error."""
    s = get_skeleton("g1")
    m = synthetic_motion(s, 50, seed=2)
    feats = source_features(m["base_pos"], m["base_quat"], m["q"], s, 30.0)
    motion = TargetMotion(s, 30.0, m["q"], m["base_pos"], quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy())
    got = sequence_metrics(feats, s, motion)
    assert got["g_mpbpe"] < 1e-5 and got["mpbve"] < 1e-4 and got["mpboe"] < 1e-3
    assert got["limit_violation"] == 0.0 and got["jerk"] > 0
    shifted = TargetMotion(s, 30.0, m["q"], m["base_pos"] + [0.0, 0.0, 0.1], motion.base_rot)
    assert abs(sequence_metrics(feats, s, shifted)["g_mpbpe"] - 0.1) < 1e-4  # 10 cm up: 10 cm off everywhere


def test_the_results_table_says_which_robots_are_zero_shot():
    rows = [RobotResult("h1", True, 10, 1.0, {"g_mpbpe": 0.1}), RobotResult("newbot", False, 10, 2.0, {"g_mpbpe": 0.2})]
    lines = format_results(rows).splitlines()
    assert lines[1].split()[:2] == ["h1", "yes"] and "no: zero-shot" in lines[2]
    assert lines[1].split()[3] == "-" and np.isclose(float(lines[2].split()[3]), 0.2)  # missing: "-"
    assert lines[0].split()[4:7] == ["g_mpbpe[m]", "mpboe[rad]", "mpbve[m/s]"] and "jerk_frame[rad/f3]" in lines[0]
    assert any(line.split()[0] == "limit_violation" for line in lines[3:])  # the legend, one line per column
