"""Human motion capture (BVH) as a retargeting source: the same motion written in another studio's
convention gives the same robot motion; the command line, dataset runs and evaluation take BVH;
the model refuses a human source it never saw. Real clips (../shared/data/bvh) where present."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from bvh_factory import BANDAI_NAMES, fold_root, human_definition, smooth_motion, upsample, write_bvh

from mer_data.base.errors import MerError
from mer_data.motion.sources import read_source
from mer_data.robots.registry import load_robot
from mer_models.retarget.clip import retarget_features
from mer_models.solver.physics import PhysicsConfig

TO_LAFAN = {
    "Spine": "Spine", "Chest": "Spine1", "Neck": "Neck", "Head": "Head",
    **{f"{b}_{s}": f"{side}{lafan}" for s, side in (("L", "Left"), ("R", "Right")) for b, lafan in (
        ("Shoulder", "Shoulder"), ("UpperArm", "Arm"), ("LowerArm", "ForeArm"), ("Hand", "Hand"),
        ("UpperLeg", "UpLeg"), ("LowerLeg", "Leg"), ("Foot", "Foot"), ("Toes", "Toe"))},
}  # fmt: skip


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _key_points(path: Path, target: str = "g1") -> np.ndarray:
    """(F, 14, 3) world key points [m] of ``path`` retargeted to ``target`` (optimiser, physical terms)."""
    src = read_source(path, "bvh")
    robot = load_robot(target)
    res = retarget_features(src.features(), src.skeleton, robot.skeleton, method="optimize", physics=PhysicsConfig())
    pos, _ = res.motion.forward_kinematics()
    return pos[:, list(robot.skeleton.keypoints.values())]


def test_the_same_motion_in_another_convention_gives_the_same_robot_motion(tmp_path):
    """Bandai's convention (joint_Root on the floor, 6 channels ZXY, Y-up, cm, 30 Hz) and LAFAN1's
    (Hips as ROOT, 3 channels ZYX, Z-up, metres, 120 Hz) of one motion: G1's key points within 1 mm."""
    rng = np.random.default_rng(3)
    fig = smooth_motion(human_definition(rng, 46, BANDAI_NAMES, angle=10.0, yaw=20.0), rng)
    a, b = tmp_path / "bandai.bvh", tmp_path / "lafan.bvh"
    a.write_text(write_bvh(fig, order="ZXY", six=True, up="y", units="cm", fps=30.0))
    b.write_text(write_bvh(upsample(fold_root(fig, TO_LAFAN), 4), order="ZYX", up="z", units="m", fps=120.0))
    sa, sb = read_source(a, "bvh"), read_source(b, "bvh")
    assert sb.skeleton.node_names != sa.skeleton.node_names  # two different skeletons ...
    assert sa.motion.num_frames == sb.motion.num_frames == 46  # ... of one motion at 30 Hz
    pa, pb = _key_points(a), _key_points(b)
    assert np.abs(pa - pb).max() < 1e-3


@pytest.mark.filterwarnings("ignore:Gimbal lock")  # scipy writing an Euler triple at +-90 deg: the rotation is still exact
def test_a_real_clip_in_another_convention_gives_the_same_robot_motion(bandai, tmp_path):
    """A Bandai walk re-exported with LAFAN1 names, 3 channels ZYX, 120 Hz, Z-up, metres: the same
    G1 and H1 motion within 1 mm."""
    from bvh_factory import Figure

    from mer_data.motion.bvh import read_bvh

    clip = read_bvh(bandai[0].parent / "dataset-1_walk_normal_001.bvh", facing="keep")
    F = min(clip.num_frames, 90)
    pos, rot = clip.positions(slice(0, F)), clip.rotations(slice(0, F))
    par = [j.parent for j in clip.joints]
    local = np.stack([rot[:, k] if p < 0 else np.swapaxes(rot[:, p], -1, -2) @ rot[:, k] for k, p in enumerate(par)], 1)
    rel = np.stack([pos[:, k] if p < 0 else np.einsum("fji,fj->fi", rot[:, p], pos[:, k] - pos[:, p])
                    for k, p in enumerate(par)], 1)  # fmt: skip
    fig = Figure([j.name for j in clip.joints], par, rel[0], [j.end_site for j in clip.joints], local, pos[:, 0],
                 {k: rel[:, k] for k in range(1, len(par)) if np.ptp(rel[:, k], axis=0).max() > 1e-9})  # fmt: skip
    a = tmp_path / "a.bvh"
    a.write_text(write_bvh(fig, order="ZXY", six=True, up="y", units="cm", fps=30.0))
    b = tmp_path / "b.bvh"
    b.write_text(write_bvh(upsample(fold_root(fig, TO_LAFAN), 4), order="ZYX", up="z", units="m", fps=120.0))
    for target in ("g1", "h1"):
        assert np.abs(_key_points(a, target) - _key_points(b, target)).max() < 1e-3, target


def test_the_command_line_takes_bvh_and_the_model_refuses_it(tmp_path, capsys):
    from mer_data.motion.lafan1 import read_lafan1_csv
    from mer_models.cli import main

    rng = np.random.default_rng(0)
    clip = tmp_path / "in" / "bvh" / "walk.bvh"
    clip.parent.mkdir(parents=True)
    clip.write_text(write_bvh(smooth_motion(human_definition(rng, 75, BANDAI_NAMES, angle=10.0, yaw=20.0), rng), six=True))
    out = tmp_path / "h1.csv"
    assert main(["retarget", str(clip), "--target", "h1", "-o", str(out)]) == 0  # source and method from the extension
    m = read_lafan1_csv(out, load_robot("h1"))
    assert m.num_frames == 75 and np.isfinite(m.joints).all()
    capsys.readouterr()
    assert main(["retarget", str(clip), "--target", "h1", "-o", str(tmp_path / "x.csv"), "--method", "diffusion"]) == 1
    assert "never seen a human" in capsys.readouterr().err and not (tmp_path / "x.csv").exists()
    assert main(["retarget", str(out), "--source", "bvh", "--target", "g1", "-o", str(tmp_path / "y.csv")]) == 1
    assert "not a BVH file" in capsys.readouterr().err
    # a folder of BVH files, as a dataset and in evaluation
    assert main(["retarget", "--input", str(tmp_path / "in"), "--source", "bvh", "--targets", "g1", "--out", str(tmp_path / "ds"),
                 "--quiet"]) == 0  # fmt: skip
    row = json.loads((tmp_path / "ds" / "g1" / "walk.metrics.json").read_text())
    assert row["frames"] == 75 and row["limit_violation"] == 0 and row["floor_frames"] == 0
    report = tmp_path / "eval.json"
    assert main(["evaluate", "--input", str(tmp_path / "in"), "--source", "bvh", "--targets", "g1", "--split", "all",
                 "--stride", "30", "--save", str(report)]) == 0  # fmt: skip
    rows = json.loads(report.read_text())["rows"]
    assert rows and rows[0]["metrics"]["g_mpbpe"]["mean"] < 0.05


def test_a_keypoint_file_overrides_and_a_bad_one_is_refused(tmp_path):
    from mer_data.motion.sources import BvhOptions, load_bvh_keypoints

    rng = np.random.default_rng(1)
    clip = tmp_path / "c.bvh"
    clip.write_text(write_bvh(smooth_motion(human_definition(rng, 20, BANDAI_NAMES), rng), six=True))
    good = tmp_path / "k.yaml"
    good.write_text("left_toe: Toes_L_End\n")
    src = read_source(clip, "bvh", bvh=BvhOptions(keypoints=load_bvh_keypoints(good)))
    assert src.skeleton.node_names[src.skeleton.keypoints["left_toe"]] == "Toes_L_End"
    for text, msg in (("left_paw: Hand_L\n", "unknown key point"), ("left_hand: [1, 2]\n", "must name a BVH joint"),
                      ("- a\n- b\n", "not a mapping")):  # fmt: skip
        good.write_text(text)
        with pytest.raises(MerError, match=msg):
            load_bvh_keypoints(good)
