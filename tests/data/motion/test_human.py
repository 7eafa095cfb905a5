"""A BVH human as a source skeleton: key points from every common naming convention, overrides,
the skeleton's forward kinematics equal to the file's, translations folded or refused, foot
contacts. Real clips: ../shared/data/bvh (skipped when absent)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import torch
from bvh_factory import LAFAN_NAMES, Figure, canonical_fk, human_definition, write_bvh
from hypothesis import given, settings
from hypothesis import strategies as st

from mer_data.base.errors import BVHError
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.motion.bvh import parse_bvh_text, read_bvh
from mer_data.motion.contacts import foot_contacts, sole_points
from mer_data.motion.features import motion_features, split_features
from mer_data.motion.human import (
    assign_keypoints,
    base_joint,
    bvh_nodes,
    human_motion,
    human_skeleton,
    keypoint_table,
)
from mer_data.robots.card import DEFAULT_BODY_PARTS
from mer_data.robots.registry import get_skeleton
from mer_data.skeleton import KEYPOINTS, Skeleton

CONVENTIONS = {
    "lafan1": LAFAN_NAMES,
    "bandai": {
        "root": "joint_Root", "hips": "Hips", "spine": ["Spine", "Chest", "Chest2"], "neck": "Neck", "head": "Head",
        "clavicle": "Shoulder_{s}", "upperarm": "UpperArm_{s}", "forearm": "LowerArm_{s}", "hand": "Hand_{s}",
        "thigh": "UpperLeg_{s}", "shin": "LowerLeg_{s}", "foot": "Foot_{s}", "toe": "Toes_{s}", "left": "L", "right": "R",
    },
    "cmu": {
        "hips": "Hips", "spine": ["LowerBack", "Spine", "Spine1"], "neck": "Neck", "head": "Head",
        "clavicle": "{S}Shoulder", "upperarm": "{S}Arm", "forearm": "{S}ForeArm", "hand": "{S}Hand",
        "hipjoint": "{s}HipJoint", "thigh": "{S}UpLeg", "shin": "{S}Leg", "foot": "{S}Foot", "toe": "{S}ToeBase",
        "left": "Left", "right": "Right",
    },
    "mixamo": {
        "hips": "mixamorig:Hips", "spine": ["mixamorig:Spine", "mixamorig:Spine1", "mixamorig:Spine2"],
        "neck": "mixamorig:Neck", "head": "mixamorig:Head", "clavicle": "mixamorig:{S}Shoulder",
        "upperarm": "mixamorig:{S}Arm", "forearm": "mixamorig:{S}ForeArm", "hand": "mixamorig:{S}Hand",
        "thigh": "mixamorig:{S}UpLeg", "shin": "mixamorig:{S}Leg", "foot": "mixamorig:{S}Foot",
        "toe": "mixamorig:{S}ToeBase", "left": "Left", "right": "Right",
    },
    "smpl": {
        "hips": "Pelvis", "spine": ["Spine1", "Spine2", "Spine3"], "neck": "Neck", "head": "Head",
        "clavicle": "{s}_Collar", "upperarm": "{s}_Shoulder", "forearm": "{s}_Elbow", "hand": "{s}_Wrist",
        "handend": "{s}_Hand", "thigh": "{s}_Hip", "shin": "{s}_Knee", "foot": "{s}_Ankle", "toe": "{s}_Foot",
        "left": "L", "right": "R",
    },
    "cmu_asf": {
        "hips": "root", "spine": ["lowerback", "upperback", "thorax"], "neck": "lowerneck", "head": "head",
        "clavicle": "{s}clavicle", "upperarm": "{s}humerus", "forearm": "{s}radius", "hand": "{s}wrist",
        "handend": "{s}hand", "hipjoint": "{s}hipjoint", "thigh": "{s}femur", "shin": "{s}tibia", "foot": "{s}foot",
        "toe": "{s}toes", "left": "l", "right": "r",
    },
    "biped": {
        "root": "Bip01", "hips": "Bip01 Pelvis", "spine": ["Bip01 Spine", "Bip01 Spine1", "Bip01 Spine2"],
        "neck": "Bip01 Neck", "head": "Bip01 Head", "clavicle": "Bip01 {s} Clavicle", "upperarm": "Bip01 {s} UpperArm",
        "forearm": "Bip01 {s} Forearm", "hand": "Bip01 {s} Hand", "thigh": "Bip01 {s} Thigh", "shin": "Bip01 {s} Calf",
        "foot": "Bip01 {s} Foot", "toe": "Bip01 {s} Toe0", "left": "L", "right": "R",
    },
}  # fmt: skip
_PART = {"hip": "thigh", "knee": "shin", "ankle": "foot", "toe": "toe", "shoulder": "upperarm", "elbow": "forearm",
         "hand": "hand"}  # fmt: skip


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """The FK here runs hundreds of tiny kernels: on a loaded machine, intra-op threads only wait."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _expected(names: dict) -> dict[str, str]:
    out = {}
    for key in KEYPOINTS:
        side, part = key.split("_")
        out[key] = names[_PART[part]].format(S=names[side], s=names[side][0])
    return out


def _clip(seed: int = 0, frames: int = 12, names: dict = LAFAN_NAMES, **kw) -> tuple[Figure, object]:
    fig = human_definition(np.random.default_rng(seed), frames, names, spine=len(names["spine"]), **kw)
    return fig, parse_bvh_text(write_bvh(fig), "human.bvh", facing="keep")


def _skeleton_positions(skel: Skeleton, bvh) -> np.ndarray:
    base_pos, base_quat, q = human_motion(bvh, skel)
    assert base_pos.shape == (bvh.num_frames, 3) and base_quat.shape == (bvh.num_frames, 4)
    assert q.shape == (bvh.num_frames, skel.num_nodes)
    np.testing.assert_allclose(np.linalg.norm(base_quat, axis=1), 1.0, atol=1e-12)
    assert (np.abs(q) <= math.pi).all() and (q[:, ~skel.revolute_mask] == 0).all()
    st_ = skeleton_tensors(skel, torch.float64)
    pos, _ = fk_skeleton(st_, torch.from_numpy(q), torch.from_numpy(base_pos), base_quat=torch.from_numpy(base_quat))
    return pos.numpy()


def _fk_error(skel: Skeleton, bvh) -> float:
    """Largest distance between the skeleton's FK and the file's, over every node that is a BVH joint [m]."""
    pos = _skeleton_positions(skel, bvh)
    ref = bvh.positions()
    at = bvh_nodes(skel)
    assert set(at) == {j.name for j in bvh.joints[base_joint(bvh) :]}  # the base and every joint below it
    return max(float(np.abs(pos[:, n] - ref[:, bvh.index(name)]).max()) for name, n in at.items())


# ---- the skeleton -----------------------------------------------------------------------------


def test_a_lafan1_style_human_becomes_a_skeleton():
    _, bvh = _clip()
    skel = human_skeleton(bvh)
    assert skel.name == "bvh" and skel.node_names[0] == "Hips" and skel.node_kinds[0] == "base"
    assert skel.node_names[1:4] == ("Spine:Zrotation", "Spine:Xrotation", "Spine:Yrotation")
    assert skel.link_names[1:4] == ("Spine",) * 3 and skel.urdf_joint_names[1] == "Spine:Zrotation"
    joints = [j for j in bvh.joints if not j.end_site]
    assert skel.num_dof == 3 * (len(joints) - 1)  # every joint below the hips is a ball joint
    sites = [n for n, k in zip(skel.node_names, skel.node_kinds) if k == "site"]
    assert sites == [j.name for j in bvh.joints if j.end_site]  # End Sites only, after the joints
    assert skel.node_kinds.index("site") == skel.num_dof + 1
    np.testing.assert_allclose(np.abs(skel.axes[skel.revolute_mask]).max(1), 1.0)  # z-up file axes
    assert (skel.lower[skel.revolute_mask] == -math.pi).all() and skel.continuous[skel.revolute_mask].all()
    assert (skel.nominal == 0).all() and (skel.mimic_source == -1).all() and not skel.locked
    assert skel.body_parts == DEFAULT_BODY_PARTS and skel.keypoint_nodes() == skel.keypoints
    at = bvh_nodes(skel)
    assert {k: skel.node_names[v] for k, v in skel.keypoints.items()} == {
        k: f"{j}:Yrotation" for k, j in _expected(LAFAN_NAMES).items()
    }
    assert all(at[j] == skel.keypoints[k] for k, j in _expected(LAFAN_NAMES).items())
    # the zero pose is the T-pose: standing on the feet, arms out, left at +y, the toes forward (+x)
    rest = skel.rest_positions
    kp = skel.keypoints
    assert rest[kp["left_ankle"], 2] < -0.7 and rest[kp["left_hand"], 1] > 0.5 and rest[kp["right_hand"], 1] < -0.5
    assert rest[kp["left_toe"], 0] > rest[kp["left_ankle"], 0]
    assert _fk_error(skel, bvh) < 1e-9
    assert Skeleton.from_json(skel.to_json()) == skel and human_skeleton(bvh).fingerprint == skel.fingerprint


@pytest.mark.parametrize("convention", sorted(CONVENTIONS))
def test_key_points_of_every_naming_convention(convention):
    names = CONVENTIONS[convention]
    _, bvh = _clip(1, 6, names)
    choice = assign_keypoints(bvh)
    assert {k: c.joint for k, c in choice.items()} == _expected(names)
    skel = human_skeleton(bvh)
    assert skel.node_names[0] == names["hips"]  # Bandai's joint_Root and the biped's Bip01 fold into the base
    assert _fk_error(skel, bvh) < 1e-9


def test_no_toe_joint_puts_the_toe_on_the_ankle_end_site():
    _, bvh = _clip(2, 6, toe=False)
    choice = assign_keypoints(bvh)
    assert (choice["left_toe"].joint, choice["left_toe"].how) == ("LeftFoot_End", "End Site of the ankle")
    skel = human_skeleton(bvh)
    assert skel.node_kinds[skel.keypoints["left_toe"]] == "site"
    assert skel.link_names[skel.keypoints["left_toe"]] == "LeftFoot"
    assert sole_points(skel)["left"] == [skel.keypoints["left_ankle"], skel.keypoints["left_toe"]]


@pytest.mark.parametrize("rest_frame", [None, 0, 7])
def test_rest_frame_measures_angles_from_that_frame(rest_frame):
    _, bvh = _clip(3, 10)
    skel = human_skeleton(bvh, rest_frame=rest_frame)
    assert _fk_error(skel, bvh) < 1e-9
    if rest_frame is not None:
        q = human_motion(bvh, skel)[2]
        np.testing.assert_allclose(q[rest_frame], 0.0, atol=1e-12)
        rest = skel.rest_positions
        kp = skel.keypoints
        left = rest[kp["left_hip"]] - rest[kp["right_hip"]]
        assert left[1] > 0 and abs(left[0]) < 1e-9  # the zero pose faces +x
        assert rest[kp["left_ankle"], 2] < -0.6  # and stands


def test_a_bvh_rest_pose_that_is_not_standing_is_reported(caplog):
    fig, _ = _clip(4, 6)
    fig.offsets[[fig.names.index(n) for n in ("LeftLeg", "LeftFoot", "RightLeg", "RightFoot")]] *= -1
    bvh = parse_bvh_text(write_bvh(fig), "folded.bvh", up="y", units="cm")  # legs folded up in the rest pose
    with caplog.at_level(logging.WARNING):
        human_skeleton(bvh)
    assert "not a standing pose; pass rest_frame=N" in caplog.text


def test_rotation_only_root_zero_channel_joints_and_channel_orders():
    fig = human_definition(np.random.default_rng(5), 8)
    fig.root_pos[:] = fig.root_pos[0]  # the root only turns
    fig.local[:, fig.names.index("Neck")] = np.eye(3)  # the neck is a fixed joint
    text = write_bvh(fig, order="YXZ", root_order="XYZ", root_rotation_only=True, fixed=frozenset({"Neck"}))
    assert "CHANNELS 3 Xrotation Yrotation Zrotation" in text.split("\n")[4]
    bvh = parse_bvh_text(text, "variant.bvh", facing="keep")
    np.testing.assert_allclose(bvh.positions(), canonical_fk(fig), atol=1e-6)
    skel = human_skeleton(bvh)
    neck = skel.node_names.index("Neck")
    assert skel.node_kinds[neck] == "site" and "Neck:Yrotation" not in skel.node_names
    assert skel.node_names[skel.parents[skel.node_names.index("Head:Yrotation")]] == "Spine1:Zrotation"
    assert skel.node_names[skel.parents[neck]] == "Spine1:Zrotation"
    assert _fk_error(skel, bvh) < 1e-9


# ---- translations ----------------------------------------------------------------------------


def test_constant_translation_channels_are_folded():
    fig = human_definition(np.random.default_rng(6), 8)
    bvh = parse_bvh_text(write_bvh(fig, six=True), "six.bvh", facing="keep")
    skel = human_skeleton(bvh)
    assert skel.num_dof == 3 * (len([j for j in bvh.joints if not j.end_site]) - 1)
    assert _fk_error(skel, bvh) < 1e-9


def test_a_moving_floor_root_folds_into_the_base():
    fig, bvh = _clip(7, 8, CONVENTIONS["bandai"])
    assert base_joint(bvh) == 1 and bvh.joints[0].name == "joint_Root"
    skel = human_skeleton(bvh)
    base_pos = human_motion(bvh, skel)[0]
    np.testing.assert_allclose(base_pos, canonical_fk(fig)[:, 1], atol=1e-6)  # the hips, not the floor point


def test_a_changing_translation_below_the_base_is_refused():
    fig = human_definition(np.random.default_rng(8), 8)
    knee = fig.names.index("LeftLeg")
    fig.moving[knee] = fig.offsets[knee] * (1 + 0.01 * np.arange(8))[:, None]  # a stretching shin
    bvh = parse_bvh_text(write_bvh(fig), "stretch.bvh")
    with pytest.raises(BVHError) as exc:
        human_skeleton(bvh)
    e = exc.value
    assert "joint 'LeftLeg': its Yposition channel changes during the clip" in e.message  # Y-up: the shin's length
    assert "at frame 8" in e.message and e.line == bvh.first_data_line + 7 and "translation only on the root" in e.fix


# ---- key point overrides and errors ------------------------------------------------------------


def test_a_partial_override_and_the_table():
    _, bvh = _clip(9, 6)
    choice = assign_keypoints(bvh, {"left_toe": "LeftToe_End", "right_hand": "RightHand"})
    assert (choice["left_toe"].joint, choice["left_toe"].how) == ("LeftToe_End", "given")
    assert choice["right_toe"].joint == "RightToe" and choice["right_hand"].how == "given"
    skel = human_skeleton(bvh, keypoints={"left_toe": "LeftToe_End"}, name="mocap")
    assert skel.name == "mocap" and skel.node_names[skel.keypoints["left_toe"]] == "LeftToe_End"
    table = keypoint_table(bvh, keypoints={"left_toe": "LeftToe_End"})
    rows = table.split("\n")
    assert len(rows) == 15 and rows[0].startswith("key points of human.bvh")
    assert rows[1].split()[:2] == ["left_hip", "LeftUpLeg"] and "name (upleg)" in rows[1]
    assert "LeftToe_End" in rows[7] and rows[7].endswith("given")


@pytest.mark.parametrize(
    "keypoints,message,fix",
    [
        ({"left_foot": "LeftFoot"}, "'left_foot' is not a key point", "did you mean 'left_toe'"),
        ({"left_toe": "LeftToes"}, "key point 'left_toe': the file has no joint 'LeftToes'", "did you mean 'LeftToe'"),
        ({"left_knee": "LeftForeArm"}, "key point 'left_knee' (LeftForeArm) is not below 'left_hip' (LeftUpLeg)",
         "keypoints={'left_hip': JOINT, 'left_knee': JOINT}"),
        ({"left_hand": "RightHand"}, "'left_hand' and 'right_hand' are the same joint 'RightHand'", "its own joint"),
        ({"left_hip": "Hips"}, "key point 'left_hip' is 'Hips', which is not below the floating base 'Hips'",
         "name a joint of the legs or arms"),
    ],
)  # fmt: skip
def test_bad_overrides_are_explained(keypoints, message, fix):
    _, bvh = _clip(10, 4)
    with pytest.raises(BVHError) as exc:
        human_skeleton(bvh, keypoints=keypoints)
    assert message in exc.value.message and (fix is None or fix in exc.value.fix), str(exc.value)


def test_a_missing_key_point_names_it_and_the_joints():
    names = dict(LAFAN_NAMES, hand="{S}Paw")
    _, bvh = _clip(11, 4, names)
    with pytest.raises(BVHError) as exc:
        human_skeleton(bvh)
    e = exc.value
    assert "no joint found for key point 'left_hand' (no left joint named like wrist/hand)" in e.message
    assert e.element == "key point left_hand" and "keypoints={'left_hand': JOINT}" in e.fix and "LeftPaw" in e.fix
    skel = human_skeleton(bvh, keypoints={"left_hand": "LeftPaw", "right_hand": "RightPaw"})
    assert skel.node_names[skel.keypoints["right_hand"]] == "RightPaw:Yrotation"


def test_a_key_point_at_or_above_the_base_is_refused():
    _, bvh = _clip(12, 4, CONVENTIONS["bandai"])
    with pytest.raises(BVHError, match="'joint_Root', which is not below the floating base 'Hips'"):
        human_skeleton(bvh, keypoints={"left_hip": "joint_Root", "left_knee": "Hips"})


def test_a_skeleton_of_another_hierarchy_is_refused():
    _, lafan = _clip(13, 4)
    _, smpl = _clip(13, 4, CONVENTIONS["smpl"])
    with pytest.raises(BVHError, match="the skeleton's base is 'Pelvis', this file's is 'Hips'"):
        human_motion(lafan, human_skeleton(smpl))
    with pytest.raises(BVHError, match="base is 'pelvis'"):
        human_motion(lafan, get_skeleton("g1"))


def test_a_skeleton_of_another_clip_with_the_same_hierarchy_works(caplog):
    _, a = _clip(14, 6)
    fig_b = human_definition(np.random.default_rng(14), 9, spine=3)  # same seed: same bones, other motion length
    b = parse_bvh_text(write_bvh(fig_b), "b.bvh", facing="keep")
    with caplog.at_level(logging.WARNING):
        assert _fk_error(human_skeleton(a), b) < 1e-9
    assert "bones differ" not in caplog.text
    _, c = _clip(15, 6)  # other bone lengths: reported
    with caplog.at_level(logging.WARNING):
        human_motion(c, human_skeleton(a))
    assert "the skeleton's bones differ from this clip's" in caplog.text


# ---- features and contacts --------------------------------------------------------------------


def test_features_and_foot_contacts_of_a_human():
    fig = human_definition(np.random.default_rng(16), 30, angle=0.0, yaw=0.0)
    fig.local[:, 0] = np.eye(3)
    fig.root_pos[:] = [0.0, 0.0, 0.95]  # standing still in the T-pose
    bvh = parse_bvh_text(write_bvh(fig), "stand.bvh")
    skel = human_skeleton(bvh)
    base_pos, base_quat, q = human_motion(bvh, skel)
    feats = motion_features(skeleton_tensors(skel, torch.float64), torch.from_numpy(base_pos),
                            torch.from_numpy(base_quat), torch.from_numpy(q), bvh.fps)  # fmt: skip
    assert feats.shape == (30, skel.num_nodes, 9) and torch.isfinite(feats).all()
    pos = split_features(feats)["pos"].numpy()
    np.testing.assert_allclose(pos, _skeleton_positions(skel, bvh), atol=1e-12)
    sp = sole_points(skel)
    assert sp == {s: [skel.keypoints[f"{s}_ankle"], skel.keypoints[f"{s}_toe"]] for s in ("left", "right")}
    assert foot_contacts(pos, skel, bvh.fps).all()  # both feet planted throughout


# ---- the round trip through the skeleton -----------------------------------------------------


@settings(max_examples=25, deadline=None, derandomize=True, database=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    convention=st.sampled_from(sorted(CONVENTIONS)),
    order=st.sampled_from(["ZXY", "ZYX", "XYZ"]),
    six=st.booleans(),
    frame=st.sampled_from([("y", "cm"), ("z", "m")]),
    fps=st.sampled_from([30.0, 120.0]),
    rest=st.sampled_from([None, 0, 5]),
    toe=st.booleans(),
)
def test_skeleton_fk_equals_the_bvh_fk(seed, convention, order, six, frame, fps, rest, toe):
    names = CONVENTIONS[convention]
    fig = human_definition(np.random.default_rng(seed), 8, names, spine=len(names["spine"]), toe=toe)
    bvh = parse_bvh_text(write_bvh(fig, order=order, six=six, up=frame[0], units=frame[1], fps=fps), "rt.bvh")
    skel = human_skeleton(bvh, rest_frame=rest)
    assert _fk_error(skel, bvh) < 1e-6


# ---- real clips -------------------------------------------------------------------------------


BANDAI_KEYPOINTS = {
    "left_hip": "UpperLeg_L", "right_hip": "UpperLeg_R", "left_knee": "LowerLeg_L", "right_knee": "LowerLeg_R",
    "left_ankle": "Foot_L", "right_ankle": "Foot_R", "left_toe": "Toes_L", "right_toe": "Toes_R",
    "left_shoulder": "UpperArm_L", "right_shoulder": "UpperArm_R", "left_elbow": "LowerArm_L",
    "right_elbow": "LowerArm_R", "left_hand": "Hand_L", "right_hand": "Hand_R",
}  # fmt: skip


@pytest.mark.slow
def test_every_bandai_clip_is_a_skeleton_whose_fk_is_the_file(bandai):
    for f in bandai:
        bvh = read_bvh(f)
        assert {k: c.joint for k, c in assign_keypoints(bvh).items()} == BANDAI_KEYPOINTS, f.name
        skel = human_skeleton(bvh, rest_frame=0)
        assert skel.node_names[0] == "Hips" and skel.num_dof == 60 and skel.num_nodes == 66
        pos = _skeleton_positions(skel, bvh)
        ref = bvh.positions()
        at = bvh_nodes(skel)
        err = max(float(np.abs(pos[:, n] - ref[:, bvh.index(name)]).max()) for name, n in at.items())
        assert err < 1e-6, (f.name, err)
        soles = [n for nodes in sole_points(skel).values() for n in nodes]
        assert -0.02 < pos[:, soles, 2].min() < 0.06, f.name  # feet on the floor


def test_bandai_walks_step_with_both_feet(bandai):
    for f in [f for f in bandai if f.name.startswith("dataset-1_walk_")][:4]:
        bvh = read_bvh(f)
        skel = human_skeleton(bvh, rest_frame=0)
        c = foot_contacts(_skeleton_positions(skel, bvh), skel, bvh.fps)
        down = c.mean(0)
        assert ((0.2 < down) & (down < 0.9)).all(), (f.name, down)  # each foot both planted and swinging
        assert (c.any(1)).mean() > 0.9  # one foot or the other is nearly always down


def test_bandai_rest_pose_is_reported_and_a_standing_frame_fixes_it(bandai, caplog):
    bvh = read_bvh(next(f for f in bandai if "bow_normal" in f.name))
    with caplog.at_level(logging.WARNING):
        human_skeleton(bvh)
    assert "not a standing pose" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        skel = human_skeleton(bvh, rest_frame=0)
    assert "not a standing pose" not in caplog.text
    rest = skel.rest_positions
    height = rest[skel.node_names.index("Head_End"), 2] - rest[[skel.keypoints["left_toe"], skel.keypoints["right_toe"]], 2].min()
    assert 1.2 < height < 1.6  # head joint above the toe joints, standing
