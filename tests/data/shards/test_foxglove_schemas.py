"""Foxglove draws mer's MCAPs: every channel's embedded JSON schema parses the way the viewer
(Lichtblick / Foxglove) parses it, the foxglove.* schemas are Foxglove's official ones, and every
message of a real `mer retarget --mcap` and `mer shards build --format mcap` output validates."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from foxglove_viewer import ViewerSchemaError, check_mcap, viewer_datatypes
from mcap.reader import make_reader
from model_helpers import synthetic_csv
from shard_helpers import make_input

from mer_data.shards.foxglove import FRAME_TRANSFORMS_SCHEMA, SCENE_UPDATE_SCHEMA
from mer_data.shards.mcap_io import _WINDOW_SCHEMA
from mer_models.cli import main

pytest.importorskip("jsonschema", reason="jsonschema validates the MCAP messages (pip install -e '.[dev]')")

VENDORED = Path(__file__).resolve().parents[3] / "mer_data" / "shards" / "foxglove_schemas"


def _schemas(path) -> dict[str, tuple[str, bytes]]:
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    return {c.topic: (s.schemas[c.schema_id].name, s.schemas[c.schema_id].data) for c in s.channels.values()}


def test_the_viewer_rules_refuse_what_lichtblick_refuses():
    """The helper is a real check: the schemas mer used to embed fail it, at the right place."""
    old_scene = {"title": "foxglove.SceneUpdate", "type": "object",
                 "properties": {"deletions": {"type": "array"}, "entities": {"type": "array", "items": {"type": "object"}}}}  # fmt: skip
    with pytest.raises(ViewerSchemaError, match=r"^deletions: array without an \"items\""):
        viewer_datatypes(old_scene, "foxglove.SceneUpdate")
    old_windows = {"title": "mer.ShardWindow", "type": "object", "properties": {"row": {"type": "integer"}, "pos": {}}}
    with pytest.raises(ViewerSchemaError, match="^pos: unsupported type None"):
        viewer_datatypes(old_windows, "mer.ShardWindow")
    nested = {"type": "object", "properties": {"m": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}}}
    with pytest.raises(ViewerSchemaError, match="unsupported array item type 'array'"):
        viewer_datatypes(nested, "x")
    enum = {"type": "object", "properties": {"k": {"oneOf": [{"const": 0}, {"const": "a"}]}}}
    with pytest.raises(ViewerSchemaError, match="oneOf"):
        viewer_datatypes(enum, "x")


def test_embedded_schemas_are_the_official_ones_and_parse():
    for name, text in (("FrameTransforms", FRAME_TRANSFORMS_SCHEMA), ("SceneUpdate", SCENE_UPDATE_SCHEMA)):
        assert text == (VENDORED / f"{name}.json").read_bytes()
        schema = json.loads(text)
        assert schema["title"] == f"foxglove.{name}" and "foxglove-sdk" in schema["$comment"]
        types = viewer_datatypes(schema, f"foxglove.{name}")
        assert len(types) > 3
    scene = viewer_datatypes(json.loads(SCENE_UPDATE_SCHEMA), "foxglove.SceneUpdate")
    assert ("deletions", "foxglove.SceneUpdate.deletions", True) in scene["foxglove.SceneUpdate"]
    assert ("type", "uint32", False) in scene["foxglove.SceneUpdate.entities.lines"]  # LineType enum
    assert "MIT License" in (VENDORED / "LICENSE").read_text()
    win = viewer_datatypes(json.loads(_WINDOW_SCHEMA), "mer.ShardWindow")
    assert ("base64", "uint8", True) in win["mer.ShardWindow.pos"] and ("clip", "string", False) in win["mer.ShardWindow"]


def test_every_message_of_a_retarget_mcap_validates(tmp_path, capsys):
    src = synthetic_csv(tmp_path / "walk.csv", frames=20)
    out = tmp_path / "h1.mcap"
    code = main(["retarget", str(src), "--source", "g1", "--target", "h1", "--method", "optimize", "--mcap", str(out)])
    assert code == 0, capsys.readouterr().err
    assert {t: n for t, (n, _) in _schemas(out).items()} == {
        "/tf": "foxglove.FrameTransforms", "/skeleton": "foxglove.SceneUpdate", "/reference": "foxglove.SceneUpdate",
        "/robot": "foxglove.SceneUpdate", "/robot_description": "std_msgs/String"}  # fmt: skip
    foxglove = {d for n, d in _schemas(out).values() if n.startswith("foxglove.")}
    assert foxglove == {FRAME_TRANSFORMS_SCHEMA, SCENE_UPDATE_SCHEMA}
    assert check_mcap(out) == {"/tf": 20, "/skeleton": 1, "/reference": 20, "/robot": 1, "/robot_description": 1}


def test_every_message_of_a_shard_mcap_validates(tmp_path, capsys):
    clips = {"dance1_subject1": (2.2, 0.0, 0.1), "walk1_subject1": (2.4, 0.5, 0.0)}
    inp = make_input(tmp_path / "in", clips=clips)
    out = tmp_path / "out"
    code = main(["shards", "build", "--input", str(inp), "--robots", "g1", "h1", "--out", str(out), "--augment", "1",
                 "--workers", "1", "--format", "mcap", "--split", "all"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    files = sorted(out.glob("*.mcap"))
    assert files
    total = {}
    for path in files:
        assert {t: n for t, (n, _) in _schemas(path).items()} == {
            "/mer/windows": "mer.ShardWindow", "/tf": "foxglove.FrameTransforms", "/skeleton": "foxglove.SceneUpdate",
            "/robot": "foxglove.SceneUpdate", "/robot_description": "std_msgs/String"}  # fmt: skip
        for topic, n in check_mcap(path).items():
            total[topic] = total.get(topic, 0) + n
    assert total["/mer/windows"] > 0 and total["/tf"] > 0
    assert total["/skeleton"] == total["/robot"] == total["/robot_description"] == len(files)  # once per file


def test_a_nonconforming_message_is_caught(tmp_path):
    """check_mcap fails on a message the official schema rejects (a sphere without its colour)."""
    from mcap.writer import Writer

    path = tmp_path / "bad.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("foxglove.SceneUpdate", "jsonschema", SCENE_UPDATE_SCHEMA)
        ch = w.register_channel("/s", "json", sid)
        ident = {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}}
        ent = {"timestamp": {"sec": 0, "nsec": 0}, "frame_id": "world", "id": "a", "lifetime": {"sec": 0, "nsec": 0},
               "frame_locked": False, "metadata": [], "arrows": [], "cubes": [], "cylinders": [], "lines": [], "triangles": [],
               "texts": [], "models": [], "spheres": [{"pose": ident, "size": {"x": 1, "y": 1, "z": 1}}]}  # fmt: skip
        w.add_message(ch, 0, json.dumps({"deletions": [], "entities": [ent]}).encode(), 0)
        w.finish()
    with pytest.raises(AssertionError, match="/s message 0: at 'entities/0/spheres/0': 'color' is a required property"):
        check_mcap(path)
