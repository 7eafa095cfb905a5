"""Samplers: schedule, exactness on a Gaussian, evaluation counts, guidance, callbacks."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from model_helpers import MICRO, mixed_batch

from mer_models.config import ConfigError, EnergyConfig, SamplerConfig
from mer_models.diffusion.model import RetargetModel
from mer_models.diffusion.sampling import (
    CountingDenoiser,
    EnergyGuidance,
    feedback_sigmas,
    karras_sigmas,
    sample_euler,
    sample_euler_ancestral,
    sample_feedback,
    sample_heun,
)
from mer_models.retarget.inference import sample_conditions


def test_karras_schedule():
    s = karras_sigmas(16, 0.002, 80.0, 7.0)
    assert s.shape == (17,) and s[-1] == 0
    assert math.isclose(float(s[0]), 80.0, rel_tol=1e-5) and math.isclose(float(s[-2]), 0.002, rel_tol=1e-4)
    assert (s[:-1][1:] < s[:-1][:-1]).all()
    i = 5
    expect = (80 ** (1 / 7) + i / 15 * (0.002 ** (1 / 7) - 80 ** (1 / 7))) ** 7
    assert math.isclose(float(s[i]), expect, rel_tol=1e-5)


class Gaussian:
    """Exact denoiser of data ~ N(mu, s^2) per element: D = (s^2 x + sigma^2 mu) / (s^2 + sigma^2)."""

    def __init__(self, mu, s):
        self.mu, self.s = mu, s

    def __call__(self, x, sigma, cond):
        return (self.s**2 * x + sigma**2 * self.mu) / (self.s**2 + sigma**2)


def _exact(x, mu, s, sigma_max=80.0, sigma_min=0.002):
    """Closed-form probability-flow ODE solution for Gaussian data: x - mu scales with sqrt(s^2 + sigma^2)."""
    return (x - mu) * math.sqrt(s**2 + sigma_min**2) / math.sqrt(s**2 + sigma_max**2) + mu


def test_heun_solves_the_ode_and_counts_evaluations():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(20000, generator=g, dtype=torch.float64) * 80.0
    den = CountingDenoiser(Gaussian(0.3, 0.5))
    out = sample_heun(den, x, karras_sigmas(32).double(), None)
    assert den.calls == 2 * 32 - 1
    assert float((out - _exact(x, 0.3, 0.5)).abs().max()) < 0.05
    out16 = sample_heun(Gaussian(0.3, 0.5), x, karras_sigmas(16).double(), None)
    assert abs(float(out16.std()) - 0.5) < 0.05  # second order: 16 steps already land near


def test_the_1000_step_sampler_solves_the_same_ode():
    g = torch.Generator().manual_seed(1)
    x = torch.randn(5000, generator=g, dtype=torch.float64) * 80.0
    c = CountingDenoiser(Gaussian(-0.2, 0.4))
    b = sample_euler(c, x, karras_sigmas(1000).double(), None)
    assert c.calls == 1000
    assert float((b - _exact(x, -0.2, 0.4)).abs().max()) < 0.01


def test_ancestral_sampler_is_stochastic_but_right_in_distribution():
    g = torch.Generator().manual_seed(2)
    x = torch.randn(20000, generator=g) * 80.0
    out = sample_euler_ancestral(Gaussian(0.1, 0.5), x, karras_sigmas(200), None, generator=g)
    assert abs(float(out.mean()) - 0.1) < 0.02 and abs(float(out.std()) - 0.5) < 0.03


def test_callback_and_guidance_hooks_are_called():
    seen, guided = [], []
    x = torch.randn(10) * 80

    def guidance(d, sigma, cond):
        guided.append(float(sigma))
        return d

    sample_heun(Gaussian(0, 0.5), x, karras_sigmas(4), None, guidance=guidance, callback=lambda info: seen.append(info["i"]))
    assert seen == [0, 1, 2, 3] and len(guided) == 4  # one guided estimate per step


def test_energy_guidance_lowers_the_energy_and_keeps_limits():
    torch.manual_seed(0)
    model = RetargetModel(MICRO).eval()
    b = mixed_batch(("h1", "tron1"))
    energy = EnergyConfig()
    res = {}
    for scale in (0.0, 0.05):
        cond = model.conditions(b)
        d = sample_conditions(model, cond, SamplerConfig(steps=4, guidance=scale), energy=energy, generator=torch.Generator().manual_seed(0))
        res[scale] = model.energy(d, cond, energy)["total"]
        q = model.decode(d, cond)["q"]
        g = cond.tgt_graph
        assert ((q >= g.lower[:, None] - 1e-6) & (q <= g.upper[:, None] + 1e-6)).all()
    assert (res[0.05] < 0.7 * res[0.0]).all()


def test_sampling_is_reproducible_with_a_seed():
    torch.manual_seed(0)
    model = RetargetModel(MICRO).eval()
    b = mixed_batch(("h1",))
    outs = [
        sample_conditions(model, model.conditions(b), SamplerConfig(steps=3), generator=torch.Generator().manual_seed(7))
        for _ in range(2)
    ]
    torch.testing.assert_close(outs[0], outs[1], rtol=0, atol=0)


def test_guidance_scale_zero_is_the_identity():
    model = RetargetModel(MICRO)
    b = mixed_batch(("h1",))
    cond = model.conditions(b)
    d = torch.randn(cond.shape)
    assert EnergyGuidance(model, EnergyConfig(), 0.0)(d, torch.tensor(1.0), cond) is d


def test_init_noise_zero_is_deterministic_and_a_goal_prior_model_starts_at_its_goals():
    import dataclasses

    torch.manual_seed(0)
    model = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    with torch.no_grad():
        model.net.joint_head.weight.normal_(0, 0.5)
    b = mixed_batch(("h1",))

    def run(seed, noise, steps=2):
        return sample_conditions(model, model.conditions(b), SamplerConfig(steps=steps, method="euler", init_noise=noise),
                                 generator=torch.Generator().manual_seed(seed))  # fmt: skip

    torch.testing.assert_close(run(1, 0.0), run(2, 0.0), rtol=0, atol=0)
    assert (run(1, 1.0) - run(2, 1.0)).abs().max() > 1e-3
    seen = []
    cond = model.conditions(b)
    orig = model.denoise
    try:  # the sampler's first input is the goal prior itself
        model.denoise = lambda x, s, c: (seen.append(x.clone()), orig(x, s, c))[1]
        sample_conditions(model, cond, SamplerConfig(steps=1, method="euler", init_noise=0.0))
    finally:
        del model.denoise
    torch.testing.assert_close(seen[0], model.goal_prior(cond), rtol=0, atol=0)
    with pytest.raises(ConfigError, match="init_noise"):
        SamplerConfig(init_noise=2.0)


def test_feedback_sampler_feeds_the_projected_estimate_back():
    """sample_feedback: the first evaluation at sigma_max on x, every further one at the feedback
    sigma on project(previous estimate); one evaluation per positive sigma; returns the last."""
    calls = []

    def den(x, sigma, cond):
        calls.append((float(sigma), x.clone()))
        return x * 0.5 + float(sigma)

    def project(d, cond):
        return d - 1.0

    x = torch.full((1, 2, 3, 9), 4.0)
    sig = feedback_sigmas(3, 80.0, 0.3)
    torch.testing.assert_close(sig, torch.tensor([80.0, 0.3, 0.3, 0.0]))
    out = sample_feedback(den, x, sig, None, project=project)
    assert [s for s, _ in calls] == pytest.approx([80.0, 0.3, 0.3])
    d1 = x * 0.5 + 80.0
    torch.testing.assert_close(calls[1][1], d1 - 1.0)
    d2 = (d1 - 1.0) * 0.5 + 0.3
    torch.testing.assert_close(calls[2][1], d2 - 1.0)
    torch.testing.assert_close(out, (d2 - 1.0) * 0.5 + 0.3)
    calls.clear()
    one = sample_feedback(den, x, feedback_sigmas(1, 80.0, 0.3), None, project=project)
    assert len(calls) == 1 and torch.equal(one, d1)


def test_feedback_sampling_runs_steps_evaluations_and_keeps_the_limits():
    torch.manual_seed(0)
    m = RetargetModel(dataclasses.replace(MICRO, goal_input=True, goal_prior=True)).eval()
    with torch.no_grad():
        for head in (m.net.base_head, m.net.joint_head):
            head.weight.normal_(0, 0.5)
    b = mixed_batch(("g1", "tron1"))
    cond = m.conditions(b)
    stats = {}
    d = sample_conditions(m, cond, SamplerConfig(method="feedback", steps=4, init_noise=0.0), stats=stats)
    assert stats["nfe"] == 4
    q, g = m.decode(d, cond)["q"], cond.tgt_graph
    assert ((q >= g.lower[:, None] - 1e-6) & (q <= g.upper[:, None] + 1e-6)).all()
    with pytest.raises(ConfigError, match="feedback_sigma"):
        SamplerConfig(feedback_sigma=0.0)
