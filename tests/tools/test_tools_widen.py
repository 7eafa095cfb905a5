"""``tools/overfit_probe.py --ffn``: a checkpoint widened function-preservingly."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import pytest
import torch
from model_helpers import MICRO, mixed_batch

from mer_models.config import SamplerConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.retarget.inference import sample_conditions

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
from overfit_probe import ffn_width, widen_ffn  # noqa: E402


def test_a_wider_feed_forward_computes_the_same_function_and_can_learn():
    torch.manual_seed(0)
    narrow = RetargetModel(MICRO).eval()
    with torch.no_grad():  # a trained-looking network: the fresh one's zero output heads pass no gradient back
        for p in narrow.parameters():
            p.add_(0.05 * torch.randn_like(p))
    wide = RetargetModel(dataclasses.replace(MICRO, ffn=3 * MICRO.ffn)).eval()
    wide.load_state_dict(widen_ffn(narrow.state_dict(), 3 * MICRO.ffn))  # strict: every tensor has its new shape
    batch = mixed_batch(("h1", "atlas"))
    sampler = SamplerConfig(steps=1, method="euler", init_noise=0.0)
    with torch.no_grad():
        a = sample_conditions(narrow, narrow.conditions(batch), sampler)
        b = sample_conditions(wide, wide.conditions(batch), sampler)
    torch.testing.assert_close(b, a, atol=1e-5, rtol=0)
    # the new units are silent but not dead: their outgoing weights get gradients
    cond = wide.conditions(batch)
    wide.denoise(torch.zeros_like(a), 1.0, cond).square().sum().backward()
    w2 = next(p for n, p in wide.named_parameters() if n.endswith(".ffn.3.weight"))
    assert w2.grad[:, MICRO.ffn :].abs().sum() > 0
    with pytest.raises(SystemExit, match="narrower"):
        widen_ffn(narrow.state_dict(), MICRO.ffn - 1)


def test_a_learning_curve_starts_a_wider_run_from_the_widened_checkpoint(tmp_path):
    from learning_curve import widened_init
    from safetensors.torch import load_file, save_file

    init = tmp_path / "init" / "model.safetensors"
    init.parent.mkdir()
    save_file(RetargetModel(MICRO).state_dict(), str(init))
    dest = tmp_path / "run.widened.safetensors"
    assert widened_init(init, MICRO.ffn, dest) == init and not dest.exists()  # already that wide: read as it is
    assert widened_init(init, 2 * MICRO.ffn, dest) == dest
    wide = RetargetModel(dataclasses.replace(MICRO, ffn=2 * MICRO.ffn))
    wide.load_state_dict(load_file(str(dest)))  # strict: the shapes of the wider network
    assert sorted(p.name for p in tmp_path.iterdir()) == ["init", "run.widened.safetensors"]  # no temporary file left
    assert (ffn_width(init), ffn_width(dest)) == (MICRO.ffn, 2 * MICRO.ffn)  # what --init without --ffn trains at
