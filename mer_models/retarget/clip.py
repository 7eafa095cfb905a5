"""Retargeting as a library: a source motion (CSV or arrays) → a target motion, and its files.

:func:`retarget_features` is the core (features in, :class:`~mer_models.export.writers.TargetMotion`
out; :func:`retarget_features_many` for several targets at once) with two methods:

* ``diffusion``: the guided-diffusion model, long-horizon (:mod:`mer_models.retarget.long_horizon`);
* ``optimize``: the optimisation baseline on the whole motion (:mod:`mer_models.solver.optimize`), no
  model needed.

:func:`retarget_file` reads the source CSV through the shard tooling's LAFAN1 reader
(:func:`mer_data.motion.lafan1.read_lafan1_csv`: bad columns, NaNs and the like are refused with the
file and line), resamples it to the model's 30 Hz when needed, retargets, and writes the outputs
(:mod:`mer_models.export.writers`, :mod:`mer_models.export.plot`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from mer_data.base.errors import MerError
from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import axis_angle_to_matrix
from mer_data.motion.features import source_features
from mer_data.robots.registry import Robot, as_robot, get_skeleton
from mer_data.skeleton import Skeleton
from mer_models.batch import graph_from_batch
from mer_models.config import EnergyConfig, SamplerConfig
from mer_models.export.writers import (
    NPZ_FPS,
    TargetMotion,
    check_motion_finite,
    npz_robot,
    require_tracker,
    write_csv,
    write_mcap,
    write_npz,
)
from mer_models.solver.ik import DEFAULT_SMOOTH
from mer_models.solver.optimize import DEFAULT_GN_ITERS, DEFAULT_ITERS, optimize_motion
from mer_models.zoo.checkpoint import Checkpoint, check_robot, resolve_model

from .feasible import feasible_motion
from .long_horizon import prepare_reference, retarget_sequences, warm_sequences

log = logging.getLogger(__name__)

__all__ = ["METHODS", "RetargetResult", "source_features", "retarget_features", "retarget_features_many", "retarget_file", "sequence_metrics", "MODEL_FPS",
           "zero_shot_notes"]

METHODS = ("diffusion", "optimize")
MODEL_FPS = 30.0


@dataclass
class RetargetResult:
    """What a retargeting produced.

    Attributes:
        motion: the target motion (world frame).
        reference_points: (F, K, 3) the scaled reference key points it tracks (world frame) [m].
        method: ``diffusion`` or ``optimize``.
        outputs: kind → path of every file written.
        reference_nodes: (F, Jr, 3) every node of the reference scaled to the target (world frame) [m].
        reference_skeleton: the reference (source) skeleton of ``reference_nodes``.
        prepared: what :func:`~mer_models.retarget.long_horizon.prepare_reference` made of the reference for
            this target (features, scaled nodes, shift, rotation goals), for metrics without preparing again.
    """

    motion: TargetMotion
    reference_points: np.ndarray
    method: str
    outputs: dict[str, Path] = field(default_factory=dict)
    reference_nodes: np.ndarray | None = None
    reference_skeleton: Skeleton | None = None
    prepared: tuple | None = None
    metrics: dict | None = None  # retarget_file(metrics=True): the paper's metrics and the artifact figures
    notes: list[str] = field(default_factory=list)  # what a user should know about this result (a zero-shot target, ...)


def _check_finite(feats: np.ndarray) -> None:
    bad = ~np.isfinite(feats).all(axis=(1, 2))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise MerError(
            f"the source motion has non-finite values (frame {i + 1}, {int(bad.sum())} frame(s))",
            line=i + 1,
            fix="repair or drop those frames",
        )


def _reference_points(scaled: np.ndarray, shift: np.ndarray, eta: np.ndarray) -> np.ndarray:
    pairs = np.flatnonzero(eta.any(0))
    return scaled[:, pairs] + shift


def geometry_of(target: Skeleton):
    """The collision model of the registered robot whose skeleton ``target`` is (a library caller
    that passed a skeleton, not a robot), or None: an augmented or edited skeleton has none."""
    from mer_data.robots.collision import collision_model

    try:
        robot = as_robot(target.name)
    except MerError:
        return None
    return collision_model(robot) if robot.skeleton.fingerprint == target.fingerprint else None


#: The no-slip term's weight for human sources (relative to ``rho``): 16 measured 0.2 / 0.3 cm/s median
#: stance skate on G1 / H1 (Bandai subset) against 0.7 / 1.4 at the solver's 1 (docs/decisions.md).
HUMAN_XY_WEIGHT = 16.0


def human_physics(cfg=None):
    """The physical terms of a human source (BVH, SMPL family, joint positions): ``cfg`` (default
    :class:`~mer_models.solver.physics.PhysicsConfig`) with the constraint method, whose stance
    constraint keeps the robot's sole on the floor and its lowest point from sliding while the
    human's foot is down (:func:`mer_data.motion.contacts.foot_contacts`; measured: docs/model.md
    §Feet of human sources). A source that floats or sinks gets the same: the contacts come from each
    foot's own standing level."""
    import dataclasses

    from mer_models.solver.physics import PhysicsConfig

    return dataclasses.replace(cfg or PhysicsConfig(), method="constraints", xy_weight=HUMAN_XY_WEIGHT)


def physics_inputs(feats: np.ndarray, ref: Skeleton, geometry, fps: float, cfg, contacts: torch.Tensor | None = None):
    """:class:`~mer_models.solver.physics.PhysicsInputs` of one motion for a target whose collision
    model is ``geometry``: the source's foot contacts from its features (N, Jr, 9), unless given
    (``contacts`` (1, N, 2))."""
    from mer_data.motion.contacts import foot_contacts
    from mer_data.motion.features import split_features
    from mer_models.solver.physics import PhysicsInputs

    if contacts is None:
        pos = split_features(torch.from_numpy(np.asarray(feats, np.float64)))["pos"].numpy()
        contacts = torch.from_numpy(foot_contacts(pos, ref, fps))[None]
    return PhysicsInputs.of_reference(geometry, contacts, fps, cfg, ref)


def balance_inputs(target: Skeleton, cfg, fps: float):
    """:class:`~mer_models.solver.balance_term.BalanceInputs` of the registered robot whose skeleton
    ``target`` is (its masses and collision model)."""
    from mer_models.solver.balance_term import BalanceInputs

    robot = as_robot(target.name)
    if robot.skeleton.fingerprint != target.fingerprint:
        raise MerError(f"--balance needs the registered robot's masses; {target.name!r} was given as an edited skeleton",
                       fix="retarget to the registered robot, or leave out --balance")  # fmt: skip
    return BalanceInputs.of_robot(robot, cfg, fps)


def _optimize_sequence(feats, scaled, rot_goals, ref: Skeleton, target: Skeleton, eta, energy: EnergyConfig, fps, iters, gn_iters, device,
                       smooth: float = DEFAULT_SMOOTH, init: dict | None = None, physics=None, balance=None):
    """The optimiser on one whole motion; ``physics``: its :class:`~mer_models.solver.physics.PhysicsInputs`;
    ``balance``: its :class:`~mer_models.solver.balance_term.BalanceInputs`."""
    from mer_data.motion.samples import TrainingSample, collate

    batch = collate([TrainingSample(feats[:3].astype(np.float32), ref, target, eta)])
    g = graph_from_batch(batch, "tgt", device)
    goal = torch.from_numpy(scaled).float()[None].to(device)
    rot = axis_angle_to_matrix(torch.from_numpy(feats[:, 0, 0:3]).float())[None].to(device)
    eta_t = torch.from_numpy(eta.astype(np.float32))[None].to(device)
    goal_rot = torch.from_numpy(rot_goals[0]).float()[None].to(device)
    rot_mask = torch.from_numpy(rot_goals[1])[None].to(device)
    warm = None
    if init is not None:
        warm = {k: torch.from_numpy(np.asarray(init[k])).float()[None].to(device) for k in ("q", "base_pos", "base_rot")}
    out = optimize_motion(energy, g, eta_t, goal, rot, iters=iters, gn_iters=gn_iters, fps=fps, goal_rot=goal_rot, rot_mask=rot_mask,
                        smooth=smooth, init=warm, physics=physics, balance=balance)
    return {k: out[k][0].double().cpu().numpy() for k in ("q", "base_pos", "base_rot")}


def retarget_features(
    reference: np.ndarray,
    source: str | Skeleton,
    target: str | Skeleton,
    **kw,
) -> RetargetResult:
    """Retarget source features (F, Jr, 9) (world frame, at ``fps``) to ``target``.

    One target of :func:`retarget_features_many` (the options are documented there).
    """
    return retarget_features_many(reference, source, [target], **kw)[0]


def retarget_features_many(
    reference: np.ndarray,
    source: str | Skeleton,
    targets: Sequence[str | Skeleton],
    *,
    method: str = "diffusion",
    checkpoint: Checkpoint | None = None,
    steps: int | None = None,
    guidance: float | None = None,
    seed: int = 0,
    fps: float = MODEL_FPS,
    allow_unseen: bool = False,
    opt_iters: int = DEFAULT_ITERS,
    opt_gn_iters: int = DEFAULT_GN_ITERS,
    opt_smooth: float = DEFAULT_SMOOTH,
    energy: EnergyConfig | None = None,
    refine: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    bf16: bool = False,
    physics=None,
    geometry=None,
    balance=None,
) -> list[RetargetResult]:
    """Retarget source features (F, Jr, 9) (world frame, at ``fps``) to every robot of ``targets``.

    ``checkpoint`` is required for ``diffusion``; ``steps``/``guidance`` override its sampler
    configuration. With ``diffusion`` the targets are sampled window by window, the reference encoded
    once per window for all of them (:func:`~mer_models.retarget.long_horizon.retarget_sequences`).
    ``opt_*`` and ``energy`` set the optimiser (``opt_smooth``: its temporal prior,
    :mod:`mer_models.solver.ik`). ``refine`` > 0 warm-starts the optimiser from the model's output for at
    most that many Levenberg-Marquardt iterations on the whole motion (diffusion only;
    :func:`mer_models.solver.ik.coupled_lm_ik`); None: the model's own default (a warm-start model's
    ``WarmConfig.refine``, the diffusion model's 0). A warm-start checkpoint (``run.kind`` ``warm``,
    :mod:`mer_models.warm`) runs as the ``diffusion`` method does, in one pass over the whole motion. ``allow_unseen`` retargets to a
    robot the model never saw (zero-shot; the paper fine-tunes instead). ``progress`` gets
    (windows done, windows) of the model's pass. ``bf16``: the network under bfloat16 autocast
    (diffusion only; about twice as fast on CPUs with AMX, :mod:`mer_models.diffusion.precision`).
    ``physics``: a :class:`~mer_models.solver.physics.PhysicsConfig`: the optimiser (and ``refine``)
    also minimises its physical terms (:mod:`mer_models.solver.physics`; by default: every body
    above the floor and joints within their speed limits); None (the default): key points and
    orientations only. ``geometry``: each target's collision model (default: the registered robot's).
    ``balance``: a :class:`~mer_models.solver.balance_term.BalanceConfig`: the optimiser (and ``refine``)
    then holds the single-support ZMP in the stance foot and flight ballistic (a registered target's
    masses; :mod:`mer_models.solver.balance_term`).

    Returns:
        One result per target, in the order of ``targets``.
    """
    if method not in METHODS:
        raise MerError(f"unknown method {method!r}; known: {', '.join(METHODS)}", fix="use --method diffusion or optimize")
    ref = get_skeleton(source) if isinstance(source, str) else source
    tgts = [get_skeleton(t) if isinstance(t, str) else t for t in targets]
    if not tgts:
        raise MerError("no target robot given", fix="name at least one target robot")
    reference = np.asarray(reference, np.float64)
    if reference.ndim != 3 or reference.shape[1:] != (ref.num_nodes, 9):
        raise MerError(f"source features have shape {reference.shape}, expected (F, {ref.num_nodes}, 9) for {ref.name!r}")
    _check_finite(reference)
    etas = [joint_map(t, ref) for t in tgts]
    prepared = [prepare_reference(reference, ref, t) for t in tgts]
    phys: list = [None] * len(tgts)
    if physics is not None:  # the source's contacts once; each target's geometry as given, else its registered robot's
        geos = list(geometry) if geometry is not None else [geometry_of(t) for t in tgts]
        first = physics_inputs(prepared[0][0], ref, geos[0], fps, physics)
        phys = [None if g is None else physics_inputs(None, ref, g, fps, physics, first.contacts) for g in geos]
    bal = [None if balance is None else balance_inputs(t, balance, fps) for t in tgts]
    outs: list[dict[str, np.ndarray]]
    labels = [method] * len(tgts)
    notes: list[list[str]] = [[] for _ in tgts]
    if method == "diffusion":
        if checkpoint is None:
            raise MerError("the diffusion method needs a model", fix="pass --model PATH, or use --method optimize")
        if ref.name in ("bvh", "smpl", "joints"):  # mer_data.motion.sources.HUMAN_SOURCES
            raise MerError(f"the model was trained on robot sources only: it has never seen a human ({ref.name}) source",
                           fix="use --method optimize (the default for a human input)")  # fmt: skip
        if not allow_unseen:
            for t in tgts:
                check_robot(checkpoint, t.name, "targets", t.fingerprint)
            check_robot(checkpoint, ref.name, "references", ref.fingerprint)
        notes = [zero_shot_notes(checkpoint, t.name, ref.name) for t in tgts]
        run = checkpoint.run
        sampler = run.sampler if guidance is None else SamplerConfig(**{**run.sampler.__dict__, "guidance": float(guidance)})
        if run.kind == "warm":  # one pass of the warm-start network, finished by its `refine` iterations by default
            outs = warm_sequences(checkpoint.model, reference, ref, tgts, fps=fps, etas=etas, prepared=prepared, bf16=bf16,
                                  progress=progress)  # fmt: skip
        else:
            outs = retarget_sequences(
                checkpoint.model, reference, ref, tgts, sampler, energy=energy or run.energy, fps=fps, steps=steps,
                seed=seed, etas=etas, prepared=prepared, progress=progress, bf16=bf16,
            )  # fmt: skip
        refine = model_refine(checkpoint, refine)
        labels = [model_label(checkpoint, refine)] * len(tgts)
        if refine > 0:
            device = next(checkpoint.model.parameters()).device
            for i, (t, eta, (feats, scaled, shift, rot_goals)) in enumerate(zip(tgts, etas, prepared)):
                init = {"q": outs[i]["q"], "base_pos": np.asarray(outs[i]["base_pos"]) - shift, "base_rot": outs[i]["base_rot"]}
                out = _optimize_sequence(feats, scaled, rot_goals, ref, t, eta, energy or EnergyConfig(), fps, 0, refine, device,
                                         smooth=opt_smooth, init=init, physics=phys[i], balance=bal[i])  # fmt: skip
                out["base_pos"] = out["base_pos"] + shift
                outs[i] = out
    else:
        device = next(checkpoint.model.parameters()).device if checkpoint is not None else torch.device("cpu")
        outs = []
        for i, (t, eta, (feats, scaled, shift, rot_goals)) in enumerate(zip(tgts, etas, prepared)):
            out = _optimize_sequence(feats, scaled, rot_goals, ref, t, eta, energy or EnergyConfig(), fps, opt_iters, opt_gn_iters,
                                     device, smooth=opt_smooth, physics=phys[i], balance=bal[i])  # fmt: skip
            out["base_pos"] = out["base_pos"] + shift
            outs.append(out)
    results = []
    for i, (t, eta, prep, out, label) in enumerate(zip(tgts, etas, prepared, outs, labels)):
        _, scaled, shift, _ = prep
        motion = TargetMotion(t, fps, out["q"], out["base_pos"], out["base_rot"])
        if phys[i] is not None and (method == "optimize" or (refine or 0) > 0):
            motion = feasible_motion(motion, phys[i].model, physics)
        results.append(RetargetResult(motion, _reference_points(scaled, shift, eta), label, reference_nodes=scaled + shift,
                                      reference_skeleton=ref, prepared=prep, notes=notes[i]))  # fmt: skip
    return results


def model_refine(checkpoint: Checkpoint | None, refine: int | None) -> int:
    """The refinement iterations of a model run: ``refine``, or the model's own default when None (a
    warm start's ``WarmConfig.refine``, the diffusion model's 0)."""
    if refine is not None:
        return refine
    return checkpoint.run.warm.refine if checkpoint is not None and checkpoint.run.kind == "warm" else 0


def model_label(checkpoint: Checkpoint | None, refine: int | None) -> str:
    """What a model run is called in summaries: its kind, with ``+refineK`` when refined."""
    kind = checkpoint.run.kind if checkpoint is not None else "diffusion"
    k = model_refine(checkpoint, refine)
    return f"{kind}+refine{k}" if k else kind


def zero_shot_notes(checkpoint: Checkpoint, target: str, source: str) -> list[str]:
    """What to tell a user whose model never saw ``target`` (or ``source`` as a reference): the
    result is zero-shot (``allow_unseen``), and what does better."""
    seen_t, seen_r = checkpoint.robots.get("targets", {}), checkpoint.robots.get("references", {})
    out = []
    if target not in seen_t:
        out.append(f"zero-shot: the model never saw {target!r} as a target (it saw {', '.join(sorted(seen_t)) or 'none'}); "
                   f"expect lower accuracy: `mer finetune --robot {target} ...` adapts the model, --refine 5 or --method optimize "
                   "(the default) runs the optimiser")  # fmt: skip
    if source not in seen_r:
        out.append(f"zero-shot: the model never saw {source!r} as a source (it saw {', '.join(sorted(seen_r)) or 'none'})")
    return out


def retarget_file(
    input_csv: str | Path,
    source: str | Robot,
    target: str | Robot,
    *,
    out_csv: str | Path | None = None,
    npz: str | Path | None = None,
    mcap: str | Path | None = None,
    plot: str | Path | None = None,
    video: str | Path | None = None,
    video_fps: float | None = None,
    video_range: tuple[float, float | None] | None = None,
    model: str | Path | None = None,
    method: str = "diffusion",
    input_fps: float = MODEL_FPS,
    device: str = "cpu",
    npz_fps: float | None = NPZ_FPS,
    npz_for: str | None = None,
    bvh=None,
    metrics: bool = False,
    **kw,
) -> RetargetResult:
    """Read a LAFAN1-layout CSV of ``source`` (or a BVH of a human: ``source`` ``"bvh"`` or a
    ``.bvh`` input, read with ``bvh``, :class:`~mer_data.motion.sources.BvhOptions`;
    :func:`mer_data.motion.sources.read_source`), retarget it to ``target`` and write the outputs.

    ``video`` (.gif or .mp4, :mod:`mer_models.export.video`) shows the scaled reference and the result
    side by side, at ``video_fps`` (default the motion's 30 Hz), over ``video_range`` (start, end) [s]
    (default the first 10 s). Extra keywords go to
    :func:`retarget_features`. Unknown robots, a CSV that does not match the source's layout,
    non-finite values, a model that never saw the target, a video format that cannot be written:
    each a MerError. ``metrics``: also :func:`sequence_metrics` of the result (``res.metrics``).
    """
    if video is not None:
        from mer_models.export.video import check_video_path

        check_video_path(video, video_fps)  # before the work: a bad ending or a missing ffmpeg fails at once

    from mer_data.motion.sources import human_kind, read_source

    human = human_kind(input_csv, source)  # bvh, smpl, joints (from --source, else the file's content), None: a CSV
    src_robot = human if human else as_robot(source)  # resolved once: below, Robots only
    tgt_robot = as_robot(target)
    if npz is not None:  # refuse an npz that cannot be written before the work: which tracker reads it
        require_tracker(npz_for, "npz_for=")
        npz_robot(tgt_robot.skeleton, tgt_robot, npz)
    checkpoint = resolve_model(model, device) if (model is not None and method == "diffusion") else None
    if method == "diffusion" and checkpoint is None:
        raise MerError("the diffusion method needs a model", fix="pass --model PATH, or use --method optimize")
    src = read_source(input_csv, src_robot, fps=input_fps, bvh=bvh)
    skel, feats = src.skeleton, src.features()
    for note in src.notes:
        log.info("%s: %s", input_csv, note)
    if kw.get("physics") is not None:
        from mer_data.robots.collision import collision_model

        kw["geometry"] = [collision_model(tgt_robot)]
    res = retarget_features(feats, skel, tgt_robot.skeleton, method=method, checkpoint=checkpoint, fps=MODEL_FPS, **kw)
    check_motion_finite(res.motion, out_csv or npz or mcap or plot or video)  # all outputs or none
    if metrics:
        from mer_data.robots.collision import collision_model
        from mer_data.robots.inertia import mass_model

        res.metrics = sequence_metrics(feats, skel, res.motion, prepared=res.prepared, geometry=collision_model(tgt_robot),
                                       masses=mass_model(tgt_robot))
    if out_csv is not None:
        res.outputs["csv"] = write_csv(out_csv, res.motion, robot=tgt_robot)
    if npz is not None:
        res.outputs["npz"] = write_npz(npz, res.motion, tracker=npz_for, fps=npz_fps, robot=tgt_robot)
    if mcap is not None:
        res.outputs["mcap"] = write_mcap(mcap, res.motion, reference_points=res.reference_points)
    if plot is not None:
        from mer_models.export.plot import plot_motion

        res.outputs["png"] = plot_motion(plot, res.motion, reference_points=res.reference_points)
    if video is not None:
        from mer_models.export.video import write_video

        res.outputs["video"] = write_video(video, res.motion, res.reference_points, reference_nodes=res.reference_nodes,
                                           reference_skeleton=res.reference_skeleton, fps=video_fps,
                                           time_range=video_range)  # fmt: skip
    return res


def sequence_metrics(
    reference: np.ndarray, source: Skeleton, motion: TargetMotion, *, prepared: tuple | None = None, geometry=None,
    masses=None, torques: bool = False,
) -> dict[str, float]:
    """The paper's metrics (:func:`mer_models.retarget.metrics.window_metrics`) of a whole retargeted motion.

    Args:
        reference: (F, Jr, 9) source features (world frame) the motion was retargeted from.
        source: the source skeleton; ``motion``: the result (world frame, same frames).
        prepared: :func:`~mer_models.retarget.long_horizon.prepare_reference` of ``reference`` for this
            target, when the caller has it (saves computing the goals again).
        geometry: the target's :class:`~mer_data.robots.collision.CollisionModel`: adds the artifact
            metrics (:func:`mer_models.retarget.artifacts.artifact_metrics`); with ``masses`` (the target's
            :class:`~mer_data.robots.inertia.MassModel`) the balance metrics too (:mod:`.balance`).

    Returns:
        metric name -> value over the whole motion (``g_mpbpe`` [m], ``mpboe`` [rad], ``mpbve`` [m/s],
        ``jerk`` [rad/s^3], ``limit_violation`` [fraction of frames]; ``gt_*`` are NaN).
    """
    from mer_data.motion.samples import TrainingSample, collate

    from .metrics import window_metrics

    tgt = motion.skeleton
    feats, scaled, shift, (goal_rot, rot_mask) = prepared or prepare_reference(reference, source, tgt)
    batch = collate([TrainingSample(feats[:4].astype(np.float32), source, tgt, joint_map(tgt, source))])  # the graphs
    batch["reference"] = torch.from_numpy(feats.astype(np.float32))[None]
    batch["ref_scaled_pos"] = torch.from_numpy(scaled)[None]
    batch["ref_goal_rot"] = torch.from_numpy(goal_rot)[None]
    batch["ref_rot_mask"] = torch.from_numpy(rot_mask)[None]
    out = {"q": torch.from_numpy(np.asarray(motion.q))[None], "base_pos": torch.from_numpy(np.asarray(motion.base_pos) - shift)[None],
           "base_rot": torch.from_numpy(np.asarray(motion.base_rot))[None]}
    metrics: dict = {k: float(v[0]) for k, v in window_metrics(out, batch, motion.fps).items()}
    if geometry is not None:
        from .artifacts import motion_artifacts

        metrics.update(motion_artifacts(motion.q, motion.base_pos, motion.base_rot, motion.fps, tgt, geometry, reference, source,
                                        masses=masses, torques=torques))
    return metrics
