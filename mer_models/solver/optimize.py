"""The optimiser: minimise the retargeting energy directly over the joint trajectory and the base.

The same energy as the model's guidance (:mod:`mer_models.solver.energy`, with ``L_cst = 0`` because
positions come from FK), minimised per window or per whole motion, batched over samples of mixed
robots and over frames through the foundation's FK. It is

* the teacher of the learned model and the reference for how close the model gets to the optimum,
* the clean sample ``x`` of the EDM term for targets without motion data (docs/model.md),
* a retargeter that needs no model (``mer retarget --method optimize``), for any registered robot.

Stage 1 (always): Levenberg-Marquardt on key-point positions, base/feet/hand orientations, the
nominal pose and a temporal smoothness prior (:func:`mer_models.solver.ik.gauss_newton_ik`), projected
onto the limits, stopping once every frame has converged. Without a warm start it runs coarse to
fine: every 2nd frame from the nominal angles, the scaled reference's base trajectory and the
reference's base orientation; then every frame from the interpolation of those key frames, which
is close enough that a few iterations finish it (and neighbouring frames start in the same basin).
Those few are whole-window iterations (``fine="coupled"``, below; :data:`OPTIMIZER_VERSION` 2): on
LAFAN1, 4 of them land at 0.94-0.99x the g-mpbpe of the 10 Jacobi ones of version 1, with 0.66-1.01x
its jerk, in 0.85x the time (median over 16 source-target pairs; docs/model.md §The optimiser).

A warm start (``init``: a model's output, ``--refine K``) is already smooth and near the goals;
there the Jacobi-style prior mostly holds frames back (it pulls each frame towards its neighbours'
previous iterate, so frames cannot move together within one iteration). Its K iterations are
Levenberg-Marquardt on the whole window instead (:func:`mer_models.solver.ik.coupled_lm_ik`): the same
terms, the prior's frame coupling solved exactly (one block-tridiagonal system per sample), joints
held at a limit the gradient pushes past, one damping per sample (docs/model.md §The optimiser as
a refinement: on LAFAN1, 5 iterations from `mer-base`'s output land at 0.85-1.01x the optimiser's
g-mpbpe with 0.77-1.00x its jerk, on all 16 source-target pairs).

Stage 2 (``iters > 0``, off by default): Adam on the whole energy, velocity terms included, with
limits by construction (``q = lower + (upper - lower) sigmoid(z)``, ``R = R_1 Exp(omega)``, a
cosine-decayed step). Measured on LAFAN1 it lowered g-mpbpe by 0.2 mm on H1 while tripling the
jerk (it moves weakly constrained joints), so the default leaves it out (docs/model.md).

Every sample's result depends on its own data only: the loss is a *sum* over samples, and the
Levenberg-Marquardt damping, acceptance and solve are per frame (per sample for a warm start).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any

import torch

from mer_data.kinematics.rotations import axis_angle_to_matrix, matrix_to_quat, quat_slerp, quat_to_matrix
from mer_models.batch import BatchGraph, batch_fk
from mer_models.config import EnergyConfig

from .constrained import constrain
from .energy import energy_terms
from .ik import DEFAULT_SMOOTH, DEFAULT_TOL, coupled_lm_ik, gauss_newton_ik
from .limits import limit_clip, limit_logit
from .progress import solver_stage

log = logging.getLogger(__name__)

__all__ = ["optimize_motion", "DEFAULT_ITERS", "DEFAULT_GN_ITERS", "DEFAULT_FINE", "FINE_ITERS", "FINE_OF_VERSION", "OPTIMIZER_VERSION"]

#: Adam iterations of stage 2 (0: off; see the module docstring).
DEFAULT_ITERS = 0
#: Most Levenberg-Marquardt iterations of stage 1 (it stops earlier once converged).
DEFAULT_GN_ITERS = 30
#: Coarse-to-fine warm start: every ``DEFAULT_STRIDE``-th frame is solved first (4 was faster but
#: let Valkyrie's wrists settle in different branches between key frames: jerk 0.022 -> 0.046), the rest start
#: from the interpolated solution and get the fine stage (1: off).
DEFAULT_STRIDE = 2
#: The fine stage (every frame, from the interpolated key frames): ``"coupled"``, Levenberg-Marquardt
#: on the whole window (:func:`mer_models.solver.ik.coupled_lm_ik`, as a warm-started refinement), or
#: ``"jacobi"``, frame by frame with the Jacobi-style prior (the only one before
#: :data:`OPTIMIZER_VERSION` 2). Most iterations of each: :data:`FINE_ITERS` (docs/model.md §The optimiser).
FINE_ITERS = {"coupled": 4, "jacobi": 10}
#: The fine stage of each version of the schedule.
FINE_OF_VERSION = {1: "jacobi", 2: "coupled"}
#: Version of the default schedule, recorded with every teacher solve (``mer shards solve`` refuses a
#: folder solved by another one until ``--force``): 1 = Jacobi fine stage (10 iterations), 2 = whole-window fine stage (4).
OPTIMIZER_VERSION = 2
DEFAULT_FINE = FINE_OF_VERSION[OPTIMIZER_VERSION]

def _interpolate(coarse: dict[str, torch.Tensor], idx: torch.Tensor, T: int) -> dict[str, torch.Tensor]:
    """Key-frame solutions at frames ``idx`` (K,) → every frame of 0..T-1: angles and base position
    linear, base orientation slerped, between the neighbouring key frames."""
    t = torch.arange(T, device=idx.device, dtype=coarse["q"].dtype)
    hi = torch.searchsorted(idx, torch.arange(T, device=idx.device)).clamp(1, len(idx) - 1)
    lo = hi - 1
    w = ((t - idx[lo].to(t.dtype)) / (idx[hi] - idx[lo]).to(t.dtype)).clamp(0, 1)
    out = {}
    for k in ("q", "base_pos"):
        a, b = coarse[k][:, lo], coarse[k][:, hi]
        out[k] = a + (b - a) * w[None, :, None]
    qa, qb = matrix_to_quat(coarse["base_rot"][:, lo]), matrix_to_quat(coarse["base_rot"][:, hi])
    out["base_rot"] = quat_to_matrix(quat_slerp(qa, qb, w[None, :, None].expand(qa.shape[:2] + (1,)).squeeze(-1)))
    return out


def optimize_motion(
    cfg: EnergyConfig,
    graph: BatchGraph,
    eta: torch.Tensor,
    goal: torch.Tensor,
    ref_base_rot: torch.Tensor,
    *,
    goal_rot: torch.Tensor | None = None,
    rot_mask: torch.Tensor | None = None,
    iters: int = DEFAULT_ITERS,
    gn_iters: int = DEFAULT_GN_ITERS,
    smooth: float = DEFAULT_SMOOTH,
    tol: float = DEFAULT_TOL,
    stride: int = DEFAULT_STRIDE,
    fine: str = DEFAULT_FINE,
    refine_iters: int | None = None,
    lr: float = 0.02,
    fps: float = 30.0,
    init: dict[str, torch.Tensor] | None = None,
    stats: dict | None = None,
    physics: Any = None,
    balance: Any = None,
) -> dict[str, torch.Tensor]:
    """Minimise the energy for a batch.

    Args:
        graph: target side (B samples, Jt nodes).
        eta: (B, Jt, Jr) joint map; goal: (B, T, Jr, 3) scaled reference positions [m].
        ref_base_rot: (B, T, 3, 3) reference base orientation (initial base orientation).
        goal_rot, rot_mask: (B, T, Jr, 3, 3) orientation goals and (B, Jr) the tracked reference
            nodes (:func:`mer_data.motion.samples.reference_goals`); omitted: positions only.
        iters: Adam iterations of stage 2 (0 skips it).
        gn_iters: at most this many Levenberg-Marquardt iterations of stage 1 (0 skips it).
        smooth, tol: stage 1's temporal prior weight and convergence tolerance (:mod:`mer_models.solver.ik`).
        stride, fine, refine_iters: without ``init``, stage 1 first solves every ``stride``-th frame
            (``gn_iters``, frame by frame), then all frames from the interpolation with the ``fine``
            solver (``"coupled"``: whole windows, ``"jacobi"``: frame by frame), at most
            ``refine_iters`` iterations (default :data:`FINE_ITERS` of ``fine``). Windows shorter
            than ``3 * stride`` frames are solved frame by frame from the start (``gn_iters``).
        lr: step of the angle logits [1] and base rotation [rad]; the base position uses lr/5 [m].
        init: optional warm start ``{"q", "base_pos", "base_rot"}`` (e.g. a model's output): then
            stage 1 is ``gn_iters`` iterations of :func:`~mer_models.solver.ik.coupled_lm_ik` (with
            ``smooth > 0``; else frame by frame).
        stats: receives ``gn_iterations``.
        physics: :class:`~mer_models.solver.physics.PhysicsInputs`: the physical terms in stage 1
            (floor, stance and swing feet, self-penetration, joint speed; :mod:`.physics`).
        balance: :class:`~mer_models.solver.balance_term.BalanceInputs`: its rounds after stage 1 (``--balance``).

    Returns:
        ``q`` (B, T, Jt) [rad] inside the limits, ``base_pos`` (B, T, 3), ``base_rot`` (B, T, 3, 3),
        and ``energy`` (B,) the final weighted energy (against ``goal`` as given: the physical
        terms' goal edits are not counted); all detached.
    """
    if fine not in FINE_ITERS:
        raise ValueError(f"fine={fine!r}: expected one of {', '.join(map(repr, FINE_ITERS))}")
    B, T = goal.shape[:2]
    J = graph.parents.shape[1]
    repair, goal_in = physics, goal
    constrained = physics if physics is not None and physics.cfg.method == "constraints" else None
    if constrained is not None:  # the plain solve first, then the least change that meets the constraints
        physics = repair = None
    elif physics is not None:
        goal = physics.separate_feet(physics.lock_goals(goal), ref_base_rot)
        physics = physics.main()
    lower, upper = graph.lower[:, None].expand(B, T, J), graph.upper[:, None].expand(B, T, J)
    gkw = {"goal_rot": goal_rot, "rot_mask": rot_mask}
    with torch.no_grad():
        if init is None:
            q0 = graph.nominal[:, None].expand(B, T, J).clone()
            p0 = goal[:, :, 0].clone()
            r0 = ref_base_rot.clone()
        else:
            q0 = torch.minimum(torch.maximum(init["q"], lower), upper)
            p0, r0 = init["base_pos"].clone(), init["base_rot"].clone()
        if gn_iters > 0:
            ik_stats: dict = {}
            ik_iters = gn_iters
            whole = init is not None and smooth > 0  # the whole window at once (module docstring)
            if init is None and stride > 1 and T >= 3 * stride:
                # coarse to fine: key frames first (the prior spans `stride` frames there: weight / stride^2)
                idx = torch.unique(torch.cat([torch.arange(0, T, stride), torch.tensor([T - 1])])).to(goal.device)
                sub = {"goal_rot": None if goal_rot is None else goal_rot[:, idx], "rot_mask": rot_mask}
                coarse = physics.frames(idx, stride) if physics is not None and physics.cfg.coarse else None
                with solver_stage("key frames"):
                    qk, pk, rk = gauss_newton_ik(cfg, graph, eta, goal[:, idx], q0[:, idx], p0[:, idx], r0[:, idx], iters=gn_iters,
                                                 smooth=smooth / stride**2, tol=tol, physics=coarse, **sub)  # fmt: skip
                warm = _interpolate({"q": qk, "base_pos": pk, "base_rot": rk}, idx, T)
                q0, p0, r0 = warm["q"], warm["base_pos"], warm["base_rot"]
                ik_iters = min(gn_iters, FINE_ITERS[fine] if refine_iters is None else refine_iters)
                if physics is not None and physics.cfg.fine_iters:
                    ik_iters = max(ik_iters, physics.cfg.fine_iters)
                whole = fine == "coupled" and smooth > 0
            with solver_stage("all frames"):
                if whole:
                    q0, p0, r0 = coupled_lm_ik(cfg, graph, eta, goal, q0, p0, r0, iters=ik_iters, smooth=smooth, tol=tol,
                                               stats=ik_stats, physics=physics, **gkw)  # fmt: skip
                else:
                    q0, p0, r0 = gauss_newton_ik(cfg, graph, eta, goal, q0, p0, r0, iters=ik_iters, smooth=smooth, tol=tol,
                                                 stats=ik_stats, physics=physics, **gkw)  # fmt: skip
            if stats is not None:
                stats["gn_iterations"] = ik_stats.get("iterations", 0)
            if constrained is not None and smooth > 0:
                with solver_stage("constraints"):
                    q0, p0, r0 = constrain(cfg, graph, eta, goal, q0, p0, r0, physics=constrained, smooth=smooth, tol=tol, **gkw)
            rounds = repair.cfg.repair_rounds if repair is not None and repair.repairs and smooth > 0 else 0
            seen = moved = None
            for rnd in range(rounds):  # the self term, on the pairs the solve (or the last round) left interpenetrating
                pos, rot = batch_fk(graph, q0, p0, r0)
                fix = repair.repair(pos, rot, first=rnd == 0, seen=seen, moved=moved)
                if fix is None:
                    break
                # only the samples with a pair interpenetrating, each on its own; the self term stiffer each round
                rows, terms = fix
                seen = terms.found
                terms = dataclasses.replace(terms, cfg=dataclasses.replace(terms.cfg, w_self=terms.cfg.w_self * terms.cfg.repair_growth**rnd))
                sub = {k: None if v is None else v[rows] for k, v in gkw.items()}
                with solver_stage("self-contact repair"):
                    qr, pr, rr = coupled_lm_ik(cfg, graph.select(rows), eta[rows], goal[rows], q0[rows], p0[rows], r0[rows],
                                               iters=repair.cfg.self_repair_iters, smooth=smooth * repair.cfg.repair_smooth, tol=tol, physics=terms,
                                               hold=terms.held_frames(), **sub)  # fmt: skip
                q0, p0, r0 = q0.clone(), p0.clone(), r0.clone()
                q0[rows], p0[rows], r0[rows] = qr, pr, rr
                moved = torch.zeros(B, T, dtype=torch.bool, device=q0.device)
                moved[rows] = torch.as_tensor(terms.free, device=q0.device)
            if balance is not None and smooth > 0:
                with solver_stage("balance"):
                    # under the constraint method its floor and joint-speed terms hold the balance rounds, as penalties
                    held = constrained.main() if constrained is not None else physics
                    q0, p0, r0 = balance.solve(cfg, graph, eta, goal, q0, p0, r0, smooth=smooth, tol=tol, physics=held, **gkw)
    if iters > 0:
        z = limit_logit(q0, lower, upper).clone().requires_grad_(True)
        pos = p0.clone().requires_grad_(True)
        omega = torch.zeros(B, T, 3, dtype=goal.dtype, device=goal.device, requires_grad=True)
        opt = torch.optim.Adam([{"params": [z, omega], "lr": lr}, {"params": [pos], "lr": lr / 5}])
        base_lrs = [g["lr"] for g in opt.param_groups]
        for it in range(iters):
            for g, base in zip(opt.param_groups, base_lrs):
                g["lr"] = base * 0.5 * (1 + math.cos(math.pi * it / iters))
            q, p, r = limit_clip(z, lower, upper), pos, r0 @ axis_angle_to_matrix(omega)
            e = energy_terms(cfg, graph, q, p, r, eta, goal, fps, **gkw)["total"]
            opt.zero_grad(set_to_none=True)
            e.sum().backward()
            opt.step()
        with torch.no_grad():
            q0, p0, r0 = limit_clip(z, lower, upper), pos.detach(), r0 @ axis_angle_to_matrix(omega)
    with torch.no_grad():
        q = q0 * graph.revolute[:, None]
        e = energy_terms(cfg, graph, q, p0, r0, eta, goal_in, fps, **gkw)["total"]  # against the goals as given
    log.debug("optimize_motion: %d Adam iterations, mean energy %.5f", iters, float(e.mean()))
    return {"q": q.detach(), "base_pos": p0.detach(), "base_rot": r0.detach(), "energy": e.detach()}
