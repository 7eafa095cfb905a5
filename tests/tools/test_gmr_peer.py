"""tools/gmr_peer.py: GMR's BVH route as a benchmark peer (GMR itself is never a mer dependency).

The calibration and conversion helpers are tested without GMR; the end-to-end run skips unless
``GMR_PYTHON`` names an interpreter with GMR installed and the Bandai Namco clips are present.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import gmr_peer  # noqa: E402


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return gmr_peer.quat_to_rotmat(q / np.linalg.norm(q, axis=1, keepdims=True))


def test_rotation_helpers():
    rng = np.random.default_rng(0)
    for R in _random_rotations(rng, 20):
        np.testing.assert_allclose(gmr_peer.quat_to_rotmat(gmr_peer.rotmat_to_quat(R)), R, atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    for a, b in rng.normal(size=(20, 2, 3)):
        S = gmr_peer.shortest_rotation(a, b)
        np.testing.assert_allclose(S @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        np.testing.assert_allclose(S @ np.cross(a, b), np.cross(a, b), atol=1e-9)  # about the common normal
    a = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(gmr_peer.shortest_rotation(a, -a) @ a, -a, atol=1e-12)
    u1, v1, u2, v2 = rng.normal(size=(4, 3))
    F = gmr_peer.frame_rotation(u1, v1, u2, v2)
    np.testing.assert_allclose(F @ (u1 / np.linalg.norm(u1)), u2 / np.linalg.norm(u2), atol=1e-12)
    n1, n2 = np.cross(u1, v1), np.cross(u2, v2)
    np.testing.assert_allclose(F @ (n1 / np.linalg.norm(n1)), n2 / np.linalg.norm(n2), atol=1e-12)
    np.testing.assert_allclose(gmr_peer.rot_z(math.pi / 2) @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)


# a stand-in for G1 at its zero pose (elbows bent, forearms forward) and the table of bvh_to_g1.json
_LINKS = {  # GMR human body -> (G1 body, position at the zero pose)
    "Hips": ("pelvis", (0.0, 0.0, 0.79)), "Spine2": ("torso_link", (0.0, 0.0, 0.84)),
    "LeftUpLeg": ("left_hip_roll_link", (0.0, 0.12, 0.66)), "LeftLeg": ("left_knee_link", (0.0, 0.12, 0.35)),
    "LeftFootMod": ("left_ankle_roll_link", (0.0, 0.12, 0.04)), "LeftArm": ("left_shoulder_roll_link", (0.0, 0.14, 1.08)),
    "LeftForeArm": ("left_elbow_link", (0.02, 0.15, 0.9)), "LeftHand": ("left_wrist_yaw_link", (0.2, 0.15, 0.89)),
    "RightUpLeg": ("right_hip_roll_link", (0.0, -0.12, 0.66)), "RightLeg": ("right_knee_link", (0.0, -0.12, 0.35)),
    "RightFootMod": ("right_ankle_roll_link", (0.0, -0.12, 0.04)), "RightArm": ("right_shoulder_roll_link", (0.0, -0.14, 1.08)),
    "RightForeArm": ("right_elbow_link", (0.02, -0.15, 0.9)), "RightHand": ("right_wrist_yaw_link", (0.2, -0.15, 0.89)),
}  # fmt: skip


def _joint_of(body: str) -> str:
    return gmr_peer.BANDAI_FEET[body][1] if body in gmr_peer.BANDAI_FEET else gmr_peer.BANDAI_BODIES[body]


def test_calibration_recovers_the_bone_frame_convention():
    """A human standing exactly in G1's zero pose (turned by a heading, its own bone frames C_b):
    the offsets are C_b^-1, whatever the heading and the robot's link frames."""
    rng = np.random.default_rng(1)
    table = {link: [body, 10, 10, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]] for body, (link, _) in _LINKS.items()}
    robot_pos = {link: np.array(p) for link, p in _LINKS.values()}
    robot_rot = dict(zip(robot_pos, _random_rotations(rng, len(robot_pos))))
    heading = gmr_peer.rot_z(0.7)
    convention = {}
    pos, rot = {}, {}
    for body, (link, p) in _LINKS.items():
        joint = _joint_of(body)
        convention[body] = _random_rotations(rng, 1)[0]
        rot[joint] = heading @ robot_rot[link] @ convention[body]
        if body not in gmr_peer.BANDAI_FEET:
            pos[joint] = heading @ np.array(p)
    pos["Foot_L"], pos["Foot_R"] = heading @ robot_pos["left_ankle_roll_link"], heading @ robot_pos["right_ankle_roll_link"]
    offsets = gmr_peer.calibrated_offsets(pos, rot, robot_pos, robot_rot, table)
    assert set(offsets) == set(_LINKS)
    for body, q in offsets.items():
        np.testing.assert_allclose(gmr_peer.quat_to_rotmat(np.array(q)), convention[body].T, atol=1e-9, err_msg=body)

    # the arms hanging straight down instead: the upper arm keeps its frame, the forearm (and hand)
    # is turned forward about the elbow's axis, the shortest way
    for side in ("L", "R"):
        low, hand = f"LowerArm_{side}", f"Hand_{side}"
        bent = pos[hand] - pos[low]
        down = np.linalg.norm(bent) * (heading @ np.array([0.0, 0.0, -1.0]))
        turn = gmr_peer.shortest_rotation(bent, down)
        pos[hand] = pos[low] + down
        for j in (low, hand):
            rot[j] = turn @ rot[j]
    straight = gmr_peer.calibrated_offsets(pos, rot, robot_pos, robot_rot, table)
    for body in _LINKS:
        np.testing.assert_allclose(gmr_peer.quat_to_rotmat(np.array(straight[body])), convention[body].T, atol=1e-9,
                                   err_msg=body)  # fmt: skip


def test_auto_height_is_gmrs_formula():
    pos = {"Head": np.array([0.0, 0.0, 1.5]), "Foot_L": np.array([0.0, 0.1, 0.1]), "Foot_R": np.array([0.0, -0.1, 0.08])}
    assert gmr_peer.auto_height(pos) == pytest.approx(1.5 - 0.08 + 0.2)


def test_gmr_qpos_becomes_mer_node_angles():
    from mer_data.robots.registry import load_robot

    skel = load_robot("g1").skeleton
    rng = np.random.default_rng(2)
    names = list(skel.joint_names)
    rng.shuffle(names)  # GMR's order need not be mer's
    T = 5
    angles = rng.uniform(-1, 1, size=(T, len(names)))
    quat = rng.normal(size=(T, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    qpos = np.concatenate([rng.normal(size=(T, 3)), quat, angles], axis=1)
    shift = np.array([1.0, -2.0, 0.0])
    motion = gmr_peer.gmr_motion(qpos, names, skel, shift)
    for k, n in enumerate(names):
        np.testing.assert_array_equal(motion.q[:, skel.node_names.index(n)], angles[:, k])
    assert np.all(motion.q[:, ~skel.dof_mask] == 0)
    np.testing.assert_allclose(motion.base_pos, qpos[:, :3] + shift)
    np.testing.assert_allclose(motion.base_quat() * np.sign(motion.base_quat()[:, :1]), quat * np.sign(quat[:, :1]), atol=1e-12)
    with pytest.raises(ValueError, match="no joint"):
        gmr_peer.gmr_motion(qpos[:, :-1], names[:-1], skel, shift)


@pytest.mark.slow
def test_end_to_end_on_a_short_clip(shared_dir: Path, capsys):
    """Both retargeters on the first frames of one Bandai Namco walk (skips without GMR)."""
    clips = shared_dir / "data" / "bvh" / "bandai1"
    if not (clips / "dataset-1_walk_normal_001.bvh").is_file():
        pytest.skip(f"no Bandai Namco clips in {clips}")
    python = os.environ.get("GMR_PYTHON")
    if not python:
        pytest.skip("GMR_PYTHON is not set (an interpreter with GMR installed: tools/gmr_peer.py)")
    try:
        gmr_peer.check_gmr(python)
    except gmr_peer.GmrUnavailable as exc:
        pytest.skip(str(exc))
    rc = gmr_peer.main(["--gmr-python", python, "--bvh-dir", str(clips), "--clips", "walk_normal_001", "--max-frames", "24",
                        "--mer-methods", "optimize", "--human-height", "1.75"])  # fmt: skip
    assert rc == 0
    captured = capsys.readouterr()
    out = captured.out + captured.err
    table = out.split("(the human reference")[0]  # the main table, not the per-clip one
    rows = {
        line.split()[0] + " " + line.split()[1]: line.split()
        for line in table.splitlines()
        if line.startswith(("GMR h=", "mer "))
    }
    assert set(rows) >= {"GMR h=1.75", "mer optimize"}, out
    for cells in rows.values():
        assert cells[2] == "24" and float(cells[3]) > 0  # frames, g-mpbpe [mm]
    assert "max 0.000 mm" in out  # GMR read the same human as mer, in the same world
