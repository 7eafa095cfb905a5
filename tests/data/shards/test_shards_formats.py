"""HDF5 and MCAP hold the same content: identical samples, lossless round trips, Foxglove channels."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import torch
from mcap.reader import make_reader
from shard_helpers import assert_same_arrays, build, make_input, shard_arrays

from mer_data.base.errors import ShardFormatError
from mer_data.kinematics.fk import fk_skeleton, skeleton_tensors
from mer_data.kinematics.rotations import quat_to_matrix
from mer_data.shards import ShardDataset, open_shard
from mer_data.shards.hdf5_io import Hdf5ShardWriter
from mer_data.shards.mcap_io import McapShardWriter
from mer_data.skeleton import Skeleton

CLIPS = {"dance1_subject1": (3.0, 0.0, 0.1), "fallAndGetUp1_subject1": (2.5, 1.0, -0.2), "fight1_subject2": (2.2, 2.0, 0.3),
         "walk1_subject1": (4.0, 0.5, 0.0)}  # fmt: skip


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    inp = make_input(tmp_path_factory.mktemp("in"), clips=CLIPS)
    h5, mc = tmp_path_factory.mktemp("h5"), tmp_path_factory.mktemp("mcap")
    build(inp, h5)
    build(inp, mc, format="mcap", mcap_preview=2)
    return h5, mc


def test_both_formats_give_identical_samples(both):
    h5, mc = both
    a, b = ShardDataset(h5), ShardDataset(mc)
    assert len(a) == len(b) > 0 and [f.format for f in b.files] == ["mcap"] * 4
    for i in range(len(a)):
        x, y = a[i], b[i]
        assert x.reference.tobytes() == y.reference.tobytes()
        assert x.joint_map.tobytes() == y.joint_map.tobytes()
        assert x.target_skeleton.to_json() == y.target_skeleton.to_json()
        assert x.reference_skeleton.to_json() == y.reference_skeleton.to_json()
        assert (x.target is None) == (y.target is None)
        if x.target is not None:
            assert x.target.tobytes() == y.target.tobytes()
        px, py = dict(x.provenance), dict(y.provenance)
        assert px.pop("file").replace(".h5", "") == py.pop("file").replace(".mcap", "") and px == py
    for name in (p.name for p in h5.glob("*.h5")):
        assert_same_arrays(shard_arrays(h5 / name), shard_arrays(mc / name.replace(".h5", ".mcap")))


def test_round_trip_hdf5_mcap_hdf5_is_lossless(both, tmp_path):
    h5, _ = both
    src = open_shard(h5 / "g1-train-00000-of-00001.h5")
    rows = src.rows(0, src.num_rows)
    w = McapShardWriter(tmp_path / "x.mcap", src.meta)
    w.append(rows)
    w.close()
    mid = open_shard(tmp_path / "x.mcap")
    w2 = Hdf5ShardWriter(tmp_path / "y.h5", mid.meta)
    w2.append(mid.rows(0, mid.num_rows))
    w2.close()
    back = open_shard(tmp_path / "y.h5")
    assert_same_arrays(rows, back.rows(0, back.num_rows))
    assert back.meta.to_attrs() == src.meta.to_attrs()


def _world_from_transforms(msg: dict) -> dict[str, np.ndarray]:
    """Compose a FrameTransforms message into world positions of every child frame."""
    tf = {t["child_frame_id"]: t for t in msg["transforms"]}
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {"world": (np.zeros(3), np.eye(3))}

    def pose(frame):
        if frame not in out:
            t = tf[frame]
            p, r = pose(t["parent_frame_id"])
            q = t["rotation"]
            rot = quat_to_matrix(torch.tensor([q["w"], q["x"], q["y"], q["z"]], dtype=torch.float64)).numpy()
            tr = np.array([t["translation"][k] for k in "xyz"])
            out[frame] = (p + r @ tr, r @ rot)
        return out[frame]

    return {f: pose(f)[0] for f in tf}


def test_mcap_is_a_foxglove_scene_of_the_skeleton(both):
    """TF frames are the URDF's links (Foxglove's URDF layer attaches the robot's visuals to them),
    the URDF and the collision shapes ride along, once per file."""
    from lxml import etree

    from mer_data.robots.registry import load_robot

    _, mc = both
    path = mc / "h1-train-00000-of-00001.mcap"
    shard = open_shard(path)
    skel = Skeleton.from_json(shard.meta.skeletons["h1"])
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert schemas == {"/mer/windows": "mer.ShardWindow", "/tf": "foxglove.FrameTransforms", "/skeleton": "foxglove.SceneUpdate",
                           "/robot": "foxglove.SceneUpdate", "/robot_description": "std_msgs/String"}  # fmt: skip
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        tfs = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/tf"])]
    with open(path, "rb") as f:
        msgs = {}
        for _, ch, m in make_reader(f).iter_messages(topics=["/skeleton", "/robot", "/robot_description"]):
            msgs.setdefault(ch.topic, []).append(json.loads(m.data))
    scenes, urdf = msgs["/skeleton"], msgs["/robot_description"][0]["data"]
    clips = len(shard.meta.sources)
    assert len(tfs) == clips * 2 * 60 and len(scenes) == len(msgs["/robot"]) == 1  # 2 preview windows per clip, 60 frames each
    assert urdf == load_robot("h1").urdf_path.read_text()
    links = {el.get("name") for el in etree.fromstring(urdf.encode()).findall("link")}
    assert all({t["child_frame_id"] for t in m["transforms"]} == links for m in tfs)
    ents = scenes[0]["entities"]
    joints = [j for j in range(skel.num_nodes) if skel.node_kinds[j] != "site"]
    assert len(ents) == len(joints) and sum(len(e["lines"][0]["points"]) // 2 for e in ents if e["lines"]) == skel.num_nodes - 1
    # composing the transforms of a frame reproduces the stored node positions (the FK of the data):
    # every joint node sits at the origin of its link's frame
    pos = shard.row("pos", 0)
    for t in (0, 31, 59):
        world = _world_from_transforms(tfs[t])
        got = np.stack([world[skel.link_names[j]] for j in joints])
        np.testing.assert_allclose(got, pos[t, joints], atol=1e-5)
    # and the stored angles drive the foundation's FK to the same place
    st = skeleton_tensors(skel, torch.float64)
    q = torch.from_numpy(shard.row("q", 0).astype(np.float64))
    rv = torch.from_numpy(shard.row("base_rotvec", 0).astype(np.float64))
    from mer_data.kinematics.rotations import axis_angle_to_quat

    fk, _ = fk_skeleton(st, q, torch.from_numpy(pos[:, 0].astype(np.float64)), base_quat=axis_angle_to_quat(rv))
    np.testing.assert_allclose(fk.numpy(), pos, atol=1e-5)


def test_damaged_and_foreign_files(both, tmp_path):
    h5, mc = both
    src = h5 / "g1-eval-00000-of-00001.h5"
    cut = tmp_path / "cut.h5"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    with pytest.raises(ShardFormatError):
        open_shard(cut)
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"hello, not a shard")
    with pytest.raises(ShardFormatError, match="neither HDF5 nor MCAP"):
        open_shard(junk)
    msrc = mc / "g1-eval-00000-of-00001.mcap"
    mcut = tmp_path / "cut.mcap"
    mcut.write_bytes(msrc.read_bytes()[: msrc.stat().st_size // 2])
    with pytest.raises(ShardFormatError):
        ShardDataset(mcut)[0]
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ShardFormatError, match="not a mer shard"):
        open_shard(other)
    old = tmp_path / "old.h5"
    old.write_bytes(src.read_bytes())
    with h5py.File(old, "r+") as f:
        f.attrs["format_version"] = 0
    with pytest.raises(ShardFormatError, match="format version 0") as exc:
        open_shard(old)
    assert "mer shards build" in exc.value.fix
