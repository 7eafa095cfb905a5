"""Robot names as a person types them (issue 40, item 6): suggestions, case, speed."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from urdf_factory import biped

from mer_data.base.errors import RegistryError, UnknownRobotError
from mer_data.base.suggest import close_matches, did_you_mean
from mer_data.robots import registry
from mer_data.robots.register import register_robot
from mer_data.robots.registry import get_skeleton, known_names, load_robot, lookup_name, unregister_robot
from mer_models.cli import main

REPO = Path(__file__).resolve().parents[3]


def test_close_matches_offer_the_clear_winner_alone():
    robots = ["g1", "h1", "h1_2", "atlas", "romeo", "valkyrie"]
    assert close_matches("romoe", robots) == ["romeo"]
    assert close_matches("valkrie", robots) == ["valkyrie"]
    assert close_matches("G1", robots) == ["g1"]  # case only
    assert close_matches("g1", robots) == [] and close_matches("nosuch", robots) == []
    assert did_you_mean("romoe", robots) == "did you mean 'romeo'?" and did_you_mean("zzz", robots) == ""
    assert did_you_mean("mer-bse", ["mer-base", "mer-paper", "mer-paper-talos"]) == "did you mean 'mer-base'?"


def test_an_unknown_robot_suggests_the_closest_known_one(tmp_path, capsys):
    register_robot("romeo", biped().write(tmp_path / "b.urdf"))
    with pytest.raises(UnknownRobotError) as info:
        load_robot("romoe")
    text = str(info.value)
    assert "unknown robot 'romoe'; did you mean 'romeo'?" in text and "known robots: g1" in text
    assert "use 'romeo', or register it" in text
    assert main(["robots", "show", "valkrie"]) == 1
    assert "did you mean 'valkyrie'?" in capsys.readouterr().err
    with pytest.raises(UnknownRobotError) as info:  # nothing close: the list and how to register
        load_robot("nosuch")
    assert "did you mean" not in str(info.value) and "mer robots register nosuch" in str(info.value)


def test_robot_names_are_case_insensitive_on_lookup(tmp_path, capsys):
    assert load_robot("G1") is load_robot("g1") and get_skeleton("Valkyrie").name == "valkyrie"
    assert lookup_name("H1_2") == "h1_2"
    register_robot("mybot", biped().write(tmp_path / "b.urdf"))
    assert load_robot("MyBot").name == "mybot"
    assert main(["robots", "show", "G1", "--json"]) == 0 and '"name": "g1"' in capsys.readouterr().out
    with pytest.raises(RegistryError, match="cannot be unregistered"):
        unregister_robot("G1")
    assert unregister_robot("MYBOT").name == "mybot"


def test_registering_keeps_lower_case_names(tmp_path):
    with pytest.raises(RegistryError, match=r"robot names are lower-case: 'newbot'"):
        register_robot("NewBot", biped().write(tmp_path / "b.urdf"))
    assert "newbot" not in known_names()


def test_an_unknown_robot_is_reported_without_reading_any_robot(tmp_path, monkeypatch):
    """Listing names for the message reads folders only: no card, URDF or skeleton is loaded."""
    register_robot("romeo", biped().write(tmp_path / "b.urdf"))

    def boom(*a, **k):
        raise AssertionError("a skeleton was built to report an unknown name")

    monkeypatch.setattr(registry, "build_skeleton", boom)
    monkeypatch.setattr(registry, "load_card", boom)
    t0 = time.perf_counter()
    with pytest.raises(UnknownRobotError, match="did you mean 'romeo'"):
        load_robot("romoe")
    assert time.perf_counter() - t0 < 0.2
    assert known_names()[-1] == "romeo"


def test_an_unknown_robot_on_the_command_line_is_reported_in_well_under_a_second(mer_home):
    """A fresh process (no warm caches): from the command's start to the message, ``mer``'s own start-up aside."""
    code = "import time, sys; from mer_models.cli import main; t = time.perf_counter(); rc = main(['robots', 'show', 'romoe']); " \
           "print(f'{time.perf_counter() - t:.3f}', file=sys.stderr); sys.exit(rc)"  # fmt: skip
    env = {"MER_HOME": str(mer_home), "PATH": "/usr/bin:/bin", "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 1 and "unknown robot 'romoe'" in r.stderr
    seconds = float(r.stderr.strip().splitlines()[-1])
    assert seconds < 1.0, seconds  # measured 0.01 s
