"""tools/mink_peer.py: the mink/MuJoCo benchmark peer poses mer's key-point IK problem faithfully.

Skipped where the benchmark-only packages mink and mujoco are absent (they are not mer deps).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("mink")

import torch  # noqa: E402

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import mink_peer  # noqa: E402

FK_ROBOTS = ("g1", "h1", "atlas", "talos", "valkyrie")  # talos: locked grippers + their mimics


@pytest.fixture(scope="module")
def peers():
    cache: dict[str, mink_peer.MinkRobot] = {}

    def get(name: str) -> mink_peer.MinkRobot:
        if name not in cache:
            cache[name] = mink_peer.build_mink_robot(name)
        return cache[name]

    return get


def _random_state(skel, rng, n):
    """(n, J) node angles within the limits (0 off the dofs), (n, 3) base positions, (n, 4) wxyz."""
    q = rng.uniform(skel.lower, skel.upper, size=(n, skel.num_nodes))
    q[:, ~skel.dof_mask] = 0.0
    bp = rng.normal(size=(n, 3))
    bq = rng.normal(size=(n, 4))
    return q, bp, bq / np.linalg.norm(bq, axis=1, keepdims=True)


def _mer_keypoints(mr, q_nodes, bp, bq, keypoints):
    st = skeleton_tensors(mr.skeleton, dtype=torch.float64)
    pos, _ = fk_skeleton(st, torch.tensor(q_nodes), torch.tensor(bp), base_quat=torch.tensor(bq))
    idx = [0 if k == mink_peer.BASE else mr.skeleton.keypoints[k] for k in keypoints]
    return pos.numpy()[..., idx, :]


@pytest.mark.parametrize("robot", FK_ROBOTS)
def test_mujoco_sites_match_mer_fk(peers, robot):
    mr = peers(robot)
    skel = mr.skeleton
    assert mr.joint_names == skel.joint_names
    present = [k for k, v in skel.keypoints.items() if v >= 0]
    assert set(mr.keypoints) == {"base", *present}
    rng = np.random.default_rng(7)
    q, bp, bq = _random_state(skel, rng, 16)
    ref = _mer_keypoints(mr, q, bp, bq, mr.keypoints)
    got = mink_peer.keypoints_fk(mr, q[:, skel.dof_mask], bp, bq)
    np.testing.assert_allclose(got, ref, atol=1e-5, rtol=0)


@pytest.mark.parametrize("robot", ("g1", "h1", "atlas"))
def test_reachable_motion_is_tracked_within_limits(peers, robot):
    """A smooth ramp from the nominal pose to a random in-limit pose (targets from mer's FK)."""
    mr = peers(robot)
    skel = mr.skeleton
    rng = np.random.default_rng(3)
    q_end, bp, bq = _random_state(skel, rng, 1)
    s = np.linspace(0.0, 1.0, 20)[:, None]
    q = skel.nominal + s * (q_end - skel.nominal)
    q[:, ~skel.dof_mask] = 0.0
    T = len(q)
    bp, bq = np.repeat(bp, T, 0), np.repeat(bq, T, 0)
    keypoints = list(mr.keypoints)
    targets = _mer_keypoints(mr, q, bp, bq, keypoints)

    out = mink_peer.solve_keypoints(
        mr, targets, keypoints, base_pos0=bp[0], base_quat0_wxyz=bq[0], iters_per_frame=5, posture_cost=0.0
    )
    assert out["q"].shape == (T, mr.n_dof)
    assert out["base_pos"].shape == (T, 3) and out["base_quat_wxyz"].shape == (T, 4)
    assert out["keypoints_w"].shape == (T, len(keypoints), 3)
    assert out["seconds"] > 0
    err = np.linalg.norm(out["keypoints_w"] - targets, axis=-1)
    assert err.mean() < 5e-3, f"mean key-point error {err.mean() * 1e3:.2f} mm"

    lo, hi = skel.lower[skel.dof_mask], skel.upper[skel.dof_mask]
    assert np.all(out["q"] >= lo - 1e-6) and np.all(out["q"] <= hi + 1e-6)
    # the returned angles are in mer's joint order: mer's FK of them gives the achieved points
    q_nodes = np.zeros((T, skel.num_nodes))
    q_nodes[:, skel.dof_mask] = out["q"]
    again = _mer_keypoints(mr, q_nodes, out["base_pos"], out["base_quat_wxyz"], keypoints)
    np.testing.assert_allclose(again, out["keypoints_w"], atol=1e-5, rtol=0)


def test_subset_of_keypoints_and_bad_names(peers):
    mr = peers("h1")
    targets = mink_peer.keypoints_fk(mr, np.zeros(mr.n_dof), np.array([0, 0, 1.0]), np.array([1.0, 0, 0, 0]))
    sub = ["base", "left_hand", "right_toe"]
    idx = [mr.keypoints.index(k) for k in sub]
    out = mink_peer.solve_keypoints(
        mr, targets[None, idx], sub, base_pos0=np.array([0, 0, 1.0]), base_quat0_wxyz=np.array([1.0, 0, 0, 0]),
        iters_per_frame=2,
    )  # fmt: skip
    assert out["keypoints_w"].shape == (1, 3, 3)
    assert np.linalg.norm(out["keypoints_w"][0] - targets[idx], axis=-1).max() < 1e-6
    with pytest.raises(ValueError, match="no key point"):
        mink_peer.solve_keypoints(
            mr, np.zeros((1, 1, 3)), ["nose"], base_pos0=np.zeros(3), base_quat0_wxyz=np.array([1.0, 0, 0, 0])
        )
    with pytest.raises(ValueError, match="targets_w"):
        mink_peer.solve_keypoints(
            mr, np.zeros((1, 2, 3)), ["base"], base_pos0=np.zeros(3), base_quat0_wxyz=np.array([1.0, 0, 0, 0])
        )
