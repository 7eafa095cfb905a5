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
from typing import Callable

import numpy as np
import torch

from mer_data.jointmap import joint_map
from mer_data.samples import TrainingSample, collate, reference_goals
from mer_data.skeleton import Skeleton

from .config import EnergyConfig, SamplerConfig
from .inference import sample_conditions
from .kinematics import batch_features
from .model import RetargetModel
from .representation import normalize, transform_features

log = logging.getLogger(__name__)

__all__ = ["clip_starts", "prepare_reference", "retarget_sequence"]


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
    (:func:`mer_data.samples.reference_goals`).
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
    energy: EnergyConfig | None = None,
    fps: float = 30.0,
    steps: int | None = None,
    method: str | None = None,
    seed: int = 0,
    inpaint: bool = True,
    eta: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, np.ndarray]:
    """Retarget a whole motion with the model.

    Args:
        reference: (N, Jr, 9) features of the source motion in the world frame.
        ref, target: the two skeletons; ``eta`` defaults to :func:`mer_data.jointmap.joint_map`.
        sampler: steps, noise schedule, guidance and ``overlap``.
        inpaint: False concatenates independently sampled clips (for comparison only).

    Returns:
        ``q`` (N, Jt) [rad], ``base_pos`` (N, 3) [m], ``base_rot`` (N, 3, 3), world frame, float64.
    """
    frames = model.cfg.frames
    overlap = sampler.overlap
    n = reference.shape[0]
    if n < 1:
        raise ValueError("the motion has no frames")
    eta = joint_map(target, ref) if eta is None else eta
    feats, scaled, shift, _ = prepare_reference(reference, ref, target)
    pad = max(0, frames - n)
    if pad:
        feats = np.concatenate([feats, np.repeat(feats[-1:], pad, 0)])
        feats[n:, 0, 6:9] = 0
        feats[n:, 1:, 4:7] = 0
        scaled = np.concatenate([scaled, np.repeat(scaled[-1:], pad, 0)])
    total = feats.shape[0]
    starts = clip_starts(total, frames, overlap)
    dev = next(model.parameters()).device
    gen = torch.Generator(device=dev).manual_seed(seed)
    Jt = target.num_nodes
    q = np.zeros((total, Jt))
    base_pos = np.zeros((total, 3))
    base_rot = np.zeros((total, 3, 3))
    done = 0  # frames [0, done) are final
    for k, s in enumerate(starts):
        batch = _window_batch(feats[s : s + frames], scaled[s : s + frames], ref, target, eta)
        cond = model.conditions(batch, fps)
        known = done - s if (inpaint and k > 0) else 0
        wrapper = None
        if known > 0:
            g = cond.tgt_graph
            prev = batch_features(
                g,
                torch.from_numpy(q[s:done]).float()[None].to(dev),
                torch.from_numpy(base_pos[s:done]).float()[None].to(dev),
                torch.from_numpy(base_rot[s:done]).float()[None].to(dev),
                fps,
            )
            prev = normalize(transform_features(prev, cond.rot, cond.origin), model.cfg) * g.mask[:, None, :, None]

            def wrapper(den, prev=prev, known=known):
                def inpainted(x, sigma, c):
                    d = den(x, sigma, c)
                    return torch.cat([prev[:, :known], d[:, known:]], 1)

                return inpainted

        d = sample_conditions(model, cond, sampler, energy=energy, method=method, steps=steps, generator=gen, denoiser_wrapper=wrapper)
        out = model.decode(d, cond)
        lo = max(done, s)
        q[lo : s + frames] = out["q"][0, lo - s :].double().cpu().numpy()
        base_pos[lo : s + frames] = out["base_pos"][0, lo - s :].double().cpu().numpy()
        base_rot[lo : s + frames] = out["base_rot"][0, lo - s :].double().cpu().numpy()
        done = s + frames
        if progress is not None:
            progress(k + 1, len(starts))
    base_pos = base_pos + shift
    return {"q": q[:n], "base_pos": base_pos[:n], "base_rot": base_rot[:n]}
