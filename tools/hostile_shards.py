"""The hostile shard, teacher, Hub and output classes of issue 41, generated and probed (the driver
and the table are ``tools/hostile_inputs.py``; its docstring says what each outcome means)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

import h5py  # noqa: E402
import numpy as np  # noqa: E402
from hostile_files import lzf_bomb, replace_pos, write_teacher  # noqa: E402

PROBE = r'''
import json, os, sys, time, traceback
def status(key):
    return int(next(l for l in open("/proc/self/status") if l.startswith(key)).split()[1]) * 1024
def reset_peak():
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass
import numpy as np
import torch  # noqa: F401 -- the imports every mer command has, before the baseline
from mer_data.base.errors import MerError
from mer_data.shards import BuildConfig, ShardDataset, build_shards
from mer_models.training.teacher import SolverConfig, solve_shards

def read(path, teacher=None):
    """Every sample; returns a digest of what was read (reference, target, skeletons, provenance)."""
    import hashlib
    h = hashlib.sha256()
    ds = ShardDataset(path, teacher=teacher)
    for i in range(len(ds)):
        s = ds[i]
        h.update(np.asarray(s.reference).tobytes())
        h.update(s.target_skeleton.fingerprint.encode() + json.dumps(s.provenance, sort_keys=True, default=str).encode())
        if s.target is not None:
            h.update(np.asarray(s.target).tobytes())
    return h.hexdigest()

def act(kind, args):
    if kind == "read":
        return read(args["path"])
    elif kind == "teacher":
        return read(args["path"], teacher=True)
    elif kind == "solve":
        solve_shards(args["path"], solver=SolverConfig(gn_iters=1, physics=None), out=args.get("out"))
    elif kind == "build":
        cfg = BuildConfig(input="", robots=("g1",), targets=("g1",), synthetic=1, synthetic_seconds=2.5, augment=0,
                          split="all", format=args.get("format", "hdf5"))
        build_shards(cfg, args["out"])
    elif kind == "hf":
        read(args["url"])
    elif kind == "model":
        from mer_models.hub import client
        with client.settings(cache_dir=args["cache"]):
            client.fetch_file(args["repo"], args["file"], "main", what=args["repo"])
    else:
        raise ValueError(kind)

out = []
for case in json.loads(sys.argv[1]):
    for k, v in case.get("env", {}).items():
        os.environ[k] = v
    reset_peak()
    base, t = status("VmRSS"), time.perf_counter()
    digest = None
    try:
        digest = act(case["action"], case["args"])
        outcome, msg = "ok", ""
    except MerError as exc:
        outcome, msg = type(exc).__name__, str(exc).splitlines()[0]
    except BaseException as exc:
        outcome, msg = "NOT A MerError: " + type(exc).__name__, traceback.format_exc()[-600:]
    for k in case.get("env", {}):
        os.environ.pop(k, None)
    out.append({"label": case["label"], "outcome": outcome, "message": msg[:300], "s": time.perf_counter() - t,
                "peak": status("VmHWM"), "growth": max(status("VmHWM") - base, 0), "digest": digest})
print("RESULT " + json.dumps(out))
'''


def probe(cases: list[dict], env: dict | None = None, wrap: list[str] | None = None) -> list[dict]:
    """Run ``cases`` in one fresh interpreter (``wrap``: a command prefix, e.g. a mount namespace)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    cmd = [sys.executable, "-c", PROBE, json.dumps(cases)]
    r = subprocess.run((wrap or []) + cmd, env=env, capture_output=True, text=True, timeout=1800)
    line = next((x for x in r.stdout.splitlines() if x.startswith("RESULT ")), None)
    if line is None:
        return [{"label": c["label"], "outcome": f"NOT A MerError: process died (rc {r.returncode})",
                 "message": r.stderr[-300:], "s": 0, "peak": 0, "growth": 0} for c in cases]  # fmt: skip
    return json.loads(line[7:])


# ---- the valid shards and their hostile variants --------------------------------------------------


def build_valid(root: Path) -> dict[str, Path]:
    from mer_data.shards import BuildConfig, build_shards

    out = {}
    for fmt in ("hdf5", "mcap"):
        cfg = BuildConfig(input="", robots=("g1",), targets=("g1", "h1"), synthetic=2, synthetic_seconds=2.5, augment=2,
                          format=fmt, split="all")  # fmt: skip
        build_shards(cfg, root / "valid" / fmt)
        out[fmt] = next((root / "valid" / fmt).glob("*.h5" if fmt == "hdf5" else "*.mcap"))
    return out


class Cases:
    def __init__(self, root: Path, valid: dict[str, Path]) -> None:
        self.root, self.valid, self.n = root, valid, 0

    def copy(self, fmt: str = "hdf5") -> Path:
        self.n += 1
        d = self.root / "cases" / f"{self.n:03d}"
        d.mkdir(parents=True)
        return Path(shutil.copy(self.valid[fmt], d))

    def h5(self, edit) -> Path:
        p = self.copy()
        with h5py.File(p, "r+") as f:
            edit(f, p)
        return p


def _replace(f, name, **kw):
    del f[name]
    f.create_dataset(name, **kw)


def _edit_array(name: str, fn):
    def edit(f, p):
        a = f[name][...]
        fn(a)
        f[name][...] = a

    return edit


def hdf5_classes(c: Cases) -> dict[str, list[dict]]:
    secret = c.root / "secret.bin"
    secret.write_bytes(np.arange(4096, dtype="<f8").tobytes())
    other = c.root / "other.h5"
    with h5py.File(c.valid["hdf5"], "r") as f, h5py.File(other, "w") as o:
        for k in ("pos", "q", "base_rotvec", "origin_xy"):
            o.create_dataset(k, data=f[k][...] + 1)
        shapes = {k: f[k].shape for k in f}
    row = int(np.prod(shapes["pos"][1:])) * 4

    def read(p: Path) -> dict:
        return {"action": "read", "args": {"path": str(p)}}

    def ext_link(name):
        def e(f, p):
            del f[name]
            f[name] = h5py.ExternalLink(str(other), "/" + name)

        return e

    def ext_storage(name, src):
        def e(f, p):
            n = int(np.prod(shapes[name]))
            _replace(
                f,
                name,
                shape=shapes[name],
                dtype=f[name].dtype if name in f else "<f4",
                external=[(str(src), 0, n * np.dtype(f[name].dtype).itemsize)],
            )

        return e

    def vds(name):
        def e(f, p):
            layout = h5py.VirtualLayout(shape=shapes[name], dtype=f[name].dtype)
            layout[...] = h5py.VirtualSource(str(other), name, shape=shapes[name])
            del f[name]
            f.create_virtual_dataset(name, layout)

        return e

    def soft(name):
        def e(f, p):
            f.move(name, name + "_hidden")
            f[name] = h5py.SoftLink("/" + name + "_hidden")

        return e

    def gz(declared_rows: int, real: int):
        def e(f, p):
            z, block = zlib.compressobj(9), bytes(1 << 20)  # ``real`` zeros, streamed
            payload = b"".join(z.compress(block) for _ in range(max(real >> 20, 1))) + z.flush()
            replace_pos(f, ["shuffle", "gzip"], payload, chunk_rows=declared_rows)

        return e

    def lzf(declared_rows: int, real: int):
        def e(f, p):
            b = lzf_bomb(real)
            replace_pos(f, ["shuffle", "lzf"], b[: declared_rows * row], chunk_rows=declared_rows)

        return e

    def pipeline(filters):
        def e(f, p):
            replace_pos(f, filters, None)

        return e

    def attr(key, value):
        def e(f, p):
            f.attrs[key] = value

        return e

    def big_rows(f, p):
        _replace(
            f, "pos", shape=(10**6,) + shapes["pos"][1:], dtype="<f4", chunks=(4000,) + shapes["pos"][1:], compression="gzip"
        )
        f.attrs["num_rows"] = 10**6

    def huge_product(f, p):
        for k in list(f):
            shp = (10**7,) + shapes[k][1:]
            dt = f[k].dtype
            del f[k]
            f.create_dataset(k, shape=shp, dtype=dt, chunks=(1,) + shp[1:] if len(shp) > 1 else (1024,))
        f.attrs["num_rows"] = 10**7

    def array_attr(f, p):
        f.attrs["targets"] = np.zeros((1000, 1000))

    n, k = shapes["sample_target"]
    cls: dict[str, list[dict]] = {
        "HDF5 external links": [{"label": x, **read(c.h5(ext_link(x)))} for x in ("pos", "q")],
        "HDF5 soft links": [{"label": "q", **read(c.h5(soft("q")))}],
        "HDF5 external storage": [{"label": "origin_xy<-secret", **read(c.h5(ext_storage("origin_xy", secret)))}]
        + (
            [{"label": "origin_xy<-/etc/passwd", **read(c.h5(ext_storage("origin_xy", Path("/etc/passwd"))))}]
            if Path("/etc/passwd").stat().st_size >= np.prod(shapes["origin_xy"]) * 8
            else []
        ),
        "HDF5 virtual datasets": [{"label": x, **read(c.h5(vds(x)))} for x in ("base_rotvec", "pos")],
        "HDF5 gzip bombs": [
            {"label": "chunk of 1 row, 8 MB inflated", **read(c.h5(gz(1, 8 << 20)))},
            {"label": "16 MiB chunk, 1 GB inflated", **read(c.h5(gz((16 << 20) // row, 1 << 30)))},
        ],
        "HDF5 LZF bombs": [
            {"label": "chunk of 1 row, 60x", **read(c.h5(lzf(1, 60 * row)))},
            {"label": "16 MiB chunk, 1.4 GB of output", **read(c.h5(lzf((16 << 20) // row, 87 * ((16 << 20) // row) * row)))},
        ],
        "HDF5 filters mer does not write": [
            {"label": "+".join(x), **read(c.h5(pipeline(x)))}
            for x in (["scaleoffset"], ["nbit"], ["gzip", "lzf"], ["lzf", "shuffle"])
        ],
        "HDF5 huge declared shapes": [
            {"label": "num_rows 1e10", **read(c.h5(attr("num_rows", 10**10)))},
            {"label": "1e6 rows, 816 MB gzip chunks", **read(c.h5(big_rows))},
            {"label": "1e7 rows in every column", **read(c.h5(huge_product))},
        ],
        "HDF5 huge attributes": [
            {"label": "300 MB string", **read(c.h5(attr("config", json.dumps({"x": "y" * 300_000_000}))))},
            {"label": "20 MB skeleton", **read(c.h5(attr("skeleton:h1", "x" * 20_000_000)))},
            {"label": "8 MB array", **read(c.h5(array_attr))},
        ],
        "HDF5 wrong dtypes and shapes": [
            {"label": name, **read(c.h5(lambda f, p, name=name, kw=kw: _replace(f, name, **kw)))}
            for name, kw in {
                "sample_target": dict(shape=(n, k), dtype="<f8"),
                "clip": dict(shape=(n,), dtype="<i4"),
                "link_scales": dict(data=np.zeros((n, 3), "<f4")),
                "dropped": dict(shape=(n, k), dtype=h5py.ref_dtype),
                "start_frame": dict(shape=(n,), dtype=np.dtype([("a", "<i4"), ("b", "<f4")])),
                "pos": dict(shape=(n, 2), dtype="|S4"),
            }.items()
        ],
        "HDF5 nested / non-JSON attributes": [
            {"label": label, **read(c.h5(attr(key, value)))}
            for label, (key, value) in {
                "nested 100k": ("targets", "[" * 100_000 + "]" * 100_000),
                "not JSON": ("config", "{not json"),
                "wrong type": ("targets", json.dumps({"a": 1})),
                "skeleton": ("skeleton:h1", json.dumps({"node_names": 5})),
                "variants -3": ("variants", -3),
            }.items()
        ],
        "HDF5 out-of-range indices": [
            {"label": "sample_target -1", **read(c.h5(_edit_array("sample_target", lambda a: a.__setitem__((0, 0), -1))))},
            {"label": "sample_variant 7", **read(c.h5(_edit_array("sample_variant", lambda a: a.__setitem__((1, 2), 7))))},
            {"label": "start_frame -5", **read(c.h5(_edit_array("start_frame", lambda a: a.__setitem__(0, -5))))},
        ],
        "HDF5 NaN / out-of-range values": [
            {"label": "pos NaN", **read(c.h5(_edit_array("pos", lambda a: a.__setitem__((1, 3, 2, 0), np.nan))))},
            {"label": "origin inf", **read(c.h5(_edit_array("origin_xy", lambda a: a.__setitem__((0, 0), np.inf))))},
            {"label": "link scale 1e30", **read(c.h5(_edit_array("link_scales", lambda a: a.__setitem__((0, 1, 0), 1e30))))},
        ],
    }
    teachers = []
    for label, kw in (("another build", {"build": "0" * 64}), ("NaN angles", {"q": lambda a: (a.__setitem__((0, 1, 0, 3), np.nan), a)[1]}),
                      ("NaN energy", {"energy": lambda a: (a.__setitem__((0, 0), np.nan), a)[1]}),
                      ("another shape", {"q": lambda a: a[:, :, :, :5]})):  # fmt: skip
        p = c.copy()
        write_teacher(p, **kw)
        teachers.append({"label": label, "action": "teacher", "args": {"path": str(p)}})
    cls["Teacher files"] = teachers
    return cls


def _plain_mcap(src: Path, dst: Path) -> None:
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f, open(dst, "wb") as out:
        r = make_reader(f)
        w = Writer(out, compression=CompressionType.NONE)
        w.start(profile="", library="hostile")
        summary = r.get_summary()
        sids = {s.id: w.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        cids = {ch.id: w.register_channel(ch.topic, ch.message_encoding, sids[ch.schema_id]) for ch in summary.channels.values()}
        for _, ch, m in r.iter_messages(log_time_order=False):
            w.add_message(cids[ch.id], m.log_time, m.data, m.publish_time, m.sequence)
        for md in r.iter_metadata():
            w.add_metadata(md.name, md.metadata)
        w.finish()


def _mcap_with_chunk(
    path: Path, compression: str, declared: int, real: int, meta: dict[str, str], extra_records: int = 0
) -> None:
    import lz4.frame
    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk, DataEnd, Footer, Header, Metadata

    if compression == "zstd":
        z = zstandard.ZstdCompressor().compressobj()
        data = b"".join(z.compress(b"\0" * (1 << 20)) for _ in range(max(real >> 20, 1))) + z.flush()
    elif compression == "lz4":
        data = lz4.frame.compress(b"\0" * real)
    else:
        data = b""
    b = RecordBuilder()
    Header(profile="", library="hostile").write(b)
    if compression:
        Chunk(compression=compression, data=data, message_start_time=0, message_end_time=0, uncompressed_crc=1,
              uncompressed_size=declared).write(b)  # fmt: skip
    for i in range(extra_records):
        Metadata(name=f"x{i}", metadata={}).write(b)
    Metadata(name="mer.shard", metadata=meta).write(b)
    DataEnd(data_section_crc=0).write(b)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
    path.write_bytes(b"\x89MCAP0\r\n" + b.end() + b"\x89MCAP0\r\n")


def mcap_classes(c: Cases) -> dict[str, list[dict]]:
    from mer_data.shards import open_shard

    attrs = open_shard(c.valid["mcap"]).meta.to_attrs()
    meta = {k: v if isinstance(v, str) else json.dumps(v) for k, v in attrs.items()}
    rng = np.random.default_rng(41)
    plain = c.root / "plain.mcap"
    _plain_mcap(c.valid["mcap"], plain)
    flips = []
    raw0 = c.valid["mcap"].read_bytes()
    for i in range(30):  # random bytes of the real (zstd) shard
        raw = bytearray(raw0)
        for _ in range(int(rng.integers(1, 4))):
            raw[int(rng.integers(0, len(raw)))] = int(rng.integers(0, 256))
        p = c.root / "flips" / str(i) / c.valid["mcap"].name  # the same name: provenance names the file
        p.parent.mkdir(parents=True)
        p.write_bytes(bytes(raw))
        flips.append({"label": f"flip {i}", "action": "read", "args": {"path": str(p)}})
    raw = bytearray(plain.read_bytes())  # a digit of the motion, uncompressed: only the CRC tells
    at = raw.index(b'"base64": "') + 20
    raw[at] = ord("B") if raw[at] != ord("B") else ord("C")
    p = c.root / "digit.mcap"
    p.write_bytes(bytes(raw))
    flips.append({"label": "one digit of the motion", "action": "read", "args": {"path": str(p)}})
    raw = bytearray(plain.read_bytes())  # a stale payload: one window's row bytes copied over another's
    first = raw.index(b'"pos": {"dtype"')
    second = raw.index(b'"pos": {"dtype"', first + 1)
    length = raw.index(b"}", first) - first
    raw[second : second + length] = raw[first : first + length]
    p = c.root / "stale.mcap"
    p.write_bytes(bytes(raw))

    def chunk(label, comp, declared, real, extra=0, env=None):
        q = c.root / f"{label.replace(' ', '_')}.mcap"
        _mcap_with_chunk(q, comp, declared, real, meta, extra)
        return {"label": label, "action": "read", "args": {"path": str(q)}, **({"env": env} if env else {})}

    return {
        "MCAP flipped bytes": flips,
        "MCAP stale payloads": [{"label": "a window's bytes over another's", "action": "read", "args": {"path": str(p)}}],
        "MCAP zstd bombs": [
            chunk("zstd declared 1 GiB", "zstd", 1 << 30, 8 << 20),
            chunk("zstd declares 1000, 1.2 GB", "zstd", 1000, 1200 << 20),
        ],
        "MCAP lz4 bombs": [
            chunk("lz4 declares 1000, 64 MB", "lz4", 1000, 64 << 20),
            chunk("lz4 declared 1 GiB", "lz4", 1 << 30, 16 << 20),
        ],
        "MCAP huge record counts": [
            chunk("200k records, limit 100k", "", 0, 0, extra=200_000, env={"MER_MAX_MCAP_RECORDS": "100000"}),
            chunk("a chunk declaring 2^40 bytes", "zstd", 1 << 40, 1 << 20),
        ],
    }
