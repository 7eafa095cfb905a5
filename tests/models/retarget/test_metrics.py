"""Metric definitions: zero for the reference itself, exact values on constructed errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from model_helpers import mixed_batch

from mer_models.retarget.metrics import summarize, window_metrics
from mer_models.solver.energy import split_motion


def _motion(b):
    q, bp, br = split_motion(b["target"].double())
    return {"q": q, "base_pos": bp, "base_rot": br}


def test_the_reference_itself_scores_zero():
    b = mixed_batch(("g1",))
    m = window_metrics(_motion(b), b)
    for k in ("g_mpbpe", "mpbve", "mpboe", "gt_mpbpe", "gt_mpbve", "gt_mpboe", "limit_violation"):
        assert m[k][0] < 1e-5, k
    assert m["jerk"][0] > 0


def test_a_shifted_base_gives_the_shift():
    b = mixed_batch(("g1",))
    mo = _motion(b)
    mo["base_pos"] = mo["base_pos"] + torch.tensor([0.0, 0.0, 0.05], dtype=torch.float64)
    m = window_metrics(mo, b)
    assert m["g_mpbpe"][0] == pytest.approx(0.05, abs=1e-6)
    assert m["mpbve"][0] < 1e-5 and m["mpboe"][0] < 1e-5
    assert m["gt_mpbpe"][0] == pytest.approx(0.05, abs=1e-6)


def test_jerk_of_a_cubic_is_six_times_its_coefficient():
    b = mixed_batch(("g1",))
    mo = _motion(b)
    t = torch.arange(60, dtype=torch.float64) / 30.0
    a = 0.01  # rad/s^3
    dof = b["tgt_mimic_source"][0] == torch.arange(b["tgt_mask"].shape[1])
    dof &= b["tgt_revolute"][0]
    mo["q"] = torch.zeros_like(mo["q"])
    mo["q"][0, :, dof] = (a * t**3)[:, None]
    m = window_metrics(mo, b)
    assert m["jerk"][0] == pytest.approx(6 * a, rel=1e-5)
    assert m["jerk_frame"][0] == pytest.approx(6 * a / 30**3, rel=1e-5)


def test_limit_violations_count_frames():
    b = mixed_batch(("h1",))
    mo = _motion(mixed_batch(("h1",)))
    mo["q"] = torch.zeros(1, 60, b["tgt_mask"].shape[1], dtype=torch.float64)
    j = int(torch.nonzero(b["tgt_revolute"][0])[0])
    mo["q"][0, :15, j] = float(b["tgt_upper"][0, j]) + 0.01
    m = window_metrics(mo, b)
    assert m["limit_violation"][0] == pytest.approx(0.25)
    assert np.isnan(m["gt_mpbpe"][0])  # no H1 data in this batch


def test_frames_held_at_a_limit_are_counted_per_joint():
    b = mixed_batch(("h1",))
    mo = _motion(b)
    mo["q"] = torch.zeros(1, 60, b["tgt_mask"].shape[1], dtype=torch.float64)
    j, k = (int(i) for i in torch.nonzero(b["tgt_revolute"][0] & (b["tgt_lower"][0] < -0.01))[:2])
    mo["q"][0, :30, j] = float(b["tgt_upper"][0, j]) - 1e-3  # half the frames at the upper limit
    mo["q"][0, :, k] = float(b["tgt_lower"][0, k]) + 0.01  # near, not at, the lower limit
    m = window_metrics(mo, b, joints={"a": j, "b": k, "base": 0})
    assert m["at_limit/a"][0] == pytest.approx(0.5)
    assert m["at_limit/b"][0] == 0.0
    assert np.isnan(m["at_limit/base"][0])  # not a joint
    assert m["limit_violation"][0] == 0.0


def test_summary_ignores_missing_values():
    s = summarize({"a": np.array([1.0, 3.0, np.nan])})
    assert s["a"] == {"mean": 2.0, "std": 1.0, "n": 2}
