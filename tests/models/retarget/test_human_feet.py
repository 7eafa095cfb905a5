"""Feet of human sources (issue 49): a source that floats (a standing, swaying human whose soles
never come below 4 cm) still gets contacts from its own standing level, and the human sources'
physical terms (`human_physics`, what the commands use) put the robot's stance soles on the floor
and keep them still while the human's feet are down."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import torch
from body_model_files import TPOSE22

from mer_data.base.errors import MerError
from mer_data.motion.contacts import foot_contacts
from mer_data.motion.features import split_features
from mer_data.motion.sources import BvhOptions, read_source
from mer_data.robots.collision import collision_model
from mer_data.robots.registry import load_robot
from mer_models.cli.retarget import physics_option
from mer_models.retarget.artifacts import motion_artifacts
from mer_models.retarget.clip import human_physics, retarget_features
from mer_models.solver.physics import PhysicsConfig

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _floating_human(tmp_path, frames: int = 45):
    """HumanML3D-layout positions (y up) of a human standing 4 cm above the floor, swaying its arms and hips."""
    t = np.linspace(0, 2 * np.pi, frames)[:, None]
    P = np.repeat((TPOSE22 + [0, 0.97, 0])[None], frames, 0)  # the T-pose's soles at about 4 cm
    P[:, [16, 18, 20]] += 0.06 * np.sin(t)[..., None] * [0, -1, 0.5]  # the left arm waves
    P[:, [0, 1, 2, 3, 6, 9, 12, 15]] += 0.02 * np.sin(2 * t)[..., None] * [1, 0, 0]  # the hips sway
    np.save(tmp_path / "stand.npy", P.astype(np.float32))
    return read_source(tmp_path / "stand.npy", "joints", bvh=BvhOptions(fps=30.0))


def test_a_floating_source_stands_on_the_floor(tmp_path):
    src = _floating_human(tmp_path)
    feats = src.features()
    pos = split_features(torch.from_numpy(feats))["pos"].numpy()
    contacts = foot_contacts(pos, src.skeleton, 30.0)
    assert contacts.mean() > 0.9  # floating, yet down: the standing level is the motion's own
    robot = load_robot("g1")
    model = collision_model(robot)
    out = {}
    for name, phys in (("penalty", PhysicsConfig(method="penalty")), ("human", human_physics())):
        m = retarget_features(feats, src.skeleton, robot.skeleton, method="optimize", physics=phys, geometry=[model]).motion
        out[name] = motion_artifacts(m.q, m.base_pos, m.base_rot, 30.0, robot.skeleton, model, feats, src.skeleton)
    assert out["human"]["hover_frames"] <= 0.05, out["human"]["hover_frames"]  # soles within 1 cm while the feet are down
    assert out["human"]["floor_frames"] == 0 and out["human"]["speed_frames"] == 0
    assert not out["human"]["skate_median"] > 0.01  # [m/s]
    assert out["penalty"]["hover_frames"] > 0.5  # the old stance lock: the robot floats with its source


def test_the_commands_give_human_sources_the_human_physics():
    args = argparse.Namespace(physics=True, source="smpl")
    assert physics_option(args) == human_physics() and physics_option(args).method == "constraints"
    assert physics_option(argparse.Namespace(physics=True, source="g1")) == PhysicsConfig()
    assert physics_option(argparse.Namespace(physics=False, source="bvh")) is None
    assert physics_option(argparse.Namespace(physics=True, source="g1", physics_method="constraints")) == PhysicsConfig(method="constraints")
    assert physics_option(argparse.Namespace(physics=True, source="bvh", physics_method="constraints")) == human_physics()
    assert physics_option(argparse.Namespace(physics=True, source="bvh", physics_method="penalty")) == PhysicsConfig(method="penalty")
    with pytest.raises(MerError, match="--no-physics"):
        physics_option(argparse.Namespace(physics=False, source="g1", physics_method="penalty"))
