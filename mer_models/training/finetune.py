"""Fine-tuning to a new robot (paper, unseen embodiments): add its skeleton to the training targets
and continue training from a base model's weights.

The model is conditioned on the skeleton graph, so every weight carries over: nothing is added or
re-initialised. The base is resolved through the zoo (a zoo name, a checkpoint folder or a Hub id
``ORG/NAME``, verified as :func:`mer_models.zoo.resolve` verifies it), its configuration is kept
(``--batch-size``, ``--lr``, ``--seed`` may override the training section), the optimiser starts
fresh (with the configuration's warm-up), and step counting starts at 0.

Data: the reference windows of ``--shards`` (or of ``--synthetic`` motion) are used twice over:
as they are (the targets the base already knows, so it does not forget them) and, for a fraction
``new_fraction`` of the samples, retargeted to the new robot. The new robot needs no motion data of
its own: as for every target without data, the trainer's clean sample is the optimisation
baseline's solution on that window, computed on the fly (docs/model.md).

Both model kinds fine-tune alike: a diffusion base (``run.kind`` ``diffusion``) through the EDM
trainer, a warm-start base (``warm``, :mod:`mer_models.warm`) through its own loop, which solves the
samples without a teacher with ``run.train.opt_iters`` LM iterations. A warm base's ``--synthetic``
windows are ``WarmConfig.crop`` frames long (what its trainer crops every window to anyway, so no
solved frame is thrown away), a diffusion base's ``ModelConfig.frames``. Where the base's learning
rate decays (``lr_decay_steps`` > 0), the decay is spread over the fine-tune's own ``steps`` (after
the base's warm-up), so a short fine-tune ends at the base's final rate instead of running at its peak.

The checkpoint records the base (zoo name, repository, pinned revision, sha256 of its weights, and
the base's own data description, so the licence of LAFAN1-derived weights carries over) under
``data``; ``mer zoo publish`` and the card renderer read it back ("fine-tuned from ...").
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch

from mer_data.base.errors import MerError
from mer_data.kinematics.jointmap import joint_map
from mer_data.motion.samples import TrainingSample
from mer_data.robots.registry import get_skeleton, load_robot
from mer_data.skeleton import Skeleton
from mer_models.config import RunConfig
from mer_models.hub.checkpoint_files import CONFIG, WEIGHTS
from mer_models.zoo.checkpoint import load_checkpoint

from .train import TrainResult, train

log = logging.getLogger(__name__)

__all__ = ["WithNewTarget", "finetune", "base_record", "window_frames"]


class WithNewTarget(torch.utils.data.Dataset):
    """The samples of ``base``; a seeded fraction of them re-targeted to ``robot``.

    Sample ``i`` is ``base[i]`` unchanged, or, with probability ``fraction`` (drawn from
    (``seed``, ``i``), so the set is a pure function of the index), the same reference window with
    ``robot`` as its target: the joint map is recomputed, and the target motion is None (the
    trainer fills it with the optimisation baseline) unless ``robot`` is the reference robot itself.
    """

    def __init__(self, base: torch.utils.data.Dataset, robot: Skeleton, fraction: float = 0.5, seed: int = 0) -> None:
        if not 0.0 < fraction <= 1.0:
            raise MerError(f"the fraction of new-robot samples is {fraction}, it must be in (0, 1]", element="fraction")
        self.base, self.robot, self.fraction, self.seed = base, robot, float(fraction), int(seed)
        self._maps: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.base)

    def is_new(self, i: int) -> bool:
        return bool(np.random.default_rng([self.seed, 7919, i]).random() < self.fraction)

    def __getitem__(self, i: int) -> TrainingSample:
        s = self.base[i]
        if not self.is_new(i):
            return s
        ref = s.reference_skeleton
        if ref.fingerprint not in self._maps:
            self._maps[ref.fingerprint] = joint_map(self.robot, ref)
        same = ref.name == self.robot.name and ref.fingerprint == self.robot.fingerprint
        return TrainingSample(
            reference=s.reference,
            reference_skeleton=ref,
            target_skeleton=self.robot,
            joint_map=self._maps[ref.fingerprint],
            target=s.reference.copy() if same else None,
            provenance={**s.provenance, "target": self.robot.name, "augmentation": 0, "finetune": 1},
        )


def base_record(spec: str | Path, revision: str | None = None) -> tuple[Path, dict[str, Any]]:
    """Resolve the base through the zoo: its verified folder and what the fine-tune records of it."""
    from mer_models.hub.integrity import sha256_file
    from mer_models.hub.resolve import resolve

    res = resolve(spec, revision)
    rec: dict[str, Any] = {
        "base_model": res.name,
        "base_repo_id": res.repo_id,
        "base_revision": res.revision,
        "base_source": res.source,
        "base_sha256": sha256_file(res.folder / WEIGHTS),
    }
    if res.source == "local":
        rec["base_checkpoint"] = str(res.folder.resolve())
    return res.folder, {k: v for k, v in rec.items() if v is not None}


def window_frames(run: RunConfig) -> int:
    """Frames of the ``--synthetic`` windows: a warm base's training crop (``WarmConfig.crop``, its
    trainer would cut every longer window to it after solving all of it), else ``ModelConfig.frames``."""
    if run.kind == "warm" and run.warm.crop > 0:
        return run.warm.crop
    return run.model.frames


def _decay_steps(run: RunConfig, steps: int, out: Path, resume: bool) -> int:
    """The fine-tune's ``lr_decay_steps``: 0 (constant rate) where the base has none; on ``--resume``,
    what the fine-tune recorded (so a resumed run may ask for more ``--steps``); else the fine-tune's
    steps after the warm-up."""
    if run.train.lr_decay_steps <= 0:
        return 0
    if resume and (out / CONFIG).is_file():
        from mer_models.hub.checkpoint_files import read_meta

        try:
            return int(read_meta(out)["run"]["train"]["lr_decay_steps"])
        except (KeyError, TypeError, ValueError):
            pass  # an odd record: train() names the difference when it compares the configurations
    return max(1, steps - run.train.warmup)


def _check_pairs(robot: Skeleton, references: Sequence[Skeleton]) -> None:
    for ref in references:
        eta = joint_map(robot, ref)
        if int(eta.sum()) <= 1:  # the base pair only
            raise MerError(
                f"robot {robot.name!r} shares no key point with the reference robot {ref.name!r}: nothing to retarget to",
                element=robot.name,
                fix=f"check its key points (`mer robots show {robot.name}`) and register it again with --keypoints FILE --force",
            )


def finetune(
    base: str | Path,
    robot: str,
    out: str | Path,
    *,
    shards: Sequence[str | Path] | None = None,
    synthetic: int | None = None,
    steps: int = 200,
    source: str = "g1",
    split: str = "train",
    new_fraction: float = 0.5,
    revision: str | None = None,
    resume: bool = False,
    device: str = "cpu",
    batch_size: int | None = None,
    lr: float | None = None,
    seed: int | None = None,
    log_every: int | None = None,
    save_every: int | None = None,
    progress: Callable[[dict], None] | None = None,
) -> TrainResult:
    """Fine-tune ``base`` for ``robot`` on ``shards`` (or ``synthetic`` windows of ``source``) into ``out``.

    Errors (each a :class:`~mer_data.base.errors.MerError` with a fix): an unknown robot, a base that
    is unknown or not available (unpublished, not cached offline), shards with no windows in
    ``split``, a robot that shares no key point with the data's reference robots.
    """
    if (shards is None) == (synthetic is None):
        raise MerError("give either shards or a number of synthetic windows", fix="pass --shards DIR or --synthetic N")
    if steps < 1:
        raise MerError(f"--steps is {steps}, it must be >= 1")
    skel = load_robot(robot).skeleton  # resolved once; unknown: UnknownRobotError listing the known ones
    folder, record = base_record(base, revision)
    ckpt = load_checkpoint(folder)
    run = ckpt.run
    over = {k: v for k, v in {"batch_size": batch_size, "lr": lr, "seed": seed, "log_every": log_every,
                               "save_every": save_every}.items() if v is not None}  # fmt: skip
    # the fine-tune mixes the base's targets with the new robot sample by sample: no batches grouped by
    # reference window (the base may have trained with them; a training-speed option, not the model's)
    over["ref_group"] = 1
    run = run.replace(train=dataclasses.replace(run.train, **over))
    run = run.replace(train=dataclasses.replace(run.train, lr_decay_steps=_decay_steps(run, steps, Path(out), resume)))
    if robot in ckpt.robots.get("targets", {}):
        log.warning("the base already has %r among its targets; training continues on it", robot)
    record["base_step"] = ckpt.step
    record["base_data"] = dict(ckpt.data)
    if shards is not None:
        from mer_data.shards import ShardDataset

        data = ShardDataset(list(shards), split=None if split == "all" else split)
        if len(data) == 0:
            raise MerError(f"the shards hold no {split!r} windows", path=str(shards[0]),
                           fix="build them with a training split (mer shards build --split paper|all) or pass --split all")  # fmt: skip
        refs = {name: get_skeleton(name) for name in sorted({w.robot for w in data.windows})}
        info: dict[str, Any] = {"shards": [str(p) for p in data.paths], "split": split, "samples": len(data)}
    else:
        from .synthetic import SyntheticDataset

        if synthetic < run.train.batch_size:
            raise MerError(f"--synthetic {synthetic} is fewer than one batch of {run.train.batch_size}", fix="pass a larger N")
        known = [t for t in ckpt.targets if t != robot]
        usable = []
        for t in known:
            try:
                get_skeleton(t)
                usable.append(t)
            except MerError:
                log.warning("the base's target %r is not registered here; it is left out of the replayed data", t)
        frames = window_frames(run)
        data = SyntheticDataset(source, tuple(usable or [source]), size=synthetic, frames=frames, augment=True,
                                seed=run.train.seed)  # fmt: skip
        refs = {source: get_skeleton(source)}
        info = {"synthetic": synthetic, "source": source, "targets": [*usable, robot], "samples": synthetic, "frames": frames}
    _check_pairs(skel, list(refs.values()))
    dataset = WithNewTarget(data, skel, new_fraction, run.train.seed)
    info.update({"finetune_robot": robot, "finetune_fraction": new_fraction, **record})
    known_robots = {side: dict(v) for side, v in ckpt.robots.items()}
    known_robots.setdefault("targets", {})[robot] = skel.fingerprint  # a fraction of every epoch targets it
    log.info("fine-tuning %s for %r: %d samples, %.0f%% retargeted to it", record.get("base_model") or folder, robot,
             len(dataset), 100 * new_fraction)  # fmt: skip
    return train(run, dataset, out, steps=steps, resume=resume, device=device, data_info=info, progress=progress,
                 init=None if resume else folder / WEIGHTS, known_robots=known_robots)  # fmt: skip
