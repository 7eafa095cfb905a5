"""``--refine K``: the model's output as the optimiser's warm start (mer evaluate and mer retarget)."""

from __future__ import annotations

import json

import numpy as np
from model_helpers import micro_checkpoint, synthetic_csv  # noqa: F401 (fixture)

from mer_models.cli import main


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
    assert "--refine 3: --method optimize runs no model" in capsys.readouterr().err


def _warm_start_case():
    """Two synthetic G1 windows retargeted to G1 (reachable goals), and a smooth warm start off the
    optimiser's solution (angles 0.2 rad and the base 4 cm away, slowly varying; 8 cm g-mpbpe): what
    a model's output looks like to the refinement."""
    import torch
    from model_helpers import mixed_batch

    from mer_data.kinematics.rotations import axis_angle_to_matrix
    from mer_models.batch import graph_from_batch
    from mer_models.config import EnergyConfig
    from mer_models.solver.optimize import optimize_motion

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


def test_a_warm_start_solves_whole_windows_and_lands_at_the_optimiser():
    """``--refine K``: K Levenberg-Marquardt iterations with the frames coupled exactly
    (:func:`mer_models.solver.ik.coupled_lm_ik`). From a smooth warm start 8 cm off, 5 of them land within
    5 % of the optimiser's g-mpbpe with less jerk than the Jacobi-stage optimiser, where 5 Jacobi
    iterations stay 1.2x farther off; the cost falls monotonically and every sample is solved on its own."""
    import torch

    from mer_models.retarget.metrics import window_metrics
    from mer_models.solver.ik import coupled_lm_ik, gauss_newton_ik
    from mer_models.solver.optimize import optimize_motion

    b, args, kw, best, warm = _warm_start_case()
    refined = optimize_motion(*args, **kw, gn_iters=5, init=warm)
    cfg, g, eta, goal, _ = args
    q, bp, br = gauss_newton_ik(cfg, g, eta, goal, warm["q"], warm["base_pos"].clone(), warm["base_rot"].clone(), iters=5, **kw)
    jacobi = {"q": q * g.revolute[:, None], "base_pos": bp, "base_rot": br}
    mr, mj, mb, mw = (window_metrics(o, b) for o in (refined, jacobi, best, warm))
    assert (mw["g_mpbpe"] > 0.05).all(), mw["g_mpbpe"]  # the warm start is far off
    assert (mr["g_mpbpe"] < 1.05 * mb["g_mpbpe"]).all(), (mr["g_mpbpe"], mb["g_mpbpe"])
    assert (mj["g_mpbpe"] > 1.15 * mr["g_mpbpe"]).all(), (mj["g_mpbpe"], mr["g_mpbpe"])  # measured 1.2x
    # less jerk than the optimiser with the Jacobi fine stage (version 1; measured 0.8-0.85x), as
    # little as the default optimiser, whose fine stage is this solver too
    v1 = window_metrics(optimize_motion(*args, **kw, fine="jacobi"), b)
    assert (mr["jerk_frame"] < 0.95 * v1["jerk_frame"]).all(), (mr["jerk_frame"], v1["jerk_frame"])
    assert (mr["jerk_frame"] < 1.01 * mb["jerk_frame"]).all(), (mr["jerk_frame"], mb["jerk_frame"])
    assert (mr["limit_violation"] == 0).all()
    # the cost never rises, iteration after iteration
    costs = []
    for k in range(5):
        st: dict = {}
        coupled_lm_ik(cfg, g, eta, goal, warm["q"], warm["base_pos"].clone(), warm["base_rot"].clone(), iters=k, stats=st, **kw)
        costs.append(st["cost"].sum(-1))
    assert all((costs[k + 1] <= costs[k]).all() for k in range(4)) and (costs[4] < 0.5 * costs[0]).all(), costs
    # one damping per sample, nothing shared: a sample solved alone gives the same result
    one = {k: v[1:] for k, v in warm.items()}
    sub = {k: (v[1:] if torch.is_tensor(v) else v) for k, v in kw.items()}
    g1 = type(g)(**{f: getattr(g, f)[1:] for f in g.__dataclass_fields__})
    alone = optimize_motion(cfg, g1, eta[1:], goal[1:], args[4][1:], **sub, gn_iters=5, init=one)
    torch.testing.assert_close(alone["q"], refined["q"][1:], atol=1e-5, rtol=0)


def test_the_block_tridiagonal_solve_is_the_dense_solve():
    """:func:`block_tridiagonal_solve` against ``torch.linalg.solve`` of the assembled system, for
    random SPD blocks and couplings, several window lengths (1 frame included)."""
    import torch

    from mer_models.solver.tridiagonal import block_tridiagonal_solve

    gen = torch.Generator().manual_seed(0)
    for T in (1, 2, 3, 7, 31, 100):
        B, n = 3, 5
        a = torch.randn(B, T, n, n, generator=gen, dtype=torch.float64)
        a = a @ a.transpose(-1, -2) + 4 * torch.eye(n, dtype=torch.float64)
        c = 0.7 * torch.randn(B, max(T - 1, 0), n, generator=gen, dtype=torch.float64)
        rhs = torch.randn(B, T, n, generator=gen, dtype=torch.float64)
        x, ok = block_tridiagonal_solve(a, c, rhs)
        dense = torch.zeros(B, T * n, T * n, dtype=torch.float64)
        for t in range(T):
            dense[:, t * n : (t + 1) * n, t * n : (t + 1) * n] = a[:, t]
            if t + 1 < T:
                dense[:, t * n : (t + 1) * n, (t + 1) * n : (t + 2) * n] = torch.diag_embed(c[:, t])
                dense[:, (t + 1) * n : (t + 2) * n, t * n : (t + 1) * n] = torch.diag_embed(c[:, t])
        # numpy's LAPACK, not torch's: batched float64 LU in torch 2.13's MKL fails at n = 155 with 2
        # threads on some CPUs ("Parameter 6 was incorrect on entry to DLASWP")
        ref = torch.from_numpy(np.linalg.solve(dense.numpy(), rhs.reshape(B, -1, 1).numpy())).reshape(B, T, n)
        assert ok.all()
        torch.testing.assert_close(x, ref, atol=1e-10, rtol=1e-10)
    a[1, 3] = -torch.eye(n, dtype=torch.float64)  # not positive definite: that sample gets no step
    x, ok = block_tridiagonal_solve(a, c, rhs)
    assert ok.tolist() == [True, False, True] and (x[1] == 0).all() and torch.isfinite(x).all()


def test_the_coupled_prior_has_the_jacobi_prior_gradient():
    """The whole-window prior ``smooth/4 sum (q_{t+1} - q_t)^2`` has, in the interior, the gradient
    the optimiser's Jacobi prior steps along, ``smooth (q_t - (q_{t-1} + q_{t+1}) / 2)``: both solvers
    share their fixed point (docs/model.md)."""
    import torch

    from mer_models.solver.ik import _neighbour_mean, _velocity_prior

    q = torch.randn(2, 9, 4, dtype=torch.float64, requires_grad=True)
    w = torch.rand(2, 1, 4, dtype=torch.float64)
    _velocity_prior(q, w / 4).sum().backward()
    jacobi = w * (q - _neighbour_mean(q))
    torch.testing.assert_close(q.grad[:, 1:-1], jacobi[:, 1:-1].detach())


def test_refine_below_zero_is_refused(tmp_path, capsys, micro_checkpoint):  # noqa: F811
    data = tmp_path / "data"
    synthetic_csv(data / "g1" / "clip0.csv", "g1", frames=120, seed=0)
    assert main(["evaluate", "--model", str(micro_checkpoint), "--input", str(data), "--source", "g1", "--targets", "h1",
                 "--split", "all", "--max-windows", "1", "--methods", "refine", "--refine", "-1"]) == 1  # fmt: skip
    assert "--refine must be >= 0, got -1" in capsys.readouterr().err
    src = synthetic_csv(tmp_path / "walk.csv", frames=60)
    assert main(["retarget", str(src), "--source", "g1", "--target", "h1", "--model", str(micro_checkpoint), "--refine", "-2",
                 "-o", str(tmp_path / "x.csv")]) == 1  # fmt: skip
    assert "--refine must be >= 0, got -2" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()
