"""Model configuration: presets, validation, strict JSON round trip."""

from __future__ import annotations

import json

import pytest

from mer_data.base.errors import ConfigError
from mer_models.config import ModelConfig, SamplerConfig, TrainConfig, from_dict, preset


def test_paper_preset_is_the_papers_configuration():
    run = preset("paper")
    m = run.model
    assert (m.hidden, m.layers, m.heads, m.ffn, m.window, m.frames) == (240, 4, 6, 1024, 31, 60)
    assert run.train.batch_size == 16
    assert run.sampler.steps <= 20
    assert (run.train.p_mean, run.train.p_std, m.sigma_data) == (0.0, 1.5, 0.5)


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ConfigError, match="paper, tiny, base"):
        preset("huge")


@pytest.mark.parametrize(
    "kw, field",
    [({"hidden": 50, "heads": 6}, "hidden"), ({"window": 30}, "window"), ({"layers": 0}, "layers"), ({"dropout": 1.0}, "dropout")],
)
def test_invalid_values_name_the_field(kw, field):
    with pytest.raises(ConfigError) as e:
        ModelConfig(**kw)
    assert f"ModelConfig.{field}" in str(e.value)


def test_sampler_validation():
    with pytest.raises(ConfigError, match="SamplerConfig.sigma_min"):
        SamplerConfig(sigma_min=100.0)


@pytest.mark.parametrize("name", ["tiny", "paper"])
def test_json_round_trip(name):
    run = preset(name)
    assert from_dict(json.loads(json.dumps(run.to_dict()))) == run


def test_unknown_missing_and_mistyped_fields_are_refused_by_name():
    d = preset("tiny").to_dict()
    d["model"]["attention_kind"] = "flash"
    with pytest.raises(ConfigError) as e:
        from_dict(d)
    assert "model.attention_kind" in str(e.value)
    d = preset("tiny").to_dict()
    del d["energy"]["w_vel"]
    with pytest.raises(ConfigError) as e:
        from_dict(d)
    assert "energy.w_vel" in str(e.value)
    d = preset("tiny").to_dict()
    d["model"]["layers"] = "two"
    with pytest.raises(ConfigError) as e:
        from_dict(d)
    assert "model.layers" in str(e.value)
    d = preset("tiny").to_dict()
    d["extra_section"] = {}
    with pytest.raises(ConfigError, match="extra_section"):
        from_dict(d)


def test_base_samples_with_few_euler_steps_and_old_checkpoints_load_with_heun():
    run = preset("base")
    assert (run.sampler.method, run.sampler.steps, run.sampler.init_noise) == ("euler", 1, 0.0)  # 1 network evaluation, deterministic
    d = json.loads(json.dumps(run.to_dict()))
    assert from_dict(d) == run
    del d["sampler"]["method"]  # written before the field existed
    assert from_dict(d).sampler.method == "heun"
    with pytest.raises(ConfigError, match="method"):
        SamplerConfig(method="rk4")


def test_base_takes_the_goals_and_old_checkpoints_load_without_them():
    run = preset("base")
    assert run.model.goal_input and run.model.goal_prior
    assert run.train.start_frac == 0.5 and preset("paper").train.start_frac == 0.0
    old = json.loads(json.dumps(run.to_dict()))
    del old["train"]["start_frac"]  # written before the field existed: trained on EDM's noise only
    assert from_dict(old).train.start_frac == 0.0
    with pytest.raises(ConfigError, match="start_frac"):
        TrainConfig(start_frac=1.5)
    assert not (preset("paper").model.goal_input or preset("paper").model.goal_prior)
    d = json.loads(json.dumps(run.to_dict()))
    assert from_dict(d).model.goal_input is True
    del d["model"]["goal_input"], d["model"]["goal_prior"], d["model"]["norm_first"]  # written before the fields existed
    assert (from_dict(d).model.goal_input, from_dict(d).model.goal_prior, from_dict(d).model.norm_first) == (False, False, False)
    d["model"]["goal_input"] = 1  # an integer is not a flag
    with pytest.raises(ConfigError, match="model.goal_input"):
        from_dict(d)


def test_feedback_frac_shares_the_batch_with_start_frac_and_old_checkpoints_load_without_it():
    assert TrainConfig(start_frac=0.5, feedback_frac=0.5).feedback_frac == 0.5
    with pytest.raises(ConfigError, match="feedback_frac"):
        TrainConfig(start_frac=0.5, feedback_frac=0.75)
    d = json.loads(json.dumps(preset("base").to_dict()))
    del d["train"]["feedback_frac"], d["sampler"]["feedback_sigma"]  # written before the fields existed
    run = from_dict(d)
    assert run.train.feedback_frac == 0.0 and run.sampler.feedback_sigma == SamplerConfig().feedback_sigma


def test_ref_group_divides_the_batch_and_old_checkpoints_load_ungrouped():
    assert TrainConfig(batch_size=16, ref_group=4).ref_group == 4
    for bad in (0, 3, 2.0):
        with pytest.raises(ConfigError, match="ref_group"):
            TrainConfig(batch_size=16, ref_group=bad)
    d = json.loads(json.dumps(preset("base").to_dict()))
    del d["train"]["ref_group"]  # written before the field existed
    assert from_dict(d).train.ref_group == 1
