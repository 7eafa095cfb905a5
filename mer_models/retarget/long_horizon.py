"""Long-horizon retargeting (paper, Long-Horizon Motion Inference): any length, in model-sized clips.

The input is cut into clips of ``frames`` (60) frames that overlap by ``overlap`` frames. Clip k+1
starts ``frames - overlap`` frames after clip k; the last clip is aligned with the end of the
motion (its overlap is then larger). While clip k+1 is sampled, its first ``overlap`` frames are
*in-painted*: at every denoising step the known part of the x0-prediction is overwritten with the
frames clip k produced there (AnyTop's scheme), so the new frames are generated to continue them.
The output keeps clip k's frames in the overlap, so consecutive clips join without a seam.

A motion shorter than one clip is padded by holding its last frame, and trimmed afterwards.

Everything happens in the frame of the whole motion: its first base position is moved to the
origin, the reference is body-part scaled once for the whole motion, each clip is sampled in its
own canonical frame and mapped back, and the original position is restored at the end.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

import numpy as np
import torch

from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample, collate, reference_goals
from mer_data.skeleton import Skeleton
from mer_models.batch import batch_features
from mer_models.config import EnergyConfig, SamplerConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.diffusion.precision import network_autocast
from mer_models.diffusion.representation import transform_features

from .inference import sample_conditions

log = logging.getLogger(__name__)

__all__ = ["clip_starts", "prepare_reference", "retarget_sequence", "retarget_sequences"]


def clip_starts(n: int, frames: int, overlap: int) -> list[int]:
    """Start frames of the clips covering ``n`` frames (every frame is in at least one clip)."""
    if overlap >= frames:
        raise ValueError(f"overlap ({overlap}) must be smaller than the clip length ({frames})")
    if n <= frames:
        return [0]
    stride = frames - overlap
    starts = list(range(0, n - frames + 1, stride))
    if starts[-1] + frames < n:
        starts.append(n - frames)
    return starts


def _positions(feats: np.ndarray) -> np.ndarray:
    return np.concatenate([feats[:, :1, 3:6], feats[:, 1:, 1:4]], axis=1)


def prepare_reference(
    reference: np.ndarray, ref: Skeleton, target: Skeleton
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Move a whole motion's features (N, Jr, 9) so its first base x, y is at the origin.

    Returns the shifted features, the node positions scaled to the target (N, Jr, 3), the shift
    (3,) that was subtracted, and the orientation goals ((N, Jr, 3, 3), mask (Jr,))
    (:func:`mer_data.motion.samples.reference_goals`).
    """
    feats = np.asarray(reference, np.float64).copy()
    shift = np.array([feats[0, 0, 3], feats[0, 0, 4], 0.0])
    feats[:, 0, 3:6] -= shift
    feats[:, 1:, 1:4] -= shift
    scaled, goal_rot, rot_mask = reference_goals(feats, ref, target)
    return feats, scaled, shift, (goal_rot, rot_mask)


def _window_batch(ref_feats: np.ndarray, scaled: np.ndarray, ref: Skeleton, target: Skeleton, eta: np.ndarray) -> dict:
    sample = TrainingSample(ref_feats.astype(np.float32), ref, target, eta)
    batch = collate([sample])
    batch["ref_scaled_pos"] = torch.from_numpy(scaled.astype(np.float32))[None]
    return batch


def retarget_sequence(
    model: RetargetModel,
    reference: np.ndarray,
    ref: Skeleton,
    target: Skeleton,
    sampler: SamplerConfig,
    *,
    eta: np.ndarray | None = None,
    **kw,
) -> dict[str, np.ndarray]:
    """Retarget a whole motion with the model to one target (:func:`retarget_sequences`)."""
    return retarget_sequences(model, reference, ref, [target], sampler, etas=None if eta is None else [eta], **kw)[0]


def retarget_sequences(
    model: RetargetModel,
    reference: np.ndarray,
    ref: Skeleton,
    targets: Sequence[Skeleton],
    sampler: SamplerConfig,
    *,
    energy: EnergyConfig | None = None,
    fps: float = 30.0,
    steps: int | None = None,
    method: str | None = None,
    seed: int = 0,
    inpaint: bool = True,
    etas: Sequence[np.ndarray] | None = None,
    prepared: Sequence[tuple] | None = None,
    progress: Callable[[int, int], None] | None = None,
    bf16: bool = False,
) -> list[dict[str, np.ndarray]]:
    """Retarget a whole motion with the model to several targets at once.

    Window by window, the reference encoder (which does not depend on the target) runs once, and
    each target is sampled from its encoding in turn: retargeting one motion to eight robots took
    65 % of the time of eight one-target calls (``tools/bench_targets.py``, docs/model.md). A padded batch of all
    targets was measured slower than this loop on the CPU (the padding to the largest robot's
    nodes costs more than the per-call overhead it saves). Each target has its own generator
    seeded with ``seed``, so its output is a one-target call's whichever targets it shares the
    pass with.

    Args:
        reference: (N, Jr, 9) features of the source motion in the world frame.
        ref, targets: the skeletons; ``etas`` (per target) default to :func:`mer_data.kinematics.jointmap.joint_map`.
        prepared: per target, :func:`prepare_reference` of ``reference`` when the caller has it.
        sampler: steps, noise schedule, guidance and ``overlap``.
        inpaint: False concatenates independently sampled clips (for comparison only).
        progress: called with (windows done, windows) of the motion.
        bf16: the network under bfloat16 autocast (fast on AMX CPUs and accelerators, :mod:`mer_models.diffusion.precision`).

    Returns:
        Per target: ``q`` (N, Jt) [rad], ``base_pos`` (N, 3) [m], ``base_rot`` (N, 3, 3), world frame, float64.
    """
    targets = list(targets)
    if not targets:
        raise ValueError("no target robot given")
    frames = model.cfg.frames
    overlap = sampler.overlap
    n = reference.shape[0]
    if n < 1:
        raise ValueError("the motion has no frames")
    etas = [joint_map(t, ref) for t in targets] if etas is None else list(etas)
    if len(etas) != len(targets):
        raise ValueError(f"{len(etas)} joint maps for {len(targets)} targets")
    prepared = [prepare_reference(reference, ref, t) for t in targets] if prepared is None else list(prepared)
    if len(prepared) != len(targets):
        raise ValueError(f"{len(prepared)} prepared references for {len(targets)} targets")
    feats, _, shift, _ = prepared[0]  # the shifted features and the shift do not depend on the target
    scaled = [p[1] for p in prepared]
    pad = max(0, frames - n)
    if pad:
        feats = np.concatenate([feats, np.repeat(feats[-1:], pad, 0)])
        feats[n:, 0, 6:9] = 0
        feats[n:, 1:, 4:7] = 0
        scaled = [np.concatenate([s, np.repeat(s[-1:], pad, 0)]) for s in scaled]
    total = feats.shape[0]
    starts = clip_starts(total, frames, overlap)
    dev = next(model.parameters()).device
    # per target: its own generator seeded with `seed` (its noise is a one-target call's) and its motion so far
    gens = [torch.Generator(device=dev).manual_seed(seed) for _ in targets]
    q = [np.zeros((total, t.num_nodes)) for t in targets]
    base_pos = [np.zeros((total, 3)) for _ in targets]
    base_rot = [np.zeros((total, 3, 3)) for _ in targets]
    done = 0  # frames [0, done) are final
    for k, s in enumerate(starts):
        tokens = None  # the reference window's encoding, shared by every target
        known = done - s if (inpaint and k > 0) else 0
        lo = max(done, s)
        for i, t in enumerate(targets):
            batch = _window_batch(feats[s : s + frames], scaled[i][s : s + frames], ref, t, etas[i])
            cond = model.conditions(batch, fps)
            if tokens is None:
                with torch.no_grad(), network_autocast(dev, bf16):
                    tokens = model.encode(cond)
            cond.ref_tokens = tokens
            wrapper = None
            if known > 0:
                g = cond.tgt_graph
                prev = batch_features(
                    g,
                    torch.from_numpy(q[i][s:done]).float()[None].to(dev),
                    torch.from_numpy(base_pos[i][s:done]).float()[None].to(dev),
                    torch.from_numpy(base_rot[i][s:done]).float()[None].to(dev),
                    fps,
                )
                prev = model.to_sample(transform_features(prev, cond.rot, cond.origin), cond)

                def wrapper(den, prev=prev, known=known):
                    def inpainted(x, sigma, c):
                        d = den(x, sigma, c)
                        return torch.cat([prev[:, :known], d[:, known:]], 1)

                    return inpainted

            d = sample_conditions(model, cond, sampler, energy=energy, method=method, steps=steps, generator=gens[i],
                                  denoiser_wrapper=wrapper, bf16=bf16)  # fmt: skip
            out = model.decode(d, cond)
            q[i][lo : s + frames] = out["q"][0, lo - s :].double().cpu().numpy()
            base_pos[i][lo : s + frames] = out["base_pos"][0, lo - s :].double().cpu().numpy()
            base_rot[i][lo : s + frames] = out["base_rot"][0, lo - s :].double().cpu().numpy()
        done = s + frames
        if progress is not None:
            progress(k + 1, len(starts))
    return [{"q": q[i][:n], "base_pos": base_pos[i][:n] + shift, "base_rot": base_rot[i][:n]} for i in range(len(targets))]


def warm_sequences(
    model,
    reference: np.ndarray,
    ref: Skeleton,
    targets: Sequence[Skeleton],
    *,
    fps: float = 30.0,
    etas: Sequence[np.ndarray] | None = None,
    prepared: Sequence[tuple] | None = None,
    bf16: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> list[dict[str, np.ndarray]]:
    """Retarget a whole motion (N, Jr, 9) with the warm-start model (:class:`~mer_models.warm.model.WarmModel`)
    to every robot of ``targets``: one pass over the whole motion per target (the network sees a few
    frames around each, :meth:`~mer_models.warm.model.WarmModel.predict` bounds its memory), no
    windows to stitch. Returns per target ``q`` (N, Jt) [rad], ``base_pos`` (N, 3) [m] (world frame)
    and ``base_rot`` (N, 3, 3)."""
    etas = list(etas) if etas is not None else [joint_map(t, ref) for t in targets]
    prepared = list(prepared) if prepared is not None else [prepare_reference(reference, ref, t) for t in targets]
    dev = next(model.parameters()).device
    outs = []
    for i, (t, eta, (feats, scaled, shift, (goal_rot, rot_mask))) in enumerate(zip(targets, etas, prepared)):
        batch = _window_batch(feats, scaled, ref, t, eta)
        batch["ref_goal_rot"] = torch.from_numpy(goal_rot.astype(np.float32))[None]
        batch["ref_rot_mask"] = torch.from_numpy(rot_mask)[None]
        with network_autocast(dev, bf16):
            out = model.predict(batch, fps)
        outs.append({"q": out["q"][0].double().cpu().numpy(), "base_pos": out["base_pos"][0].double().cpu().numpy() + shift,
                     "base_rot": out["base_rot"][0].double().cpu().numpy()})  # fmt: skip
        if progress is not None:
            progress(i + 1, len(targets))
    return outs
