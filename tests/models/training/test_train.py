"""Training: losses, exact resume, refusals, the paper configuration, DDP under torchrun."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from model_helpers import MICRO, assert_resume_exact, dataset, micro_run, mixed_batch
from safetensors.torch import load_file

from mer_data.base.errors import CheckpointError, ConfigError
from mer_models.config import preset
from mer_models.diffusion.model import RetargetModel
from mer_models.training.train import clean_samples, native_bf16, train

REPO = Path(__file__).resolve().parents[3]


def test_training_logs_losses_and_writes_a_checkpoint(tmp_path):
    res = train(micro_run(), dataset(), tmp_path / "c", steps=2)
    assert res.step == 2
    lines = [json.loads(x) for x in (tmp_path / "c" / "train_log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines] == [1, 2]
    for k in ("loss", "edm", "f_kp", "f_cst", "f_vel", "f_norm", "f_total", "grad_norm", "lr"):
        assert all(torch.isfinite(torch.tensor(r[k])) for r in lines), k


def test_resume_is_exact(tmp_path):
    assert_resume_exact(micro_run(), tmp_path)
    assert json.loads((tmp_path / "b" / "trainer_state.json").read_text())["step"] == 4


def test_resume_is_exact_with_dropout(tmp_path):
    """Dropout draws from the global generator, whose state the checkpoint restores after the data
    loader's iterator has drawn its seed (restored before it, the masks after a resume shifted)."""
    run = micro_run()
    assert_resume_exact(run.replace(model=dataclasses.replace(run.model, dropout=0.2)), tmp_path)


def test_resume_refuses_another_configuration(tmp_path):
    run = micro_run()
    train(run, dataset(), tmp_path / "a", steps=1)
    other = run.replace(train=dataclasses.replace(run.train, lr=0.5))
    with pytest.raises(ConfigError, match="train.lr"):
        train(other, dataset(), tmp_path / "a", steps=2, resume=True)


def test_existing_checkpoint_needs_resume(tmp_path):
    train(micro_run(), dataset(), tmp_path / "a", steps=1)
    with pytest.raises(CheckpointError, match="--resume"):
        train(micro_run(), dataset(), tmp_path / "a", steps=2)
    with pytest.raises(CheckpointError, match="nothing to resume"):
        train(micro_run(), dataset(), tmp_path / "new", steps=2, resume=True)


def test_clean_sample_without_a_teacher_is_the_optimisers_solution():
    """No teacher file: every sample is solved on the fly, its own data window included (one
    teacher for every target; the data window is not what the energy tracks)."""
    run = micro_run()
    m = RetargetModel(MICRO)
    b = mixed_batch(("g1", "h1"))
    assert b["has_target"][0] and not b["has_teacher"].any()
    cond = m.conditions(b)
    x = clean_samples(m, b, cond, run)
    assert not torch.allclose(x[0], m.target_sample(b["target"], cond)[0], atol=1e-3)  # not G1's own window
    e = m.energy(x, cond, run.energy)
    assert float(e["cst"].max()) < 1e-6  # FK-consistent features of the IK solutions
    assert float(e["kp"].max()) < 0.02


@pytest.mark.slow
def test_paper_configuration_trains_on_cpu(tmp_path):
    run = preset("paper")
    run = run.replace(train=dataclasses.replace(run.train, batch_size=2, opt_iters=2))
    res = train(run, dataset(("h1",), size=4), tmp_path / "p", steps=1)
    assert res.step == 1 and (tmp_path / "p" / "model.safetensors").stat().st_size > 20e6


@pytest.mark.slow
def test_ddp_under_torchrun_with_gloo(tmp_path):
    out = tmp_path / "ddp"
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "MER_DDP_BACKEND": "gloo"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "mer_models", "train", "--config", "tiny", "--synthetic", "8", "--steps", "2", "--batch-size", "2",
           "--out", str(out)]  # fmt: skip
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    state = json.loads((out / "trainer_state.json").read_text())
    assert state["world_size"] == 2 and state["step"] == 2
    rng = load_file(str(out / "optimizer.safetensors"))
    assert {"rng.noise.0", "rng.noise.1", "rng.torch.0", "rng.torch.1"} <= set(rng)


def test_resume_accepts_another_sampler(tmp_path):
    """Sampling settings are inference choices: a run continues after they change."""
    run = micro_run()
    train(run, dataset(), tmp_path / "a", steps=1)
    other = run.replace(sampler=dataclasses.replace(run.sampler, steps=3, method="euler"))
    res = train(other, dataset(), tmp_path / "a", steps=2, resume=True)
    assert res.step == 2
    assert json.loads((tmp_path / "a" / "config.json").read_text())["run"]["sampler"]["method"] == "euler"


def test_learning_rate_warms_up_then_decays_by_cosine():
    from mer_models.training.train import _lr

    run = micro_run()
    run = run.replace(train=dataclasses.replace(run.train, lr=1.0, warmup=10, lr_decay_steps=100, lr_min_ratio=0.1))
    assert _lr(run, 0) == pytest.approx(0.1) and _lr(run, 9) == pytest.approx(1.0)
    assert _lr(run, 10) == pytest.approx(1.0) and _lr(run, 60) == pytest.approx(0.55) and _lr(run, 110) == pytest.approx(0.1)
    assert _lr(run, 10_000) == pytest.approx(0.1)
    const = run.replace(train=dataclasses.replace(run.train, lr_decay_steps=0))
    assert _lr(const, 500) == 1.0


def test_bf16_warns_where_the_cpu_would_emulate_it(tmp_path, monkeypatch, caplog):
    """On a CPU without AMX/AVX512-BF16, bf16 autocast is emulated and slower than float32: the
    run still trains (the user asked for it) but the log says so; with native bf16 it does not."""
    import mer_models.training.train as train_module

    for native, folder in ((False, "emulated"), (True, "native")):
        monkeypatch.setattr(train_module, "native_bf16", lambda device="cpu", native=native: native)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="mer_models.training.train"):
            res = train(micro_run(), dataset(), tmp_path / folder, steps=1, bf16=True)
        assert res.step == 1
        assert ("without native bfloat16" in caplog.text) is not native, caplog.text


def test_native_bf16_follows_the_cpus_own_check(monkeypatch):
    assert native_bf16("meta") is True  # accelerators run bf16 natively
    assert native_bf16("cpu") is bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():  # a PyTorch without oneDNN's check: the CPU flags (Linux) decide
        monkeypatch.setattr(torch.ops, "mkldnn", object())
        flags = cpuinfo.read_text()
        assert native_bf16("cpu") is ("amx_bf16" in flags or "avx512_bf16" in flags)
