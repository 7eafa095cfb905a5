"""What a Foxglove viewer does with an MCAP's JSON channels, re-stated for tests.

Lichtblick (the open-source Foxglove app, packages/mcap-support ``parseJsonSchema``) turns a
channel's ``jsonschema`` into message datatypes before it draws anything; a schema it cannot parse
makes it drop the channel. Its rules, as implemented in :func:`viewer_datatypes`:

* the root and every nested object have ``"type": "object"``; ``properties`` may be absent;
* a property is either ``oneOf`` alternatives that are all numeric ``const`` (an enum: uint32), or has
  a ``type`` among boolean, string (``contentEncoding`` absent or ``base64``), number, integer,
  object (parsed recursively) or array;
* an array has ``items`` whose ``type`` is boolean, string (no ``contentEncoding``), number,
  integer or object (recursively); arrays of arrays, ``null`` and untyped properties are refused.

On top of parsing, :func:`check_mcap` validates every message of every channel against its
embedded schema with ``jsonschema`` and decodes every ``base64`` string the way the viewer does.
"""

from __future__ import annotations

import base64
import binascii
import json
from pathlib import Path

from mcap.reader import make_reader

_SCALARS = {"boolean": "bool", "number": "float64"}


class ViewerSchemaError(ValueError):
    """The viewer would refuse the schema (and drop the channel)."""


def _integer(schema: dict) -> str:
    lo = schema.get("minimum", schema.get("exclusiveMinimum"))
    return "uint32" if isinstance(lo, (int, float)) and lo >= 0 else "int32"


def viewer_datatypes(schema: dict, name: str) -> dict[str, list[tuple[str, str, bool]]]:
    """Datatypes the viewer derives from ``schema``: type name -> [(field, type, is_array)].

    Raises :class:`ViewerSchemaError` naming the key path where the viewer would fail.
    """
    out: dict[str, list[tuple[str, str, bool]]] = {}

    def obj(s: dict, tname: str, path: list[str]) -> None:
        if not isinstance(s, dict) or s.get("type") != "object":
            raise ViewerSchemaError(f'{".".join(path) or name}: expected "type": "object", got {s!r:.80}')
        fields: list[tuple[str, str, bool]] = []
        for fname, fs in (s.get("properties") or {}).items():
            where = ".".join(path + [fname])
            if not isinstance(fs, dict):
                raise ViewerSchemaError(f"{where}: property schema is not an object")
            if isinstance(fs.get("oneOf"), list):
                if not all(isinstance(a, dict) and isinstance(a.get("const"), (int, float)) and not isinstance(a.get("const"), bool)
                           for a in fs["oneOf"]):  # fmt: skip
                    raise ViewerSchemaError(f"{where}: oneOf alternatives must have number values")
                fields.append((fname, "uint32", False))
                continue
            t = fs.get("type")
            if t in _SCALARS:
                fields.append((fname, _SCALARS[t], False))
            elif t == "string":
                enc = fs.get("contentEncoding")
                if enc not in (None, "base64"):
                    raise ViewerSchemaError(f"{where}: unsupported contentEncoding {enc!r}")
                fields.append((fname, "uint8" if enc else "string", enc is not None))
            elif t == "integer":
                fields.append((fname, _integer(fs), False))
            elif t == "object":
                obj(fs, f"{tname}.{fname}", path + [fname])
                fields.append((fname, f"{tname}.{fname}", False))
            elif t == "array":
                it = fs.get("items")
                if not isinstance(it, dict):
                    raise ViewerSchemaError(f'{where}: array without an "items" schema')
                it_t = it.get("type")
                if it_t in _SCALARS:
                    fields.append((fname, _SCALARS[it_t], True))
                elif it_t == "string":
                    if it.get("contentEncoding") is not None:
                        raise ViewerSchemaError(f"{where}: contentEncoding on array items is unsupported")
                    fields.append((fname, "string", True))
                elif it_t == "integer":
                    fields.append((fname, _integer(it), True))
                elif it_t == "object":
                    obj(it, f"{tname}.{fname}", path + [fname])
                    fields.append((fname, f"{tname}.{fname}", True))
                else:
                    raise ViewerSchemaError(f"{where}: unsupported array item type {it_t!r}")
            else:
                raise ViewerSchemaError(f"{where}: unsupported type {t!r}")
        out[tname] = fields

    obj(schema, name, [])
    return out


def _decode_base64(value, schema: dict, where: str) -> None:
    """Decode every ``contentEncoding: base64`` string of ``value`` (as the viewer's post-processing does)."""
    if not isinstance(value, dict):
        return
    for fname, fs in (schema.get("properties") or {}).items():
        if fname not in value:
            continue
        v = value[fname]
        if fs.get("type") == "string" and fs.get("contentEncoding") == "base64":
            try:
                base64.b64decode(v, validate=True)
            except (binascii.Error, TypeError) as exc:
                raise AssertionError(f"{where}.{fname}: not base64 ({exc})") from None
        elif fs.get("type") == "object":
            _decode_base64(v, fs, f"{where}.{fname}")
        elif fs.get("type") == "array" and isinstance(fs.get("items"), dict) and fs["items"].get("type") == "object":
            for i, x in enumerate(v):
                _decode_base64(x, fs["items"], f"{where}.{fname}[{i}]")


def check_mcap(path: str | Path) -> dict[str, int]:
    """Parse every JSON channel's schema as the viewer does and validate every message against it.

    Returns messages per topic. Raises :class:`ViewerSchemaError` (schema) or ``AssertionError``
    (a message that does not conform, with its topic, index and the failing key path).
    """
    from jsonschema import Draft202012Validator

    counts: dict[str, int] = {}
    validators: dict[int, tuple[Draft202012Validator, dict]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        for ch in summary.channels.values():
            sc = summary.schemas[ch.schema_id]
            assert ch.message_encoding == "json" and sc.encoding == "jsonschema", (ch.topic, ch.message_encoding, sc.encoding)
            schema = json.loads(sc.data)
            viewer_datatypes(schema, sc.name)
            Draft202012Validator.check_schema(schema)
            validators[ch.id] = (Draft202012Validator(schema), schema)
            counts[ch.topic] = 0
        for _, ch, msg in reader.iter_messages(log_time_order=False):
            v, schema = validators[ch.id]
            data = json.loads(msg.data)
            errors = sorted(v.iter_errors(data), key=lambda e: list(e.absolute_path))
            if errors:
                e = errors[0]
                where = "/".join(map(str, e.absolute_path))
                raise AssertionError(
                    f"{ch.topic} message {counts[ch.topic]}: at '{where}': {e.message[:200]} ({len(errors)} errors)"
                )
            _decode_base64(data, schema, ch.topic)
            counts[ch.topic] += 1
    return counts


def mcap_messages(path: str | Path) -> dict[str, list[tuple[int, dict]]]:
    """Every JSON message of an MCAP by topic, in order: (log time [ns], decoded message)."""
    out: dict[str, list[tuple[int, dict]]] = {}
    with open(path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages():
            out.setdefault(ch.topic, []).append((msg.log_time, json.loads(msg.data)))
    return out


def tf_world(tfs: list[dict], frame: str):
    """world <- ``frame`` (4, 4) composed, as a viewer does, from the transforms of one
    ``foxglove.FrameTransforms`` message (unit quaternions x, y, z, w)."""
    import numpy as np

    by_child = {t["child_frame_id"]: t for t in tfs}
    out = np.eye(4)
    while frame in by_child:
        t = by_child[frame]
        x, y, z, w = (t["rotation"][k] for k in "xyzw")
        m = np.eye(4)
        m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]  # fmt: skip
        m[:3, 3] = [t["translation"][k] for k in "xyz"]
        out = m @ out
        frame = t["parent_frame_id"]
    assert frame == "world", f"the chain of frames ends at {frame!r}, not world"
    return out
