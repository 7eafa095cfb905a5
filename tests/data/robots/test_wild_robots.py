"""Registering robots from public collections (../shared/robots-wild) without a key-point file.

Each robot's proposal is pinned: the link every key point lands on (with its offset where it is a
site), its confidence, and the joints locked as fingers. The conventions are those of
docs/robots.md: fingers locked and the hand at the wrist/palm; quadrupeds' hind legs are the legs
and front legs the arms; a point foot or a wheel is the ankle (no toe).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from mer_data.robots.keypoints import propose_robot
from mer_data.robots.register import register_robot
from mer_data.robots.urdf import load_urdf
from mer_data.skeleton import KEYPOINTS

WILD = (
    "bolt", "hyq", "icub", "limx_p441a", "romeo", "solo12", "tron1_wheelfoot", "unitree_a1", "unitree_b2",
    "unitree_g1_hands", "unitree_h1_hands", "unitree_r1",
)  # fmt: skip
QUADRUPEDS = ("hyq", "solo12", "unitree_a1", "unitree_b2")

# key point: left link[@offset]   right link[@offset]   confidence ("-": absent)
PROPOSED = {
    "bolt": """
        hip      FL_UPPER_LEG                       FR_UPPER_LEG                       high
        knee     FL_LOWER_LEG                       FR_LOWER_LEG                       high
        ankle    FL_FOOT                            FR_FOOT                            medium
        toe      -                                  -                                  absent
        shoulder -                                  -                                  absent
        elbow    -                                  -                                  absent
        hand     -                                  -                                  absent
    """,
    "hyq": """
        hip      lh_upperleg                        rh_upperleg                        high
        knee     lh_lowerleg                        rh_lowerleg                        high
        ankle    lh_foot                            rh_foot                            medium
        toe      -                                  -                                  absent
        shoulder lf_upperleg                        rf_upperleg                        medium
        elbow    lf_lowerleg                        rf_lowerleg                        medium
        hand     lf_foot                            rf_foot                            medium
    """,
    "icub": """
        hip      l_hip_2                            r_hip_2                            high
        knee     l_lower_leg                        r_lower_leg                        high
        ankle    l_ankle_2                          r_ankle_2                          high
        toe      -                                  -                                  absent
        shoulder l_shoulder_2                       r_shoulder_2                       high
        elbow    l_elbow_1                          r_elbow_1                          high
        hand     l_hand_dh_frame                    r_hand_dh_frame                    high
    """,
    "limx_p441a": """
        hip      hip_L_Link                         hip_R_Link                         high
        knee     knee_L_Link                        knee_R_Link                        high
        ankle    contact_L_Link                     contact_R_Link                     medium
        toe      -                                  -                                  absent
        shoulder -                                  -                                  absent
        elbow    -                                  -                                  absent
        hand     -                                  -                                  absent
    """,
    "romeo": """
        hip      LHipPitchLink                      RHipPitchLink                      high
        knee     LKneePitchLink                     RKneePitchLink                     high
        ankle    l_ankle                            r_ankle                            high
        toe      l_ankle@0.13,0,-0.0684             r_ankle@0.13,0,-0.0684             low
        shoulder LShoulderYawLink                   RShoulderYawLink                   high
        elbow    LElbowYawLink                      RElbowYawLink                      high
        hand     l_gripper                          r_gripper                          high
    """,
    "solo12": """
        hip      HL_UPPER_LEG                       HR_UPPER_LEG                       high
        knee     HL_LOWER_LEG                       HR_LOWER_LEG                       high
        ankle    HL_FOOT                            HR_FOOT                            medium
        toe      -                                  -                                  absent
        shoulder FL_UPPER_LEG                       FR_UPPER_LEG                       medium
        elbow    FL_LOWER_LEG                       FR_LOWER_LEG                       medium
        hand     FL_FOOT                            FR_FOOT                            medium
    """,
    "tron1_wheelfoot": """
        hip      hip_L_Link                         hip_R_Link                         high
        knee     knee_L_Link                        knee_R_Link                        high
        ankle    wheel_L_Link                       wheel_R_Link                       medium
        toe      -                                  -                                  absent
        shoulder -                                  -                                  absent
        elbow    -                                  -                                  absent
        hand     -                                  -                                  absent
    """,
    "unitree_a1": """
        hip      RL_thigh                           RR_thigh                           high
        knee     RL_calf                            RR_calf                            high
        ankle    RL_foot                            RR_foot                            medium
        toe      -                                  -                                  absent
        shoulder FL_thigh                           FR_thigh                           medium
        elbow    FL_calf                            FR_calf                            medium
        hand     FL_foot                            FR_foot                            medium
    """,
    "unitree_b2": """
        hip      RL_thigh                           RR_thigh                           high
        knee     RL_calf                            RR_calf                            high
        ankle    RL_foot                            RR_foot                            medium
        toe      -                                  -                                  absent
        shoulder FL_thigh                           FR_thigh                           medium
        elbow    FL_calf                            FR_calf                            medium
        hand     FL_foot                            FR_foot                            medium
    """,
    "unitree_g1_hands": """
        hip      left_hip_roll_link                 right_hip_roll_link                high
        knee     left_knee_link                     right_knee_link                    high
        ankle    left_ankle_roll_link               right_ankle_roll_link              high
        toe      left_ankle_roll_link@0.125,0,-0.035 right_ankle_roll_link@0.125,0,-0.035 medium
        shoulder left_shoulder_roll_link            right_shoulder_roll_link           high
        elbow    left_elbow_link                    right_elbow_link                   high
        hand     left_hand_palm_link                right_hand_palm_link               high
    """,
    "unitree_h1_hands": """
        hip      left_hip_pitch_link                right_hip_pitch_link               high
        knee     left_knee_link                     right_knee_link                    high
        ankle    left_ankle_link                    right_ankle_link                   high
        toe      left_ankle_link@0.19,0,-0.062      right_ankle_link@0.19,0,-0.062     medium
        shoulder left_shoulder_roll_link            right_shoulder_roll_link           high
        elbow    left_elbow_link                    right_elbow_link                   high
        hand     L_hand_base_link                   R_hand_base_link                   high
    """,
    "unitree_r1": """
        hip      left_hip_roll_link                 right_hip_roll_link                high
        knee     left_knee_link                     right_knee_link                    high
        ankle    left_ankle_roll_link               right_ankle_roll_link              high
        toe      -                                  -                                  absent
        shoulder left_shoulder_roll_link            right_shoulder_roll_link           high
        elbow    left_elbow_link                    right_elbow_link                   high
        hand     left_wrist_roll_link               right_wrist_roll_link              medium
    """,
}

# finger joints locked (mimic fingers follow their master and are not listed): a pattern every
# locked joint matches, and how many
FINGERS = {
    "romeo": (r"^[LR]Hand$", 2),
    "unitree_g1_hands": (r"_hand_(thumb|index|middle)_\d_joint$", 14),
    "unitree_h1_hands": (r"^[LR]_(thumb_proximal_(yaw|pitch)|index|middle|ring|pinky)(_proximal)?_joint$", 12),
}


def _expected(name: str) -> dict[str, tuple[str | None, tuple[float, float, float], str]]:
    out = {}
    for row in PROPOSED[name].strip().splitlines():
        part, left, right, conf = row.split()
        for side, cell in (("left", left), ("right", right)):
            link, _, off = cell.partition("@")
            offset = tuple(float(x) for x in off.split(",")) if off else (0.0, 0.0, 0.0)
            out[f"{side}_{part}"] = (None if link == "-" else link, offset, conf)
    return out


@pytest.fixture(scope="module")
def proposals(shared_wild_robots):
    return {n: propose_robot(load_urdf(shared_wild_robots / n / f"{n}.urdf")) for n in WILD}


def test_the_table_covers_every_wild_robot(shared_wild_robots):
    folders = sorted(p.name for p in shared_wild_robots.iterdir() if (p / f"{p.name}.urdf").is_file())
    assert folders == sorted(WILD) == sorted(PROPOSED)


@pytest.mark.parametrize("name", WILD)
def test_wild_robot_proposal_is_pinned(name, proposals):
    got = proposals[name]
    for key, (link, offset, conf) in _expected(name).items():
        p = got.keypoints[key]
        assert p.confidence == conf, (key, p)
        assert p.reason
        if link is None:
            assert p.spec is None, (key, p)
            continue
        assert p.spec is not None and p.spec.link == link, (key, p)
        np.testing.assert_allclose(p.spec.offset, offset, atol=1e-4, err_msg=key)
    pattern, count = FINGERS.get(name, ("^$", 0))
    assert len(got.locked) == count and all(re.search(pattern, j) for j in got.locked), sorted(got.locked)
    assert all(v == 0.0 for v in got.locked.values())
    assert any("quadruped" in n for n in got.notes) == (name in QUADRUPEDS)


@pytest.mark.parametrize("name", WILD)
def test_wild_robot_key_points_are_mirror_images(name, proposals):
    """Left and right proposals sit at mirrored places (these robots are left-right symmetric)."""
    kp = proposals[name].keypoints
    for key in KEYPOINTS:
        if key.startswith("left_") and kp[key].position is not None:
            other = kp[key.replace("left_", "right_")]
            np.testing.assert_allclose(other.position, np.multiply(kp[key].position, [1, -1, 1]), atol=2e-3, err_msg=key)


def test_hands_are_at_the_wrist_not_on_a_finger(proposals):
    """The issue's three cases: a thumb tip or a finger link was taken for the hand."""
    for name in ("romeo", "unitree_g1_hands", "unitree_h1_hands"):
        for side in ("left", "right"):
            link = proposals[name].keypoints[f"{side}_hand"].spec.link
            assert not re.search(r"thumb|finger|index|middle|ring|pinky", link, re.I), (name, link)


def test_icub_backward_root_frame_keeps_left_on_the_left(proposals):
    """iCub's root frame looks backwards: its l_* limbs lie at y < 0 and are still the left ones."""
    kp = proposals["icub"].keypoints
    assert kp["left_hip"].spec.link.startswith("l_") and kp["left_hip"].position[1] < 0
    assert any("backwards" in n for n in proposals["icub"].notes)


def test_every_shared_urdf_registers_in_one_call(shared_wild_robots, shared_robots):
    """Every URDF of robots-wild and robots registers with no key-point file, with what it ignored said."""
    folders = [shared_wild_robots / n for n in WILD] + sorted(
        p for p in shared_robots.iterdir() if p.is_dir() and (p / f"{p.name}.urdf").is_file()
    )
    assert len(folders) == 20
    for folder in folders:
        rep = register_robot(f"u_{folder.name}", folder / f"{folder.name}.urdf")
        s = rep.robot.skeleton
        for k, p in rep.proposals.items():  # the skeleton carries what was proposed
            assert (s.keypoints[k] >= 0) == (p.spec is not None), (folder.name, k)
            if p.spec is not None:
                np.testing.assert_allclose(s.rest_positions[s.keypoints[k]], p.position, atol=1e-9)
        assert sum(v >= 0 for v in s.keypoints.values()) >= 6, folder.name
        assert not [w for w in rep.warnings if "key points" in w], (folder.name, rep.warnings)
