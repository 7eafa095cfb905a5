"""Correcting key points one at a time (issue 40, item 5).

A ``--keypoints`` file may give only the key points that change (merged over the proposal);
``mer robots keypoints NAME --write FILE`` writes the current set as an editable file that
registers back to the same key points; registration says where the card went; the ``check:`` list
leaves out what is absent by design (a point foot's toe, the arms of a robot without any).
"""

from __future__ import annotations

import pytest
import yaml
from urdf_factory import biped, humanoid, quadruped

from mer_data.base.errors import RobotCardError
from mer_data.robots.register import keypoints_yaml, load_keypoints_file, register_robot
from mer_data.robots.registry import get_skeleton, load_robot, robots_dir
from mer_data.skeleton import KEYPOINTS
from mer_models.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_two_entry_keypoint_file_is_merged_over_the_proposal(tmp_path, capsys):
    urdf = humanoid().write(tmp_path / "h.urdf")
    kfile = tmp_path / "toes.yaml"
    kfile.write_text("left_toe: {link: left_foot_link, offset: [0.12, 0.0, -0.05]}\nright_hand: null\n")
    assert set(load_keypoints_file(kfile)) == {"left_toe", "right_hand"}  # only what the file gives
    code, out, err = run(capsys, "robots", "register", "fixbot", "--urdf", urdf, "--keypoints", str(kfile))
    assert code == 0, err
    assert "[given] from toes.yaml" in out and "list all 14" not in out + err
    card = yaml.safe_load((robots_dir() / "fixbot" / "robot.yaml").read_text())["keypoints"]
    assert card["left_toe"] == {"link": "left_foot_link", "offset": [0.12, 0.0, -0.05]}
    assert card["right_hand"] is None
    # every other key point is the proposal's
    proposed = register_robot("plain", urdf, dry_run=True).card.keypoints
    for k in KEYPOINTS:
        if k not in ("left_toe", "right_hand"):
            assert load_robot("fixbot").card.keypoints[k] == proposed[k], k
    skel = get_skeleton("fixbot")
    assert skel.keypoints["right_hand"] == -1 and skel.node_kinds[skel.keypoints["left_toe"]] == "site"


def test_an_empty_or_unknown_keypoint_file_is_refused(tmp_path):
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing here\n")
    with pytest.raises(RobotCardError, match="gives no key point"):
        load_keypoints_file(empty)
    bad = tmp_path / "bad.yaml"
    bad.write_text("left_tow: {link: x}\n")
    with pytest.raises(RobotCardError, match="unknown key point"):
        load_keypoints_file(bad)


def test_registration_prints_where_the_card_went(tmp_path, capsys):
    urdf = biped().write(tmp_path / "b.urdf")
    code, out, err = run(capsys, "robots", "register", "cardbot", "--urdf", urdf)
    assert code == 0, err
    assert f"robot card: {robots_dir() / 'cardbot' / 'robot.yaml'}" in out
    code, out, _ = run(capsys, "robots", "register", "cardbot2", "--urdf", urdf, "--dry-run")
    assert code == 0 and "robot card:" not in out  # nothing written


def test_write_round_trips_into_registration(tmp_path, capsys):
    urdf = humanoid().write(tmp_path / "h.urdf")
    kfile = tmp_path / "toes.yaml"
    kfile.write_text("left_toe: {link: left_foot_link, offset: [0.123456789, 0.0, -0.05]}\n")
    assert run(capsys, "robots", "register", "orig", "--urdf", urdf, "--keypoints", str(kfile))[0] == 0
    out_file = tmp_path / "kp.yaml"
    code, out, err = run(capsys, "robots", "keypoints", "ORIG", "--write", str(out_file))  # case ignored
    assert code == 0, err
    assert "wrote the 14 key points of 'orig'" in out
    text = out_file.read_text()
    assert text.startswith("# Key points of robot 'orig'") and "--keypoints THIS_FILE --force" in text
    assert set(yaml.safe_load(text)) == set(KEYPOINTS)
    code, printed, _ = run(capsys, "robots", "keypoints", "orig")
    assert code == 0 and printed == text  # without --write: the same text on stdout
    # the written file registers back to exactly the same key points and skeleton
    assert run(capsys, "robots", "register", "again", "--urdf", urdf, "--keypoints", str(out_file))[0] == 0
    assert load_robot("again").card.keypoints == load_robot("orig").card.keypoints
    assert get_skeleton("again").keypoints == get_skeleton("orig").keypoints


def test_write_of_a_builtin_robot_gives_its_card(tmp_path):
    g1 = load_robot("g1")
    text = keypoints_yaml(g1)
    assert "register a copy under another name" in text and "my_g1" in text
    f = tmp_path / "g1.yaml"
    f.write_text(text)
    assert load_keypoints_file(f) == {k: g1.card.keypoints[k] for k in KEYPOINTS}


def test_point_foot_robots_are_not_told_to_check_toes(tmp_path):
    rep = register_robot("quad", quadruped().write(tmp_path / "q.urdf"), dry_run=True)
    assert rep.proposals["left_toe"].confidence == "absent" and rep.proposals["left_toe"].by_design
    assert rep.to_check() == [] and "check:" not in rep.summary()
    assert "[absent, by design] point foot" in rep.summary()
    armless = register_robot("legs", biped().write(tmp_path / "b.urdf"), dry_run=True)
    assert armless.to_check() == [] and armless.proposals["left_hand"].by_design


def test_wild_point_foot_robot_gets_no_check_line_but_romeo_does(shared_wild_robots):
    a1 = register_robot("a1", shared_wild_robots / "unitree_a1" / "unitree_a1.urdf", dry_run=True)
    assert a1.to_check() == [] and "check:" not in a1.summary()
    romeo = register_robot("romeo", shared_wild_robots / "romeo" / "romeo.urdf", dry_run=True)
    assert romeo.to_check() == ["left_toe", "right_toe"]  # low: the front of the sole frames
    line = next(l for l in romeo.summary().splitlines() if "check:" in l)
    assert "only the key points that change" in line
