"""Robots, meshes and motion capture from strangers (issue 51): each class refused at its root, with
mer's own error naming the file. Inputs are built in code (tests/hostile_sources.py), small: limits
are lowered where a class is an amplification, so a regression fails on the limit instead of
exhausting memory. ``tools/hostile_robots.py`` runs the full-size cases and measures them."""

from __future__ import annotations

import hostile_sources as hs
import numpy as np
import pytest

from mer_data.base.errors import BVHError, MalformedURDFError, MerError, MotionFormatError, RobotCardError
from mer_data.base.numbers import parse_count, parse_number
from mer_data.base.safe_io import safe_yaml_load, strict_json_loads
from mer_data.robots.mesh_io import MeshArchiveError, read_mesh
from mer_data.robots.mjcf import load_mjcf, registry_copy
from mer_data.robots.register import load_keypoints_file
from mer_data.robots.shapes import shapes_from_urdf
from mer_data.robots.urdf import load_urdf

# ---- 1. MJCF expansion bombs ---------------------------------------------------------------------


@pytest.mark.parametrize("make", [lambda d: hs.replicate_bomb(d, count=40, depth=2), lambda d: hs.flexcomp_bomb(d, "40 40 1"),
                                  lambda d: hs.jointed_replicate(d, 40)], ids=["replicate", "flexcomp", "jointed"])  # fmt: skip
def test_mjcf_expansion_is_counted_before_mujoco_expands_it(tmp_path, monkeypatch, make):
    monkeypatch.setenv("MER_MAX_MJCF_ELEMENTS", "1000")  # 1,600 would be made: refused, MuJoCo never called
    path = make(tmp_path)
    with pytest.raises(MalformedURDFError, match="MER_MAX_MJCF_ELEMENTS") as e:
        load_mjcf(path)
    assert e.value.path == str(path) and e.value.line and e.value.element


def test_an_mjcf_within_the_element_limit_still_loads(tmp_path, monkeypatch):
    monkeypatch.setenv("MER_MAX_MJCF_ELEMENTS", "1000")
    model = load_mjcf(hs.jointed_replicate(tmp_path, 10))  # 100 jointed bodies
    assert sum(j.type == "continuous" for j in model.joints) == 100


# ---- 2-3. MJCF files outside its folder, <asset><model> and the working directory ------------------


@pytest.mark.parametrize("kind", ["include-abs", "include-up", "meshdir-abs", "mesh-abs", "mesh-up", "mesh-link"])
def test_an_mjcf_reads_nothing_outside_its_folder(tmp_path, kind):
    path = hs.outside_mjcf(tmp_path / "model", kind, tmp_path / "outside")
    with pytest.raises(MalformedURDFError, match="outside the model's folder") as e:
        load_mjcf(path)
    assert e.value.path == str(path) and e.value.element


def test_asset_model_is_read_from_the_models_folder_whatever_the_working_directory(tmp_path, monkeypatch):
    path = hs.model_asset(tmp_path / "model", tmp_path / "cwd")
    monkeypatch.chdir(tmp_path / "cwd")  # holds another sub.xml, which MuJoCo would read
    names = [j.name for j in load_mjcf(path).joints]
    assert "p_own_joint" in names and "p_CWD_JOINT" not in names
    text, extra = registry_copy(path)  # self-contained: the sub-model stored beside it, named relatively
    assert list(extra) == ["model-0.xml"] and 'file="model-0.xml"' in text and "own_joint" in extra["model-0.xml"]


def test_asset_model_outside_the_folder_is_refused(tmp_path):
    with pytest.raises(MalformedURDFError, match="outside the model's folder"):
        load_mjcf(hs.model_asset(tmp_path / "model", tmp_path / "cwd", outside=True))


# ---- 4. meshes that are archives -----------------------------------------------------------------


def test_an_archive_mesh_is_refused_never_unpacked(tmp_path):
    z = hs.zip_mesh(tmp_path / "m.zip", 1 << 20)
    with pytest.raises(MeshArchiveError, match="zip archive"):
        read_mesh(z)
    urdf = load_urdf(hs.urdf(tmp_path, mesh="m.zip"))
    with pytest.raises(MeshArchiveError, match="link 'a'"):  # registration's reader: an error, not a warning
        shapes_from_urdf(urdf)
    (tmp_path / "g.stl").write_bytes(hs.gzip_bytes(1 << 20))  # the name does not matter: the bytes do
    with pytest.raises(MeshArchiveError, match="gzip"):
        read_mesh(tmp_path / "g.stl")


def test_a_real_mesh_still_reads(tmp_path):
    v, f = read_mesh(hs.write_stl(tmp_path / "t.stl", 2.0))
    assert f.shape == (4, 3) and np.isclose(v.max(), 2.0)


# ---- 5. BVH / CSV amplification: limits on what is produced ---------------------------------------


def test_zero_channel_joints_cannot_amplify_the_kinematics(tmp_path, monkeypatch):
    from mer_data.motion.sources import read_source

    monkeypatch.setenv("MER_MAX_MOTION_VALUES", "200000")  # 100 frames x ~230 joints x 12 numbers: over
    path = hs.zero_channel_bvh(tmp_path / "z.bvh", extra=200, frames=100)
    with pytest.raises(BVHError, match="MER_MAX_MOTION_VALUES"):
        read_source(path, "bvh")


@pytest.mark.parametrize("kind", ["bvh", "csv"])
def test_resampling_is_bounded_by_what_it_would_make(tmp_path, kind):
    from mer_data.motion.sources import read_source
    from mer_data.robots.registry import load_robot

    if kind == "bvh":  # Frame Time: 10 -> 0.1 Hz, 300 frames made per frame at 30 Hz
        path, args = hs.slow_bvh(tmp_path / "s.bvh", "10", 20), ("bvh",)
        kw = {}
    else:  # --fps 0.05 on a CSV: 600 frames per frame
        path, args, kw = hs.g1_csv(tmp_path / "g1.csv", 20), (load_robot("g1"),), {"fps": 0.05}
    with pytest.raises(MotionFormatError, match="MER_MAX_UPSAMPLING") as e:
        read_source(path, *args, **kw)
    assert e.value.path == str(path)


def test_a_bvh_table_past_the_produced_limit_is_refused_before_it_is_allocated(tmp_path, monkeypatch):
    from mer_data.motion.bvh import read_bvh

    monkeypatch.setenv("MER_MAX_MOTION_VALUES", "1000")
    with pytest.raises(BVHError, match="channel table"):
        read_bvh(hs.slow_bvh(tmp_path / "a.bvh", "0.0333333", 40))  # 40 frames x 69 channels


# ---- 8. numbers Python accepts and the formats do not ---------------------------------------------


def test_the_strict_number_reader():
    for good, v in (("1.5", 1.5), ("-2", -2.0), (".5", 0.5), ("5.", 5.0), ("3e-4", 3e-4), (" 7 ", 7.0), (b"+1E2", 100.0)):
        assert parse_number(good) == v
    for bad in ("1_0", "\uff11\uff10", "\u0661", "nan", "inf", "-Infinity", "0x10", "", "1e999", "1.2.3", "1 2"):
        assert parse_number(bad) is None, bad
    assert parse_count("12") == 12 and parse_count("1_2") is None and parse_count("-1") is None


@pytest.mark.parametrize("text,where", [("-1_0", "limit"), ("-\uff11", "limit"), ("0.\u0661", "origin")])
def test_urdf_numbers_python_would_read_are_refused(tmp_path, text, where):
    path = hs.odd_number_urdf(tmp_path, text, where)
    with pytest.raises(MalformedURDFError, match="not a decimal number") as e:
        load_urdf(path)
    assert e.value.line == 2 or e.value.line == 1
    assert "joint name='j'" in str(e.value)


@pytest.mark.parametrize("text", ["1_0", "\uff11\uff10"])
def test_csv_cells_python_would_read_are_refused(tmp_path, text):
    from mer_data.motion.lafan1 import read_lafan1_csv

    path = hs.g1_csv(tmp_path / "g1.csv", 10, cell=(3, 9, text))
    with pytest.raises(MotionFormatError, match="non-numeric cell") as e:
        read_lafan1_csv(path, "g1")
    assert e.value.line == 4 and e.value.element == "column 10"


def test_mjcf_counts_are_strict(tmp_path):
    with pytest.raises(MalformedURDFError, match="not a whole number"):
        load_mjcf(hs.mjcf(tmp_path, hs.BODY.format('<replicate count="1_0"><geom size=".1"/></replicate>')))


# ---- 10. duplicate keys ---------------------------------------------------------------------------


def test_duplicate_keys_are_refused_in_json_and_yaml(tmp_path):
    from mer_data.motion.sources import load_bvh_keypoints

    for kind in ("json", "yaml"):
        with pytest.raises(MerError, match="left_ankle"):
            load_bvh_keypoints(hs.duplicate_keys(tmp_path / f"k.{kind}", kind))
    (tmp_path / "r.json").write_text('{"left_toe": null, "left_toe": {"link": "a", "offset": [0, 0, 0]}}')
    with pytest.raises(RobotCardError, match="appears twice"):
        load_keypoints_file(tmp_path / "r.json")
    with pytest.raises(ValueError, match="twice"):
        strict_json_loads('{"a": {"b": 1, "b": 2}}')
    assert safe_yaml_load("a: 1\nb: {c: 2}\n") == {"a": 1, "b": {"c": 2}}


def test_a_kinematics_only_reload_does_not_refuse_asset_paths_it_never_reads(tmp_path):
    path = hs.outside_mjcf(tmp_path / "model", "meshdir-abs", tmp_path / "outside")  # as an older registry copy may hold
    with pytest.raises(MalformedURDFError, match="outside"):
        load_mjcf(path)
    assert "torso" in load_mjcf(path, geometry=False).links  # meshes dropped unread: nothing outside is opened
