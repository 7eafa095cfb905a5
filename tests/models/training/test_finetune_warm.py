"""`mer finetune` of a warm-start base (:mod:`mer_models.warm`) for a robot it never saw: a micro warm
checkpoint trained here, fine-tuned for a registered robot (the example humanoid generated in code, and
Romeo from ``../shared/robots-wild`` where it is present), then evaluated and used by `mer retarget`."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
from model_helpers import synthetic_csv, synthetic_folder
from safetensors.torch import load_file

from mer_data.motion.samples import collate
from mer_data.robots.example import EXAMPLE_ROBOT, write_example_urdf
from mer_data.robots.register import register_robot
from mer_data.robots.registry import get_skeleton
from mer_models.cli import main
from mer_models.config import WarmConfig, preset
from mer_models.hub.integrity import sha256_file
from mer_models.training.finetune import WithNewTarget, window_frames
from mer_models.training.synthetic import SyntheticDataset
from mer_models.training.warm import fill_teacher
from mer_models.warm.model import WarmModel
from mer_models.zoo.checkpoint import check_robot, load_checkpoint

MICRO = WarmConfig(hidden=16, layers=2, heads=2, ffn=32, kernel=3, stride=2, crop=16)
FAST = ["--synthetic", "8", "--batch-size", "4", "--log-every", "1"]


@pytest.fixture(scope="module")
def warm_base(tmp_path_factory):
    """A micro warm checkpoint (G1 -> G1, H1; 3 steps) whose learning rate decays, as ``mer-warm``'s does."""
    from mer_models.training.train import train

    run = preset("warm")
    run = run.replace(name="micro-warm", warm=MICRO,
                      train=dataclasses.replace(run.train, batch_size=4, warmup=2, lr=1e-2, lr_decay_steps=40, save_every=1000,
                                                log_every=1, opt_iters=3))  # fmt: skip
    out = tmp_path_factory.mktemp("warm_base") / "base"
    torch.manual_seed(0)
    train(run, SyntheticDataset("g1", ("h1", "g1"), size=8, seed=1), out, steps=3)
    return out


@pytest.fixture(params=["example", "romeo"])
def robot(request, tmp_path):
    """A robot no built-in model saw, registered in the test's MER_HOME: the example humanoid (always), Romeo
    from ../shared/robots-wild (skipped where absent)."""
    if request.param == "example":
        register_robot(EXAMPLE_ROBOT, write_example_urdf(tmp_path / "urdf" / f"{EXAMPLE_ROBOT}.urdf"))
        return EXAMPLE_ROBOT
    wild = request.getfixturevalue("shared_wild_robots")
    urdf = wild / "romeo" / "romeo.urdf"
    if not urdf.is_file():
        pytest.skip(f"{urdf} is absent")
    register_robot("romeo", urdf)
    return "romeo"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_warm_base_fine_tunes_for_a_new_robot_and_records_its_base(tmp_path, capsys, warm_base, robot):
    out = tmp_path / "ft"
    code, o, err = run(capsys, "finetune", "--base", warm_base, "--robot", robot, "--steps", "3", "--out", out, *FAST)
    assert code == 0, err
    assert f"fine-tuned for {robot}" in o and "step      3" in err
    base, ckpt = load_checkpoint(warm_base), load_checkpoint(out)
    assert isinstance(ckpt.model, WarmModel) and ckpt.run.kind == "warm" and ckpt.step == 3
    assert ckpt.run.warm == base.run.warm and ckpt.run.energy == base.run.energy
    # the new robot joins the base's targets, with its skeleton's fingerprint
    assert set(ckpt.targets) == set(base.targets) | {robot} and ckpt.references == base.references
    check_robot(ckpt, robot, "targets", get_skeleton(robot).fingerprint)
    # finetune's record of the base, and of what it trained on
    d = ckpt.data
    assert d["base_checkpoint"] == str(warm_base.resolve()) and d["base_source"] == "local" and d["base_step"] == 3
    assert d["base_sha256"] == sha256_file(warm_base / "model.safetensors") and d["finetune_robot"] == robot
    assert d["targets"] == ["g1", "h1", robot] and d["synthetic"] == 8 and d["frames"] == MICRO.crop
    # the base's decay spread over the fine-tune's 3 steps (after its 2 warm-up steps)
    assert base.run.train.lr_decay_steps == 40 and ckpt.run.train.lr_decay_steps == 1
    a, b = load_file(str(warm_base / "model.safetensors")), load_file(str(out / "model.safetensors"))
    assert a.keys() == b.keys() and any(not torch.equal(a[k], b[k]) for k in a)  # trained, from the base's weights

    # evaluated on the new robot (the base refuses it) and used by mer retarget without --allow-unseen
    data = synthetic_folder(tmp_path / "data", {"walk1_subject1": 90, "run1_subject2": 90})
    code, _, err = run(capsys, "evaluate", "--model", out, "--input", data, "--source", "g1", "--targets", robot, "--split", "all",
                       "--max-windows", "2", "--methods", "model", "refine", "--refine", "2", "--save", tmp_path / "r.json")  # fmt: skip
    assert code == 0, err
    rows = {r["method"]: r["metrics"]["g_mpbpe"]["mean"] for r in json.loads((tmp_path / "r.json").read_text())["rows"]}
    assert np.isfinite(list(rows.values())).all() and rows["refine"] < rows["model"]
    code, _, err = run(capsys, "evaluate", "--model", warm_base, "--input", data, "--source", "g1", "--targets", robot,
                       "--split", "all", "--max-windows", "2", "--methods", "model")  # fmt: skip
    assert code == 1 and "never trained with" in err
    src = synthetic_csv(tmp_path / "walk.csv", frames=40, seed=3)
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", robot, "--model", out, "-o", tmp_path / "r.csv")
    assert code == 0, err
    m = np.loadtxt(tmp_path / "r.csv", delimiter=",")
    assert m.shape == (40, 7 + get_skeleton(robot).num_dof) and np.isfinite(m).all()


def test_a_resumed_warm_fine_tune_may_go_further(tmp_path, capsys, warm_base, robot):
    """The decay is recorded once: --resume with more --steps continues instead of refusing a changed config."""
    out = tmp_path / "ft"
    assert run(capsys, "finetune", "--base", warm_base, "--robot", robot, "--steps", "3", "--out", out, *FAST)[0] == 0
    code, _, err = run(capsys, "finetune", "--base", warm_base, "--robot", robot, "--steps", "5", "--out", out, "--resume", *FAST)
    assert code == 0, err
    ckpt = load_checkpoint(out)
    assert ckpt.step == 5 and ckpt.run.train.lr_decay_steps == 1
    log = [json.loads(x) for x in (out / "train_log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [1, 2, 3, 4, 5]


def test_the_new_robots_samples_are_solved_on_the_fly(warm_base, robot):
    """The new robot has no teacher: the warm trainer's fill_teacher gives every such sample the optimiser's
    solution, whose key points track the scaled reference far better than the nominal pose does."""
    from mer_data.kinematics.rotations import axis_angle_to_matrix
    from mer_models.batch import batch_fk, graph_from_batch

    ckpt = load_checkpoint(warm_base)
    ds = WithNewTarget(SyntheticDataset("g1", ("h1",), size=4, frames=window_frames(ckpt.run)), get_skeleton(robot), 1.0, 0)
    batch = collate([ds[i] for i in range(4)])
    assert batch["tgt_names"] == [robot] * 4 and not batch["has_teacher"].any()
    fill_teacher(batch, ckpt.run)
    t = batch["teacher"]
    assert batch["has_teacher"].all() and torch.isfinite(t).all()
    g = graph_from_batch(batch, "tgt")
    eta = batch["joint_map"].float()  # (B, Jt, Jr)
    goal = torch.einsum("bjr,btrc->btjc", eta, batch["ref_scaled_pos"])
    keyed = eta[:, 1:].sum(-1) > 0  # key points other than the base: (B, Jt - 1)
    base_pos, base_rot = t[:, :, 0, 3:6], axis_angle_to_matrix(t[:, :, 0, 0:3])
    nominal = torch.where(g.dof, g.nominal, torch.zeros_like(g.nominal))[:, None].expand_as(t[..., 0])
    start = batch_fk(g, nominal, base_pos, base_rot)[0]

    def err(pos):  # mean key-point distance to the goals [m]
        d = (pos[:, :, 1:] - goal[:, :, 1:]).norm(dim=-1)
        return float(d.permute(0, 2, 1)[keyed].mean())

    assert err(t[..., 1:4]) < 0.5 * err(start)


def test_window_frames_of_each_kind():
    assert window_frames(preset("warm")) == preset("warm").warm.crop == 20
    assert window_frames(preset("base")) == preset("base").model.frames == 60
    no_crop = preset("warm").replace(warm=dataclasses.replace(preset("warm").warm, crop=0))
    assert window_frames(no_crop) == no_crop.model.frames
