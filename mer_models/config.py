"""Configuration of the retargeting model, its energy, its sampler and its training (frozen, validated).

Every checkpoint stores these as JSON (``config.json``); :func:`from_dict` refuses unknown or
missing fields by name, so a checkpoint written by other code fails loudly instead of loading
half-right.

Presets (:data:`PRESETS`):

* ``paper``: the paper's configuration (H = 240, 4 layers per decoder, 6 heads, FFN 1024,
  batch 16, ``T_w`` = 31, 60-frame windows).
* ``tiny``: the same architecture, small enough to train on 2 CPU cores in minutes (tests, CPU experiments).
* ``base``: between the two, the configuration of ``mer-base``: trainable on a CPU in hours (on 2
  cores a step's cost is set by the number of tokens, not by the width: H = 96 costs 1.3x ``tiny``
  per sample for 6x the parameters, docs/model.md); takes the goals as input and denoises around
  them, trains mostly at high noise and samples with one deterministic step (1 network evaluation).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

from mer_data.base.errors import ConfigError
from mer_data.base.limits import limit, too_big

__all__ = [
    "ModelConfig",
    "EnergyConfig",
    "SamplerConfig",
    "TrainConfig",
    "RunConfig",
    "WarmConfig",
    "KINDS",
    "PRESETS",
    "preset",
    "from_dict",
    "ConfigError",
]


def _check(cond: bool, cls: str, name: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"{msg}", element=f"{cls}.{name}", fix="correct the value (see docs/model.md)")


def _check_finite(obj) -> None:
    """Every float field finite (an infinite scale or noise level turns every output into NaN)."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, float):
            _check(math.isfinite(v), type(obj).__name__, f.name, f"{f.name}={v} must be a finite number")


@dataclass(frozen=True)
class ModelConfig:
    """The network (paper, Network Architecture).

    Attributes:
        hidden: latent width ``H`` of every token.
        layers: layers per transformer decoder (reference encoder and denoiser each).
        heads: heads of the spatial and temporal self-attention (head width ``H / heads``).
        cross_heads_per_condition: heads given to each condition in the multi-conditional cross
            attention (3 conditions in the reference encoder, 4 in the denoiser), head width
            ``H / heads``; the concatenation is projected back to ``H``.
        ffn: hidden width of the feed-forward block.
        dropout: dropout after attention and feed-forward blocks.
        window: temporal attention window ``T_w`` (odd): frame i sees frames i-(T_w-1)/2 .. i+(T_w-1)/2.
        frames: frames per window (the clip length the model is trained and sampled on).
        sigma_data: EDM ``sigma_data`` of the normalized features.
        pos_scale: [m] positions are divided by this in the diffusion space.
        vel_scale: [m/s] velocities are divided by this in the diffusion space.
        goal_input: give every target token its scaled-reference goal (position, position relative to
            the base goal, velocity, orientation, each with a flag; :data:`mer_models.diffusion.model.GOAL_DIM`
            channels) through its own encoder, added to the token: the network then learns the
            target's inverse kinematics from goals it is told, instead of also learning the scaling
            from the reference tokens (docs/model.md). Checkpoints written before it existed load
            with ``False``.
        goal_prior: denoise around the goals (residual diffusion): ``D = P + precond(x - P)`` where
            ``P`` (:meth:`mer_models.diffusion.model.RetargetModel.goal_prior`) holds the base's goal pose and
            every node's goal position and velocity (angles 0). At high noise the output starts at
            the goals instead of at zero; at low noise ``D -> x`` as before. Checkpoints written
            before it existed load with ``False``.
        norm_first: pre-norm layers, ``x + f(LayerNorm(x))`` with a final LayerNorm per decoder,
            instead of the paper's post-norm ``LayerNorm(x + f(x))`` (default, and what checkpoints
            written before it existed load with).
        split_encoding: the frame sinusoids fill the first half of every token's channels and the
            node sinusoids the second (and the graph conditions' node sinusoids the second half too),
            instead of both being added into all channels, where (frame t, node j) and (frame j,
            node t) get the same code. No parameters. Checkpoints written before it existed load
            with ``False`` (summed).
        goal_frame_rotation: the base orientation in the diffusion space is ``delta``, the rotation
            from the base's orientation goal, ``R = R_goal Exp(delta)`` (``R_goal`` = I where the
            base has no orientation goal), instead of the rotation vector of ``R`` (minus the
            goal's rotation vector with ``goal_prior``). Training targets, samples, the energy and
            the decoding all go through it (docs/model.md). Checkpoints written before it existed
            load with ``False``.
    """

    hidden: int = 240
    layers: int = 4
    heads: int = 6
    cross_heads_per_condition: int = 2
    ffn: int = 1024
    dropout: float = 0.1
    window: int = 31
    frames: int = 60
    sigma_data: float = 0.5
    pos_scale: float = 1.0
    vel_scale: float = 2.0
    goal_input: bool = False
    goal_prior: bool = False
    norm_first: bool = False
    split_encoding: bool = False
    goal_frame_rotation: bool = False

    def __post_init__(self) -> None:
        c = "ModelConfig"
        for name in ("hidden", "layers", "heads", "cross_heads_per_condition", "ffn", "frames"):
            _check(isinstance(getattr(self, name), int) and getattr(self, name) > 0, c, name, "must be a positive integer")
        _check(self.hidden % self.heads == 0, c, "hidden", f"hidden={self.hidden} is not divisible by heads={self.heads}")
        for name in ("goal_input", "goal_prior", "norm_first", "split_encoding", "goal_frame_rotation"):
            _check(isinstance(getattr(self, name), bool), c, name, "must be true or false")
        _check(self.window % 2 == 1 and self.window >= 1, c, "window", f"window={self.window} must be odd and >= 1")
        _check(0.0 <= self.dropout < 1.0, c, "dropout", "must be in [0, 1)")
        for name in ("sigma_data", "pos_scale", "vel_scale"):
            _check(float(getattr(self, name)) > 0, c, name, "must be > 0")
        _check_finite(self)

    def check_size(self) -> None:
        """Refuse (ConfigError) a network over ``MER_MAX_MODEL_PARAMETERS`` before it is allocated."""
        n = self.estimated_parameters
        if n > limit("MER_MAX_MODEL_PARAMETERS"):
            msg, fix = too_big("MER_MAX_MODEL_PARAMETERS", n)
            raise ConfigError(
                f"{msg} (hidden={self.hidden}, layers={self.layers}, ffn={self.ffn}, "
                f"cross_heads_per_condition={self.cross_heads_per_condition}); nothing was built",
                element="ModelConfig.layers",
                fix=fix,
            )

    @property
    def head_dim(self) -> int:
        return self.hidden // self.heads

    @property
    def estimated_parameters(self) -> int:
        """Parameters of the network, estimated from the configuration alone (within ~25 %), so that
        an absurd configuration is refused before anything is allocated."""
        H = self.hidden
        per_layer = 12 * H * H + 2 * H * self.ffn + 16 * self.cross_heads_per_condition * self.head_dim * H
        return 2 * self.layers * per_layer


@dataclass(frozen=True)
class EnergyConfig:
    """The energy ``f_kin = L_kp + L_cst + L_vel + L_norm`` and its weight in the loss.

    One setting for every robot (paper). Units: ``L_kp``, ``L_cst`` [m^2], ``L_vel`` [(m/s)^2],
    ``L_norm`` [rad^2] + [(m/s)^2]; each term is a mean over the frames and the bodies it covers.

    Attributes:
        w_kp, w_cst, w_vel, w_norm: the paper's ``w0 .. w3``.
        lam: ``lambda``, the energy's weight against the EDM denoising term.
        w_ori: weight of the orientation term ``L_ori`` (base, feet, hands) [m^2 / rad^2]: at
            0.003, 0.1 rad of orientation error costs as much as 5.5 mm of key-point error
            (docs/model.md). Checkpoints written before the term existed load with 0.
    """

    w_kp: float = 1.0
    w_cst: float = 1.0
    w_vel: float = 0.01
    w_norm: float = 1e-3
    lam: float = 10.0
    w_ori: float = 0.003

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = float(getattr(self, f.name))
            _check(math.isfinite(v) and v >= 0, "EnergyConfig", f.name, "must be a finite number >= 0")


SAMPLER_METHODS = ("heun", "euler", "ancestral", "feedback")


@dataclass(frozen=True)
class SamplerConfig:
    """EDM sampling (Karras et al. 2022, Alg. 1).

    Attributes:
        steps: Heun steps (network evaluations: ``2 * steps - 1``).
        sigma_min, sigma_max, rho: the Karras noise schedule.
        guidance: step size of test-time energy guidance (0 = off): each denoised estimate moves
            by ``-guidance * grad f_kin`` (see :mod:`mer_models.diffusion.sampling`).
        overlap: frames in-painted from the previous clip in long-horizon retargeting.
        method: ``heun`` (EDM Alg. 1), ``euler`` (probability-flow ODE, one evaluation per step) or
            ``ancestral``. With few steps Heun's corrector is unstable for an imperfect denoiser: its
            slope at the next, much smaller sigma is multiplied by the whole step (measured on
            ``mer-base`` at 300 steps: Heun 2 steps put the base 94 m off, Euler 1-8 steps 0.35 m),
            so few-step presets use ``euler`` (docs/model.md). ``feedback``: learned iterative
            refinement, ``steps`` network evaluations: the first at ``sigma_max`` from the sampler's
            start, every further one at ``feedback_sigma`` on the previous estimate made kinematically
            consistent (its position and velocity features recomputed by FK of its angles and base
            pose), for models trained with ``TrainConfig.feedback_frac`` (docs/model.md).
        feedback_sigma: the noise level the ``feedback`` sampler's refinement evaluations run at.
        init_noise: scale of the initial noise (1: EDM's ``sigma_max * N(0, I)``; 0: start at the
            noise distribution's mean, a deterministic retargeting). Models with ``goal_prior`` start
            at their goals plus that noise. Checkpoints written before it existed load with 1.
    """

    steps: int = 16
    sigma_min: float = 0.002
    sigma_max: float = 80.0
    rho: float = 7.0
    guidance: float = 0.0
    overlap: int = 10
    method: str = "heun"
    init_noise: float = 1.0
    feedback_sigma: float = 0.3

    def __post_init__(self) -> None:
        c = "SamplerConfig"
        _check(0.0 <= self.init_noise <= 1.0, c, "init_noise", f"init_noise={self.init_noise} must be in [0, 1]")
        _check(self.method in SAMPLER_METHODS, c, "method", f"method={self.method!r} is not one of {', '.join(SAMPLER_METHODS)}")
        _check(isinstance(self.steps, int) and self.steps >= 1, c, "steps", "must be an integer >= 1")
        _check(0 < self.sigma_min < self.sigma_max, c, "sigma_min", "need 0 < sigma_min < sigma_max")
        _check(self.rho > 0, c, "rho", "must be > 0")
        _check(self.guidance >= 0, c, "guidance", "must be >= 0")
        _check(0 < self.feedback_sigma < self.sigma_max, c, "feedback_sigma", "need 0 < feedback_sigma < sigma_max")
        _check(isinstance(self.overlap, int) and self.overlap >= 1, c, "overlap", "must be an integer >= 1")
        _check_finite(self)


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
_LEGACY = {ModelConfig: {"goal_input": False, "goal_prior": False, "norm_first": False, "split_encoding": False, "goal_frame_rotation": False}, EnergyConfig: {"w_ori": 0.0}, SamplerConfig: {"method": "heun", "init_noise": 1.0, "feedback_sigma": 0.3}, TrainConfig: {"lr_decay_steps": 0, "lr_min_ratio": 0.1, "start_frac": 0.0, "feedback_frac": 0.0, "ref_group": 1, "ema": 0.0}}


def _section(cls, data: Any, where: str):
    if not isinstance(data, Mapping):
        raise ConfigError(f"section {where!r} must be a JSON object", element=where)
    names = {f.name for f in dataclasses.fields(cls)}
    data = {**_LEGACY.get(cls, {}), **data}
    unknown = sorted(set(data) - names)
    missing = sorted(names - set(data))
    if unknown:
        raise ConfigError(
            f"field(s) {', '.join(f'{where}.{u}' for u in unknown)} are not known to this version of mer "
            f"(known: {', '.join(sorted(names))})",
            element=f"{where}.{unknown[0]}",
            fix="load it with the mer version that wrote it, or convert the checkpoint",
        )
    if missing:
        raise ConfigError(
            f"field(s) {', '.join(f'{where}.{m}' for m in missing)} are missing",
            element=f"{where}.{missing[0]}",
            fix="the checkpoint was written by another version of mer; convert it or retrain",
        )
    for f in dataclasses.fields(cls):
        v = data[f.name]
        default = getattr(cls(), f.name)
        ok = isinstance(v, type(default)) or (isinstance(default, float) and isinstance(v, int) and not isinstance(v, bool))
        if isinstance(default, int) and not isinstance(default, bool) and isinstance(v, bool):
            ok = False
        if not ok:
            raise ConfigError(
                f"field {where}.{f.name} has the wrong type ({type(v).__name__}, expected {type(default).__name__})",
                element=f"{where}.{f.name}",
            )
    kw = {k: (float(v) if isinstance(getattr(cls(), k), float) else v) for k, v in data.items()}
    return cls(**kw)


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
    run = RunConfig(name=data["name"], kind=data["kind"], **{k: _section(cls, data[k], k) for k, cls in _SECTIONS.items()})
    run.model.check_size()
    return run
