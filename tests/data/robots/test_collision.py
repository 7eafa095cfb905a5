"""Collision geometry: the file format (strict), shapes from a URDF (meshes as hulls, missing meshes,
nothing read outside the URDF's folder), fitted capsules, feet and the pairs that are checked."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from mer_data.base.errors import RobotCardError
from mer_data.robots.card import parse_card
from mer_data.robots.collision import collision_model, polytope, shape_vertices
from mer_data.robots.hulls import simplify_hull
from mer_data.robots.registry import load_robot
from mer_data.robots.shapes import Shape, dump_collision, parse_collision, shapes_from_urdf
from mer_data.robots.urdf import load_urdf

GOOD = {"format": "mer-collision", "format_version": 1, "robot": "r", "source": "test",
        "links": {"a": [{"type": "box", "size": [0.1, 0.2, 0.3], "xyz": [0, 0, 0.1], "rpy": [0, 0, 0.5]},
                        {"type": "sphere", "radius": 0.05, "xyz": [0.1, 0, 0]},
                        {"type": "hull", "vertices": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]}]},
        "missing": []}  # fmt: skip


def test_round_trip_keeps_every_shape():
    cf = parse_collision(json.dumps(GOOD))
    again = parse_collision(dump_collision(cf))
    assert list(again.links) == ["a"] and [s.type for s in again.links["a"]] == ["box", "sphere", "hull"]
    for s1, s2 in zip(cf.links["a"], again.links["a"]):
        np.testing.assert_allclose(shape_vertices(s1), shape_vertices(s2), atol=2e-5)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda d: d.update(format="x"), "not a mer-collision"),
        (lambda d: d.update(format_version=9), "format_version"),
        (lambda d: d["links"]["a"].append({"type": "cone"}), "type one of"),
        (lambda d: d["links"]["a"].append({"type": "sphere", "radius": -1}), "radius"),
        (lambda d: d["links"]["a"].append({"type": "box", "size": [1, 1]}), "size"),
        (lambda d: d["links"]["a"].append({"type": "box", "size": [1, 1, 1], "color": 1}), "unknown field"),
        (lambda d: d["links"]["a"].append({"type": "hull", "vertices": [[0, 0, 0]] * 70}), "4 to 64"),
        (lambda d: d["links"]["a"].append({"type": "hull", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]}), "flat"),
    ],
)
def test_bad_files_are_refused_with_the_element(edit, match):
    d = json.loads(json.dumps(GOOD))
    edit(d)
    with pytest.raises(RobotCardError, match=match):
        parse_collision(json.dumps(d), "c.json")
    with pytest.raises(RobotCardError, match="not valid JSON"):
        parse_collision('{"format": NaN', "c.json")


def test_nan_and_huge_numbers_are_refused():
    text = json.dumps(GOOD).replace("0.05", "NaN")
    with pytest.raises(RobotCardError):
        parse_collision(text)
    text = json.dumps(GOOD).replace("0.05", "1e9")
    with pytest.raises(RobotCardError, match="finite numbers"):
        parse_collision(text)


def test_the_card_names_a_file_beside_it():
    from mer_data.skeleton import KEYPOINTS

    base = "name: r\nurdf: r.urdf\nkeypoints: {" + ", ".join(f"{k}: null" for k in KEYPOINTS) + "}\n"
    assert parse_card(base + "collision: collision.json\n").collision == "collision.json"
    for bad in ("../x.json", "/etc/passwd", "a/b.json", ".hidden"):
        with pytest.raises(RobotCardError, match="collision"):
            parse_card(base + f"collision: {bad}\n")


def test_primitive_polytopes_contain_their_shape():
    eye = np.eye(4)
    for s, far in ((Shape("sphere", eye, radius=0.1), 0.1), (Shape("cylinder", eye, radius=0.05, length=0.2), 0.05),
                   (Shape("capsule", eye, radius=0.05, length=0.2), 0.05)):  # fmt: skip
        _, planes, _ = polytope(shape_vertices(s))
        rng = np.random.default_rng(0)
        d = rng.normal(size=(500, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        if s.type == "sphere":
            surface = d * far
        else:  # points on the curved side and on the caps' rims
            ang = rng.uniform(0, 2 * np.pi, 500)
            surface = np.stack([np.cos(ang) * far, np.sin(ang) * far, rng.uniform(-0.1, 0.1, 500)], 1)
        inside = (surface @ planes[:, :3].T + planes[:, 3]).max(1)
        assert inside.max() <= 1e-9  # circumscribed
        assert inside.max() > -0.02 * far * 10  # and not much larger


def test_simplified_hull_is_inside_and_close():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(2000, 3)) * [0.1, 0.05, 0.03]
    v, err, _ = simplify_hull(pts, 48)
    assert len(v) <= 48 and err < 0.01
    _, planes, _ = polytope(pts)
    assert ((v @ planes[:, :3].T + planes[:, 3]).max(1) <= 1e-5).all()  # an inner approximation (10 µm rounding)


def _stl(path, vertices: np.ndarray) -> None:
    """A binary STL of the tetrahedra fan of ``vertices`` (enough for a hull)."""
    tris = [(0, i, i + 1) for i in range(1, len(vertices) - 1)]
    with open(path, "wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(tris)))
        for a, b, c in tris:
            f.write(struct.pack("<12fH", 0, 0, 0, *vertices[a], *vertices[b], *vertices[c], 0))


URDF = """<?xml version="1.0"?>
<robot name="m">
  <link name="base"><collision><geometry><mesh filename="package://m_description/meshes/base.stl" scale="2 2 2"/></geometry></collision></link>
  <link name="arm"><collision><origin xyz="0 0 0.1" rpy="0 0 0"/><geometry><box size="0.1 0.1 0.2"/></geometry></collision></link>
  <link name="hand"><collision><geometry><mesh filename="meshes/missing.stl"/></geometry></collision></link>
  <link name="out"><collision><geometry><mesh filename="../outside.stl"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="3"/></joint>
  <joint name="j2" type="revolute"><parent link="arm"/><child link="hand"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-1" upper="1"/></joint>
  <joint name="j3" type="fixed"><parent link="hand"/><child link="out"/><origin xyz="0 0 0.1"/></joint>
</robot>
"""


def test_shapes_from_urdf_reads_meshes_under_its_folder_only(tmp_path):
    root = tmp_path / "robot"
    (root / "meshes").mkdir(parents=True)
    cube = np.array([[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)], float)
    _stl(root / "meshes" / "base.stl", cube)
    _stl(tmp_path / "outside.stl", cube)  # beside the folder the user named: never read
    (root / "m.urdf").write_text(URDF)
    cf, errors = shapes_from_urdf(load_urdf(root / "m.urdf"))
    assert [s.type for s in cf.links["base"]] == ["hull"] and [s.type for s in cf.links["arm"]] == ["box"]
    np.testing.assert_allclose(cf.links["base"][0].vertices.max(0), [0.2, 0.2, 0.2])  # scale applied
    assert set(cf.missing) == {"hand", "out"}
    assert errors["base"] < 1e-6
    cf2, _ = shapes_from_urdf(load_urdf(root / "m.urdf"), load_meshes=False)
    assert "base" not in cf2.links and "base" in cf2.missing


def test_builtin_models_cover_every_body_and_mark_the_feet():
    for name in ("g1", "h1", "atlas", "tron1"):
        r = load_robot(name)
        m = collision_model(r)
        carried = set(m.node.tolist())
        bodies = {j for j, k in enumerate(r.skeleton.node_kinds) if k != "site"}
        assert bodies <= carried  # every body collides (its own shapes, or fitted ones)
        assert (m.foot == 1).any() and (m.foot == 2).any()
        ankle = r.skeleton.keypoints["left_ankle"]
        assert set(m.node[m.foot == 1].tolist()) <= set(np.flatnonzero(r.skeleton.subtree(ankle)).tolist()) | set(
            np.flatnonzero(r.skeleton.subtree(max(r.skeleton.keypoints["left_toe"], 0))).tolist())
        node_pairs = {(int(m.node[a]), int(m.node[b])) for a, b in m.pairs}
        parents = r.skeleton.parents
        assert all(a != b and parents[a] != b and parents[b] != a for a, b in node_pairs)
        assert np.isfinite(m.velocity_limit[1:][np.array(r.skeleton.node_kinds[1:]) == "revolute"]).all()


def test_a_urdf_without_collision_gets_fitted_capsules(tmp_path):
    from urdf_factory import humanoid

    from mer_data.robots.register import register_robot

    text = humanoid().xml()
    import re

    text = re.sub(r"<collision>.*?</collision>", "", text, flags=re.S)  # no geometry at all
    (tmp_path / "h.urdf").write_text(text)
    register_robot("bare", tmp_path / "h.urdf")
    r = load_robot("bare")
    m = collision_model(r)
    assert set(m.source) == {"fitted"}
    bodies = {j for j, k in enumerate(r.skeleton.node_kinds) if k != "site"}
    assert bodies <= set(m.node.tolist())  # every body collides
    assert len(m.pairs) > 0


def test_registration_keeps_mesh_hulls_and_warns_about_missing_meshes(tmp_path):
    from urdf_factory import humanoid

    from mer_data.robots.register import register_robot

    root = tmp_path / "robot"
    (root / "meshes").mkdir(parents=True)
    cube = np.array([[x, y, z] for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)], float)
    _stl(root / "meshes" / "pelvis.stl", cube)
    text = humanoid().xml()
    first = text.index("<link name=")
    end = text.index(">", first)
    base = text[first + len('<link name="') : text.index('"', first + len('<link name="'))]
    mesh = ('<collision><geometry><mesh filename="meshes/pelvis.stl"/></geometry></collision>'
            '<collision><geometry><mesh filename="meshes/gone.stl"/></geometry></collision>')  # fmt: skip
    if text[end - 1] == "/":  # <link name="x"/>
        text = text[: end - 1] + ">" + mesh + "</link>" + text[end + 1 :]
    else:
        text = text[: end + 1] + mesh + text[end + 1 :]
    (root / "h.urdf").write_text(text)
    report = register_robot("meshy", root / "h.urdf")
    assert any("could not be read" in w and base in w for w in report.warnings)
    r = load_robot("meshy")
    assert r.card.collision == "collision.json" and (r.folder / "collision.json").is_file()
    m = collision_model(r)
    assert "mesh" in m.counts() and base in m.missing
    hull = [i for i in range(m.num_shapes) if m.source[i] == "mesh"][0]
    assert m.link[hull] == base
