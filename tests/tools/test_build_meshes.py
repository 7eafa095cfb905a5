"""tools/build_meshes.py: the built-ins' visual meshes tool. Its pieces on inputs built in code: the
face budget shared by area, the URDF rewrite that touches only the visual file names (line ends
kept), the binary STL mer reads back, and the decimation that keeps the shape (the latter skips
where the ``[tools]`` extra, fast-simplification, is absent)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import build_meshes  # noqa: E402

from mer_data.robots.mesh_io import read_mesh  # noqa: E402


def test_the_budget_is_shared_by_area_capped_by_what_a_file_has_and_floored():
    out = build_meshes.allocate([100_000, 100_000, 50, 10_000], [3.0, 1.0, 5.0, 0.001], budget=8000, floor=48)
    assert out[2] == 50  # a file under its share keeps all its faces
    assert out[3] == 48  # the floor
    assert abs(out[0] - 3 * out[1]) <= 3  # the rest in proportion to area
    assert sum(out) <= 8000 and sum(out) > 7900


def test_the_urdf_rewrite_touches_only_the_visual_file_names_and_keeps_line_ends(tmp_path):
    text = ('<robot name="r">\r\n<link name="a">\r\n  <visual><geometry><mesh filename="package://p/meshes/a.STL"/></geometry></visual>\r\n'
            '  <collision><geometry><mesh filename="package://p/meshes/a.STL"/></geometry></collision>\r\n</link>\r\n</robot>\r\n')  # fmt: skip
    urdf = tmp_path / "r.urdf"
    urdf.write_bytes(text.encode())
    refs = build_meshes.visual_mesh_lines(urdf)
    assert [(line, name) for line, name, _ in refs] == [(3, "package://p/meshes/a.STL")]
    out = build_meshes.rewrite_urdf(text, {3: ("package://p/meshes/a.STL", "visual/a.STL")})
    assert out == text.replace(
        '<visual><geometry><mesh filename="package://p/meshes/a.STL"', '<visual><geometry><mesh filename="visual/a.STL"'
    )
    assert build_meshes.rewrite_urdf(out, {3: ("visual/a.STL", "visual/a.STL")}) == out  # a rerun
    taken: dict[str, str] = {}
    assert build_meshes.shipped_name("m/arm/a.STL", taken) == "a.STL"
    assert build_meshes.shipped_name("m/leg/a.stl", taken) == "leg_a.stl"  # the same name, another file
    assert build_meshes.shipped_name("m/head.dae", taken) == "head.stl"


def test_the_stl_written_reads_back_and_decimation_keeps_the_shape(tmp_path):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.1)  # 20480 faces
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    path = tmp_path / "s.stl"
    path.write_bytes(build_meshes.stl_bytes(v, f, "test"))
    assert path.stat().st_size == 84 + 50 * len(f)
    rv, rf = read_mesh(path)  # mer's own reader (the capped one the viewer uses)
    assert len(rf) == len(f) and np.allclose(rv[rf], v[f], atol=1e-7)
    pytest.importorskip("fast_simplification", reason="the [tools] extra decimates (pip install -e '.[tools]')")
    dv, df, how, dist = build_meshes.simplify(v, f, 500)
    assert 100 < len(df) <= 550 and how
    assert dist < 0.01 and np.abs(np.linalg.norm(dv, axis=1) - 0.1).max() < 0.01  # still a 10 cm sphere
