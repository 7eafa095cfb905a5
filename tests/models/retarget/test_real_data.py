"""The real LAFAN1 robot data (../shared; skipped where absent): retargeting G1 → H1 lands near
H1's own retargeted motion of the same clip, within H1's limits."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.motion.lafan1 import read_lafan1_csv
from mer_data.robots.registry import get_skeleton
from mer_models.cli import main
from mer_models.retarget.clip import retarget_file


@pytest.fixture
def g1_clip(lafan1_dir, tmp_path):
    lines = (lafan1_dir / "g1" / "walk1_subject1.csv").read_text().splitlines()[300:420]
    p = tmp_path / "walk.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_optimisation_baseline_matches_h1s_own_data(g1_clip, lafan1_dir, tmp_path):
    res = retarget_file(g1_clip, "g1", "h1", out_csv=tmp_path / "h1.csv", method="optimize", opt_iters=30, opt_gn_iters=10)
    h1 = get_skeleton("h1")
    truth = read_lafan1_csv(lafan1_dir / "h1" / "walk1_subject1.csv", "h1")
    st = skeleton_tensors(h1, torch.float64)
    sl = slice(300, 420)
    pos_t, _ = fk_skeleton(st, torch.from_numpy(truth.node_angles(h1)[sl]), torch.from_numpy(truth.base_pos[sl]),
                           base_quat=torch.from_numpy(truth.base_quat[sl]))  # fmt: skip
    pos, _ = res.motion.forward_kinematics()
    kp = [j for j in h1.keypoint_nodes().values()]
    # H1's own data is retargeted by another pipeline (and its root path is scaled differently):
    # compare root-relative key points
    rel = lambda p: p[:, kp] - p[:, :1]  # noqa: E731
    err = np.linalg.norm(rel(pos) - rel(pos_t.numpy()), axis=-1).mean()
    assert err < 0.12, err
    q = np.loadtxt(tmp_path / "h1.csv", delimiter=",")[:, 7:]
    back = read_lafan1_csv(tmp_path / "h1.csv", "h1")
    lim = back.node_angles(h1)
    assert ((lim >= h1.lower - 1e-6) & (lim <= h1.upper + 1e-6)).all() and q.shape == (120, 19)


def test_evaluate_baseline_on_real_windows(lafan1_dir, capsys):
    code = main(["evaluate", "--input", str(lafan1_dir), "--source", "g1", "--targets", "h1", "--methods", "optimize",
                 "--max-windows", "1", "--opt-iters", "20", "--opt-gn-iters", "10", "--json"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    rows = json.loads(out)["rows"]
    assert {r["domain"] for r in rows} == {"in-domain", "out-of-domain"}
    for r in rows:
        assert r["metrics"]["g_mpbpe"]["mean"] < 0.1
        assert r["metrics"]["gt_mpbpe"]["n"] == 1  # H1's own window is the ground truth
        assert r["metrics"]["limit_violation"]["mean"] == 0
