"""Fuzzing the three parsers of untrusted input with hypothesis: the motion CSV reader, the URDF loader
(with the skeleton built from it) and the checkpoint loader.

Every generated input must either load or raise the package's own error type (``MerError``) --
never another exception -- within a time and memory bound. The runs are derandomized (the same
inputs in CI every time) and bounded in examples; ``MER_FUZZ_EXAMPLES=N`` runs N per parser.
Statistics (inputs tried, accepted, refused, the slowest) are printed at the end of the session.
"""

from __future__ import annotations

import gzip
import json
import os
import resource
import shutil
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from fuzz_stats import STATS
from hostile_files import lzf_bomb, lzf_compress, replace_pos
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from urdf_factory import humanoid

import mer_models
from mer_data.base.errors import MerError
from mer_data.motion.lafan1 import decompress_motion, parse_lafan1, write_lafan1_csv
from mer_data.robots.builder import build_skeleton
from mer_data.robots.card import RobotCard
from mer_data.robots.registry import load_robot
from mer_data.robots.urdf import parse_urdf_bytes
from mer_data.synthesis.walking import walking_motion
from mer_models.zoo import DEFAULT_MODEL
from mer_models.zoo.checkpoint import load_checkpoint

EXAMPLES = int(os.environ.get("MER_FUZZ_EXAMPLES", "0"))
TIME_BOUND_S = 5.0  # per input (the slowest seen is ~0.1 s)
MEMORY_BOUND = 256 * 2**20  # Python + numpy allocations per input [bytes]
BUNDLED = Path(mer_models.__file__).parent / "bundled" / DEFAULT_MODEL  # the bundled default model (mer-base)


def fuzz_settings(n: int):
    return settings(
        max_examples=EXAMPLES or n,
        deadline=None,  # the bound is asserted below, with the input that broke it
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture],
    )


def _run(parser: str, fn, data, *, memory: bool = True):
    """Call ``fn(data)``: it must return or raise MerError, within the bounds; record the statistics."""
    s = STATS.setdefault(parser, {"inputs": 0, "loaded": 0, "refused": 0, "slowest_s": 0.0, "slowest_input": ""})
    if memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        fn(data)
        s["loaded"] += 1
    except MerError:
        s["refused"] += 1
    finally:
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] if memory else 0
        if memory:
            tracemalloc.stop()
        s["inputs"] += 1
        if elapsed > s["slowest_s"]:
            s["slowest_s"] = elapsed
            s["slowest_input"] = repr(data)[:120]
    assert elapsed < TIME_BOUND_S, f"{parser} took {elapsed:.2f} s on {repr(data)[:200]}"
    assert peak < MEMORY_BOUND, f"{parser} allocated {peak / 2**20:.0f} MiB on {repr(data)[:200]}"


# ---- motion CSV -----------------------------------------------------------------------------

def _valid_csv() -> bytes:
    m = walking_motion("g1", 0.4)
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return write_lafan1_csv(Path(d) / "w.csv", m).read_bytes()


VALID_CSV = _valid_csv()
CELLS = st.sampled_from(
    ["0", "1.5", "-0.000000", "1e30", "-1e308", "nan", "inf", "-inf", "", " ", "abc", "1,2", "0x10", "1e-320",
     "99999999999999999999999", "+2", " 3.25 ", "1.000000", "\x00", "\u00e9", "1_000", "1e", "."]
)  # fmt: skip


@st.composite
def csv_inputs(draw) -> bytes:
    kind = draw(st.sampled_from(["bytes", "mutate", "cells", "rows"]))
    if kind == "bytes":
        return draw(st.binary(max_size=2048))
    if kind == "cells":  # rows of drawn cells, of drawn lengths
        rows = draw(st.lists(st.lists(CELLS, min_size=30, max_size=40), min_size=1, max_size=6))
        end = draw(st.sampled_from(["\n", "\r\n", ""]))
        return (end or "\n").join(",".join(r) for r in rows).encode("utf-8", "surrogatepass") + end.encode()
    lines = VALID_CSV.split(b"\n")[: draw(st.integers(1, 12))]
    data = b"\n".join(lines) + b"\n"
    if kind == "rows":  # valid rows, one cell replaced
        i = draw(st.integers(0, len(lines) - 1))
        cells = lines[i].split(b",")
        cells[draw(st.integers(0, len(cells) - 1))] = draw(CELLS).encode("utf-8", "surrogatepass")
        lines[i] = b",".join(cells)
        data = b"\n".join(lines) + b"\n"
    for _ in range(draw(st.integers(0 if kind == "rows" else 1, 4))):  # byte-level edits
        pos = draw(st.integers(0, len(data)))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        chunk = draw(st.binary(min_size=1, max_size=8))
        if op == "insert":
            data = data[:pos] + chunk + data[pos:]
        elif op == "delete":
            data = data[:pos] + data[pos + len(chunk) :]
        else:
            data = data[:pos] + chunk + data[pos + len(chunk) :]
    if draw(st.booleans()):
        data = b"\xef\xbb\xbf" + data
    return data


def _read_csv(data: bytes) -> None:
    m = parse_lafan1(data, load_robot("g1"), path="fuzz.csv")
    assert np.isfinite(m.base_pos).all() and np.isfinite(m.joints).all() and np.isfinite(m.base_quat).all()


@fuzz_settings(300)
@given(data=csv_inputs())
def test_fuzz_motion_csv_reader(data):
    _run("motion CSV", _read_csv, data)


@st.composite
def gz_inputs(draw) -> bytes:
    whole_rows = b"\n".join(VALID_CSV.split(b"\n")[:3]) + b"\n"
    body = gzip.compress(draw(st.sampled_from([whole_rows, whole_rows, b"", b"0" * 5000])), mtime=0)
    for _ in range(draw(st.integers(0, 3))):
        pos = draw(st.integers(0, len(body)))
        body = body[:pos] + draw(st.binary(min_size=0, max_size=6)) + body[pos + draw(st.integers(0, 6)) :]
    return body


@fuzz_settings(100)
@given(data=gz_inputs())
def test_fuzz_motion_gzip(data):
    _run("motion CSV (.gz)", lambda d: _read_csv(decompress_motion(d, "fuzz.csv.gz")), data)


# ---- URDF -----------------------------------------------------------------------------------

VALID_URDF = humanoid().xml().encode()
NAMES = st.sampled_from(["a", "b", "c", "d", "base", "", "a b", "\u00e9", "x" * 40])
NUMS = st.sampled_from(["0", "1", "-1", "0.5 0 0", "0 0 1", "1 2", "1e308 0 0", "nan 0 0", "inf", "", "a b c",
                        "1e3 0 0", "0 0 1e-300", "3.14159 0 0", "1e6", "-1e7", "0 0 0 0"])  # fmt: skip
TYPES = st.sampled_from(["revolute", "continuous", "prismatic", "fixed", "floating", "planar", "hinge", ""])


@st.composite
def urdf_trees(draw) -> bytes:
    """Random documents of links and joints with drawn names, types and numbers."""
    links = draw(st.lists(NAMES, min_size=0, max_size=6))
    out = ['<?xml version="1.0"?>', f'<robot name="{draw(NAMES)}">']
    for name in links:
        geo = draw(st.sampled_from(["", f'<collision><geometry><box size="{draw(NUMS)}"/></geometry></collision>',
                                    f'<collision><origin xyz="{draw(NUMS)}"/><geometry><sphere radius="{draw(NUMS)}"/></geometry></collision>',
                                    f'<inertial><mass value="{draw(NUMS)}"/></inertial>']))  # fmt: skip
        out.append(f'<link name="{name}">{geo}</link>')
    for i in range(draw(st.integers(0, 7))):
        parts = [f'<joint name="{draw(NAMES)}{i}" type="{draw(TYPES)}">']
        parts.append(f'<parent link="{draw(NAMES)}"/><child link="{draw(NAMES)}"/>')
        if draw(st.booleans()):
            parts.append(f'<origin xyz="{draw(NUMS)}" rpy="{draw(NUMS)}"/>')
        if draw(st.booleans()):
            parts.append(f'<axis xyz="{draw(NUMS)}"/>')
        if draw(st.booleans()):
            parts.append(f'<limit lower="{draw(NUMS)}" upper="{draw(NUMS)}" effort="1" velocity="1"/>')
        if draw(st.booleans()):
            parts.append(f'<mimic joint="{draw(NAMES)}{draw(st.integers(0, 7))}" multiplier="{draw(NUMS)}"/>')
        out.append("".join(parts) + "</joint>")
    out.append("</robot>")
    text = "\n".join(out)
    codec = draw(st.sampled_from(["utf-8", "utf-8", "utf-8", "utf-16", "utf-8-sig"]))
    return text.encode(codec)


VALID_NUMS = st.sampled_from(["0 0 0", "0.1 0 -0.2", "0 0 1", "0.3 -0.2 0.5", "3.14159 0 0", "0 0 1e3", "1e-9 0 0",
                              "0 0 -1e3", "-1e3 1e3 1e3"])  # fmt: skip
AXES = st.sampled_from(["0 0 1", "1 0 0", "0 1 0", "0.3 -0.2 0.5", "1e-6 0 0", "1e6 1e6 0", "0 0 -1"])


@st.composite
def urdf_valid_trees(draw) -> bytes:
    """Well-formed trees (each joint's parent is an earlier link) with drawn types and values."""
    n = draw(st.integers(1, 12))
    out = ['<robot name="t">'] + [f'<link name="l{i}"/>' for i in range(n)]
    for i in range(1, n):
        jt = draw(st.sampled_from(["revolute", "continuous", "fixed", "revolute", "continuous", "revolute"]))
        lo, hi = sorted(draw(st.lists(st.sampled_from([-1e6, -3.0, -0.5, 0.0, 0.5, 3.0, 1e6]), min_size=2, max_size=2)))
        mimic = f'<mimic joint="j{draw(st.integers(1, n - 1))}" multiplier="{draw(st.sampled_from(["1", "-1", "1e6"]))}"/>' \
            if draw(st.integers(0, 9)) == 0 else ""  # fmt: skip
        out.append(
            f'<joint name="j{i}" type="{jt}"><parent link="l{draw(st.integers(0, i - 1))}"/><child link="l{i}"/>'
            f'<origin xyz="{draw(VALID_NUMS)}" rpy="{draw(VALID_NUMS)}"/><axis xyz="{draw(AXES)}"/>'
            f'<limit lower="{lo}" upper="{hi}"/>{mimic}</joint>'
        )
    return ("\n".join(out) + "\n</robot>").encode()


@st.composite
def urdf_inputs(draw) -> bytes:
    kind = draw(st.sampled_from(["bytes", "tree", "valid", "valid", "mutate"]))
    if kind == "bytes":
        return draw(st.binary(max_size=2048))
    if kind == "tree":
        return draw(urdf_trees())
    if kind == "valid":
        return draw(urdf_valid_trees())
    data = VALID_URDF
    for _ in range(draw(st.integers(1, 5))):
        pos = draw(st.integers(0, len(data)))
        chunk = draw(st.one_of(st.binary(min_size=1, max_size=8), st.sampled_from(
            [b"<!DOCTYPE r>", b"<!ENTITY e 'x'>", b"&e;", b"<a>" * 70, b"</link>", b'"', b"1e308", b"\x00"])))  # fmt: skip
        cut = draw(st.integers(0, 8))
        data = data[:pos] + chunk + data[pos + cut :]
    return data


def _load_urdf(data: bytes) -> None:
    urdf = parse_urdf_bytes(data, "fuzz.urdf")
    skel = build_skeleton(urdf, RobotCard(name="fuzz", urdf="fuzz.urdf", keypoints={}))
    for a in (skel.offsets, skel.axes, skel.lower, skel.upper, skel.rest_rotations):
        assert np.isfinite(a).all()


@fuzz_settings(300)
@given(data=urdf_inputs())
def test_fuzz_urdf_loader(data):
    _run("URDF loader", _load_urdf, data)


# ---- checkpoint -----------------------------------------------------------------------------

CONFIG = json.loads((BUNDLED / "config.json").read_text())
WEIGHTS = (BUNDLED / "model.safetensors").read_bytes()
VALUES = st.one_of(
    st.sampled_from([None, True, 0, -1, 1, 2, 3, 7, 10**6, 10**12, 0.0, -0.5, 1e308, float("inf"), float("nan"), "", "x",
                     [], {}, [1, 2], {"a": 1}]),
    st.integers(-(10**20), 10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)  # fmt: skip


def _paths(obj, prefix=()):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))


PATHS = list(_paths(CONFIG))


@st.composite
def checkpoint_inputs(draw) -> tuple[bytes, bytes]:
    cfg = json.loads(json.dumps(CONFIG))
    for _ in range(draw(st.integers(0, 3))):
        path = draw(st.sampled_from(PATHS))
        node = cfg
        try:
            for k in path[:-1]:
                node = node[k]
            if draw(st.integers(0, 4)) == 0:
                node.pop(path[-1], None)
            else:
                node[path[-1]] = draw(VALUES)
        except (KeyError, TypeError):
            pass
    text = json.dumps(cfg)
    if draw(st.integers(0, 5)) == 0:  # broken JSON text
        pos = draw(st.integers(0, len(text)))
        text = text[:pos] + draw(st.text(max_size=4)) + text[pos + draw(st.integers(0, 4)) :]
    weights = WEIGHTS
    wkind = draw(st.sampled_from(["same", "same", "truncate", "header", "bytes"]))
    if wkind == "truncate":
        weights = WEIGHTS[: draw(st.integers(0, len(WEIGHTS)))]
    elif wkind == "header":
        pos = draw(st.integers(0, 400))
        weights = WEIGHTS[:pos] + draw(st.binary(min_size=1, max_size=8)) + WEIGHTS[pos + draw(st.integers(0, 8)) :]
    elif wkind == "bytes":
        weights = draw(st.binary(max_size=256))
    return text.encode("utf-8", "surrogatepass"), weights


@pytest.fixture(scope="module")
def ckpt_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz") / "ckpt"
    shutil.copytree(BUNDLED, d)
    return d


@fuzz_settings(120)
@given(data=checkpoint_inputs())
def test_fuzz_checkpoint_loader(data, ckpt_dir, monkeypatch):
    monkeypatch.setenv("MER_MAX_MODEL_PARAMETERS", "20000000")  # the knob: above the paper model (~12 M), 80 MB
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    (ckpt_dir / "config.json").write_bytes(data[0])
    (ckpt_dir / "model.safetensors").write_bytes(data[1])
    _run("checkpoint loader", lambda _: load_checkpoint(ckpt_dir), data, memory=False)  # torch memory: RSS below
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) * 1024  # Linux: KiB
    assert grown < MEMORY_BOUND, f"peak RSS grew by {grown / 2**20:.0f} MiB on {repr(data)[:200]}"


def test_yaml_aliases_are_refused_in_cards_and_key_point_files(tmp_path):
    """A "billion laughs" in YAML: nine levels of aliases expand 1 KB to 10^9 entries."""
    from mer_data.base.errors import MerError
    from mer_data.robots.card import parse_card
    from mer_data.robots.register import load_keypoints_file

    lines = ['a0: &a0 ["x","x","x","x","x","x","x","x","x","x"]']
    lines += [f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 10)]
    bomb = "\n".join(lines) + "\n"
    with pytest.raises(MerError, match="alias"):
        parse_card(bomb, "card.yaml")
    f = tmp_path / "kp.yaml"
    f.write_text("keypoints:\n  base: &b {link: x}\n  left_hip: *b\n")
    with pytest.raises(MerError, match="alias"):
        load_keypoints_file(f)


# ---- BVH (human motion capture) -------------------------------------------------------------


def _valid_bvh() -> bytes:
    """A small Y-up centimetre human (LAFAN1 names, 3 frames) that reads into a skeleton."""
    body = []

    def chain(names, offsets, depth, six=False):
        ind = "  " * depth
        name, rest = names[0], names[1:]
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if six else "3 Zrotation Yrotation Xrotation"
        body.extend([f"{ind}JOINT {name}", f"{ind}{{", f"{ind}  OFFSET {offsets[0]}", f"{ind}  CHANNELS {chans}"])
        if rest:
            chain(rest, offsets[1:], depth + 1)
        else:
            body.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET {offsets[-1]}", f"{ind}  }}"])
        body.append(f"{ind}}}")

    for s, x in (("Left", 9), ("Right", -9)):
        chain([f"{s}UpLeg", f"{s}Leg", f"{s}Foot", f"{s}Toe"], [f"{x} -2 0", "0 -42 0", "0 -42 0", "0 -6 13", "0 0 5"], 1)
    chain(["Spine", "Neck", "Head"], ["0 12 0", "0 30 0", "0 10 0", "0 15 0"], 1)
    for s, x in (("Left", 1), ("Right", -1)):
        chain([f"{s}Arm", f"{s}ForeArm", f"{s}Hand"], [f"{17 * x} 40 0", f"{28 * x} 0 0", f"{25 * x} 0 0", f"{8 * x} 0 0"], 2)
    channels = 6 + 3 * sum(1 for line in body if "CHANNELS 3" in line)
    frames = [" ".join(["1.5", "95", "-2.25"] + [f"{(7 * i + f) % 19 - 9}.5" for i in range(channels - 3)]) for f in range(3)]
    text = "\n".join(["HIERARCHY", "ROOT Hips", "{", "  OFFSET 0 0 0",
                      "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation", *body, "}",
                      "MOTION", "Frames: 3", "Frame Time: 0.0333333", *frames]) + "\n"  # fmt: skip
    return text.encode()


VALID_BVH = _valid_bvh()
BVH_WORDS = st.sampled_from(
    ["{", "}", "JOINT", "ROOT", "End", "Site", "OFFSET", "CHANNELS", "MOTION", "Frames:", "Frame Time:", "6", "3", "0",
     "7", "-1", "Xposition", "Zrotation", "Wrotation", "nan", "1e999", "1e300", "0.0", "1_0", "\u0663", "Hips", "\t",
     "\n", "\r", " ", "\x00", "\u00e9", "LeftUpLeg", "mixamorig:", "_L", "-0", ".5", "e5", "99999999999"]
)  # fmt: skip


@st.composite
def bvh_inputs(draw) -> bytes:
    kind = draw(st.sampled_from(["bytes", "tokens", "mutate", "lines"]))
    if kind == "bytes":
        return draw(st.binary(max_size=2048))
    if kind == "tokens":  # the valid file with runs of BVH words spliced in
        data = VALID_BVH
        for _ in range(draw(st.integers(1, 4))):
            pos = draw(st.integers(0, len(data)))
            words = " ".join(draw(st.lists(BVH_WORDS, min_size=1, max_size=6))).encode("utf-8", "surrogatepass")
            data = data[:pos] + words + data[pos + draw(st.integers(0, 12)) :]
        return data
    if kind == "lines":  # whole lines dropped, doubled or swapped
        lines = VALID_BVH.split(b"\n")
        for _ in range(draw(st.integers(1, 3))):
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            op = draw(st.sampled_from(["drop", "double", "swap"]))
            if op == "drop":
                del lines[i]
            elif op == "double":
                lines.insert(i, lines[i])
            else:
                lines[i], lines[j] = lines[j], lines[i]
            if not lines:
                break
        return b"\n".join(lines)
    data = VALID_BVH
    for _ in range(draw(st.integers(1, 4))):  # byte-level edits
        pos = draw(st.integers(0, len(data)))
        chunk = draw(st.binary(min_size=1, max_size=8))
        op = draw(st.sampled_from(["insert", "delete", "replace"]))
        if op == "insert":
            data = data[:pos] + chunk + data[pos:]
        elif op == "delete":
            data = data[:pos] + data[pos + len(chunk) :]
        else:
            data = data[:pos] + chunk + data[pos + len(chunk) :]
    return data


def _read_bvh(data: bytes) -> None:
    from mer_data.motion.bvh import parse_bvh_bytes
    from mer_data.motion.human import human_motion, human_skeleton

    m = parse_bvh_bytes(data, "fuzz.bvh")
    assert np.isfinite(m.positions()).all()
    skel = human_skeleton(m)  # the human on top: key points, folding, nodes
    base_pos, base_quat, q = human_motion(m, skel)
    assert np.isfinite(base_pos).all() and np.isfinite(base_quat).all() and np.isfinite(q).all()


def test_the_valid_bvh_reads_into_a_human():
    _read_bvh(VALID_BVH)


@fuzz_settings(300)
@given(data=bvh_inputs())
def test_fuzz_bvh_reader(data):
    _run("BVH", _read_bvh, data)


# ---- shards from strangers (issue 41): MCAP bytes and HDF5 datasets -----------------------------


@pytest.fixture(scope="module")
def shard_files(tmp_path_factory) -> dict[str, bytes]:
    """The bytes of one small valid shard per format (synthetic motion)."""
    from mer_data.shards import BuildConfig, build_shards

    root, out = tmp_path_factory.mktemp("fuzz_shards"), {}
    for fmt, suffix in (("hdf5", "*.h5"), ("mcap", "*.mcap")):
        cfg = BuildConfig(input="", robots=("g1",), targets=("g1", "h1"), synthetic=1, synthetic_seconds=2.5, augment=2,
                          format=fmt, split="all")  # fmt: skip
        build_shards(cfg, root / fmt)
        out[fmt] = next((root / fmt).glob(suffix)).read_bytes()
    return out


def _read_shard(path: Path) -> None:
    from mer_data.shards import ShardDataset

    ds = ShardDataset(path, teacher=None)
    for i in range(len(ds)):
        s = ds[i]
        assert np.isfinite(s.reference).all()


@fuzz_settings(60)
@given(data=st.data())
def test_fuzz_mcap_shard_bytes(data, shard_files, tmp_path_factory):
    """Flipped, overwritten and cut bytes of an MCAP shard: read as before, or a MerError (CRCs checked)."""
    raw = bytearray(shard_files["mcap"])
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(raw) - 1))
        raw[at] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(8, len(raw)))]
    p = tmp_path_factory.mktemp("mcap") / "s.mcap"
    p.write_bytes(bytes(raw))
    _run("MCAP shard", _read_shard, p)


_H5_COLUMNS = ("pos", "q", "base_rotvec", "origin_xy", "start_frame", "sample_target", "sample_variant", "link_scales",
               "dropped", "clip")  # fmt: skip
_H5_DTYPES = ("<f4", "<f8", "<i2", "<i8", "|b1", "|S4", "<c8")


@fuzz_settings(60)
@given(data=st.data())
def test_fuzz_hdf5_shard_datasets(data, shard_files, tmp_path_factory):
    """A column replaced by one of another dtype, shape, value, link kind or storage: read or a MerError."""
    import h5py

    p = tmp_path_factory.mktemp("h5") / "s.h5"
    p.write_bytes(shard_files["hdf5"])
    name = data.draw(st.sampled_from(_H5_COLUMNS))
    kind = data.draw(st.sampled_from(("dtype", "shape", "value", "soft", "external")))
    with h5py.File(p, "r+") as f:
        old = f[name]
        shape, dtype = old.shape, old.dtype
        if kind == "value" and dtype.kind in "fi":
            a = old[...]
            idx = tuple(data.draw(st.integers(0, n - 1)) for n in a.shape)
            bad = [np.nan, np.inf, -1, 1e30] if dtype.kind == "f" else [-1, -(2**15), 2**15 - 1, 7]
            a[idx] = data.draw(st.sampled_from(bad))
            old[...] = a
        elif kind == "soft":
            f.move(name, name + "_moved")
            f[name] = h5py.SoftLink("/" + name + "_moved")
        elif kind == "external":
            secret = p.with_name("secret.bin")
            secret.write_bytes(b"\x00" * 4096)
            del f[name]
            f.create_dataset(name, shape=(1,), dtype="<f8", external=[(str(secret), 0, 8)])
        else:
            del f[name]
            if kind == "dtype":
                shape_new, dtype_new = shape, np.dtype(data.draw(st.sampled_from(_H5_DTYPES)))
            else:
                shape_new = tuple(data.draw(st.lists(st.integers(0, 5), min_size=0, max_size=4)))
                dtype_new = dtype if dtype.kind != "O" else np.dtype("<f4")
            f.create_dataset(name, shape=shape_new, dtype=dtype_new)
    _run("HDF5 shard", _read_shard, p)


# ---- HDF5 filters and attributes from strangers (issue 41): LZF and deflate bombs, filter orders ----


_PIPELINES = [("lzf",), ("shuffle", "lzf"), ("gzip",), ("shuffle", "gzip"), ("lzf", "fletcher32"), ("gzip", "lzf"),
              ("lzf", "shuffle"), ("shuffle", "gzip", "fletcher32"), ("scaleoffset",), ("nbit",)]  # fmt: skip


def _replace_pos(path: Path, pipeline: tuple[str, ...], payload: bytes | None, chunk_rows: int = 1) -> None:
    """:func:`hostile_files.replace_pos` on the shard file at ``path``."""
    import h5py

    with h5py.File(path, "r+") as f:
        replace_pos(f, pipeline, payload, chunk_rows)


@fuzz_settings(40)
@given(data=st.data())
def test_fuzz_hdf5_filter_pipelines_and_chunks(data, shard_files, tmp_path_factory):
    """Filters in any order, chunks that are bombs, garbage, cut or valid: read, or a MerError, bounded."""
    import zlib

    p = tmp_path_factory.mktemp("filters") / "s.h5"
    p.write_bytes(shard_files["hdf5"])
    import h5py

    with h5py.File(p, "r") as f:
        cbytes = int(np.prod(f["pos"].shape[1:])) * 4
    pipeline = data.draw(st.sampled_from(_PIPELINES))
    kind = data.draw(st.sampled_from(["bomb", "valid", "garbage", "cut", "empty"]))
    outer = next((x for x in reversed(pipeline) if x in ("lzf", "gzip")), None)
    raw = np.zeros(cbytes, np.uint8).tobytes() if kind != "bomb" else bytes(64 * cbytes)
    if kind in ("bomb", "valid", "cut"):
        payload = lzf_bomb(len(raw)) if outer == "lzf" and kind == "bomb" else lzf_compress(raw) if outer == "lzf" \
            else zlib.compress(raw, 9) if outer == "gzip" else raw  # fmt: skip
        if kind == "cut":
            payload = payload[: data.draw(st.integers(0, max(len(payload) - 1, 0)))]
    elif kind == "garbage":
        payload = data.draw(st.binary(min_size=1, max_size=512))
    else:
        payload = None
    _replace_pos(p, pipeline, payload)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _run("HDF5 filters", _read_shard, p)
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) * 1024
    assert grown < MEMORY_BOUND, f"peak RSS grew by {grown / 2**20:.0f} MiB on {pipeline} {kind}"


def test_an_lzf_chunk_that_inflates_past_its_size_is_refused(shard_files, tmp_path):
    """LZF decompresses 88x at best and h5py's filter grows its buffer until the output fits: a chunk
    stored within its declared size may expand 88-fold (it was read as zeros, silently)."""
    from mer_data.base.errors import ShardFormatError

    p = tmp_path / "s.h5"
    p.write_bytes(shard_files["hdf5"])
    import h5py

    with h5py.File(p, "r") as f:
        cbytes = int(np.prod(f["pos"].shape[1:])) * 4
    bomb = lzf_bomb(60 * cbytes)
    assert len(bomb) < cbytes  # stored within its declared size: only decompressing tells
    _replace_pos(p, ("shuffle", "lzf"), bomb)
    with pytest.raises(ShardFormatError, match="inflates to more than its declared"):
        _read_shard(p)
    _replace_pos(p, ("lzf", "shuffle"), lzf_compress(bytes(cbytes)))  # compression under another filter: unchecked
    with pytest.raises(ShardFormatError, match="after compressing"):
        _read_shard(p)


def _rss_probe(script: str, *args: str) -> dict:
    """Run ``script`` in a fresh interpreter; it prints one JSON line, with the growth of VmHWM as "rss_growth"."""
    import subprocess
    import sys

    head = ("import json, sys, time\n"
            "def hwm():\n    return int(next(l for l in open('/proc/self/status') if l.startswith('VmHWM')).split()[1]) * 1024\n")  # fmt: skip
    r = subprocess.run([sys.executable, "-c", head + script, *args], capture_output=True, text=True, timeout=300,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


_OPEN_AND_READ = """
from mer_data.base.errors import MerError
from mer_data.shards import ShardDataset
base, t = hwm(), time.perf_counter()
try:
    ds = ShardDataset(sys.argv[1], teacher=None)
    [ds[i] for i in range(len(ds))]
    err = None
except MerError as exc:
    err = str(exc)
print(json.dumps({"error": err, "s": time.perf_counter() - t, "rss_growth": hwm() - base}))
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs /proc (Linux) to read the peak RSS")
def test_worst_lzf_chunk_and_huge_attribute_stay_bounded(shard_files, tmp_path):
    """The largest chunk mer accepts (16 MiB declared) stored as an LZF bomb (1.4 GB of output), and an
    80 MB string attribute: each a MerError within seconds and 128 (160) MiB of resident growth (HDF5 would
    take minutes and 1.4 GB for the first, ~400 MB for the second)."""
    import h5py

    p = tmp_path / "lzf.h5"
    p.write_bytes(shard_files["hdf5"])
    with h5py.File(p, "r") as f:
        row = int(np.prod(f["pos"].shape[1:])) * 4
    rows = (16 << 20) // row  # the largest chunk under MER_MAX_HDF5_CHUNK_BYTES
    _replace_pos(p, ("shuffle", "lzf"), lzf_bomb(87 * rows * row)[: rows * row], chunk_rows=rows)
    got = _rss_probe(_OPEN_AND_READ, str(p))
    assert got["error"] and "inflates" in got["error"] and got["s"] < 10 and got["rss_growth"] < 128 << 20, got
    q = tmp_path / "attr.h5"
    q.write_bytes(shard_files["hdf5"])
    with h5py.File(q, "r+") as f:
        f.attrs["config"] = json.dumps({"x": "y" * 80_000_000})
    got = _rss_probe(_OPEN_AND_READ, str(q))
    assert got["error"] and "MER_MAX_HDF5_ATTR_BYTES" in got["error"] and got["rss_growth"] < 160 << 20, got


def test_a_chunk_too_short_for_its_checksum_is_refused(shard_files, tmp_path):
    """HDF5's Fletcher-32 filter reads the 4 bytes of its checksum from the chunk's end without
    checking there are 4: a 3-byte chunk read out of bounds (a segfault, found by the fuzz test above)."""
    import zlib

    from mer_data.base.errors import ShardFormatError

    p = tmp_path / "s.h5"
    p.write_bytes(shard_files["hdf5"])
    _replace_pos(p, ("shuffle", "gzip", "fletcher32"), b"\x01\x02\x03")
    with pytest.raises(ShardFormatError, match="too few for its checksum"):
        _read_shard(p)
    _replace_pos(p, ("shuffle", "gzip"), zlib.compress(b"\0" * 4096)[:-6])  # a cut stream: less than the chunk
    with pytest.raises(ShardFormatError, match="not valid compressed data|decompresses to"):
        _read_shard(p)
