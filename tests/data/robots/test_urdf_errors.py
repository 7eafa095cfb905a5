"""Bad URDFs: each refused with its own error class, the file, the line and a fix."""

from __future__ import annotations

import pytest

from mer_data.base.errors import (
    BrokenReferenceError,
    KinematicTreeError,
    MalformedURDFError,
    MerError,
    RobotCardError,
    UnsafeURDFError,
    UnsupportedJointError,
)
from mer_data.robots.builder import build_skeleton
from mer_data.robots.card import KeypointSpec, RobotCard
from mer_data.robots.registry import load_robot
from mer_data.robots.urdf import load_urdf, parse_urdf_bytes
from mer_data.skeleton import KEYPOINTS

HEAD = '<?xml version="1.0"?>\n<robot name="r">\n'


def urdf(body: str) -> bytes:
    return (HEAD + body + "\n</robot>\n").encode()


def rev(name, parent, child, line_extra="", limit='<limit lower="-1" upper="1"/>', axis='<axis xyz="0 1 0"/>'):
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f"{axis}{limit}{line_extra}</joint>"
    )


def blank_card(**kw) -> RobotCard:
    return RobotCard(name="r", urdf="r.urdf", keypoints={k: None for k in KEYPOINTS}, **kw)


def test_valid_minimal_urdf_loads():
    m = parse_urdf_bytes(urdf('<link name="a"/><link name="b"/>\n' + rev("j", "a", "b")), "mini.urdf")
    assert m.root == "a" and m.joint_names == ("j",)


def test_malformed_xml_names_file_and_line():
    data = urdf('<link name="a"/>\n<link name="b">\n<joint name="j"')
    with pytest.raises(MalformedURDFError) as e:
        parse_urdf_bytes(data, "bad.urdf")
    assert e.value.path == "bad.urdf" and e.value.line is not None and e.value.line >= 4
    assert "bad.urdf:" in str(e.value) and "fix:" in str(e.value)


def test_not_a_robot_element():
    with pytest.raises(MalformedURDFError, match="not <robot>"):
        parse_urdf_bytes(b"<sdf><model/></sdf>", "x.sdf")


def test_missing_child_link():
    data = urdf('<link name="a"/>\n' + rev("j", "a", "ghost"))
    with pytest.raises(BrokenReferenceError) as e:
        parse_urdf_bytes(data, "r.urdf")
    assert "ghost" in str(e.value) and e.value.line == 4 and "joint 'j'" in str(e.value)


def test_missing_parent_link_suggests_close_name():
    data = urdf('<link name="pelvis"/><link name="b"/>\n' + rev("j", "pelvs", "b"))
    with pytest.raises(BrokenReferenceError, match="did you mean 'pelvis'"):
        parse_urdf_bytes(data, "r.urdf")


def test_missing_parent_element():
    data = urdf('<link name="a"/><link name="b"/>\n<joint name="j" type="fixed"><child link="b"/></joint>')
    with pytest.raises(MalformedURDFError, match="missing <parent"):
        parse_urdf_bytes(data, "r.urdf")


def test_cycle_is_refused():
    body = '<link name="a"/><link name="b"/><link name="c"/>\n' + rev("j1", "a", "b") + "\n" + rev("j2", "b", "c") + "\n" + rev("j3", "c", "b")
    with pytest.raises(KinematicTreeError) as e:
        parse_urdf_bytes(urdf(body), "r.urdf")
    assert "two joints" in str(e.value) or "cycle" in str(e.value)


def test_pure_cycle_without_root():
    body = '<link name="a"/><link name="b"/>\n' + rev("j1", "a", "b") + "\n" + rev("j2", "b", "a")
    with pytest.raises(KinematicTreeError, match="cycle"):
        parse_urdf_bytes(urdf(body), "r.urdf")


def test_two_roots_are_refused():
    body = '<link name="a"/><link name="b"/><link name="c"/><link name="d"/>\n' + rev("j1", "a", "b") + "\n" + rev("j2", "c", "d")
    with pytest.raises(KinematicTreeError) as e:
        parse_urdf_bytes(urdf(body), "r.urdf")
    assert "'a'" in str(e.value) and "'c'" in str(e.value) and "single root" in str(e.value)


@pytest.mark.parametrize("jtype", ["prismatic", "planar", "floating"])
def test_unsupported_joint_types_name_the_joint(jtype):
    lim = '<limit lower="0" upper="0.1"/>' if jtype == "prismatic" else ""
    body = (
        '<link name="a"/><link name="b"/>\n'
        f'<joint name="slider" type="{jtype}"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>{lim}</joint>'
    )
    model = parse_urdf_bytes(urdf(body), "r.urdf")
    with pytest.raises(UnsupportedJointError) as e:
        build_skeleton(model, blank_card())
    assert "slider" in str(e.value) and e.value.line == 4 and jtype in str(e.value)


def test_locked_prismatic_joint_is_accepted():
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>\n'
        '<joint name="slider" type="prismatic"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<limit lower="0" upper="0.5"/></joint>\n' + rev("j", "b", "c")
    )
    skel = build_skeleton(parse_urdf_bytes(urdf(body), "r.urdf"), blank_card(locked={"slider": 0.25}))
    assert skel.node_names == ("a", "j") and skel.offsets[1] == pytest.approx([0, 0, 0.25])


def test_zero_axis_is_refused():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b", axis='<axis xyz="0 0 0"/>')
    with pytest.raises(UnsupportedJointError, match="axis is zero"):
        parse_urdf_bytes(urdf(body), "r.urdf")


def test_revolute_without_limits_is_refused():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b", limit="")
    with pytest.raises(UnsupportedJointError) as e:
        parse_urdf_bytes(urdf(body), "r.urdf")
    assert "limit" in str(e.value) and "continuous" in e.value.fix


def test_inverted_limits_are_refused():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b", limit='<limit lower="1" upper="-1"/>')
    with pytest.raises(MalformedURDFError, match="above upper"):
        parse_urdf_bytes(urdf(body), "r.urdf")


def test_non_numeric_origin_is_refused_with_line():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b", line_extra='\n<origin xyz="0 zero 1"/>')
    with pytest.raises(MalformedURDFError) as e:
        parse_urdf_bytes(urdf(body), "r.urdf")
    assert e.value.line == 5 and "origin xyz" in str(e.value)


def test_duplicate_names_are_refused():
    with pytest.raises(MalformedURDFError, match="defined twice"):
        parse_urdf_bytes(urdf('<link name="a"/><link name="a"/>'), "r.urdf")


def test_mimic_of_unknown_joint():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b", line_extra='<mimic joint="nope"/>')
    with pytest.raises(BrokenReferenceError, match="nope"):
        parse_urdf_bytes(urdf(body), "r.urdf")


def test_external_entities_are_never_resolved(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET-CONTENT")
    data = (
        f'<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY xxe SYSTEM "file://{secret}">]>\n'
        '<robot name="r"><link name="&xxe;"/></robot>\n'
    ).encode()
    path = tmp_path / "evil.urdf"
    path.write_bytes(data)
    with pytest.raises(UnsafeURDFError) as e:
        load_urdf(path)
    assert e.value.line == 2 and "TOP-SECRET" not in str(e.value)


def test_internal_entities_are_refused_too():
    data = b'<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="r"><link name="&a;"/></robot>'
    with pytest.raises(UnsafeURDFError):
        parse_urdf_bytes(data, "r.urdf")


def test_missing_file(tmp_path):
    with pytest.raises(MalformedURDFError, match="not found"):
        load_urdf(tmp_path / "nope.urdf")


def test_keypoint_link_that_does_not_exist():
    body = '<link name="a"/><link name="b"/>\n' + rev("j", "a", "b")
    kps = {k: None for k in KEYPOINTS}
    kps["left_hand"] = KeypointSpec("b_typo")
    card = RobotCard(name="r", urdf="r.urdf", keypoints=kps, path="r.yaml")
    with pytest.raises(BrokenReferenceError) as e:
        build_skeleton(parse_urdf_bytes(urdf(body), "r.urdf"), card)
    assert "b_typo" in str(e.value) and e.value.path == "r.yaml" and "keypoints.left_hand" in str(e.value)


def test_locked_joint_must_exist_and_respect_limits():
    model = parse_urdf_bytes(urdf('<link name="a"/><link name="b"/>\n' + rev("j", "a", "b")), "r.urdf")
    with pytest.raises(RobotCardError, match="not in"):
        build_skeleton(model, blank_card(locked={"jj": 0.0}))
    with pytest.raises(RobotCardError, match="outside its limits"):
        build_skeleton(model, blank_card(locked={"j": 3.0}))


def test_unknown_robot_lists_the_known_ones():
    with pytest.raises(MerError) as e:
        load_robot("nosuchbot")
    assert "g1" in str(e.value) and "valkyrie" in str(e.value) and "register" in str(e.value)


def test_errors_form_one_hierarchy():
    for cls in (MalformedURDFError, UnsafeURDFError, BrokenReferenceError, KinematicTreeError, UnsupportedJointError, RobotCardError):
        assert issubclass(cls, MerError)


def test_mimic_tag_on_a_fixed_joint_is_ignored_with_a_warning():
    """Gripper URDFs often tag fixed joints with <mimic>: a fixed joint moves nothing."""
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>\n' + rev("j", "a", "b") + "\n"
        '<joint name="pad" type="fixed"><parent link="b"/><child link="c"/><origin xyz="0 0 0.1"/>'
        '<mimic joint="j" multiplier="2"/></joint>\n'
    )
    model = parse_urdf_bytes(urdf(body), "r.urdf")
    assert model.joint("pad").mimic is None and model.joint("j").mimic is None
    assert len(model.warnings) == 1 and "r.urdf:5" in model.warnings[0] and "'pad'" in model.warnings[0]
    skel = build_skeleton(model, blank_card())
    assert skel.node_names == ("a", "j") and int((skel.mimic_source >= 0).sum()) == 0


def test_prismatic_mimic_of_a_free_joint_names_a_fix_that_works():
    body = (
        '<link name="a"/><link name="b"/><link name="c"/>\n' + rev("j", "a", "b") + "\n"
        '<joint name="s" type="prismatic"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1"/><mimic joint="j"/></joint>\n'
    )
    model = parse_urdf_bytes(urdf(body), "r.urdf")
    with pytest.raises(UnsupportedJointError) as e:
        build_skeleton(model, blank_card())
    assert "--lock j=" in e.value.fix
    skel = build_skeleton(model, blank_card(locked={"j": 0.5}))  # the fix it names
    assert skel.locked == {"j": 0.5, "s": 0.5}


def test_mimics_of_a_fixed_or_a_locked_prismatic_master_are_held():
    body = (
        '<link name="a"/><link name="b"/><link name="c"/><link name="d"/><link name="e"/>\n'
        '<joint name="f" type="fixed"><parent link="a"/><child link="b"/></joint>\n'
        + rev("m1", "b", "c", line_extra='<mimic joint="f" multiplier="3" offset="0.2"/>') + "\n"
        '<joint name="s" type="prismatic"><parent link="c"/><child link="d"/><axis xyz="0 0 1"/>'
        '<limit lower="0" upper="0.1"/></joint>\n'
        + rev("m2", "d", "e", line_extra='<mimic joint="s" multiplier="2" offset="0.1"/>')
    )
    model = parse_urdf_bytes(urdf(body), "r.urdf")
    with pytest.raises(UnsupportedJointError, match="prismatic"):  # a free prismatic joint still is not
        build_skeleton(model, blank_card())
    skel = build_skeleton(model, blank_card(locked={"s": 0.05}))
    assert skel.locked == pytest.approx({"s": 0.05, "m1": 0.2, "m2": 0.2}) and skel.num_dof == 0
