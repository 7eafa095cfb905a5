"""``--bf16`` at inference: the network under bfloat16 autocast, the rest of the path float32."""

from __future__ import annotations

import json

import numpy as np
import torch
from model_helpers import synthetic_csv

from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.registry import get_skeleton
from mer_models.cli import main
from mer_models.retarget.inference import sample_conditions
from mer_models.retarget.metrics import summarize, window_metrics
from mer_models.training.synthetic import SyntheticDataset
from mer_models.zoo.checkpoint import resolve_model


def _g_mpbpe(motion, batch, tgt) -> float:
    return float(summarize(window_metrics(motion, batch, keypoints={"base": 0, **tgt.keypoints}))["g_mpbpe"]["mean"])


def test_bf16_sampling_runs_the_network_in_bf16_and_keeps_the_accuracy():
    ckpt = resolve_model("mer-base")
    model, sampler = ckpt.model, ckpt.run.sampler
    src, tgt = get_skeleton("g1"), get_skeleton("h1")
    ds = SyntheticDataset("g1", ("g1",), size=2, seed=3)
    batch = collate([TrainingSample(ds[i].reference, src, tgt, joint_map(tgt, src)) for i in range(2)])
    out = {}
    for bf16 in (False, True):
        cond = model.conditions(batch)
        out[bf16] = (sample_conditions(model, cond, sampler, energy=ckpt.run.energy, bf16=bf16), cond)
    d32, d16 = out[False][0], out[True][0]
    assert d16.dtype == torch.float32 and d16.shape == d32.shape and torch.isfinite(d16).all()
    assert not torch.equal(d16, d32)  # the network really ran in bfloat16 (float32 would give the same bits)
    e32 = _g_mpbpe(model.decode(d32, out[False][1]), batch, tgt)
    e16 = _g_mpbpe(model.decode(d16, out[True][1]), batch, tgt)
    assert abs(e16 - e32) < 0.003, (e16, e32)  # measured on LAFAN1: equal to 0.1 mm


def test_retarget_and_evaluate_take_bf16(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=60)
    base = ["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "diffusion"]
    assert main(base + ["-o", str(tmp_path / "a.csv")]) == 0
    assert main(base + ["-o", str(tmp_path / "b.csv"), "--bf16"]) == 0
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == b.shape and not np.array_equal(a, b) and np.abs(a - b)[:, 7:].max() < 0.2  # angles [rad]
    capsys.readouterr()
    assert main([*base[:-2], "--method", "optimize", "--bf16", "-o", str(tmp_path / "c.csv")]) == 1
    assert "--bf16: --method optimize runs no model" in capsys.readouterr().err and not (tmp_path / "c.csv").exists()

    data = tmp_path / "data"
    synthetic_csv(data / "g1" / "clip0.csv", "g1", frames=120, seed=0)
    ev = ["evaluate", "--model", "mer-base", "--input", str(data), "--source", "g1", "--targets", "h1", "--split", "all",
          "--max-windows", "2"]  # fmt: skip
    reps = {}
    for flag in ([], ["--bf16"]):
        assert main(ev + ["--methods", "model", *flag, "--save", str(tmp_path / "r.json")]) == 0
        reps[bool(flag)] = json.loads((tmp_path / "r.json").read_text())
    assert reps[True]["options"]["bf16"] is True and reps[False]["options"]["bf16"] is False
    g = {k: r["rows"][0]["metrics"]["g_mpbpe"]["mean"] for k, r in reps.items()}
    assert g[True] != g[False] and abs(g[True] - g[False]) < 0.003, g  # bf16 ran, and kept the accuracy
    capsys.readouterr()
    assert main(ev + ["--methods", "optimize", "--bf16"]) == 1  # nothing for bf16 to run
    assert "--bf16 runs the model's network" in capsys.readouterr().err
