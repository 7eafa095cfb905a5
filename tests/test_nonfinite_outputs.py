"""Inputs that used to give exit 0 with every output row NaN, and inputs that used to give tracebacks:
each is now a clear error (exit 1) and no file is written."""

from __future__ import annotations

import functools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from model_helpers import synthetic_csv
from safetensors.torch import load_file, save_file
from urdf_factory import humanoid

import mer_models
from mer_data.base.errors import CheckpointError, ConfigError, OutputError
from mer_data.robots.registry import get_skeleton, load_robot
from mer_models.cli import main
from mer_models.config import ModelConfig
from mer_models.export.writers import TargetMotion, write_csv, write_mcap, write_npz
from mer_models.zoo import DEFAULT_MODEL

BUNDLED = Path(mer_models.__file__).parent / "bundled" / DEFAULT_MODEL  # the bundled default model (mer-base)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    return code, cap.err


@pytest.fixture
def ckpt(tmp_path):
    dst = tmp_path / "ckpt"
    shutil.copytree(BUNDLED, dst)
    return dst


def _edit_config(ckpt: Path, edit) -> None:
    meta = json.loads((ckpt / "config.json").read_text())
    edit(meta)
    (ckpt / "config.json").write_text(json.dumps(meta))  # json.dumps writes inf as `Infinity`


def _retarget(capsys, tmp_path, ckpt):
    src = synthetic_csv(tmp_path / "src.csv", "g1", frames=60)
    out = tmp_path / "out.csv"
    code, err = run(capsys, "retarget", src, "--source", "g1", "--target", "h1", "--model", ckpt, "-o", out, "--steps", "2")
    assert not out.exists()
    return code, err


@pytest.mark.parametrize(
    "section,field", [("model", "pos_scale"), ("model", "vel_scale"), ("sampler", "sigma_max"), ("energy", "lam")]
)
def test_infinite_config_values_are_refused(capsys, tmp_path, ckpt, section, field):
    _edit_config(ckpt, lambda m: m["run"][section].__setitem__(field, float("inf")))
    code, err = _retarget(capsys, tmp_path, ckpt)
    assert code == 1 and "config.json" in err and ("Infinity" in err or "finite" in err)


def test_all_nan_weights_are_refused(capsys, tmp_path, ckpt):
    sd = load_file(str(ckpt / "model.safetensors"))
    sd = {k: v.fill_(float("nan")) if v.is_floating_point() else v for k, v in sd.items()}
    save_file(sd, str(ckpt / "model.safetensors"))
    code, err = _retarget(capsys, tmp_path, ckpt)
    assert code == 1 and "NaN/inf" in err and "model.safetensors" in err


@pytest.mark.parametrize(
    "edit,expect",
    [
        (lambda m: m.__setitem__("step", "12"), "step must be an integer"),
        (lambda m: m.__setitem__("step", [1]), "step must be an integer"),
        (lambda m: m.__setitem__("robots", ["g1"]), "robots must map"),
        (lambda m: m["robots"].__setitem__("targets", ["g1"]), "robots must map"),
        (lambda m: m["run"]["model"].__setitem__("layers", 1e6), "wrong type"),
        (lambda m: m["run"]["model"].__setitem__("layers", 1_000_000), "MER_MAX_MODEL_PARAMETERS"),
        (lambda m: m["run"]["model"].__setitem__("cross_heads_per_condition", 10**9), "MER_MAX_MODEL_PARAMETERS"),
    ],
    ids=["step-str", "step-list", "robots-list", "targets-list", "layers-float", "layers-int", "cross-heads"],
)
def test_malformed_config_fields_are_errors_not_tracebacks(capsys, tmp_path, ckpt, edit, expect):
    _edit_config(ckpt, edit)
    code, err = _retarget(capsys, tmp_path, ckpt)
    assert code == 1 and expect in err


def test_a_huge_model_is_refused_before_anything_is_allocated():
    from mer_models.diffusion.model import RetargetModel

    with pytest.raises(ConfigError, match="MER_MAX_MODEL_PARAMETERS"):
        RetargetModel(ModelConfig(layers=1_000_000))
    assert ModelConfig().estimated_parameters < 20_000_000


def test_model_name_over_255_characters(capsys, tmp_path):
    src = synthetic_csv(tmp_path / "src.csv", "g1", frames=60)
    code, err = run(capsys, "retarget", src, "--source", "g1", "--target", "h1", "--model", "m" * 300, "-o", tmp_path / "o.csv")
    assert code == 1 and "invalid model name" in err


def test_keypoint_offset_of_1e308_is_refused(capsys, tmp_path):
    g1 = load_robot("g1")
    kp = tmp_path / "kp.yaml"
    points = {k: None if v is None else {"link": v.link, "offset": list(v.offset)} for k, v in g1.card.keypoints.items()}
    points["left_toe"]["offset"] = [1.0e308, 0.0, 0.0]
    kp.write_text(yaml.safe_dump(points))
    urdf = g1.urdf_path
    code, err = run(capsys, "robots", "register", "bot", "--urdf", urdf, "--keypoints", kp)
    assert code == 1 and "left_toe" in err and "beyond" in err


def test_non_utf8_keypoint_file_is_an_error(capsys, tmp_path):
    urdf = tmp_path / "bot.urdf"
    urdf.write_text(humanoid().xml())
    kp = tmp_path / "kp.yaml"
    kp.write_bytes("left_toe: {link: pi\u00e9d}\n".encode("latin-1"))
    code, err = run(capsys, "robots", "register", "bot", "--urdf", urdf, "--keypoints", kp)
    assert code == 1 and "not UTF-8" in err and str(kp) in err


def test_writers_refuse_non_finite_motions(tmp_path):
    skel = get_skeleton("h1")
    q = np.zeros((5, skel.num_nodes))
    q[2, 3] = np.nan
    m = TargetMotion(skel, 30.0, q, np.zeros((5, 3)), np.broadcast_to(np.eye(3), (5, 3, 3)).copy())
    for writer, name in ((write_csv, "o.csv"), (functools.partial(write_npz, tracker="mjlab"), "o.npz"), (write_mcap, "o.mcap")):
        with pytest.raises(OutputError, match="'q'"):
            writer(tmp_path / name, m)
        assert not (tmp_path / name).exists()
    assert not list(tmp_path.iterdir())  # no temporary file left either


def test_saving_nan_weights_is_refused(tmp_path):
    from mer_models.hub.checkpoint_files import save_checkpoint
    from mer_models.zoo.checkpoint import load_checkpoint

    ck = load_checkpoint(BUNDLED)
    next(ck.model.parameters()).data.fill_(float("inf"))
    with pytest.raises(OutputError):
        save_checkpoint(tmp_path / "c", ck.model, ck.run, robots=ck.robots)
    assert not (tmp_path / "c").exists()
    with pytest.raises(CheckpointError):
        load_checkpoint(tmp_path / "c")
