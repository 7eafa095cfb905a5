"""Shared helpers of the model tests: synthetic batches, a tiny configuration, a tiny checkpoint."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.motion.samples import TrainingSample, collate
from mer_data.robots.registry import get_skeleton
from mer_models.config import ModelConfig, RunConfig, preset
from mer_models.export.writers import TargetMotion, write_csv
from mer_models.training.synthetic import SyntheticDataset, _features, _origin_normalize, synthetic_motion

#: a very small network for unit tests (same architecture, seconds on CPU)
MICRO = ModelConfig(hidden=24, layers=1, heads=2, cross_heads_per_condition=1, ffn=32, dropout=0.0, frames=60)


def micro_run(batch_size: int = 4) -> RunConfig:
    run = preset("tiny")
    return run.replace(
        name="micro",
        model=MICRO,
        train=dataclasses.replace(run.train, batch_size=batch_size, warmup=2, save_every=1000, log_every=1, opt_iters=3),
    )


def synthetic_csv(path, robot: str = "g1", frames: int = 90, seed: int = 0):
    """Write a synthetic motion of ``robot`` as a LAFAN1-layout CSV at 30 Hz; returns the path."""
    s = get_skeleton(robot)
    m = synthetic_motion(s, frames, seed=seed)
    rot = quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy()
    return write_csv(path, TargetMotion(s, 30.0, m["q"], m["base_pos"], rot))


def synthetic_folder(root: Path, clips: dict[str, int], robot: str = "g1") -> Path:
    """A LAFAN1-layout folder ``root/<robot>/<clip>.csv`` of seeded synthetic clips (clip -> frames)."""
    for k, (clip, n) in enumerate(clips.items()):
        synthetic_csv(root / robot / f"{clip}.csv", robot, frames=n, seed=k)
    return root


def synthetic_window(source: str = "g1", frames: int = 60, seed: int = 0, motion=synthetic_motion) -> np.ndarray:
    """(T, J, 9) float32 origin-normalized features of a synthetic motion of ``source`` (``motion``:
    the whole-body generator's windows, or ``sinusoid_motion`` where a test needs a gentle motion)."""
    s = get_skeleton(source)
    return _origin_normalize(_features(s, motion(s, frames, seed=seed), 30.0)).astype(np.float32)


def mixed_batch(
    targets=("g1", "h1", "tron1"), source="g1", frames=60, seed=0, augment_first=False, motion=synthetic_motion
) -> dict:
    """A collated batch: one synthetic window of ``source`` retargeted to each target."""
    ref = get_skeleton(source)
    samples = []
    for k, t in enumerate(targets):
        tgt = get_skeleton(t)
        if augment_first and k == 0:
            tgt = tgt.with_link_scales(np.linspace(0.7, 1.4, tgt.num_nodes))
        w = synthetic_window(source, frames, seed + k, motion)
        same = t == source and not (augment_first and k == 0)
        samples.append(TrainingSample(w, ref, tgt, joint_map(tgt, ref), w.copy() if same else None))
    return collate(samples)


def dataset(targets=("g1", "h1", "tron1"), size=16, seed=0) -> SyntheticDataset:
    return SyntheticDataset("g1", targets, size=size, augment=True, seed=seed)


@pytest.fixture(scope="session")
def micro_checkpoint(tmp_path_factory):
    """A micro model trained 3 steps on synthetic G1 → {g1, h1, tron1} windows."""
    from mer_models.training.train import train

    out = tmp_path_factory.mktemp("ckpt") / "micro"
    torch.manual_seed(0)
    train(micro_run(), dataset(), out, steps=3)
    return out


def assert_resume_exact(run: RunConfig, tmp_path, steps: int = 4) -> None:
    """``steps`` steps in one run and in two halves, the second resumed, write the same weights and
    the same optimiser file (moments, RNG states and, with a moving average, the trained weights)
    bit for bit; the runs go to ``tmp_path / "a"`` and ``tmp_path / "b"``."""
    from safetensors.torch import load_file

    from mer_models.training.train import train

    train(run, dataset(), tmp_path / "a", steps=steps)
    train(run, dataset(), tmp_path / "b", steps=steps // 2)
    train(run, dataset(), tmp_path / "b", steps=steps, resume=True)
    for name in ("model.safetensors", "optimizer.safetensors"):
        a, b = load_file(str(tmp_path / "a" / name)), load_file(str(tmp_path / "b" / name))
        assert a.keys() == b.keys(), name
        assert all(torch.equal(a[k], b[k]) for k in a), name
