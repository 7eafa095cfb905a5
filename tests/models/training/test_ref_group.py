"""Batches grouped by reference window (``TrainConfig.ref_group``): the sampler, the shared
reference encoding, and training with them (resume, refusals)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
from model_helpers import MICRO, dataset, micro_run
from safetensors.torch import load_file
from shard_helpers import build, make_input
from torch.utils.data import Subset

from mer_data.base.errors import ConfigError
from mer_data.motion.samples import collate
from mer_data.shards import ShardDataset
from mer_models.config import TrainConfig
from mer_models.diffusion.model import RetargetModel, shared_rows
from mer_models.training.order import OrderSampler, reference_groups
from mer_models.training.train import train


@pytest.fixture(scope="module")
def shards(tmp_path_factory):
    """G1 and H1 windows, targets g1 and h1, URDF + 2 augmentations: 6 samples per window."""
    inp = make_input(tmp_path_factory.mktemp("in"), clips={"walk1_subject1": (4.0, 0.5, 0.0), "dance1_subject1": (3.0, 0.0, 0.1)})
    out = tmp_path_factory.mktemp("shards")
    build(inp, out, augment=3, seed=3, split="all")
    return out


def _window(ds: ShardDataset, i: int) -> int:
    return ds.locate(i)[0].id


def test_reference_groups_partition_the_samples_by_window(shards):
    ds = ShardDataset(shards)
    groups = ds.reference_groups()
    flat = np.concatenate(groups)
    assert sorted(flat.tolist()) == list(range(len(ds)))  # a partition
    assert len(groups) == len(ds.windows)
    for g in groups:
        assert len({_window(ds, int(i)) for i in g}) == 1
        refs = [ds[int(i)].reference for i in g[:3]]
        assert all(np.array_equal(refs[0], r) for r in refs[1:])  # one reference motion per group
    assert {_window(ds, int(g[0])) for g in groups} == {w.id for w in ds.windows}


def test_reference_groups_follow_a_target_filter_and_a_subset(shards):
    ds = ShardDataset(shards, targets=["h1"], augmented=False)
    groups = ds.reference_groups()
    assert all(len(g) == 1 for g in groups) and sorted(np.concatenate(groups).tolist()) == list(range(len(ds)))
    full = ShardDataset(shards)
    sub = Subset(full, list(range(0, len(full), 2)))
    sg = reference_groups(sub)
    assert sorted(np.concatenate(sg).tolist()) == list(range(len(sub)))
    for g in sg:  # positions in the subset, still one window each
        assert len({_window(full, sub.indices[int(i)]) for i in g}) == 1
    with pytest.raises(ConfigError, match="ref_group"):
        reference_groups(dataset())


def test_grouped_sampler_batches_are_whole_windows_and_an_epoch_repeats_no_sample():
    groups = [np.arange(6 * w, 6 * w + 6) for w in range(10)]  # 10 windows x 6 samples
    s = OrderSampler(60, 8, seed=3, start=0, rank=0, world=1, groups=groups, group=2)
    assert s.per_epoch == 30 * 2 // 8  # 30 chunks of 2, 4 chunks per batch
    seen = []
    for step in range(s.per_epoch):
        b = s.batch_at(step)
        assert len(b) == 8
        for c in range(0, 8, 2):
            assert b[c] // 6 == b[c + 1] // 6  # each chunk from one window
        seen += b
    assert len(seen) == len(set(seen))
    assert s.batch_at(5) == OrderSampler(60, 8, 3, 0, 0, 1, groups, 2).batch_at(5)  # a pure function of the step
    assert s.batch_at(s.per_epoch) != s.batch_at(0)  # the next epoch draws again
    # the processes of a global batch take whole chunks and together the whole batch
    parts = [OrderSampler(60, 8, 3, 0, r, 2, groups, 2).batch_at(4) for r in range(2)]
    assert sorted(parts[0] + parts[1]) == sorted(s.batch_at(4)) and all(len(p) == 4 for p in parts)
    assert all(p[0] // 6 == p[1] // 6 and p[2] // 6 == p[3] // 6 for p in parts)


def test_sampler_without_groups_keeps_its_data_order():
    """ref_group 1 draws the batches it drew before the option existed (resumed runs continue the same)."""
    s = OrderSampler(50, 8, seed=7, start=0, rank=1, world=2)
    for step in (0, 3, 6, 9):
        epoch, k = divmod(step, 50 // 8)
        order = np.random.default_rng([7, epoch]).permutation(50)
        assert s.batch_at(step) == [int(i) for i in order[k * 8 : (k + 1) * 8][1::2]]


def test_grouped_sampler_refusals():
    groups = [np.arange(3 * w, 3 * w + 3) for w in range(4)]
    with pytest.raises(ConfigError, match="processes"):
        OrderSampler(12, 4, 0, 0, 0, 4, groups, 2)  # 2 windows per batch over 4 processes
    with pytest.raises(ConfigError, match="3 samples at most"):
        OrderSampler(12, 8, 0, 0, 0, 1, groups, 4)
    with pytest.raises(ConfigError, match="ref_group"):
        TrainConfig(batch_size=6, ref_group=4)
    with pytest.raises(ConfigError, match="ref_group"):
        TrainConfig(ref_group=0)


def test_shared_rows_finds_equal_samples():
    x = torch.tensor([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [5.0, 6.0], [3.0, 4.0]])
    first, inverse = shared_rows(x, torch.tensor([0, 1, 0, 2, 1]))
    assert first.tolist() == [0, 1, 3] and inverse.tolist() == [0, 1, 0, 2, 1]
    first, inverse = shared_rows(x, torch.tensor([0, 1, 9, 2, 1]))  # any tensor that differs separates them
    assert first.tolist() == [0, 1, 2, 3] and torch.equal(x[first][inverse], x)
    collide = torch.tensor([[2, 0], [0, 1], [2, 0]])  # equal checksums (2*1 + 0*2 = 0*1 + 1*2), different rows
    assert shared_rows(collide)[1].tolist() == [0, 1, 0]
    nan = torch.tensor([[float("nan"), 1.0], [float("nan"), 1.0]])
    assert shared_rows(nan)[0].tolist() == [0, 1]  # NaN equals nothing: never shared
    big = torch.randn(40, 60, 30, 9)
    big[[7, 23, 39]] = big[3].clone()  # equal rows far apart in the batch (a float sum of each row may differ in the last bit)
    first, inverse = shared_rows(big, torch.zeros(40, 5, dtype=torch.bool))
    assert len(first) == 37 and inverse[[3, 7, 23, 39]].unique().numel() == 1 and torch.equal(big[first][inverse], big)


def test_shared_reference_encoding_equals_encoding_every_sample(shards):
    """One window to several targets: the denoiser's output and every gradient are those of
    encoding each sample's reference on its own."""
    ds = ShardDataset(shards)
    g = ds.reference_groups()
    idx = [int(i) for i in g[0][:3]] + [int(i) for i in g[1][:2]] + [int(g[2][0])]
    batch = collate([ds[i] for i in idx])
    torch.manual_seed(0)
    m = RetargetModel(MICRO)
    for head in (m.net.base_head, m.net.joint_head):  # the heads start at zero: make the output depend on the network
        torch.nn.init.normal_(head.weight, std=0.1)
    calls = []
    m.net.encoder.register_forward_hook(lambda mod, inp, out: calls.append(out.shape[0]))
    outs, grads = [], []
    for share in (True, False):
        m.zero_grad()
        cond = m.conditions(batch)
        if not share:
            cond.ref_tokens = m.net.encode_reference(cond.reference, cond.ref_graph)
        x = torch.randn(cond.shape, generator=torch.Generator().manual_seed(1)) * 2.0
        d = m.denoise(x, torch.full((len(idx),), 3.0), cond)
        (d**2).sum().backward()
        outs.append(d.detach())
        grads.append({k: p.grad.clone() for k, p in m.named_parameters() if p.grad is not None})
    assert calls == [3, 6]  # three distinct windows encoded once each, then all six samples
    torch.testing.assert_close(outs[0], outs[1], rtol=1e-5, atol=1e-5)
    assert grads[0].keys() == grads[1].keys() and any(k.startswith("net.encoder.") for k in grads[0])
    for k in grads[0]:
        torch.testing.assert_close(grads[0][k], grads[1][k], rtol=1e-4, atol=1e-5, msg=k)


def test_the_same_reference_is_shared_and_a_different_skeleton_is_not(shards):
    ds = ShardDataset(shards)
    i = int(ds.reference_groups()[0][0])
    m = RetargetModel(MICRO)
    calls = []
    m.net.encoder.register_forward_hook(lambda mod, inp, out: calls.append(out.shape[0]))
    batch = collate([ds[i], ds[i], ds[i]])
    cond = m.conditions(batch)
    m.encode(cond)
    assert cond.ref_shared[0].tolist() == [0] and calls == [1]
    assert torch.equal(cond.reference[0], cond.reference[2])  # one canonical reference per group, bitwise
    batch["ref_offsets"][1, 3, 0] += 0.01  # a longer link on the second sample's reference skeleton
    cond = m.conditions(batch)
    m.encode(cond)
    assert cond.ref_shared[0].tolist() == [0, 1] and cond.ref_shared[1].tolist() == [0, 1, 0] and calls == [1, 2]


def test_grouped_training_resumes_exactly(shards, tmp_path):
    run = micro_run(batch_size=4)
    run = run.replace(train=dataclasses.replace(run.train, ref_group=2))
    ds = ShardDataset(shards)
    train(run, ds, tmp_path / "a", steps=2)
    train(run, ds, tmp_path / "b", steps=1)
    train(run, ds, tmp_path / "b", steps=2, resume=True)
    a, b = load_file(str(tmp_path / "a" / "model.safetensors")), load_file(str(tmp_path / "b" / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    saved = json.loads((tmp_path / "a" / "config.json").read_text())["run"]["train"]
    assert saved["ref_group"] == 2
    with pytest.raises(ConfigError, match="ref_group"):  # another grouping is another data order
        other = run.replace(train=dataclasses.replace(run.train, ref_group=1))
        train(other, ds, tmp_path / "a", steps=3, resume=True)
    with pytest.raises(ConfigError, match="ref_group"):
        train(run, dataset(), tmp_path / "c", steps=1)  # a dataset that does not know its windows
