"""Foot contacts of a source motion: a foot that steps is down while planted, up while swinging,
with hysteresis at the thresholds; real LAFAN1 walking has both feet down most of the time."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mer_data.motion.contacts import ContactConfig, foot_contacts, sole_points
from mer_data.robots.registry import get_skeleton


def _walk(skel, F=120, fps=30.0):
    """Positions (F, J, 3): the left foot planted for frames 0-39 and 80-119, swinging 40-79
    (up 10 cm, 1 m/s forward); the right foot always planted."""
    pos = np.zeros((F, skel.num_nodes, 3))
    pos[:] = skel.rest_positions - np.array([0.0, 0.0, skel.rest_positions[:, 2].min()])
    left = sole_points(skel)["left"]
    t = np.arange(F)
    swing = (t >= 40) & (t < 80)
    phase = np.clip((t - 40) / 40, 0, 1)
    pos[:, left, 2] += (np.sin(np.pi * phase) * 0.10 * swing)[:, None]
    pos[:, left, 0] += (phase * 40 / fps * 1.0)[:, None]
    return pos


def test_a_step_is_down_up_down():
    g1 = get_skeleton("g1")
    c = foot_contacts(_walk(g1), g1, 30.0)
    assert c[:38, 0].all() and c[84:, 0].all()
    assert not c[44:76, 0].any()
    assert c[:, 1].all()


def test_hysteresis_keeps_a_foot_down_between_the_thresholds():
    g1 = get_skeleton("g1")
    pos = _walk(g1)
    left = sole_points(g1)["left"]
    pos[:, left] = pos[0, left]  # planted all along...
    pos[50:60, left, 2] += 0.04  # ...but 4 cm up for a while: between on (3 cm) and off (5 cm)
    c = foot_contacts(pos, g1, 30.0)
    assert c[:, 0].all()
    pos[50:60, left, 2] += 0.02  # 6 cm: off
    c = foot_contacts(pos, g1, 30.0)
    assert not c[50:60, 0].any() and c[:50, 0].all()
    assert foot_contacts(pos, g1, 30.0, ContactConfig(off_height=0.07))[50:60, 0].all()


def test_lafan1_walking_is_mostly_on_the_ground(lafan1_dir):
    from mer_data.motion.features import split_features
    from mer_data.motion.lafan1 import read_lafan1_csv
    from mer_data.robots.registry import load_robot
    from mer_models.retarget.clip import source_features

    g1 = load_robot("g1")
    m = read_lafan1_csv(lafan1_dir / "g1" / "walk1_subject1.csv", g1)
    f = source_features(m.base_pos, m.base_quat, m.node_angles(g1.skeleton), g1.skeleton, 30.0)
    c = foot_contacts(split_features(torch.from_numpy(f))["pos"].numpy(), g1.skeleton, 30.0)[600:1050]
    share = c.mean(0)
    assert (share > 0.5).all() and (share < 0.9).all()  # walking: each foot down a bit over half the time
    assert c.any(1).mean() > 0.95  # and almost never both up


@pytest.mark.parametrize("frames", [0, 1, 2])
def test_short_motions(frames):
    g1 = get_skeleton("g1")
    assert foot_contacts(np.zeros((frames, g1.num_nodes, 3)), g1, 30.0).shape == (frames, 2)
