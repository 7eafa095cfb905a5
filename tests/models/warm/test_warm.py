"""The warm-start model (:mod:`mer_models.warm`): features, network, checkpoints, training, the commands."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from model_helpers import mixed_batch, synthetic_csv

from mer_data.base.errors import CheckpointError, ConfigError
from mer_models.batch import graph_from_batch, rot_z
from mer_models.cli import main
from mer_models.config import EnergyConfig, RunConfig, WarmConfig, from_dict, preset
from mer_models.diffusion.model import RetargetModel
from mer_models.training.synthetic import SyntheticDataset
from mer_models.warm.features import relations
from mer_models.warm.model import WarmModel, interpolate, key_frames
from mer_models.zoo.checkpoint import load_checkpoint

MICRO = WarmConfig(hidden=16, layers=2, heads=2, ffn=32, kernel=3, stride=2, crop=24)


def micro_warm_run(batch_size: int = 4) -> RunConfig:
    run = preset("warm")
    return run.replace(name="micro-warm", warm=MICRO,
                       train=dataclasses.replace(run.train, batch_size=batch_size, warmup=2, lr=1e-2, lr_decay_steps=0, save_every=1000,
                                                 log_every=1, opt_iters=3))  # fmt: skip


def randomised(cfg: WarmConfig = MICRO, seed: int = 0) -> WarmModel:
    """A model whose output heads are not zero (an untrained model's are: every input would give the nominal pose)."""
    torch.manual_seed(seed)
    m = WarmModel(cfg).eval()
    for h in (m.net.joint_head, m.net.base_head):
        torch.nn.init.normal_(h.weight, std=0.2)
        torch.nn.init.normal_(h.bias, std=0.2)
    return m


def test_relation_codes_on_a_chain():
    parents = torch.tensor([[-1, 0, 1, 2, 0]])  # 0 - 1 - 2 - 3, and 4 on 0
    c = relations(parents, torch.ones(1, 5, dtype=torch.bool))[0]
    assert c[1, 1] == 1 and c[1, 0] == 2 and c[0, 1] == 3  # self, parent, child
    assert c[2, 0] == 4 and c[0, 2] == 5  # grandparent, grandchild
    assert c[3, 0] == 6 and c[0, 3] == 7  # three hops
    assert c[4, 1] == 0 and c[1, 4] == 0 and c[3, 4] == 0  # other branches: unrelated
    masked = relations(parents, torch.tensor([[True, True, True, True, False]]))[0]
    assert (masked[4] == 0).all() and (masked[:, 4] == 0).all()


def test_key_frames_and_their_interpolation():
    assert key_frames(10, 3).tolist() == [0, 3, 6, 9] and key_frames(10, 4).tolist() == [0, 4, 8, 9]
    assert key_frames(10, 3, offset=1).tolist() == [0, 1, 4, 7, 9]
    keys = key_frames(11, 3)
    line = (2.0 * keys.float() - 1.0)[None, :, None]  # a linear function of time comes back exactly
    assert torch.allclose(interpolate(line, keys, 11)[0, :, 0], 2.0 * torch.arange(11.0) - 1.0)


def test_angles_stay_inside_the_limits_and_an_untrained_model_gives_the_nominal_pose():
    batch = mixed_batch(("h1", "tron1", "g1"))
    g = graph_from_batch(batch, "tgt")
    out = randomised().forward_batch(batch)
    assert (out["q"] >= g.lower[:, None] - 1e-6).all() and (out["q"] <= g.upper[:, None] + 1e-6).all()
    plain = WarmModel(MICRO).forward_batch(batch)
    nominal = torch.where(g.dof, g.nominal, torch.zeros_like(g.nominal))
    assert torch.allclose(plain["q"], nominal[:, None].expand_as(plain["q"]), atol=1e-4)


def test_the_output_turns_and_moves_with_the_input():
    """Yaw and shift the whole input about world z: the angles stay, the base pose turns and moves with it."""
    batch = mixed_batch(("h1", "g1"))
    m = randomised()
    with torch.no_grad():
        a = m.forward_batch(batch)
        yaw, shift = torch.tensor(0.7), torch.tensor([0.4, -1.3, 0.0])
        R = rot_z(yaw)
        moved = dict(batch)
        ref = batch["reference"].clone()
        from mer_data.kinematics.rotations import axis_angle_to_matrix, matrix_to_axis_angle

        ref[:, :, 0, 0:3] = matrix_to_axis_angle(R @ axis_angle_to_matrix(ref[:, :, 0, 0:3]))
        ref[:, :, 0, 3:6] = ref[:, :, 0, 3:6] @ R.T + shift
        moved["reference"] = ref
        moved["ref_scaled_pos"] = batch["ref_scaled_pos"] @ R.T + shift
        moved["ref_goal_rot"] = R @ batch["ref_goal_rot"]
        b = m.forward_batch(moved)
    assert torch.allclose(a["q"], b["q"], atol=1e-4)
    assert torch.allclose(a["base_pos"] @ R.T + shift, b["base_pos"], atol=1e-4)
    assert torch.allclose(R @ a["base_rot"], b["base_rot"], atol=1e-4)


def test_a_long_motion_in_chunks_is_the_one_pass():
    ds = SyntheticDataset("g1", ("h1",), size=1, frames=400)
    from mer_data.motion.samples import collate

    batch = collate([ds[0]])
    m = randomised()
    with torch.no_grad():
        whole, chunked = m.forward_batch(batch), m.predict(batch, chunk=64)
    for k in whole:
        assert torch.allclose(whole[k], chunked[k], atol=1e-5), k


def test_training_fits_the_teacher(tmp_path):
    """A few steps on a fixed set lower the regression on the teacher's solution and the energy."""
    from mer_data.motion.samples import collate
    from mer_models.training.train import train
    from mer_models.training.warm import fill_teacher

    data = SyntheticDataset("g1", ("h1", "g1"), size=6, seed=3)
    run = micro_warm_run(batch_size=6)
    fixed = run.replace(warm=dataclasses.replace(run.warm, crop=0, stride=1))  # every step sees the same frames
    samples = []  # the fixed set with its teacher solved once (the loop would solve the same six at every step)
    for i in range(len(data)):
        batch = collate([data[i]])
        fill_teacher(batch, fixed)
        samples.append(dataclasses.replace(data[i], teacher=batch["teacher"][0, :, : data[i].target_skeleton.num_nodes].numpy()))
    res = train(fixed, samples, tmp_path / "w", steps=24)
    log = [json.loads(x) for x in (tmp_path / "w" / "train_log.jsonl").read_text().splitlines()]
    def mean(key: str, rows: list) -> float:
        return float(np.mean([r[key] for r in rows]))

    assert res.step == 24  # the mean of the last four steps well below the first four's (one step is noisy)
    assert mean("loss", log[-4:]) < 0.85 * mean("loss", log[:4]) and mean("fk", log[-4:]) < 0.85 * mean("fk", log[:4])
    ckpt = load_checkpoint(tmp_path / "w")
    assert isinstance(ckpt.model, WarmModel) and ckpt.run.kind == "warm" and ckpt.targets == ["g1", "h1"]
    with pytest.raises(CheckpointError, match="'warm' model"):
        RetargetModel.from_folder(tmp_path / "w")
    # resumed in two halves: the same weights as in one run (the teacher solved in the loop)
    train(run, data, tmp_path / "a", steps=6)
    train(run, data, tmp_path / "h", steps=3)
    train(run, data, tmp_path / "h", steps=6, resume=True)
    from safetensors.torch import load_file

    a, b = load_file(str(tmp_path / "a" / "model.safetensors")), load_file(str(tmp_path / "h" / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_the_loss_is_zero_for_the_teacher_itself():
    """Regression terms vanish when the output is the teacher's solution (they measure the right thing)."""
    batch = mixed_batch(("h1",))
    m = randomised()
    with torch.no_grad():
        out = m.forward_batch(batch)
        from mer_models.batch import batch_features

        batch["teacher"] = batch_features(graph_from_batch(batch, "tgt"), out["q"], out["base_pos"], out["base_rot"])
        batch["has_teacher"][:] = True
        terms = m.loss(batch, EnergyConfig())
    assert float(terms["q"].max()) < 1e-8 and float(terms["fk"].max()) < 1e-8 and float(terms["pos"].max()) < 1e-8
    assert float(terms["rot"].max()) < 1e-6 and float(terms["energy"].min()) > 0


def test_configuration_kinds():
    run = preset("warm")
    assert run.kind == "warm" and from_dict(run.to_dict()) == run
    old = {k: v for k, v in RunConfig().to_dict().items() if k not in ("kind", "warm")}  # written before the warm kind
    assert from_dict(old).kind == "diffusion"
    with pytest.raises(ConfigError, match="kind"):
        from_dict({**run.to_dict(), "kind": "gan"})
    with pytest.raises(ConfigError, match="stride"):
        WarmConfig(stride=0)


@pytest.fixture(scope="module")
def warm_checkpoint(tmp_path_factory):
    from mer_models.training.train import train

    out = tmp_path_factory.mktemp("warm") / "w"
    torch.manual_seed(0)
    train(micro_warm_run(), SyntheticDataset("g1", ("h1", "g1", "tron1"), size=8, seed=1), out, steps=4)
    return out


def test_evaluate_and_retarget_run_the_warm_model(tmp_path, capsys, warm_checkpoint):
    data = tmp_path / "data"
    for k in range(2):
        synthetic_csv(data / "g1" / f"clip{k}.csv", "g1", frames=120, seed=k)
    code = main(["evaluate", "--model", str(warm_checkpoint), "--input", str(data), "--source", "g1", "--targets", "h1",
                 "--split", "all", "--max-windows", "2", "--methods", "model", "refine", "optimize", "--refine", "2",
                 "--save", str(tmp_path / "r.json")])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    rows = {r["method"]: r for r in json.loads((tmp_path / "r.json").read_text())["rows"]}
    g = {m: rows[m]["metrics"]["g_mpbpe"]["mean"] for m in rows}
    assert g["refine"] < g["model"] and all(math.isfinite(v) for v in g.values())
    src = synthetic_csv(tmp_path / "walk.csv", frames=90)
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(warm_checkpoint), "-o", str(tmp_path / "a.csv")]) == 0
    assert "warm+refine2" in capsys.readouterr().err  # the warm start's own refinement by default
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(warm_checkpoint), "--refine", "0",
                 "-o", str(tmp_path / "b.csv")]) == 0  # fmt: skip
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == b.shape == (90, a.shape[1]) and not np.allclose(a, b)
