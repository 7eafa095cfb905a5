"""An MCAP shard carries the robot as the retarget MCAP does: TF frames named after the URDF's links
(where Foxglove's URDF layer attaches each link's visuals), /robot_description the registered URDF,
/robot its collision shapes on those frames. Oracle for the frames: the shard's own ``pos`` column
(every joint node sits at the origin of its URDF link's frame)."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_viewer import check_mcap, mcap_messages, tf_world
from lxml import etree
from shard_helpers import build, make_input, shard_arrays

from mer_data.robots.registry import load_robot

pytest.importorskip("jsonschema", reason="jsonschema validates the MCAP messages (pip install -e '.[dev]')")


def test_shard_tf_frames_are_the_urdf_links_at_the_windows_joints(tmp_path):
    inp = make_input(tmp_path / "in", robots=("g1",), clips={"walk1_subject1": (2.4, 0.5, 0.0)})
    build(inp, tmp_path / "out", robots=("g1",), targets=("h1",), augment=1, format="mcap", mcap_preview=1, split="all")
    (path,) = sorted((tmp_path / "out").glob("*.mcap"))
    counts = check_mcap(path)  # every message against its embedded schema
    assert counts["/skeleton"] == counts["/robot"] == counts["/robot_description"] == 1
    msgs = mcap_messages(path)
    robot = load_robot("g1")
    urdf = msgs["/robot_description"][0][1]["data"]
    assert urdf == robot.urdf_path.read_text()
    links = {el.get("name") for el in etree.fromstring(urdf.encode()).findall("link")}
    tf = msgs["/tf"]
    frames = {t["child_frame_id"] for t in tf[0][1]["transforms"]}
    assert frames == links  # named as the URDF's links: no joint names, no robot prefix
    assert not any(f.endswith("_joint") for f in frames)
    assert {e["frame_id"] for e in msgs["/robot"][0][1]["entities"]} <= frames
    assert {e["frame_id"] for e in msgs["/skeleton"][0][1]["entities"]} <= frames

    cols = shard_arrays(path)
    skel = robot.skeleton
    window = cols["pos"].shape[1]
    assert len(tf) == window  # preview 1: the first window of the one clip
    assert [t for t, _ in tf] == [int(round(f * 1e9 / 30.0)) for f in range(window)]
    joints = [j for j in range(skel.num_nodes) if skel.node_kinds[j] == "revolute"]
    err = 0.0
    for f in (0, window // 2, window - 1):
        for j in joints:
            origin = tf_world(tf[f][1]["transforms"], skel.link_names[j])[:3, 3]
            err = max(err, float(np.abs(origin - cols["pos"][0, f, j]).max()))
    assert err < 2e-5, err  # JSON rounding (1e-6 m) and the column's float32


def test_a_shard_of_an_unregistered_skeleton_names_its_nodes_links(tmp_path):
    """The shard's skeleton is not the registered robot's (its card was changed after the build):
    frames are the skeleton's own links, and no robot or URDF is claimed."""
    from mer_data.shards.foxglove import registered_robot

    skel = load_robot("h1").skeleton
    assert registered_robot(skel, "h1") is not None
    scaled = skel.with_link_scales(np.full(skel.num_nodes, 1.2))
    assert registered_robot(scaled, "h1") is None
    assert registered_robot(skel, "bvh") is None
