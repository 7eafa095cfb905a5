"""One real motion, three human sources: a Bandai clip as BVH, converted into an AMASS-layout SMPL+H
npz (with a body model built from its skeleton) and into HumanML3D-layout joint positions,
retargets to G1 and H1 within 5 mm (parameters) and 2 cm (positions only) mean key-point distance
of the BVH route. Real clips from ../shared (skipped where absent); nothing derived is kept."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mer_data.motion.body_model import BODY_MODEL_ENV, JOINT_NAMES, PARENTS
from mer_data.motion.bvh import UP_ROTATIONS, fk, read_bvh
from mer_data.motion.sources import BvhOptions, read_source
from mer_data.robots.registry import load_robot
from mer_models.retarget.clip import retarget_features
from mer_models.solver.physics import PhysicsConfig

#: SMPL's 22 body joints -> Bandai's (spine3 sits on the chest, carried by it).
BANDAI = {"pelvis": "Hips", "spine1": "Spine", "spine2": "Chest", "spine3": "Chest", "neck": "Neck", "head": "Head",
          **{f"{side}_{smpl}": f"{b}_{s}" for side, s in (("left", "L"), ("right", "R")) for smpl, b in (
              ("hip", "UpperLeg"), ("knee", "LowerLeg"), ("ankle", "Foot"), ("foot", "Toes"), ("collar", "Shoulder"),
              ("shoulder", "UpperArm"), ("elbow", "LowerArm"), ("wrist", "Hand"))}}  # fmt: skip
FRAMES = 90


@pytest.fixture(autouse=True)
def _no_user_models(monkeypatch, torch_one_thread):
    monkeypatch.delenv(BODY_MODEL_ENV, raising=False)


def _convert(clip, tmp_path):
    """(AMASS npz, body-model folder, HumanML3D npy) of ``clip`` (file axes: y up)."""
    idx = [clip.index(BANDAI[n]) for n in JOINT_NAMES]
    vals = clip.values
    rest_vals = vals[:1].copy()
    for j in clip.joints:
        for col, _ in j.rotation_channels:
            rest_vals[0, col] = 0.0
    rest_pos, _ = fk(clip.joints, rest_vals)
    pos, rot = fk(clip.joints, vals)
    J = rest_pos[0, idx] * clip.scale  # the body model's rest joints: Bandai's rest pose [m]
    J[9] += 0.3 * (J[12] - J[9])  # spine3 a third of the way to the neck: on the chest
    G = rot[:, idx]
    U = UP_ROTATIONS["y"]  # file (y up) -> AMASS (z up)
    local = [U @ G[:, 0]] + [np.swapaxes(G[:, PARENTS[k]], -1, -2) @ G[:, k] for k in range(1, 22)]
    poses = np.zeros((clip.num_frames, 156))
    for k, R in enumerate(local):
        poses[:, 3 * k : 3 * k + 3] = Rotation.from_matrix(R).as_rotvec()
    trans = (pos[:, idx[0]] * clip.scale) @ U.T - J[0]
    J52 = np.concatenate([J, np.repeat(J[[20]], 15, 0), np.repeat(J[[21]], 15, 0)])  # hands at the wrists
    par = list(PARENTS) + [p for w in (20, 21) for p in (w, None, None) * 5]
    for k in range(22, 52):
        par[k] = par[k] if par[k] is not None else k - 1
    kt = np.stack([np.array(par), np.arange(52)]).astype(np.uint32)
    kt[0, 0] = 4294967295
    models = tmp_path / "models"
    (models / "smplh").mkdir(parents=True)
    np.savez(models / "smplh" / "SMPLH_NEUTRAL.npz", v_template=J52, shapedirs=np.zeros((52, 3, 16)),
             J_regressor=np.eye(52), kintree_table=kt)  # fmt: skip
    np.savez(tmp_path / "amass.npz", poses=poses, trans=trans, betas=np.zeros(16), gender=np.array("neutral"),
             mocap_framerate=np.array(clip.fps))  # fmt: skip
    P = pos[:, idx] * clip.scale
    P[:, 9] = P[:, 9] + 0.3 * (P[:, 12] - P[:, 9])
    np.save(tmp_path / "humanml3d.npy", P.astype(np.float32))
    return tmp_path / "amass.npz", models, tmp_path / "humanml3d.npy"


def _key_points(src, target: str) -> np.ndarray:
    robot = load_robot(target)
    res = retarget_features(src.features()[:FRAMES], src.skeleton, robot.skeleton, method="optimize", physics=PhysicsConfig())
    pos, _ = res.motion.forward_kinematics()
    return pos[:, list(robot.skeleton.keypoints.values())]


def test_a_bandai_clip_as_smpl_and_as_joint_positions_retargets_like_the_bvh(bandai, tmp_path):
    path = bandai[0].parent / "dataset-1_walk_normal_001.bvh"
    clip = read_bvh(path)
    amass, models, joints = _convert(clip, tmp_path)
    bvh = read_source(path, "bvh")
    smpl = read_source(amass, None, bvh=BvhOptions(body_model=str(models)))
    pts = read_source(joints, None, bvh=BvhOptions(fps=clip.fps))
    assert (smpl.kind, pts.kind) == ("smpl", "joints") and bvh.motion.num_frames == smpl.motion.num_frames == pts.motion.num_frames
    for target in ("g1", "h1"):
        ref = _key_points(bvh, target)
        d_smpl = np.linalg.norm(_key_points(smpl, target) - ref, axis=-1).mean()
        d_pts = np.linalg.norm(_key_points(pts, target) - ref, axis=-1).mean()
        print(f"{target}: mean key-point distance to the BVH route: SMPL {d_smpl * 1000:.2f} mm, positions {d_pts * 1000:.2f} mm")
        assert d_smpl < 0.005, target
        assert d_pts < 0.02, target
