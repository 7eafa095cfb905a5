"""`mer finetune`: the bundled model fine-tuned to a robot registered from a URDF, end to end, and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from model_helpers import synthetic_csv
from safetensors.torch import load_file
from zoo_helpers import make_checkpoint

from mer_data.robots.example import EXAMPLE_ROBOT, write_example_urdf
from mer_data.robots.register import register_robot
from mer_data.robots.registry import get_skeleton
from mer_models import zoo
from mer_models.cli import main
from mer_models.hub.fromckpt import card_from_checkpoint
from mer_models.hub.registry import bundled_dir
from mer_models.hub.render import render_card
from mer_models.training.finetune import WithNewTarget
from mer_models.training.synthetic import SyntheticDataset
from mer_models.zoo.checkpoint import check_robot, load_checkpoint

FAST = ["--synthetic", "8", "--batch-size", "4", "--log-every", "1"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture
def robot(tmp_path):
    """The example humanoid, registered in the test's own MER_HOME."""
    register_robot(EXAMPLE_ROBOT, write_example_urdf(tmp_path / "urdf" / f"{EXAMPLE_ROBOT}.urdf"))
    return EXAMPLE_ROBOT




def test_finetune_the_bundled_model_to_a_registered_robot_end_to_end(tmp_path, capsys, robot):
    out = tmp_path / "ft"
    code, o, err = run(capsys, "finetune", "--base", zoo.DEFAULT_MODEL, "--robot", robot, "--steps", "2", "--out", out, *FAST)
    assert code == 0, err
    assert f"fine-tuned for {robot}" in o and "step      2" in err and "mer zoo publish" in err
    base = zoo.load(zoo.DEFAULT_MODEL)
    ckpt = load_checkpoint(out)
    # the new robot joins the base's targets; the base's robots stay
    assert set(ckpt.targets) == set(base.targets) | {robot} and ckpt.references == base.references
    check_robot(ckpt, robot, "targets", get_skeleton(robot).fingerprint)  # accepted, no --allow-unseen needed
    assert ckpt.step == 2 and (ckpt.run.model, ckpt.run.energy, ckpt.run.sampler) == (base.run.model, base.run.energy, base.run.sampler)
    card = zoo.model_info(zoo.DEFAULT_MODEL).card
    assert ckpt.data["base_model"] == zoo.DEFAULT_MODEL and ckpt.data["base_source"] == "bundled"
    assert ckpt.data["base_sha256"] == card.files["model.safetensors"].sha256 and ckpt.data["base_step"] == base.step
    assert ckpt.data["finetune_robot"] == robot and ckpt.data["base_data"] == base.data

    # it retargets to the new robot without --allow-unseen
    src = synthetic_csv(tmp_path / "walk.csv", frames=40, seed=3)
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", robot, "--model", out, "-o", tmp_path / "r.csv", "--steps", "2")
    assert code == 0, err
    a = np.loadtxt(tmp_path / "r.csv", delimiter=",")
    assert a.shape == (40, 7 + get_skeleton(robot).num_dof) and np.isfinite(a).all()
    # ... which the base refuses
    code, _, err = run(capsys, "retarget", src, "--source", "g1", "--target", robot, "-o", tmp_path / "s.csv", "--steps", "2")
    assert code == 1 and "never trained with" in err and f"mer finetune --robot {robot}" in err

    # its card names the base, from the checkpoint's own metadata
    ft_card = card_from_checkpoint(out, name=f"{zoo.DEFAULT_MODEL}-demo-humanoid", status="unpublished")
    text = render_card(ft_card)
    assert ft_card.base_model == zoo.DEFAULT_MODEL and robot in ft_card.targets
    assert f"Fine-tuned from `{zoo.DEFAULT_MODEL}`" in text and f"base_model: {zoo.DEFAULT_MODEL}" in text
    assert ft_card.license == "apache-2.0"  # synthetic base, synthetic data


def test_finetuning_starts_from_the_base_weights(tmp_path, robot):
    from mer_models.training.finetune import finetune

    finetune(zoo.DEFAULT_MODEL, robot, tmp_path / "ft", synthetic=4, steps=1, batch_size=4, lr=1e-12)
    base = load_file(str(bundled_dir() / zoo.DEFAULT_MODEL / "model.safetensors"))
    tuned = load_file(str(tmp_path / "ft" / "model.safetensors"))
    assert base.keys() == tuned.keys()
    for k in base:  # one AdamW step of 1e-12: the base's weights, not a fresh initialisation
        torch.testing.assert_close(tuned[k], base[k], atol=1e-9, rtol=0)


def test_a_base_trained_with_grouped_batches_fine_tunes_ungrouped(tmp_path, robot):
    """The fine-tune mixes targets sample by sample: a base's ``ref_group`` > 1 (a training-speed
    option, recorded in its config) must not reach it."""
    import shutil

    from mer_models.training.finetune import finetune

    base = tmp_path / "base"
    shutil.copytree(bundled_dir() / zoo.DEFAULT_MODEL, base)
    meta = json.loads((base / "config.json").read_text())
    meta["run"]["train"]["ref_group"] = 4
    (base / "config.json").write_text(json.dumps(meta))
    res = finetune(str(base), robot, tmp_path / "ft", synthetic=4, steps=1, batch_size=2)
    assert res.step == 1 and load_checkpoint(tmp_path / "ft").run.train.ref_group == 1


def test_a_fraction_of_the_samples_targets_the_new_robot(robot):
    ds = SyntheticDataset("g1", ("g1", "h1"), size=64, frames=60)
    wt = WithNewTarget(ds, get_skeleton(robot), fraction=0.5, seed=0)
    names = [wt[i].target_skeleton.name for i in range(64)]
    new = sum(n == robot for n in names)
    assert 16 <= new <= 48 and {"g1", "h1"} <= set(names)
    s = wt[names.index(robot)]
    assert s.target is None and s.joint_map.shape == (get_skeleton(robot).num_nodes, get_skeleton("g1").num_nodes)
    assert s.joint_map.sum() == 15  # 14 key points + the bases
    assert [wt[i].target_skeleton.name for i in range(64)] == names  # a pure function of the index


def test_finetune_from_shards(tmp_path, capsys, robot):
    from shard_helpers import build, make_input

    make_input(tmp_path / "in", robots=("g1",), clips={"walk1_subject1": (3.0, 0.5, 0.0)})
    build(tmp_path / "in", tmp_path / "shards", robots=("g1",), targets=("g1", "h1"), split="all", augment=0)
    code, _, err = run(capsys, "finetune", "--base", zoo.DEFAULT_MODEL, "--robot", robot, "--shards", tmp_path / "shards",
                       "--steps", "1", "--batch-size", "2", "--out", tmp_path / "ft")  # fmt: skip
    assert code == 0, err
    meta = json.loads((tmp_path / "ft" / "config.json").read_text())
    assert meta["data"]["split"] == "train" and meta["data"]["shards"] and robot in meta["robots"]["targets"]
    code, _, err = run(capsys, "finetune", "--base", zoo.DEFAULT_MODEL, "--robot", robot, "--shards", tmp_path / "shards",
                       "--split", "eval", "--steps", "1", "--out", tmp_path / "ft2")  # fmt: skip
    assert code == 1 and "no 'eval' windows" in err and not (tmp_path / "ft2").exists()


@pytest.mark.parametrize("argv, message", [
    (["--base", zoo.DEFAULT_MODEL, "--robot", "nosuch"], "unknown robot 'nosuch'"),
    (["--base", "mer-paper", "--robot", "g1"], "not yet published"),
    (["--base", "no-such-model", "--robot", "g1"], "known models:"),
    (["--base", "./missing/folder", "--robot", "g1"], "no checkpoint folder"),
])
def test_refusals_are_clear_and_write_nothing(tmp_path, capsys, argv, message):
    code, _, err = run(capsys, "finetune", *argv, "--steps", "1", "--out", tmp_path / "ft", *FAST)
    assert code == 1 and message in err, err
    assert not (tmp_path / "ft").exists()


def test_a_finetune_of_lafan1_weights_stays_non_commercial(tmp_path):
    ck = make_checkpoint(tmp_path / "ck", dataset="synthetic", targets=("g1", "h1", "talos"))
    meta = json.loads((ck / "config.json").read_text())
    meta["data"] = {"synthetic": 8, "base_model": "mer-paper", "base_data": {"shards": ["shards/lafan1"], "dataset": "lafan1"}}
    (ck / "config.json").write_text(json.dumps(meta))
    card = card_from_checkpoint(ck, name="my-talos", status="unpublished")
    assert card.license == "cc-by-nc-nd-4.0" and card.base_model == "mer-paper"
