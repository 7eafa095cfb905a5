"""Synthetic motions and training samples generated in code (training, tests, demos, benchmarks).

No motion data ships with mer (LAFAN1 is CC BY-NC-ND). :func:`synthetic_motion` and
:class:`SyntheticDataset` (what ``mer train --synthetic`` and ``mer finetune --synthetic`` train on)
cut windows out of :func:`mer_data.synthesis.synthesize`: the whole-body generator behind
``mer shards build --synthetic`` (postures down to lying, falls and getting up, travel up to
sprinting, jumps). :func:`sinusoid_motion` is a gentle upright sinusoid (base tilt <= 0.094 rad,
base at standing height, 0.3-0.8 m/s) for tests that need an easy motion, not for training.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mer_data.kinematics.fk import skeleton_tensors
from mer_data.kinematics.jointmap import joint_map
from mer_data.kinematics.rotations import axis_angle_to_quat
from mer_data.motion.features import motion_features
from mer_data.motion.samples import TrainingSample
from mer_data.robots.registry import get_skeleton
from mer_data.skeleton import Skeleton
from mer_data.synthesis import synthesize

__all__ = ["synthetic_motion", "sinusoid_motion", "standing_height", "SyntheticDataset", "LEAD_IN_S"]

#: A window starts anywhere in the first ``LEAD_IN_S`` seconds of its generated clip [s] (a clip
#: begins in a drawn posture, so windows that start later catch transitions, falls and sprints).
LEAD_IN_S = 10.0


def standing_height(skel: Skeleton) -> float:
    """Base height [m] that puts the lowest node of the zero pose on the ground (z = 0)."""
    return float(max(-skel.rest_positions[:, 2].min(), 0.05))


def synthetic_motion(skel: Skeleton, frames: int, fps: float = 30.0, seed: int = 0) -> dict[str, np.ndarray]:
    """A seeded window of whole-body synthetic motion (:func:`mer_data.synthesis.synthesize`).

    The window starts 0..``LEAD_IN_S`` seconds (drawn from ``seed``) into a clip generated for it, so
    it may hold any posture, transition, fall, sprint or jump; joints never pass their limits and the
    lowest node is on the ground outside jumps. Same seed, same arrays.

    Returns ``base_pos`` (T, 3) [m], ``base_quat`` (T, 4) wxyz, ``q`` (T, J) [rad] (0 for base, sites
    and mimic joints), all float64, T = ``frames``.
    """
    if frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    lead = int(np.random.default_rng([int(seed), 0]).integers(0, int(LEAD_IN_S * fps) + 1))
    n = max(lead + frames - 1, 1)  # the clip has n + 1 frames
    motion = synthesize(skel, n / fps, fps, seed=[int(seed), 1]).motion
    w = slice(lead, lead + frames)
    return {
        "base_pos": motion.base_pos[w].copy(),
        "base_quat": motion.base_quat[w].copy(),
        "q": motion.node_angles(skel)[w].copy(),
    }


def sinusoid_motion(skel: Skeleton, frames: int, fps: float = 30.0, seed: int = 0) -> dict[str, np.ndarray]:
    """A gentle seeded motion inside the joint limits (for tests that need an easy, upright motion).

    Returns ``base_pos`` (T, 3) [m], ``base_quat`` (T, 4) wxyz, ``q`` (T, J) [rad] (0 for base/sites),
    all float64. Joints swing sinusoidally about their nominal angle within the middle 60 % of their
    range; the base walks forward at 0.3-0.8 m/s at standing height while turning slowly and bobbing
    (roll <= 0.05, pitch <= 0.08 rad). Not training data: it covers none of the base states people reach.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    J = skel.num_nodes
    q = np.zeros((frames, J))
    for j in np.flatnonzero(skel.dof_mask):
        lo, hi = skel.lower[j], skel.upper[j]
        span = hi - lo
        center = float(np.clip(skel.nominal[j], lo + 0.2 * span, hi - 0.2 * span))
        amp = rng.uniform(0.05, 0.3) * span
        f = rng.uniform(0.3, 1.2)
        phase = rng.uniform(0, 2 * math.pi)
        q[:, j] = np.clip(center + amp * np.sin(2 * math.pi * f * t + phase), lo + 0.1 * span, hi - 0.1 * span)
    yaw0 = rng.uniform(-math.pi, math.pi)
    yaw = yaw0 + rng.uniform(-0.6, 0.6) * t
    speed = rng.uniform(0.3, 0.8)
    step = speed / fps
    xy = np.cumsum(np.stack([np.cos(yaw), np.sin(yaw)], -1) * step, axis=0) + rng.uniform(-2, 2, size=2)
    z = standing_height(skel) + 0.02 * np.sin(2 * math.pi * 1.5 * t)
    roll = 0.05 * np.sin(2 * math.pi * 0.7 * t + rng.uniform(0, 6))
    pitch = 0.08 * np.sin(2 * math.pi * 0.5 * t + rng.uniform(0, 6))
    rotvec = np.stack([roll, pitch, yaw], -1)  # small roll/pitch: close enough to a z-y-x composition
    quat = axis_angle_to_quat(torch.from_numpy(rotvec)).numpy()
    return {"base_pos": np.concatenate([xy, z[:, None]], -1), "base_quat": quat, "q": q}


def _features(skel: Skeleton, motion: dict[str, np.ndarray], fps: float) -> np.ndarray:
    st = skeleton_tensors(skel, torch.float64)
    f = motion_features(
        st,
        torch.from_numpy(motion["base_pos"]),
        torch.from_numpy(motion["base_quat"]),
        torch.from_numpy(motion["q"]),
        fps,
    )
    return f.numpy()


def _origin_normalize(feats: np.ndarray) -> np.ndarray:
    out = feats.copy()
    o = feats[0, 0, 3:5].copy()
    out[:, 0, 3:5] -= o
    out[:, 1:, 1:3] -= o
    return out


class SyntheticDataset(torch.utils.data.Dataset):
    """Seeded :class:`~mer_data.motion.samples.TrainingSample` windows of synthetic motion
    (:func:`synthetic_motion`: the whole-body generator of :mod:`mer_data.synthesis`).

    Sample ``i`` retargets a synthetic window of ``source`` to ``targets[i % len(targets)]``. The
    target carries motion data (``target`` features) only when it is the source robot itself and
    unaugmented, as with real data where only some robots have motion. With ``augment`` the target
    skeleton's links are scaled by factors in [0.67, 1.5] (never for the source-as-target samples).

    Windows are origin-normalized (first base x, y at 0), as the shards' are.
    """

    def __init__(
        self,
        source: str = "g1",
        targets: tuple[str, ...] = ("g1", "h1"),
        size: int = 64,
        frames: int = 60,
        fps: float = 30.0,
        seed: int = 0,
        augment: bool = False,
    ) -> None:
        self.source = get_skeleton(source)
        self.targets = [get_skeleton(t) for t in targets]
        self.size, self.frames, self.fps, self.seed, self.augment = size, frames, fps, seed, augment

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, i: int) -> TrainingSample:
        if not 0 <= i < self.size:
            raise IndexError(i)
        rng = np.random.default_rng([self.seed, i])
        tgt = self.targets[i % len(self.targets)]
        motion = synthetic_motion(self.source, self.frames, self.fps, seed=int(rng.integers(1 << 31)))
        ref = _origin_normalize(_features(self.source, motion, self.fps)).astype(np.float32)
        same = tgt.name == self.source.name
        if self.augment and not same:
            tgt = tgt.with_link_scales(np.exp(rng.uniform(math.log(0.67), math.log(1.5), tgt.num_nodes)))
        return TrainingSample(
            reference=ref,
            reference_skeleton=self.source,
            target_skeleton=tgt,
            joint_map=joint_map(tgt, self.source),
            target=ref.copy() if same else None,
            provenance={
                "robot": self.source.name,
                "clip": f"synthetic-{self.seed}",
                "start": i,
                "target": tgt.name,
                "augmentation": int(self.augment and not same),
            },
        )
