"""The configuration of a training run and of the whole checkpoint (frozen, validated): the training
(:class:`TrainConfig`), the warm start (:class:`WarmConfig`), the run (:class:`RunConfig`: the model,
its energy, its sampler, the training and the kind), the presets and :func:`from_dict`.

Every checkpoint stores a :class:`RunConfig` as JSON (``config.json``); :func:`from_dict` refuses
unknown or missing fields by name, so a checkpoint written by other code fails loudly instead of
loading half-right. The model, energy and sampler sections are :mod:`mer_models.config`'s.

Presets (:data:`PRESETS`):

* ``paper``: the paper's configuration (H = 240, 4 layers per decoder, 6 heads, FFN 1024,
  batch 16, ``T_w`` = 31, 60-frame windows).
* ``tiny``: the same architecture, small enough to train on 2 CPU cores in minutes (tests, CPU experiments).
* ``base``: between the two, the configuration of ``mer-base`` (docs/model.md).
* ``warm``: the warm-start model (:mod:`mer_models.warm`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping

from mer_data.base.errors import ConfigError
from mer_models.config import LEGACY_FIELDS, EnergyConfig, ModelConfig, SamplerConfig, _check, _check_finite, read_section

__all__ = ["TrainConfig", "WarmConfig", "RunConfig", "KINDS", "PRESETS", "preset", "from_dict"]


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation.

    Attributes:
        batch_size: samples per step (summed over DDP ranks: each rank takes ``batch_size / world``).
        lr, weight_decay, warmup, grad_clip: AdamW with linear warm-up, then constant, or (when
            ``lr_decay_steps`` > 0) a cosine decay from ``lr`` to ``lr * lr_min_ratio`` over that many
            steps after the warm-up, constant after (``mer-base``'s curve was flat at a constant rate).
        p_mean, p_std: EDM training noise ``ln sigma ~ N(p_mean, p_std^2)``. Default N(0, 1.5^2): the
            coverage of the 1000-step cosine-schedule DDPM the paper's lineage trains with (EDM's
            image default N(-1.2, 1.2^2) leaves the high-noise regime, where retargeting is decided,
            almost untrained; docs/model.md).
        start_frac: share of every batch trained at the sampler's own starting point instead of a
            noise level drawn from ``N(p_mean, p_std^2)``: ``sigma = sigma_max`` and the sampler's
            initial state (the goals plus ``init_noise * sigma_max`` noise for a ``goal_prior``
            network). A one-step sampler only ever evaluates the network there (docs/model.md).
        feedback_frac: share of every batch trained where the ``feedback`` sampler's second
            evaluation runs: the input is the network's own (gradient-free) estimate from the
            sampler's start, made kinematically consistent, at ``sigma = sampler.feedback_sigma``;
            the network learns to correct its own errors (docs/model.md). These samples follow the
            ``start_frac`` ones; ``start_frac + feedback_frac <= 1``.
        ref_group: samples per reference window in a batch (1: every sample drawn on its own).
            With ``k`` > 1 a batch holds ``batch_size / k`` windows, each with ``k`` of its targets and
            augmentations, and the reference encoder runs once per window (its output does not depend
            on the target): a step costs less, a batch holds fewer distinct motions (docs/model.md).
            Needs a dataset that knows its windows (:class:`mer_data.shards.ShardDataset`).
        opt_iters: refinement iterations of the optimisation baseline when it supplies ``x`` for a
            target without motion data (see docs/model.md).
        ema: decay of an exponential moving average of the weights (0: none). Each step
            ``avg <- d avg + (1 - d) theta`` with ``d = min(ema, (1 + step) / (10 + step))``; a
            checkpoint's ``model.safetensors`` then holds the average (what inference loads) and the
            optimiser file the trained weights (what resume continues). Off in every preset: not yet
            measured on ``mer-base`` (docs/model.md §Training).
        seed: seeds noise, data order and initialisation.
        log_every, save_every: in steps.
    """

    batch_size: int = 16
    lr: float = 2e-4
    weight_decay: float = 0.0
    warmup: int = 200
    lr_decay_steps: int = 0
    lr_min_ratio: float = 0.1
    grad_clip: float = 1.0
    p_mean: float = 0.0
    p_std: float = 1.5
    start_frac: float = 0.0
    feedback_frac: float = 0.0
    ref_group: int = 1
    opt_iters: int = 20
    ema: float = 0.0
    seed: int = 0
    log_every: int = 10
    save_every: int = 500

    def __post_init__(self) -> None:
        c = "TrainConfig"
        for name in ("batch_size", "log_every", "save_every"):
            _check(isinstance(getattr(self, name), int) and getattr(self, name) >= 1, c, name, "must be an integer >= 1")
        _check(self.lr > 0, c, "lr", "must be > 0")
        _check(self.p_std > 0, c, "p_std", "must be > 0")
        _check(0.0 <= self.start_frac <= 1.0, c, "start_frac", f"start_frac={self.start_frac} must be in [0, 1]")
        _check(0.0 <= self.feedback_frac <= 1.0 - self.start_frac, c, "feedback_frac",
               f"feedback_frac={self.feedback_frac} must be in [0, 1 - start_frac = {1 - self.start_frac:g}]")
        _check(isinstance(self.warmup, int) and self.warmup >= 0, c, "warmup", "must be an integer >= 0")
        _check(isinstance(self.lr_decay_steps, int) and self.lr_decay_steps >= 0, c, "lr_decay_steps", "must be an integer >= 0")
        _check(0.0 <= self.lr_min_ratio <= 1.0, c, "lr_min_ratio", "must be in [0, 1]")
        _check(0.0 <= self.ema < 1.0, c, "ema", f"ema={self.ema} must be in [0, 1) (0: no average; e.g. 0.999)")
        _check(isinstance(self.opt_iters, int) and self.opt_iters >= 0, c, "opt_iters", "must be an integer >= 0")
        _check(isinstance(self.ref_group, int) and self.ref_group >= 1, c, "ref_group", "must be an integer >= 1")
        _check(self.batch_size % self.ref_group == 0, c, "ref_group",
               f"batch_size {self.batch_size} is not a multiple of ref_group {self.ref_group}")
        _check_finite(self)


#: Model kinds: ``diffusion`` (:mod:`mer_models.diffusion`, the paper's model) and ``warm`` (:mod:`mer_models.warm`).
KINDS = ("diffusion", "warm")


@dataclass(frozen=True)
class WarmConfig:
    """The warm-start network (:mod:`mer_models.warm`): one token per target node and frame, a few
    spatial-attention layers with relation codes, a short temporal convolution; its output is
    finished by ``refine`` whole-window Levenberg-Marquardt iterations (docs/model.md, The warm start).

    Attributes:
        hidden: token width.
        layers: spatial-attention + temporal-convolution + feed-forward layers.
        heads: attention heads (``hidden`` divisible by it).
        ffn: feed-forward width.
        kernel: frames of each depthwise temporal convolution (odd; the receptive field is
            ``layers * (kernel - 1) + 1`` frames).
        vel_scale: [m/s] goal velocities are divided by this.
        stride: the network runs on every ``stride``-th frame (and the last); its outputs are
            interpolated linearly in between (the optimiser's key-frame idea: ``stride`` times fewer
            tokens; the refinement finishes the frames in between).
        refine: whole-window LM iterations after the network (the default of ``--refine``).
        w_q: weight of the angle regression on the teacher's solution [1/rad^2].
        w_fk: weight of the body-position regression (FK of the output vs FK of the teacher) [1/m^2].
        w_rot: weight of the base orientation regression (chordal, vs the teacher's).
        w_pos: weight of the base position regression [1/m^2].
        w_energy: weight of the teacher's energy ``f_kin`` of the output.
        crop: frames of the random crop of each training window (0: the whole window).
    """

    hidden: int = 64
    layers: int = 3
    heads: int = 4
    ffn: int = 128
    kernel: int = 5
    vel_scale: float = 2.0
    stride: int = 1
    refine: int = 2
    w_q: float = 1.0
    w_fk: float = 100.0
    w_rot: float = 1.0
    w_pos: float = 100.0
    w_energy: float = 1.0
    crop: int = 0

    def __post_init__(self) -> None:
        c = "WarmConfig"
        for name in ("hidden", "layers", "heads", "ffn", "kernel"):
            _check(isinstance(getattr(self, name), int) and getattr(self, name) > 0, c, name, "must be a positive integer")
        _check(self.hidden % self.heads == 0, c, "hidden", f"hidden={self.hidden} is not divisible by heads={self.heads}")
        _check(self.kernel % 2 == 1, c, "kernel", f"kernel={self.kernel} must be odd")
        _check(isinstance(self.refine, int) and self.refine >= 0, c, "refine", "must be an integer >= 0")
        _check(isinstance(self.stride, int) and 1 <= self.stride <= 8, c, "stride", "must be an integer in 1..8")
        _check(isinstance(self.crop, int) and self.crop >= 0, c, "crop", "must be an integer >= 0")
        _check(self.vel_scale > 0, c, "vel_scale", "must be > 0")
        for name in ("w_q", "w_fk", "w_rot", "w_pos", "w_energy"):
            _check(getattr(self, name) >= 0, c, name, "must be >= 0")
        _check_finite(self)
        _check(self.hidden <= 4096 and self.layers <= 64 and self.ffn <= 16384, c, "hidden", "is absurdly large")


@dataclass(frozen=True)
class RunConfig:
    """Everything a checkpoint needs to rebuild and resume its model."""

    name: str = "paper"
    kind: str = "diffusion"
    model: ModelConfig = field(default_factory=ModelConfig)
    energy: EnergyConfig = field(default_factory=EnergyConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    warm: WarmConfig = field(default_factory=WarmConfig)

    def __post_init__(self) -> None:
        _check(self.kind in KINDS, "RunConfig", "kind", f"kind={self.kind!r} is not one of {', '.join(KINDS)}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def replace(self, **sections: Any) -> "RunConfig":
        return dataclasses.replace(self, **sections)


PRESETS: dict[str, RunConfig] = {
    "paper": RunConfig(name="paper", model=ModelConfig(split_encoding=True, goal_frame_rotation=True)),
    "tiny": RunConfig(
        name="tiny",
        model=ModelConfig(hidden=48, layers=2, heads=4, cross_heads_per_condition=1, ffn=96, dropout=0.0),
        train=TrainConfig(batch_size=8, lr=1e-3, warmup=100, opt_iters=6, save_every=100),
    ),
    "base": RunConfig(
        name="base",
        model=ModelConfig(
            hidden=96,
            layers=2,
            heads=4,
            cross_heads_per_condition=1,
            ffn=256,
            dropout=0.0,
            goal_input=True,
            goal_prior=True,
            split_encoding=True,
            goal_frame_rotation=True,
        ),
        sampler=SamplerConfig(steps=1, method="euler", init_noise=0.0),
        train=TrainConfig(batch_size=16, lr=7e-4, warmup=100, save_every=200, p_mean=2.0, start_frac=0.5),
    ),
    # the warm-start model (mer_models.warm): a second kind, trained by mer_models.training.warm
    "warm": RunConfig(
        name="warm",
        kind="warm",
        warm=WarmConfig(hidden=48, layers=3, heads=4, ffn=96, stride=2, crop=20),
        train=TrainConfig(batch_size=64, lr=3e-3, warmup=50, lr_decay_steps=3000, lr_min_ratio=0.02, save_every=100, opt_iters=6),
    ),
}


def preset(name: str) -> RunConfig:
    """A preset by name (``tiny``, ``base``, ``paper``, or ``warm``: the warm-start model)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ConfigError(
            f"unknown configuration {name!r}; known: {', '.join(PRESETS)}", fix=f"use --config {' | '.join(PRESETS)}"
        ) from None


_SECTIONS = {"model": ModelConfig, "energy": EnergyConfig, "sampler": SamplerConfig, "train": TrainConfig, "warm": WarmConfig}
#: Sections and top-level fields added later: a checkpoint without them loads with these.
_OPTIONAL: dict[str, Any] = {"kind": "diffusion", "warm": None}
#: Fields added after checkpoints were first written, with the value that reproduces the older
#: behaviour: a checkpoint without them loads with that value (and nothing else may be missing).
_LEGACY = {**LEGACY_FIELDS, TrainConfig: {"lr_decay_steps": 0, "lr_min_ratio": 0.1, "start_frac": 0.0, "feedback_frac": 0.0,
                                          "ref_group": 1, "ema": 0.0}}  # fmt: skip


def from_dict(data: Mapping[str, Any]) -> RunConfig:
    """Rebuild a :class:`RunConfig` from :meth:`RunConfig.to_dict`, strictly (unknown/missing → error)."""
    if not isinstance(data, Mapping):
        raise ConfigError("the run configuration must be a JSON object")
    data = {**_OPTIONAL, **data}
    if data["warm"] is None:  # written before the warm kind existed: a diffusion checkpoint
        data["warm"] = dataclasses.asdict(WarmConfig())
    known = {"name", "kind", *_SECTIONS}
    unknown = sorted(set(data) - known)
    missing = sorted(known - set(data))
    if unknown or missing:
        bad = (unknown or missing)[0]
        raise ConfigError(
            ("unknown" if unknown else "missing") + f" configuration section(s): {', '.join(unknown or missing)}",
            element=bad,
            fix="the checkpoint was written by another version of mer; convert it or retrain",
        )
    if not isinstance(data["name"], str):
        raise ConfigError("name must be a string", element="name")
    if data["kind"] not in KINDS:
        raise ConfigError(f"kind {data['kind']!r} is not one of {', '.join(KINDS)}", element="kind",
                          fix="load it with the mer version that wrote it")  # fmt: skip
    run = RunConfig(name=data["name"], kind=data["kind"], **{k: read_section(cls, data[k], k, _LEGACY) for k, cls in _SECTIONS.items()})
    run.model.check_size()
    return run
