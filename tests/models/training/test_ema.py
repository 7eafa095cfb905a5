"""A moving average of the weights (``TrainConfig.ema``): its arithmetic, where a checkpoint keeps
it and the trained weights, exact resume, and the configuration's refusals."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from model_helpers import assert_resume_exact, dataset, micro_run
from safetensors.torch import load_file

from mer_data.base.errors import ConfigError
from mer_models.config import TrainConfig, from_dict
from mer_models.hub.checkpoint_files import TRAINED_PREFIX
from mer_models.training.train import ema_decay, train, update_average
from mer_models.zoo.checkpoint import load_checkpoint

REPO = Path(__file__).resolve().parents[3]


def ema_run(decay: float = 0.9):
    run = micro_run()
    return run.replace(train=dataclasses.replace(run.train, ema=decay))


def test_decay_warms_up_then_holds():
    assert ema_decay(0.999, 0) == pytest.approx(0.1)
    assert ema_decay(0.999, 10) == pytest.approx(11 / 20)
    assert ema_decay(0.999, 10**6) == 0.999
    assert [ema_decay(0.9, s) for s in range(100)] == sorted(ema_decay(0.9, s) for s in range(100))


def test_update_average_is_the_exponential_average():
    lin = torch.nn.Linear(3, 2)
    avg = {k: torch.zeros_like(v) for k, v in lin.state_dict().items()}
    update_average(avg, lin, 0.75)
    for k, v in lin.state_dict().items():
        torch.testing.assert_close(avg[k], 0.25 * v)
    update_average(avg, lin, 0.75)
    for k, v in lin.state_dict().items():
        torch.testing.assert_close(avg[k], (0.25 * 0.75 + 0.25) * v)


def test_checkpoint_holds_the_average_and_the_trained_weights(tmp_path):
    """The weights file is the average of the trained weights along the run (recomputed here from
    a run that saves after every step), the optimiser file the trained weights."""
    run = ema_run(0.9)
    run = run.replace(train=dataclasses.replace(run.train, save_every=1))
    out = tmp_path / "c"
    trained_per_step = []
    for s in (1, 2, 3):
        train(run, dataset(), out, steps=s, resume=s > 1)
        opt = load_file(str(out / "optimizer.safetensors"))
        trained_per_step.append({k[len(TRAINED_PREFIX):]: v for k, v in opt.items() if k.startswith(TRAINED_PREFIX)})
    plain = micro_run()
    train(plain, dataset(), tmp_path / "plain", steps=3)
    start = load_file(str(tmp_path / "plain" / "model.safetensors"))  # same seed: same start, same trained weights
    assert all(torch.equal(start[k], trained_per_step[-1][k]) for k in start)
    ref = {k: v.clone() for k, v in train_start(plain).items()}
    for s, w in enumerate(trained_per_step, start=1):
        d = ema_decay(0.9, s)
        ref = {k: d * ref[k] + (1 - d) * w[k] if ref[k].is_floating_point() else w[k] for k in ref}
    avg = load_file(str(out / "model.safetensors"))
    assert avg.keys() == ref.keys()
    for k in avg:
        torch.testing.assert_close(avg[k], ref[k], rtol=1e-5, atol=1e-6)
    assert any(not torch.equal(avg[k], trained_per_step[-1][k]) for k in avg)
    ckpt = load_checkpoint(out)  # inference loads the average
    assert all(torch.equal(ckpt.model.state_dict()[k], avg[k]) for k in avg)


def train_start(run) -> dict[str, torch.Tensor]:
    """The weights a run starts from (the seed's initialisation)."""
    from mer_models.diffusion.model import RetargetModel

    torch.manual_seed(run.train.seed)
    return RetargetModel(run.model).state_dict()


def test_resume_with_an_average_is_exact(tmp_path):
    assert_resume_exact(ema_run(0.9), tmp_path)
    assert any(k.startswith(TRAINED_PREFIX) for k in load_file(str(tmp_path / "a" / "optimizer.safetensors")))


def test_no_average_no_trained_copy(tmp_path):
    train(micro_run(), dataset(), tmp_path / "a", steps=1)
    assert not any(k.startswith(TRAINED_PREFIX) for k in load_file(str(tmp_path / "a" / "optimizer.safetensors")))


def test_resume_refuses_to_switch_the_average_on(tmp_path):
    train(micro_run(), dataset(), tmp_path / "a", steps=1)
    with pytest.raises(ConfigError, match="train.ema"):
        train(ema_run(), dataset(), tmp_path / "a", steps=2, resume=True)


@pytest.mark.parametrize("bad", [1.0, -0.1, 1.5])
def test_config_refuses_a_decay_outside_0_1(bad):
    with pytest.raises(ConfigError, match="ema"):
        TrainConfig(ema=bad)


def test_checkpoints_written_before_it_load_without_an_average():
    d = micro_run().to_dict()
    del d["train"]["ema"]
    assert from_dict(d).train.ema == 0.0


def test_mer_train_ema_option(tmp_path):
    out = tmp_path / "c"
    r = subprocess.run([sys.executable, "-m", "mer_models", "train", "--config", "tiny", "--synthetic", "2", "--out", str(out),
                        "--steps", "1", "--ema", "0.99", "--batch-size", "2"], capture_output=True, text=True, cwd=REPO)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert load_checkpoint(out).run.train.ema == 0.99
    assert any(k.startswith(TRAINED_PREFIX) for k in load_file(str(out / "optimizer.safetensors")))
    r = subprocess.run([sys.executable, "-m", "mer_models", "train", "--config", "tiny", "--synthetic", "2", "--out", str(tmp_path / "x"),
                        "--steps", "1", "--ema", "1"], capture_output=True, text=True, cwd=REPO)  # fmt: skip
    assert r.returncode != 0 and "ema" in r.stderr


def test_learning_curve_scores_the_average_and_the_trained_weights(tmp_path):
    """``tools/learning_curve.py``'s ``held_out`` scores the checkpoint's average, or with
    ``trained`` the trained weights beside it: the same as a checkpoint holding those weights."""
    sys.path.insert(0, str(REPO / "tools"))
    from learning_curve import held_out
    from model_helpers import synthetic_csv

    from mer_models.hub.checkpoint_files import OPTIMIZER, WEIGHTS

    out = tmp_path / "c"
    train(ema_run(0.9), dataset(), out, steps=3)
    data = tmp_path / "lafan1"
    (data / "g1").mkdir(parents=True)
    synthetic_csv(data / "g1" / "walk1_subject1.csv", "g1", frames=120, seed=3)
    avg = held_out(out, str(data), "g1", ["h1"], 2, None)
    own = held_out(out, str(data), "g1", ["h1"], 2, None, trained=True)
    plain = tmp_path / "plain"  # the same checkpoint with the trained weights as its weights file
    plain.mkdir()
    for f in out.iterdir():
        (plain / f.name).write_bytes(f.read_bytes())
    from safetensors.torch import save_file

    opt = load_file(str(out / OPTIMIZER))
    save_file({k[len(TRAINED_PREFIX):]: v for k, v in opt.items() if k.startswith(TRAINED_PREFIX)}, str(plain / WEIGHTS))
    assert own == held_out(plain, str(data), "g1", ["h1"], 2, None)
    assert avg != own
