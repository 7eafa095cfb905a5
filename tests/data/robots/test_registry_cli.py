"""The robot registry and the `mer robots` command line, through main(argv)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import yaml
from conftest import ROBOTS
from urdf_factory import biped, humanoid, quadruped

from mer_data.base.errors import RegistryError, UnknownRobotError
from mer_data.robots import registry
from mer_data.robots.register import register_robot
from mer_data.robots.registry import get_skeleton, list_robots, load_robot, robots_dir, unregister_robot
from mer_models.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_list_shows_the_eight_builtins(capsys):
    code, out, _ = run(capsys, "robots", "list", "--json")
    assert code == 0
    rows = json.loads(out)
    assert [r["name"] for r in rows] == list(ROBOTS)
    assert {r["name"]: r["num_dof"] for r in rows}["valkyrie"] == 32
    code, out, _ = run(capsys, "robots", "list")
    assert code == 0 and "tron1" in out and "8/14" in out


def test_show_json_has_the_graph(capsys):
    code, out, _ = run(capsys, "robots", "show", "g1", "--json")
    d = json.loads(out)
    J = d["num_nodes"]
    for key in ("node_names", "node_kinds", "parents", "axes", "offsets", "lower", "upper", "urdf_joint_names"):
        assert len(d[key]) == J, key
    assert d["node_kinds"][0] == "base" and d["keypoints"]["left_knee"] == d["node_names"].index("left_knee_joint")
    assert d["urdf_joint_names"][d["keypoints"]["left_toe"]] is None
    code, out, _ = run(capsys, "robots", "show", "tron1")
    assert code == 0 and "absent key points: left_shoulder" in out


def test_unknown_robot_exits_non_zero_and_lists_known(capsys):
    code, _, err = run(capsys, "robots", "show", "nosuch")
    assert code == 1 and "known robots: g1, h1" in err


@pytest.mark.parametrize("factory", [humanoid, biped, quadruped], ids=["humanoid", "biped", "quadruped"])
def test_register_unseen_robots_with_one_command(tmp_path, capsys, factory):
    robot = factory()
    urdf = robot.write(tmp_path / "robot.urdf")
    code, out, err = run(capsys, "robots", "register", "newbot", "--urdf", urdf)
    assert code == 0, err
    assert "registered 'newbot'" in out and "key points:" in out
    skel = get_skeleton("newbot")  # used by name like a built-in
    assert skel.keypoints["left_knee"] >= 0 and skel.keypoints["right_ankle"] >= 0
    assert "newbot" in [r.name for r in list_robots()]
    code, out, _ = run(capsys, "robots", "show", "newbot", "--json")
    assert json.loads(out)["source"] == "user"
    code, out, _ = run(capsys, "robots", "unregister", "newbot")
    assert code == 0 and not (robots_dir() / "newbot").exists()
    with pytest.raises(UnknownRobotError):
        load_robot("newbot")


def test_register_with_keypoints_file_and_locks(tmp_path, capsys):
    urdf = humanoid().write(tmp_path / "h.urdf")
    kp = {k: None for k in ("left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
                            "left_toe", "right_toe", "left_shoulder", "right_shoulder", "left_elbow",
                            "right_elbow", "left_hand", "right_hand")}  # fmt: skip
    kp["left_knee"] = {"link": "left_shin_link"}
    kp["left_toe"] = {"link": "left_foot_link", "offset": [0.1, 0.0, -0.04]}
    kfile = tmp_path / "kp.yaml"
    kfile.write_text(yaml.safe_dump({"keypoints": kp}))
    code, out, err = run(capsys, "robots", "register", "kpbot", "--urdf", urdf, "--keypoints", str(kfile), "--lock", "neck_joint=0.2")
    assert code == 0, err
    skel = get_skeleton("kpbot")
    assert skel.locked == {"neck_joint": 0.2} and "neck_joint" not in skel.node_names
    assert skel.keypoints["left_hand"] == -1 and skel.node_kinds[skel.keypoints["left_toe"]] == "site"
    # the card written to the registry reads back the same
    card = yaml.safe_load((robots_dir() / "kpbot" / "robot.yaml").read_text())
    assert card["keypoints"]["left_toe"]["offset"] == [0.1, 0.0, -0.04]


def test_existing_name_is_refused_without_force(tmp_path, capsys):
    urdf = biped().write(tmp_path / "b.urdf")
    assert run(capsys, "robots", "register", "twice", "--urdf", urdf)[0] == 0
    code, _, err = run(capsys, "robots", "register", "twice", "--urdf", urdf)
    assert code == 1 and "already registered" in err and "--force" in err
    urdf2 = humanoid().write(tmp_path / "h.urdf")
    assert run(capsys, "robots", "register", "twice", "--urdf", urdf2, "--force")[0] == 0
    assert get_skeleton("twice").keypoints["left_hand"] >= 0  # replaced by the humanoid


@pytest.mark.parametrize("name", ["../evil", "g1", "Upper", "a/b", "", "x" * 70])
def test_bad_or_builtin_names_are_refused(tmp_path, name):
    urdf = biped().write(tmp_path / "b.urdf")
    with pytest.raises(RegistryError):
        register_robot(name, urdf)
    assert not robots_dir().exists() or not list(robots_dir().iterdir())


def test_a_bad_urdf_leaves_nothing_behind(tmp_path, capsys):
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="r"><link name="a"/><joint name="j" type="revolute"><parent link="a"/>'
                   '<child link="ghost"/><limit lower="0" upper="1"/></joint></robot>')  # fmt: skip
    code, _, err = run(capsys, "robots", "register", "ghostbot", "--urdf", str(bad))
    assert code == 1 and "ghost" in err and "bad.urdf" in err
    assert not robots_dir().exists() or not list(robots_dir().iterdir())


def test_interrupted_registration_is_atomic(tmp_path, monkeypatch):
    """A crash at the final rename leaves no entry and no temporary folder; a retry succeeds."""
    urdf = humanoid().write(tmp_path / "h.urdf")
    real_rename = os.rename

    def crash(src, dst):
        if str(dst).endswith("/atomic"):
            raise KeyboardInterrupt("simulated interruption")
        return real_rename(src, dst)

    monkeypatch.setattr(registry.os, "rename", crash)
    with pytest.raises(KeyboardInterrupt):
        register_robot("atomic", urdf)
    assert not (robots_dir() / "atomic").exists()
    assert not [p for p in robots_dir().iterdir() if p.name.startswith(".tmp")]
    monkeypatch.setattr(registry.os, "rename", real_rename)
    register_robot("atomic", urdf)
    assert load_robot("atomic").skeleton.num_dof == humanoid_dof()


def humanoid_dof() -> int:
    return sum(1 for j in humanoid().joints if j.type == "revolute")


def test_stale_temp_folders_are_swept(tmp_path):
    robots_dir().mkdir(parents=True)
    (robots_dir() / ".tmp-old-123").mkdir()
    register_robot("sweeper", biped().write(tmp_path / "b.urdf"))
    assert not (robots_dir() / ".tmp-old-123").exists()


def test_builtins_cannot_be_unregistered():
    with pytest.raises(RegistryError):
        unregister_robot("g1")


def test_registered_robot_matches_builtin_when_given_the_same_card(tmp_path, capsys):
    """Registering G1's URDF with G1's key points gives G1's skeleton (geometry and key points)."""
    g1 = load_robot("g1")
    kfile = tmp_path / "kp.yaml"
    kfile.write_text(yaml.safe_dump({k: (None if v is None else {"link": v.link, "offset": list(v.offset)})
                                     for k, v in g1.card.keypoints.items()}))  # fmt: skip
    register_robot("g1copy", g1.urdf_path, keypoints_file=kfile)
    copy = get_skeleton("g1copy")
    np.testing.assert_array_equal(copy.offsets, g1.skeleton.offsets)
    assert copy.keypoints == g1.skeleton.keypoints


def test_demo_refuses_an_unknown_show_robot_before_doing_anything(capsys, tmp_path):
    # the whole demo runs in tests/data/shards/test_shards_cli.py::test_demo
    code, out, err = run(capsys, "demo", "--out", str(tmp_path / "d"), "--show", "nobot")
    assert code == 1 and "--show 'nobot'" in err and "mer_demo_humanoid" in err
    assert out == "" and not (tmp_path / "d").exists()


def test_dry_run_prints_the_summary_then_the_show_table_with_verbose_and_writes_nothing(shared_wild_robots, capsys):
    urdf = str(shared_wild_robots / "unitree_h1_hands" / "unitree_h1_hands.urdf")
    code, short, err = run(capsys, "robots", "register", "h1hands", "--urdf", urdf, "--dry-run")
    assert code == 0, err
    assert short.startswith("dry run, nothing written") and "--verbose adds the node table" in short
    assert not [l for l in short.splitlines() if l[:6].strip().isdigit()]  # no node table by default
    code, out, err = run(capsys, "robots", "register", "h1hands", "--urdf", urdf, "--dry-run", "--verbose")
    assert code == 0, err
    assert not robots_dir().exists() or not list(robots_dir().iterdir())
    head = [l for l in out.splitlines() if l.lstrip().startswith("#")]
    assert len(head) == 1 and "zero-pose pos [m]" in head[0] and out.startswith("dry run, nothing written")
    assert out.index("key points:") < out.index(head[0])  # the summary first, the table after it
    rows = {l.split()[1]: l for l in out.splitlines() if l[:6].strip().isdigit()}
    assert rows["left_hand"].split()[-1] == "left_hand" and "site" in rows["left_hand"]
    assert "L_thumb_distal_joint" not in rows  # fingers locked, not nodes
    assert "[high] fixed frame 'L_hand_base_link'" in out and "locked 12 finger joint(s)" in out
    # the same table `mer robots show` prints once it is registered
    assert run(capsys, "robots", "register", "h1hands", "--urdf", urdf)[0] == 0
    _, shown, _ = run(capsys, "robots", "show", "h1hands")
    table = lambda text: [l for l in text.splitlines() if l[:6].strip().isdigit()]  # noqa: E731
    assert table(shown) == table(out)


def test_prismatic_joints_and_fixed_mimics_register_with_warnings(tmp_path, capsys):
    """A gripper with a sliding finger and a mimic-tagged fixed pad: registered, what was ignored said."""
    robot = humanoid()
    text = robot.xml().replace(
        "</robot>",
        '<link name="slide_link"/><link name="pad_link"/>'
        '<joint name="slide" type="prismatic"><parent link="left_hand_link"/><child link="slide_link"/>'
        '<axis xyz="0 1 0"/><limit lower="0.01" upper="0.04"/></joint>'
        '<joint name="pad" type="fixed"><parent link="slide_link"/><child link="pad_link"/>'
        '<mimic joint="slide"/></joint></robot>',
    )
    urdf = tmp_path / "grip.urdf"
    urdf.write_text(text)
    code, out, err = run(capsys, "robots", "register", "gripbot", "--urdf", str(urdf))
    assert code == 0, err
    assert "warning: prismatic joint(s) slide=0.01 locked" in out
    assert "fixed but carries <mimic" in out and "'pad'" in out
    assert get_skeleton("gripbot").locked == {"slide": 0.01}
