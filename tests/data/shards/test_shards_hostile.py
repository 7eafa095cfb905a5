"""Shards and teacher files from strangers (issue 41): every hostile HDF5 / MCAP file is refused with
a ``MerError`` naming the file and what is wrong; nothing outside the file is read, nothing outside
the output folder is written, memory stays bounded.

The hostile files are made from one small valid shard of each format (synthetic motion), with h5py
and the mcap writer themselves (external storage, external links, virtual datasets, compression
bombs, wrong dtypes, NaNs, out-of-range indices, flipped bytes).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hostile_files import write_teacher

from mer_data.base.errors import MerError, ShardFormatError
from mer_data.shards import BuildConfig, ShardDataset, build_shards, open_shard
from mer_data.shards.teacher import teacher_path

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> dict[str, Path]:
    """One valid shard per format: {"hdf5": path, "mcap": path}."""
    root = tmp_path_factory.mktemp("valid")
    out = {}
    for fmt in ("hdf5", "mcap"):
        cfg = BuildConfig(input="", robots=("g1",), targets=("g1", "h1"), synthetic=2, synthetic_seconds=2.5, augment=2,
                          format=fmt, split="all")  # fmt: skip
        build_shards(cfg, root / fmt)
        out[fmt] = next((root / fmt).glob("*.h5" if fmt == "hdf5" else "*.mcap"))
    return out


def _copy(src: Path, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    dst = folder / src.name
    shutil.copyfile(src, dst)
    return dst


def _replace(path: Path, name: str, **kw) -> None:
    """Replace dataset ``name`` of ``path`` by ``create_dataset(name, **kw)``."""
    with h5py.File(path, "r+") as f:
        del f[name]
        f.create_dataset(name, **kw)


def _refused(path: Path, *words: str) -> MerError:
    """ShardDataset(path)[every sample] raises a MerError naming ``path`` and every word."""
    with pytest.raises(MerError) as ei:
        ds = ShardDataset(path)
        for i in range(len(ds)):
            ds[i]
    msg = str(ei.value)
    assert str(path) in msg or path.name in msg, msg
    for w in words:
        assert w in msg, msg
    return ei.value


def test_external_storage_is_refused(valid, tmp_path):
    secret = tmp_path / "secret.bin"
    secret.write_bytes(np.arange(64, dtype="<f8").tobytes())
    p = _copy(valid["hdf5"], tmp_path / "s")
    with h5py.File(p, "r") as f:
        shape = f["origin_xy"].shape
    _replace(p, "origin_xy", shape=shape, dtype="<f8", external=[(str(secret), 0, int(np.prod(shape)) * 8)])
    _refused(p, "external storage", "origin_xy")


def test_external_link_soft_link_and_virtual_dataset_are_refused(valid, tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(valid["hdf5"], "r") as f, h5py.File(other, "w") as o:
        for c in ("pos", "q", "base_rotvec"):
            o.create_dataset(c, data=f[c][...] + 1)
        shape = f["base_rotvec"].shape
    p = _copy(valid["hdf5"], tmp_path / "ext")
    with h5py.File(p, "r+") as f:
        del f["pos"]
        f["pos"] = h5py.ExternalLink(str(other), "/pos")
    _refused(p, "external link", "pos")
    p = _copy(valid["hdf5"], tmp_path / "soft")
    with h5py.File(p, "r+") as f:
        f.move("q", "q_hidden")
        f["q"] = h5py.SoftLink("/q_hidden")
    _refused(p, "soft link", "q")
    p = _copy(valid["hdf5"], tmp_path / "vds")
    layout = h5py.VirtualLayout(shape=shape, dtype="<f4")
    layout[...] = h5py.VirtualSource(str(other), "base_rotvec", shape=shape)
    with h5py.File(p, "r+") as f:
        del f["base_rotvec"]
        f.create_virtual_dataset("base_rotvec", layout)
    _refused(p, "virtual dataset", "base_rotvec")


def test_wrong_dtypes_and_shapes_are_refused(valid, tmp_path):
    with h5py.File(valid["hdf5"], "r") as f:
        n, k = f["sample_target"].shape
    cases = {
        "sample_target": dict(shape=(n, k), dtype="<f8"),
        "clip": dict(shape=(n,), dtype="<i4"),
        "link_scales": dict(data=np.zeros((n, 3), "<f4")),
        "dropped": dict(shape=(n, k), dtype=h5py.ref_dtype),
        "start_frame": dict(shape=(n,), dtype=np.dtype([("a", "<i4"), ("b", "<f4")])),
    }
    for name, kw in cases.items():
        p = _copy(valid["hdf5"], tmp_path / name)
        _replace(p, name, **kw)
        _refused(p, name)


def test_bad_indices_and_numbers_are_refused(valid, tmp_path):
    def edit(label: str, name: str, fn) -> Path:
        p = _copy(valid["hdf5"], tmp_path / label)
        with h5py.File(p, "r+") as f:
            a = f[name][...]
            fn(a)
            f[name][...] = a
        return p

    _refused(edit("target", "sample_target", lambda a: a.__setitem__((0, 0), -1)), "sample_target", "row 0")
    _refused(edit("variant", "sample_variant", lambda a: a.__setitem__((1, 2), 7)), "sample_variant", "row 1")
    _refused(edit("scale", "link_scales", lambda a: a.__setitem__((0, 1, 0), 1e30)), "link_scales")
    _refused(edit("nan", "pos", lambda a: a.__setitem__((1, 3, 2, 0), np.nan)), "'pos'", "row 1")
    _refused(edit("origin", "origin_xy", lambda a: a.__setitem__((0, 0), np.inf)), "origin_xy")


def test_hostile_metadata_is_refused(valid, tmp_path, monkeypatch):
    cases = {
        "nested": ("targets", "[" * 100_000 + "]" * 100_000),
        "not_json": ("config", "{not json"),
        "variants": ("variants", -3),
        "rows": ("num_rows", 10**10),
        "skeleton": ("skeleton:h1", json.dumps({"node_names": 5})),
        "wrong_type": ("targets", json.dumps({"a": 1})),
    }
    for label, (key, value) in cases.items():
        p = _copy(valid["hdf5"], tmp_path / label)
        with h5py.File(p, "r+") as f:
            f.attrs[key] = value
        with pytest.raises(ShardFormatError) as ei:
            open_shard(p)
        assert p.name in str(ei.value), str(ei.value)
    p = _copy(valid["hdf5"], tmp_path / "big_attr")  # a large attribute: refused past MER_MAX_HDF5_ATTR_BYTES
    monkeypatch.setenv("MER_MAX_HDF5_ATTR_BYTES", "20000")
    with h5py.File(p, "r+") as f:
        f.attrs["config"] = json.dumps({"x": "y" * 50_000})
    with pytest.raises(ShardFormatError, match="MER_MAX_HDF5_ATTR_BYTES"):
        open_shard(p)


def test_compression_bombs_are_refused_without_inflating(valid, tmp_path):
    # a chunk stored bigger than its declared size (64 bytes), and one stored within it that inflates to 1 MB
    for label, payload in (("big", zlib.compress(b"\0" * 8_000_000)), ("fits", zlib.compress(b"\0" * 1_000_000, 9))):
        p = _copy(valid["hdf5"], tmp_path / label)
        with h5py.File(p, "r+") as f:
            shape = f["origin_xy"].shape
            del f["origin_xy"]
            d = f.create_dataset("origin_xy", shape=shape, dtype="<f8", chunks=shape, compression="gzip")
            d.id.write_direct_chunk((0, 0), payload, 0)
        with pytest.raises(ShardFormatError, match="origin_xy") as ei:
            ShardDataset(p)
        assert ("inflates" if label == "fits" else "stored in") in str(ei.value)


def test_teacher_nan_angles_and_wrong_shape_are_refused(valid, tmp_path):
    p = _copy(valid["hdf5"], tmp_path / "nan")
    write_teacher(p, q=lambda a: a.__setitem__((2, 1, 0, 3), np.nan))
    with pytest.raises(ShardFormatError, match="'q'") as ei:
        ds = ShardDataset(p, teacher=True)
        for i in range(len(ds)):
            ds[i]
    assert "row 2" in str(ei.value)
    p = _copy(valid["hdf5"], tmp_path / "energy")
    write_teacher(p, energy=lambda a: a.__setitem__((0, 0), np.nan))
    with pytest.raises(ShardFormatError, match="energy"):
        ShardDataset(p, teacher=True)


def test_solve_never_writes_through_a_planted_link(valid, tmp_path):
    from mer_models.training.teacher import SolverConfig, solve_shards

    p = _copy(valid["hdf5"], tmp_path / "shards")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    partial = teacher_path(p).with_name(teacher_path(p).name + ".partial")
    partial.parent.mkdir()
    partial.symlink_to(victim)
    with pytest.raises(MerError, match="symbolic link"):
        solve_shards(p, solver=SolverConfig(gn_iters=1, physics=None))
    assert victim.read_text() == "precious\n"
    assert not teacher_path(p).exists()


def _rewrite_mcap(src: Path, dst: Path, compression) -> None:
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as out:
        r = make_reader(f)
        w = Writer(out, compression=compression)
        w.start(profile="", library="test")
        summary = r.get_summary()
        sids = {s.id: w.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        cids = {c.id: w.register_channel(c.topic, c.message_encoding, sids[c.schema_id]) for c in summary.channels.values()}
        for _, ch, m in r.iter_messages(log_time_order=False):
            w.add_message(cids[ch.id], m.log_time, m.data, m.publish_time, m.sequence)
        for md in r.iter_metadata():
            w.add_metadata(md.name, md.metadata)
        w.finish()


def test_mcap_flipped_byte_is_refused(valid, tmp_path):
    from mcap.writer import CompressionType

    p = tmp_path / "plain.mcap"
    _rewrite_mcap(valid["mcap"], p, CompressionType.NONE)  # uncompressed: a flipped digit still parses
    raw = bytearray(p.read_bytes())
    at = raw.index(b'"base64": "') + 20
    raw[at] = ord("B") if raw[at] != ord("B") else ord("C")
    p.write_bytes(bytes(raw))
    _refused(p, "CRC")


def _probe(cases: dict[str, Path], tmp_path: Path) -> dict:
    """Open every case in a fresh interpreter; per case the error, seconds and resident memory growth."""
    script = textwrap.dedent("""
        import json, sys, time
        from mer_data.base.errors import MerError
        from mer_data.shards import ShardDataset
        def hwm():
            return int(next(l for l in open("/proc/self/status") if l.startswith("VmHWM")).split()[1]) * 1024
        out = {}
        for label, path in json.loads(sys.argv[1]).items():
            base, t = hwm(), time.perf_counter()
            try:
                ds = ShardDataset(path)
                [ds[i] for i in range(len(ds))]
                err = None
            except MerError as exc:
                err = str(exc)
            except BaseException as exc:
                err = "NOT A MerError: " + type(exc).__name__ + ": " + str(exc)[:300]
            out[label] = {"error": err, "s": time.perf_counter() - t, "rss_growth": hwm() - base}
        print(json.dumps(out))
    """)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-c", script, json.dumps({k: str(v) for k, v in cases.items()})],
                       capture_output=True, text=True, timeout=120, env=env)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _mcap_bomb(path: Path, compression: str, declared: int, real: int, meta: dict[str, str]) -> None:
    """An MCAP shard with valid metadata and one chunk: ``real`` zero bytes compressed, the header
    declaring ``declared``."""
    import lz4.frame
    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk, DataEnd, Footer, Header, Metadata

    if compression == "zstd":
        c = zstandard.ZstdCompressor().compressobj()
        data = b"".join(c.compress(b"\0" * (1 << 20)) for _ in range(real >> 20)) + c.flush()
    else:
        data = lz4.frame.compress(b"\0" * real)
    b = RecordBuilder()
    Header(profile="", library="hostile").write(b)
    Chunk(compression=compression, data=data, message_start_time=0, message_end_time=0, uncompressed_crc=1,
          uncompressed_size=declared).write(b)  # fmt: skip
    Metadata(name="mer.shard", metadata=meta).write(b)
    DataEnd(data_section_crc=0).write(b)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
    path.write_bytes(b"\x89MCAP0\r\n" + b.end() + b"\x89MCAP0\r\n")


def test_bombs_and_huge_declared_shapes_stay_bounded(valid, tmp_path):
    """In a fresh interpreter: each case is a MerError within seconds and 256 MiB of resident growth."""
    attrs = open_shard(valid["mcap"]).meta.to_attrs()
    meta = {k: v if isinstance(v, str) else json.dumps(v) for k, v in attrs.items()}
    cases = {}
    for label, comp, declared, real in (("zstd_declared", "zstd", 1 << 30, 8 << 20), ("zstd_lies", "zstd", 1000, 128 << 20),
                                        ("lz4_lies", "lz4", 1000, 64 << 20)):  # fmt: skip
        cases[label] = tmp_path / f"{label}.mcap"
        _mcap_bomb(cases[label], comp, declared, real, meta)
    # an 816 MB gzip chunk declared in a 10^6-row dataset (nothing stored): refused before any read
    p = cases["h5_big_chunks"] = _copy(valid["hdf5"], tmp_path / "chunks")
    with h5py.File(p, "r+") as f:
        shape = f["pos"].shape
        del f["pos"]
        f.create_dataset("pos", shape=(10**6,) + shape[1:], dtype="<f4", chunks=(4000,) + shape[1:], compression="gzip")
        f.attrs["num_rows"] = 10**6
    p = cases["h5_rows"] = _copy(valid["hdf5"], tmp_path / "rows")
    with h5py.File(p, "r+") as f:
        f.attrs["num_rows"] = 10**10
    got = _probe(cases, tmp_path)
    for label, r in got.items():
        assert r["error"] and not r["error"].startswith("NOT A MerError"), (label, r)
        assert ("MCAP chunk" if label.startswith(("zstd", "lz4")) else "over mer's limit") in r["error"], (label, r)
        assert r["s"] < 10, (label, r)
        assert r["rss_growth"] < 256 << 20, (label, r)
