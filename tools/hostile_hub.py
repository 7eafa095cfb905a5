"""The hostile Hub, write-redirection and full-disk classes of issue 41 (the shard classes are in
``tools/hostile_shards.py``, the driver and the table in ``tools/hostile_inputs.py``)."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

from hostile_shards import Cases, build_valid, hdf5_classes, mcap_classes, probe  # noqa: F401

# ---- the Hub ----------------------------------------------------------------------------------


def hub_classes(root: Path, valid: dict[str, Path]) -> dict[str, list[dict]]:
    """Each case runs alone (the server's lies change between them); returns the measured rows."""
    from hub_server import HubServer

    shard_dir = valid["hdf5"].parent
    files = {
        p.name: p.read_bytes() for p in shard_dir.iterdir() if p.suffix in (".h5", ".json", ".md") and "report" not in p.name
    }
    name = valid["hdf5"].name
    out: dict[str, list[dict]] = {}
    cases = [
        ("Hub lying ETag", "dataset ETag ../../..", "hf", {"etag": {name: "../../../../escaped"}}, {}),
        ("Hub lying ETag", "model ETag ../../..", "model", {"etag": {"model.safetensors": "../../../../escaped"}}, {}),
        ("Hub lying commit id", "repository sha ../..", "hf", {"sha": "../../../../escaped"}, {}),
        ("Hub lying commit id", "X-Repo-Commit differs", "hf", {"commit": "b" * 40}, {}),
        (
            "Hub lying file names",
            "listed ../../escaped.h5",
            "hf",
            {"extra": [{"type": "file", "path": "../../../escaped.h5", "size": 10, "oid": "0" * 40}]},
            {},
        ),
        (
            "Hub lying file names",
            "listed /etc/escaped.h5",
            "hf",
            {"extra": [{"type": "file", "path": "/etc/escaped.h5", "size": 10, "oid": "0" * 40}]},
            {},
        ),
        ("Hub lying sizes", "listing says 10 bytes", "hf", {"size": {"mer_meta.json": 10}}, {}),
        ("Hub lying sizes", "sends more than announced", "tamper", {}, {}),
        ("Hub oversized config", "mer_meta.json 3 MB (limit 1 MB)", "bigmeta", {}, {"MER_MAX_SIDECAR_BYTES": "1000000"}),
        ("Hub oversized config", "config.json 64 MB", "bigconfig", {}, {}),
    ]
    for cls, label, kind, lies, env in cases:
        cache = root / "hub" / hashlib.sha1(label.encode()).hexdigest()[:8]
        with HubServer(lifetime_s=600) as hub:
            hub.put("lab/shards", files)
            hub.put("org/model", {"config.json": b"{}", "model.safetensors": b"weights" * 100}, kind="model")
            hub.lie(**lies)
            args: dict = {"url": "hf://datasets/lab/shards"}
            action = "hf"
            if kind == "model":
                action, args = "model", {"repo": "org/model", "file": "model.safetensors", "cache": str(cache)}
            elif kind == "tamper":
                hub.tamper("lab/shards", "mer_meta.json", files["mer_meta.json"] + b" " * 1000)
            elif kind == "bigmeta":
                hub.put("lab/shards", {"mer_meta.json": files["mer_meta.json"] + b" " * 3_000_000}, lfs=False)
            elif kind == "bigconfig":
                hub.put("org/model", {"config.json": b"{}" + b" " * (64 << 20)}, kind="model", lfs=False)
                action, args = "model", {"repo": "org/model", "file": "config.json", "cache": str(cache)}
            before = {p for p in root.rglob("*")}
            env = {**env, "HF_ENDPOINT": hub.url, "HF_HUB_CACHE": str(cache), "HF_HOME": str(cache / "home")}
            env.pop("HF_HUB_OFFLINE", None)
            row = probe([{"label": label, "action": action, "args": args}], env=env)[0]
            escaped = [p for p in set(root.rglob("*")) - before
                       if "escaped" in str(p) or not (str(p).startswith(str(cache)) or cache.is_relative_to(p))]  # fmt: skip
            if escaped:
                row["outcome"] = f"NOT contained: wrote {escaped[0]}"
        out.setdefault(cls, []).append(row)
    return out


# ---- write redirection and full disks -----------------------------------------------------------


def _victim(root: Path, n: int) -> Path:
    v = root / "victims" / str(n)
    v.mkdir(parents=True)
    (v / "precious.txt").write_text("precious\n")
    return v


def _intact(v: Path) -> bool:
    return sorted(p.name for p in v.iterdir()) == ["precious.txt"] and (v / "precious.txt").read_text() == "precious\n"


def write_classes(root: Path, valid: dict[str, Path]) -> dict[str, list[dict]]:
    from mer_data.shards.teacher import teacher_path

    rows: dict[str, list[dict]] = {}
    plans = []
    for i, (cls, label) in enumerate([("symlinked .partial", "teacher <shard>.h5.partial"), ("symlinked .partial", "shards .partial/"),
                                      ("symlinked .partial", "shards .partial/<file>/"), ("symlinked teacher/", "teacher/"),
                                      ("symlinked output files", "teacher <shard>.h5"),
                                      ("symlinked output files", "build-report.json, README.md")]):  # fmt: skip
        v = _victim(root, i)
        d = root / "write" / str(i)
        if label.startswith("teacher"):
            d.mkdir(parents=True)
            shard = Path(shutil.copy(valid["hdf5"], d))
            t = teacher_path(shard)
            if label == "teacher/":
                t.parent.symlink_to(v, target_is_directory=True)
            else:
                t.parent.mkdir()
                (t.with_name(t.name + ".partial") if label.endswith("partial") else t).symlink_to(v / "precious.txt")
            case = {"label": label, "action": "solve", "args": {"path": str(shard)}}
        else:
            out = d / "out"
            if label == "shards .partial/":
                out.mkdir(parents=True)
                (out / ".partial").symlink_to(v, target_is_directory=True)
            elif label.startswith("shards .partial/<"):
                (out / ".partial").mkdir(parents=True)
                (out / ".partial" / "g1-train-00000-of-00001").symlink_to(v, target_is_directory=True)
            else:
                out.mkdir(parents=True)
                for name in ("build-report.json", "README.md"):
                    (out / name).symlink_to(v / "precious.txt")
            case = {"label": label, "action": "build", "args": {"out": str(out)}}
        plans.append((cls, case, v))
    got = probe([c for _, c, _ in plans])
    for (cls, case, v), row in zip(plans, got):
        intact = _intact(v)
        if row["outcome"] == "ok":
            row["outcome"] = "replaced" if intact else "NOT contained: the link's target changed"
        elif row["outcome"].startswith("NOT"):
            pass
        else:
            row["outcome"] = "refused" if intact else "NOT contained: the link's target changed"
        rows.setdefault(cls, []).append(row)
    return rows


def disk_full_classes(root: Path, valid: dict[str, Path]) -> dict[str, list[dict]]:
    if shutil.which("unshare") is None:
        return {
            "disk full": [
                {"label": "skipped: no unshare(1)", "outcome": "skipped", "message": "", "s": 0, "peak": 0, "growth": 0}
            ]
        }
    mnt = root / "full"
    mnt.mkdir()
    shard_dir = valid["hdf5"].parent
    rows = []
    for label, kb, case in (
        ("piece (64 kB free)", 64, {"action": "build", "args": {"out": str(mnt / "out")}}),
        ("merge (pieces fit)", 0, {"action": "build", "args": {"out": str(mnt / "out")}}),
        ("teacher file (96 kB free)", 96, {"action": "solve", "args": {"path": str(shard_dir), "out": str(mnt / "teacher")}}),
    ):
        if kb == 0:  # the one piece fits, the merged file (as large again) does not
            from mer_data.shards import BuildConfig, build_shards

            tmp = root / "sizes"
            build_shards(BuildConfig(input="", robots=("g1",), targets=("g1",), synthetic=1, synthetic_seconds=2.5, augment=0,
                                     split="all"), tmp)  # fmt: skip
            kb = (next(tmp.glob("*.h5")).stat().st_size * 3 // 2) // 1024
        script = f'mount -t tmpfs -o size={kb}k tmpfs {mnt} || exit 99; exec "$@"'
        r = probe([{"label": label, **case}], wrap=["unshare", "-rm", "sh", "-c", script, "sh"])[0]
        rows.append(r)
    return {"disk full": rows}


def run_shards(root: Path) -> dict[str, list[dict]]:
    """Every class of issue 41 generated under ``root`` and probed: class -> measured rows."""
    root.mkdir(parents=True, exist_ok=True)
    valid = build_valid(root)
    c = Cases(root, valid)
    results: dict[str, list[dict]] = {}
    truth = {fmt: probe([{"label": fmt, "action": "read", "args": {"path": str(p)}}])[0]["digest"] for fmt, p in valid.items()}
    for name, cases in {**hdf5_classes(c), **mcap_classes(c)}.items():
        results[name] = probe(cases)
        for r in results[name]:  # read without an error: only if what was read is what was written
            if r["outcome"] == "ok":
                fmt = "mcap" if name.startswith("MCAP") else "hdf5"
                r["outcome"] = "read unchanged" if r["digest"] == truth[fmt] else "NOT refused: altered values read"
    results.update(hub_classes(root, valid))
    results.update(write_classes(root, valid))
    results.update(disk_full_classes(root, valid))
    return results
