"""“Did you mean …?” by a distance that knows how robot names are built (issue 52, item 3): a vendor
prefix, separators and variants name the same robot; a different model number is never a typo."""

from __future__ import annotations

import pytest

from mer_data.base.suggest import close_matches, did_you_mean, family_matches

BUILTIN = ["g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie"]
# the built-ins and robots of ../shared/robots-wild registered under their folder names
REGISTERED = [*BUILTIN, "unitree_h2", "unitree_g1_hands", "tron1_wheelfoot", "romeo", "limx_p441a"]


@pytest.mark.parametrize("typed, known, want", [
    ("unitree_g1", REGISTERED, ["g1"]),  # issue 52: it said 'unitree_h2' (the vendor outweighed the model)
    ("unitree_g1", BUILTIN, ["g1"]),
    ("UNITREE-G1", REGISTERED, ["g1"]),
    ("h2", REGISTERED, ["unitree_h2"]),  # a registered H2 under its vendor's name is the answer
    ("h1-2", REGISTERED, ["h1_2"]),
    ("unitree_h1", REGISTERED, ["h1"]),
    ("limx_tron1", REGISTERED, ["tron1"]),
    ("pal_talos", REGISTERED, ["talos"]),
    ("p441a", REGISTERED, ["limx_p441a"]),
    ("g1_29dof", REGISTERED, ["g1"]),  # a variant's longer name
    ("tron", REGISTERED, ["tron1"]),
    ("tron1_wheel", REGISTERED, ["tron1_wheelfoot"]),
    ("atlas2", REGISTERED, ["atlas"]),
    ("romoe", REGISTERED, ["romeo"]),  # typos still work
    ("valkrie", REGISTERED, ["valkyrie"]),
    ("H1_2", REGISTERED, ["h1_2"]),
    ("mer-bse", ["mer-base", "mer-paper", "mer-paper-talos"], ["mer-base"]),
    ("mer_base", ["mer-base", "mer-paper"], ["mer-base"]),
    ("--targt", ["--target", "--targets", "--source"], ["--target", "--targets"]),
    ("--robot", ["--robots", "--out"], ["--robots"]),
    ("h2", BUILTIN, []),  # issue 52: it said 'h1_2'; H2 is another robot of the family
    ("g2", BUILTIN, []),
    ("zzz", REGISTERED, []),
    ("g1", REGISTERED, []),
])  # fmt: skip
def test_close_matches_respect_robot_families(typed, known, want):
    assert close_matches(typed, known) == want


def test_another_model_number_is_offered_as_the_family_not_as_the_answer():
    assert family_matches("h2", BUILTIN) == ["h1", "h1_2"]
    assert did_you_mean("h2", BUILTIN) == "nothing by that name; of the same family: 'h1' and 'h1_2' (other model numbers)"
    assert family_matches("g2", REGISTERED) == ["g1", "unitree_g1_hands"]
    assert family_matches("h2", REGISTERED) == []  # unitree_h2 is the answer, not the family
    assert did_you_mean("unitree_g1", REGISTERED) == "did you mean 'g1'?"
    assert did_you_mean("zzz", REGISTERED) == "" and family_matches("zzz", REGISTERED) == []


def test_an_unknown_robot_of_a_known_family_is_told_how_to_register_it():
    from mer_data.base.errors import UnknownRobotError
    from mer_data.robots.registry import load_robot

    with pytest.raises(UnknownRobotError) as info:
        load_robot("h2")
    text = str(info.value)
    assert "unknown robot 'h2'; nothing by that name; of the same family: 'h1' and 'h1_2'" in text
    assert "did you mean" not in text and "mer robots register h2 --urdf" in text
    with pytest.raises(UnknownRobotError, match="(?s)did you mean 'g1'.*use 'g1', or register"):
        load_robot("unitree_g1")
