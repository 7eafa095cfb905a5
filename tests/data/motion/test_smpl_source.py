"""SMPL-family parameter files and joint-position arrays as human sources (mer_data/motion/smpl.py,
joint_positions.py, body_model.py, rig.py): joints checked against the smplx package (the oracle)
on body-model files built in code with the real layout; the skeleton route reproduces them; bad
files are refused naming the file and the field."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from body_model_files import build_body_model, random_poses

from mer_data.base.errors import MerError, MotionFormatError
from mer_data.motion.body_model import BODY_MODEL_ENV, PARENTS
from mer_data.motion.joint_positions import read_joint_positions
from mer_data.motion.smpl import read_smpl, up_rotation
from mer_data.motion.sources import BvhOptions, human_kind, read_source

smplx = pytest.importorskip("smplx", reason="smplx is the test-only oracle ([dev] extra)")

T = 12
_J = {"smpl": 24, "smplh": 52, "smplx": 55}


@pytest.fixture(autouse=True)
def _no_user_models(monkeypatch, tmp_path):
    monkeypatch.delenv(BODY_MODEL_ENV, raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))


def _oracle(kind: str, model_path, poses: np.ndarray, betas: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(T, 22, 3) the smplx package's posed joints of the model file."""
    from smplx.utils import Struct
    from smplx.vertex_ids import vertex_ids

    tt = lambda a: torch.tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    n = len(poses)
    if kind == "smplx":  # its class needs 10k vertices; its kinematics (smplx.lbs) on the file's arrays instead
        from smplx.lbs import batch_rigid_transform, batch_rodrigues, blend_shapes, vertices2joints

        d = np.load(model_path)
        sd = tt(d["shapedirs"][:, :, : len(betas)])
        v = tt(d["v_template"])[None] + blend_shapes(tt(betas)[None], sd)
        J = vertices2joints(tt(d["J_regressor"]), v).expand(n, -1, -1)
        full = np.zeros((n, _J[kind], 3))
        full[:, 0], full[:, 1:22] = poses[:, :3], poses[:, 3:66].reshape(n, 21, 3)
        rot = batch_rodrigues(tt(full.reshape(-1, 3))).view(n, -1, 3, 3)
        par = torch.tensor(d["kintree_table"][0].astype(np.int64))
        par[0] = -1
        joints, _ = batch_rigid_transform(rot, J.contiguous(), par, dtype=torch.float64)
        return (joints[:, :22] + tt(trans)[:, None]).numpy()
    vid = {k: min(i, 10) for k, i in vertex_ids["smplh"].items()}
    cls = {"smpl": smplx.SMPL, "smplh": smplx.SMPLH}[kind]
    kw = dict(model_path=str(model_path), data_struct=Struct(**dict(np.load(model_path))), vertex_ids=vid,
              num_betas=len(betas), batch_size=n, dtype=torch.float64)  # fmt: skip
    if kind == "smplh":
        kw.update(use_pca=False, ext="npz")
    model = cls(**kw)
    out = model(betas=tt(np.repeat(betas[None], n, 0)), global_orient=tt(poses[:, :3]),
                body_pose=tt(poses[:, 3 : 3 + 3 * (_J[kind] - 1 if kind == "smpl" else 21)]), transl=tt(trans))  # fmt: skip
    return out.joints[:, :22].detach().numpy()


@pytest.mark.parametrize("kind, width, nbetas", [("smpl", 72, 10), ("smplh", 156, 10), ("smplx", 165, 16)])
def test_amass_joints_match_smplx(tmp_path, kind, width, nbetas):
    """AMASS layout (120 Hz: every 4th frame kept at 30 Hz) -> joint positions within 1e-5 m of smplx's."""
    model = build_body_model(tmp_path / f"{kind}.npz", kind)
    poses = random_poses(T, _J[kind])[:, :width]
    betas = np.random.default_rng(1).normal(0, 1, nbetas)
    trans = np.random.default_rng(2).normal(0, 0.3, (T, 3))
    np.savez(tmp_path / "m.npz", poses=poses, trans=trans, betas=betas, gender=np.array("neutral"),
             mocap_framerate=np.array(120.0))  # fmt: skip
    bvh = read_smpl(tmp_path / "m.npz", body_model=model)
    assert bvh.fps == 30.0 and bvh.num_frames == 3
    ref = _oracle(kind, model, poses, betas, trans)[::4] @ bvh.to_world.T  # AMASS is z up: only the facing yaw
    assert np.abs(bvh.positions() - ref).max() < 1e-5


def test_video_layout_camera_frame_matches_smplx(tmp_path):
    """global_orient / body_pose (T, 23, 3) / transl in a camera frame (y down): up detected as -y."""
    model = build_body_model(tmp_path / "SMPL_NEUTRAL.npz", "smpl")
    poses = random_poses(T, 24)
    poses[:, :3] = [np.pi, 0, 0]  # body y up -> camera y down
    trans = np.random.default_rng(3).normal(0, 0.2, (T, 3)) + [0, 0, 3]
    betas = np.zeros(10)
    np.savez(tmp_path / "v.npz", global_orient=poses[:, :3], body_pose=poses[:, 3:].reshape(T, 23, 3), transl=trans,
             betas=betas)  # fmt: skip
    bvh = read_smpl(tmp_path / "v.npz", body_model=tmp_path, fps=30)
    assert any("up axis -y" in n for n in bvh.notes)
    ref = _oracle("smpl", model, poses, betas, trans) @ (bvh.to_world @ up_rotation("-y")).T
    assert np.abs(bvh.positions() - ref).max() < 1e-5
    assert bvh.positions()[:, 15, 2].mean() > bvh.positions()[:, 10, 2].mean() + 0.5  # the head is up


def test_n_layout_and_folder_by_gender(tmp_path):
    """SMPL-X "N" split in the smplx package's folder layout, gender from the file; the skeleton route
    (read_source) reproduces the file's joints through the skeleton's own forward kinematics."""
    build_body_model(tmp_path / "models" / "smplx" / "SMPLX_MALE.npz", "smplx")
    poses = random_poses(T, 55, scale=0.2)
    np.savez(tmp_path / "n.npz", root_orient=poses[:, :3], pose_body=poses[:, 3:66], pose_hand=np.zeros((T, 90)),
             trans=np.zeros((T, 3)), betas=np.zeros(16), gender=np.array(b"male"), mocap_frame_rate=np.array(30.0),
             surface_model_type=np.array("smplx"))  # fmt: skip
    assert human_kind(tmp_path / "n.npz", None) == "smpl"
    src = read_source(tmp_path / "n.npz", "smpl", bvh=BvhOptions(body_model=str(tmp_path)))
    bvh = read_smpl(tmp_path / "n.npz", body_model=tmp_path)
    skel = src.skeleton
    pos = src.features()[..., 1:4]  # world positions of the non-base nodes (the skeleton's forward kinematics)
    want = bvh.positions()
    for key, j in (("left_ankle", 7), ("right_toe", 11), ("left_hand", 20), ("right_shoulder", 17), ("left_knee", 4)):
        assert np.abs(pos[:, skel.keypoints[key]] - want[:, j]).max() < 1e-6, key


def test_joint_positions_reproduce_positions(tmp_path):
    """HumanML3D layout (T x 22 x 3, y up): rotations derived from positions reproduce them (fixed bones)."""
    model = build_body_model(tmp_path / "m.npz", "smpl")
    poses = random_poses(T, 24, scale=0.4)
    poses[:, :3] = 0.0  # y up, as HumanML3D
    P = _oracle("smpl", model, poses, np.zeros(10), np.zeros((T, 3)))
    np.save(tmp_path / "j.npy", P.astype(np.float32))
    assert human_kind(tmp_path / "j.npy", None) == "joints"
    bvh = read_joint_positions(tmp_path / "j.npy", fps=30)
    assert any("up axis y" in n for n in bvh.notes)
    assert np.abs(bvh.positions() - P.astype(np.float32) @ (bvh.to_world @ up_rotation("y")).T).max() < 1e-5
    src = read_source(tmp_path / "j.npy", None, bvh=BvhOptions(fps=30))
    assert src.skeleton.name == "joints" and src.motion.num_frames == T
    bvh20 = read_joint_positions(tmp_path / "j.npy")  # 20 Hz by default: resampled to 30 by slerp
    assert bvh20.fps == 30.0 and bvh20.num_frames == len(np.arange(0, (T - 1) / 20 + 1e-9, 1 / 30))


def _amass(path, **over):
    poses = random_poses(6, 52)[:, :156]
    arrays = dict(poses=poses, trans=np.zeros((6, 3)), betas=np.zeros(16), gender=np.array("female"),
                  mocap_framerate=np.array(60.0))  # fmt: skip
    arrays.update(over)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})
    return path


@pytest.mark.parametrize("over, words", [
    (dict(poses=np.full((6, 156), np.nan)), ["'poses'", "NaN"]),
    (dict(poses=np.zeros((6, 150))), ["'poses' has shape (6, 150)", "T x 156"]),
    (dict(trans=np.zeros((5, 3))), ["'trans' has shape (5, 3)"]),
    (dict(trans=None), ["no 'trans'"]),
    (dict(gender=np.array("robot")), ["'gender' is 'robot'"]),
    (dict(mocap_framerate=np.array(-1.0)), ["'mocap_framerate'", "not a frame rate"]),
    (dict(poses=np.zeros((0, 156))), ["'poses' has no frames"]),
    (dict(betas=np.zeros((3, 3, 3))), ["'betas' has shape"]),
])  # fmt: skip
def test_bad_motion_files_name_the_field(tmp_path, over, words):
    build_body_model(tmp_path / "smplh" / "female" / "model.npz", "smplh")
    f = _amass(tmp_path / "bad.npz", **over)
    with pytest.raises(MotionFormatError) as e:
        read_smpl(f, body_model=tmp_path)
    text = str(e.value)
    assert str(f) in text and all(w in text for w in words), text


def test_body_model_problems(tmp_path, monkeypatch):
    f = _amass(tmp_path / "walk.npz")
    with pytest.raises(MotionFormatError, match="--body-model PATH.*MER_BODY_MODELS.*mano.is.tue.mpg.de"):
        read_smpl(f)  # nowhere to look
    build_body_model(tmp_path / "models" / "smplh" / "SMPLH_MALE.npz", "smplh")
    with pytest.raises(MotionFormatError, match=r"no SMPLH model of gender 'female'.*smplh/SMPLH_MALE.npz"):
        read_smpl(f, body_model=tmp_path)  # a gender the folder lacks
    (tmp_path / "models" / "smplh" / "SMPLH_FEMALE.pkl").write_bytes(b"\x80\x02}q\x00.")
    with pytest.raises(MotionFormatError, match=r"pickled SMPLH model.*never unpickles[\s\S]*female/model.npz"):
        read_smpl(f, body_model=tmp_path)
    smplx_model = build_body_model(tmp_path / "x.npz", "smplx", num_betas=20)
    monkeypatch.setenv(BODY_MODEL_ENV, str(smplx_model))
    with pytest.raises(MotionFormatError, match=r"the motion is SMPL\+H .* body model .* is SMPL-X \(55 joints\)"):
        read_smpl(f)  # the environment's model, of another kind than the motion's 156 columns
    np.savez(tmp_path / "obj.npz", v_template=np.array([{"a": 1}], dtype=object))
    with pytest.raises(MotionFormatError, match="Python objects"):
        read_smpl(f, body_model=tmp_path / "obj.npz")


@pytest.mark.parametrize("content, words", [
    (b"GIF89a\x01\x00\x01\x00\x00\x00\x00;", "a GIF image"),
    (b'<?xml version="1.0"?>\n<robot name="r"><link name="a"/></robot>\n', "a URDF robot description"),
    (b"\x80\x04\x95\x05\x00\x00\x00\x00\x00\x00\x00}\x94.", "a Python pickle"),
])  # fmt: skip
def test_wrong_type_inputs_are_named(tmp_path, content, words):
    """A file of another type given as a motion says what it is (not the CSV reader's complaint)."""
    f = tmp_path / "clip.csv"
    f.write_bytes(content)
    with pytest.raises(MerError, match=words):
        human_kind(f, None)


def test_fuzzed_motion_files_raise_only_mer_errors(tmp_path):
    """Random byte edits of a valid AMASS npz: it reads, or a MerError (never another exception)."""
    build_body_model(tmp_path / "smplh" / "female" / "model.npz", "smplh")
    raw = bytearray(_amass(tmp_path / "ok.npz").read_bytes())
    rng = np.random.default_rng(0)
    outcomes = {"read": 0, "refused": 0}
    for i in range(60):
        b = bytearray(raw)
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        f = tmp_path / f"f{i}.npz"
        f.write_bytes(bytes(b[: int(rng.integers(len(b) // 2, len(b) + 1))] if i % 3 == 0 else b))
        try:
            read_smpl(f, body_model=tmp_path)
            outcomes["read"] += 1
        except MerError:
            outcomes["refused"] += 1
    assert outcomes["refused"] > 0


def test_parents_are_smpls():
    assert PARENTS[:4] == (-1, 0, 0, 0) and len(PARENTS) == 22


def test_a_bvh_given_as_a_robot_description_is_named(tmp_path):
    """mer robots register --urdf with a BVH: what it is and what to do, not "repair the XML"."""
    from mer_data.robots.register import register_robot

    f = tmp_path / "walk.urdf"
    f.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n}\nMOTION\n")
    with pytest.raises(MerError, match=r"not a robot description .*BVH motion capture[\s\S]*mer retarget"):
        register_robot("walker", f, dry_run=True)


def test_the_command_line_takes_smpl_and_joint_files(tmp_path, capsys):
    """mer retarget FILE picks SMPL or joints from the content (any name); a dataset run and
    evaluation take --source smpl; a GIF given as a robot's motion is named as one."""
    import json

    from mer_models.cli import main

    build_body_model(tmp_path / "models" / "smplh" / "SMPLH_FEMALE.npz", "smplh")
    poses = random_poses(45, 52, scale=0.15)[:, :156]
    trans = np.zeros((45, 3))
    trans[:, 2] = 0.9
    clip = tmp_path / "in" / "walk.npz"
    clip.parent.mkdir()
    np.savez(clip, poses=poses, trans=trans, betas=np.zeros(16), gender=np.array("female"), mocap_framerate=np.array(30.0))
    odd = tmp_path / "walk.data"  # no telling ending: the content says
    odd.write_bytes(clip.read_bytes())
    bm = ["--body-model", str(tmp_path)]
    assert main(["retarget", str(odd), "--target", "g1", "-o", str(tmp_path / "g1.csv"), "--no-physics", *bm]) == 0
    assert "smpl -> g1" in capsys.readouterr().err
    gif = tmp_path / "walk.csv"
    gif.write_bytes(b"GIF89a\x01\x00\x01\x00\x00\x00\x00;")
    assert main(["retarget", str(gif), "--source", "g1", "--target", "h1", "-o", str(tmp_path / "x.csv")]) == 1
    assert "it looks like a GIF image" in capsys.readouterr().err and not (tmp_path / "x.csv").exists()
    assert main(["retarget", "--input", str(tmp_path / "in"), "--source", "smpl", "--targets", "g1", "--out",
                 str(tmp_path / "ds"), "--quiet", "--no-physics", *bm]) == 0  # fmt: skip
    assert json.loads((tmp_path / "ds" / "g1" / "walk.metrics.json").read_text())["frames"] == 45
    assert main(["evaluate", "--input", str(tmp_path / "in"), "--source", "smpl", "--targets", "g1", "--split", "all",
                 "--stride", "30", "--save", str(tmp_path / "eval.json"), "--no-physics", *bm]) == 0  # fmt: skip
