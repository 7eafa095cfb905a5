"""Configuration of the retargeting model, its energy and its sampler (frozen, validated); the training,
the warm start and the whole run are in :mod:`mer_models.run_config` (re-exported here).

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
from dataclasses import dataclass
from typing import Any, Mapping

from mer_data.base.errors import ConfigError
from mer_data.base.limits import limit, too_big

__all__ = [
    "ModelConfig",
    "EnergyConfig",
    "SamplerConfig",
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


#: Fields added after checkpoints were first written, with the value that reproduces the older
#: behaviour: a checkpoint without them loads with that value (and nothing else may be missing).
LEGACY_FIELDS: dict[type, dict[str, Any]] = {ModelConfig: {"goal_input": False, "goal_prior": False, "norm_first": False, "split_encoding": False, "goal_frame_rotation": False}, EnergyConfig: {"w_ori": 0.0}, SamplerConfig: {"method": "heun", "init_noise": 1.0, "feedback_sigma": 0.3}}


def read_section(cls, data: Any, where: str, legacy: Mapping[type, Mapping[str, Any]] = LEGACY_FIELDS):
    """One section of ``config.json`` as a ``cls`` instance, strictly: unknown, missing or mistyped fields are
    refused by name; the fields of ``legacy`` missing from an older checkpoint take their older value."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"section {where!r} must be a JSON object", element=where)
    names = {f.name for f in dataclasses.fields(cls)}
    data = {**legacy.get(cls, {}), **data}
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


#: The run's configuration, moved to :mod:`mer_models.run_config` (split by job), still importable from here.
_MOVED = ("TrainConfig", "WarmConfig", "RunConfig", "KINDS", "PRESETS", "preset", "from_dict")


def __getattr__(name: str) -> Any:  # a lazy re-export (PEP 562): run_config imports this module, not the reverse
    if name in _MOVED:
        from mer_models import run_config

        return getattr(run_config, name)
    raise AttributeError(f"module 'mer_models.config' has no attribute {name!r}")
