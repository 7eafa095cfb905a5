"""``mer train --synthetic``'s windows come from the whole-body generator (issue 42), not the sinusoid."""

from __future__ import annotations

import numpy as np

from mer_data.robots.registry import get_skeleton
from mer_data.synthesis.quat import qmatrix
from mer_models.training.synthetic import SyntheticDataset, sinusoid_motion, synthetic_motion


def test_training_windows_reach_the_floor_and_are_seeded():
    skel = get_skeleton("g1")
    wins = [synthetic_motion(skel, 60, seed=s) for s in range(40)]
    tilt = np.concatenate([np.arccos(np.clip(qmatrix(w["base_quat"])[:, 2, 2], -1, 1)) for w in wins])
    z = np.concatenate([w["base_pos"][:, 2] for w in wins])
    assert tilt.max() > 1.4 and z.min() < 0.15, (tilt.max(), z.min())  # lying on the floor, in 40 windows of 2 s
    assert all(w["q"].shape == (60, skel.num_nodes) and w["base_pos"].shape == (60, 3) for w in wins)
    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    assert all(np.all((w["q"][:, skel.dof_mask] >= lo) & (w["q"][:, skel.dof_mask] <= hi)) for w in wins)
    again = synthetic_motion(skel, 60, seed=7)
    assert all(again[k].tobytes() == wins[7][k].tobytes() for k in again)  # same seed, same bytes
    assert synthetic_motion(skel, 1, seed=3)["q"].shape == (1, skel.num_nodes)
    gentle = sinusoid_motion(skel, 60, seed=0)  # kept for tests that need an easy motion
    assert np.arccos(np.clip(qmatrix(gentle["base_quat"])[:, 2, 2], -1, 1)).max() < 0.1
    ds = SyntheticDataset("g1", ("g1", "h1"), size=4, frames=60, seed=3)
    a, b = ds[1], SyntheticDataset("g1", ("g1", "h1"), size=4, frames=60, seed=3)[1]
    assert a.reference.shape == (60, skel.num_nodes, 9) and np.array_equal(a.reference, b.reference)
