"""``--refine K``: the model's output as the optimiser's warm start (mer evaluate and mer retarget)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mer_data.errors import MerError

from mer_models.cli import main

from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)


def test_evaluate_refine_sits_between_the_model_and_the_optimiser(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    data = tmp_path / "data"
    for k in range(2):
        synthetic_csv(data / "g1" / f"clip{k}.csv", "g1", frames=120, seed=k)
    code = main(["evaluate", "--model", str(micro_checkpoint), "--input", str(data), "--source", "g1", "--targets", "h1",
                 "--split", "all", "--max-windows", "2", "--steps", "2", "--methods", "model", "refine", "optimize",
                 "--refine", "8", "--save", str(tmp_path / "r.json")])  # fmt: skip
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "fr/s" in out.out and "refine" in out.out
    rows = {r["method"]: r for r in json.loads((tmp_path / "r.json").read_text())["rows"]}
    g = {m: rows[m]["metrics"]["g_mpbpe"]["mean"] for m in rows}
    # a 3-step micro model is metres off; 8 iterations from its output bring it within decimetres
    assert g["model"] > 1.0 and g["refine"] < 0.05 * g["model"] and g["optimize"] < g["refine"]
    assert all(rows[m]["frames_per_s"] > 0 for m in rows) and rows["refine"]["metrics"]["limit_violation"]["mean"] == 0


def test_retarget_refine_writes_the_refined_motion(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    src = synthetic_csv(tmp_path / "walk.csv", frames=60)
    base = ["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(micro_checkpoint), "--steps", "2"]
    assert main(base + ["-o", str(tmp_path / "a.csv")]) == 0
    assert main(base + ["-o", str(tmp_path / "b.csv"), "--refine", "5"]) == 0
    err = capsys.readouterr().err
    assert "diffusion+refine5" in err
    a, b = np.loadtxt(tmp_path / "a.csv", delimiter=","), np.loadtxt(tmp_path / "b.csv", delimiter=",")
    assert a.shape == b.shape and not np.allclose(a, b)
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize", "--refine", "3", "-o", str(tmp_path / "c.csv")]) == 1
    assert "--refine refines a model's output" in capsys.readouterr().err


def _warm_start_case():
    """Two synthetic G1 windows retargeted to G1 (reachable goals), and a smooth warm start off the
    optimiser's solution (angles 0.2 rad and the base 4 cm away, slowly varying; 8 cm g-mpbpe): what
    a model's output looks like to the refinement."""
    import torch

    from mer_data.rotations import axis_angle_to_matrix
    from mer_models.config import EnergyConfig
    from mer_models.kinematics import graph_from_batch
    from mer_models.optimize import optimize_motion

    from model_helpers import mixed_batch

    b = mixed_batch(("g1", "g1"), seed=3)
    g = graph_from_batch(b, "tgt")
    args = (EnergyConfig(), g, b["joint_map"], b["ref_scaled_pos"], axis_angle_to_matrix(b["reference"][:, :, 0, 0:3]))
    kw = {"goal_rot": b["ref_goal_rot"], "rot_mask": b["ref_rot_mask"]}
    best = optimize_motion(*args, **kw)
    T, J = best["q"].shape[1:]
    t = torch.linspace(0, 1, T)[None, :, None]
    phase = torch.arange(J)[None, None, :] * 0.7
    q = (best["q"] + 0.2 * torch.sin(2 * torch.pi * t + phase)) * g.revolute[:, None]
    q = torch.minimum(torch.maximum(q, g.lower[:, None]), g.upper[:, None])
    warm = {"q": q, "base_pos": best["base_pos"] + 0.04 * torch.cos(2 * torch.pi * t), "base_rot": best["base_rot"]}
    return b, args, kw, best, warm


def test_a_warm_start_runs_its_first_iterations_without_the_temporal_prior():
    """``free_iterations``: of K warm-started iterations, up to 2 (at most half) run frame by frame;
    the refinement then lands closer to the goals than K iterations all with the prior, and the prior's
    last iterations keep the jitter near the optimiser's. (Where the goals are out of reach it can
    do worse: synthetic G1 windows to H1 and Atlas, docs/model.md; on LAFAN1 it did better.)"""
    from mer_models.ik import gauss_newton_ik
    from mer_models.metrics import window_metrics
    from mer_models.optimize import free_iterations, optimize_motion

    assert [free_iterations(k) for k in range(7)] == [0, 0, 1, 1, 2, 2, 2]
    b, args, kw, best, warm = _warm_start_case()
    two_phase = optimize_motion(*args, **kw, gn_iters=5, init=warm)
    prior_only = optimize_motion(*args, **kw, gn_iters=5, init=warm, free_iters=0)
    # free_iters=0 is the plain warm-started solve (what --refine did before)
    cfg, g, eta, goal, _ = args
    q, bp, br = gauss_newton_ik(cfg, g, eta, goal, warm["q"], warm["base_pos"].clone(), warm["base_rot"].clone(), iters=5, **kw)
    np.testing.assert_allclose(prior_only["q"].numpy(), (q * g.revolute[:, None]).numpy(), atol=1e-6)
    m2, m0, mb = (window_metrics(o, b) for o in (two_phase, prior_only, best))
    assert (m2["g_mpbpe"] < 0.9 * m0["g_mpbpe"]).all(), (m2["g_mpbpe"], m0["g_mpbpe"])
    assert (m2["jerk_frame"] < 1.5 * mb["jerk_frame"] + 1e-3).all(), (m2["jerk_frame"], mb["jerk_frame"])
    assert (m2["limit_violation"] == 0).all()
    for bad in (-1, 6):  # the library refuses what it cannot run, as the command line does
        with pytest.raises(MerError, match=f"free_iters must be between 0 and gn_iters \\(5\\), got {bad}"):
            optimize_motion(*args, **kw, gn_iters=5, init=warm, free_iters=bad)


def test_refine_free_is_checked_and_recorded(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    data = tmp_path / "data"
    synthetic_csv(data / "g1" / "clip0.csv", "g1", frames=120, seed=0)
    base = ["evaluate", "--model", str(micro_checkpoint), "--input", str(data), "--source", "g1", "--targets", "h1",
            "--split", "all", "--max-windows", "1", "--steps", "1", "--methods", "refine", "--refine", "4"]  # fmt: skip
    assert main(base + ["--refine-free", "5"]) == 1
    assert "--refine-free must be between 0 and --refine (4)" in capsys.readouterr().err
    g = {}
    for free in ("0", "2"):
        assert main(base + ["--refine-free", free, "--save", str(tmp_path / f"{free}.json")]) == 0
        rep = json.loads((tmp_path / f"{free}.json").read_text())
        assert rep["options"]["refine_free"] == int(free)
        g[free] = rep["rows"][0]["metrics"]["g_mpbpe"]["mean"]
    assert g["0"] != g["2"]  # the option reaches the refinement
    src = synthetic_csv(tmp_path / "walk.csv", frames=60)
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(micro_checkpoint), "--refine", "2",
                 "--refine-free", "3", "-o", str(tmp_path / "x.csv")]) == 1  # fmt: skip
    assert "--refine-free must be between 0 and --refine (2)" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()
