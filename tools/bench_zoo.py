"""Benchmark: ``zoo.load(default)`` from the bundled package and from a warm Hub cache (goal <= 1 s),
against its peer (the strict loader on the same folder, no name resolution, no checksum) in the same run.

    PYTHONPATH=$PWD python tools/bench_zoo.py [--name NAME] [--repeat 10]

Figures printed:

* ``import``: importing torch and the model code once (paid by any caller, not by the zoo);
* **bundled**: ``zoo.load(name)`` of the model shipped in the package: name -> card -> size and
  sha256 of every file -> model built from ``config.json`` -> weights loaded strictly; first call
  and median of the following calls;
* **warm Hub cache**: the same model published to a loopback Hub (``tests/hub_server.py``, the
  real huggingface_hub client uploads and downloads), downloaded once into an empty cache, then
  loaded by name with ``HF_HUB_OFFLINE=1``: first call and median; the Hub's request count
  before and after shows that no request was made;
* peer ``load_checkpoint(folder)``: the model package's strict loader on the same folder: the
  zoo's overhead is the ratio of the two;
* ``sha256``: the checksum throughput on this machine, which bounds the overhead for big models.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(1, str(REPO / "tests"))


def _median_time(fn, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def _timed(fn):
    t = time.perf_counter()
    v = fn()
    return v, time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--name", default=None, help="zoo name of a bundled model (default: the bundled default model)")
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()

    # The Hub client reads its configuration when first imported: the loopback Hub and an empty cache first.
    from hub_server import HubServer
    from zoo_helpers import TOKEN, client_env

    tmp = Path(tempfile.mkdtemp(prefix="mer-bench-zoo-"))
    hub = HubServer(token=TOKEN)
    os.environ.update(client_env(hub.url, tmp, tmp / "mer_home"))
    for v in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE"):
        os.environ.pop(v, None)

    (_, t_import) = _timed(lambda: (__import__("torch"), __import__("mer_models.zoo.checkpoint"), __import__("mer_models.zoo")))
    from mer_models import zoo
    from mer_models.hub.integrity import sha256_file
    from mer_models.hub.registry import Registry
    from mer_models.zoo.checkpoint import load_checkpoint

    name = args.name or zoo.DEFAULT_MODEL
    ckpt, t_first = _timed(lambda: zoo.load(name))
    res = zoo.resolve(name)
    if res.source != "bundled":
        raise SystemExit(f"{name} is not a bundled model ({res.source})")
    t_zoo = _median_time(lambda: zoo.load(name), args.repeat)
    t_peer = _median_time(lambda: load_checkpoint(res.folder), args.repeat)
    weights = res.folder / "model.safetensors"
    size = weights.stat().st_size
    t_sha = _median_time(lambda: sha256_file(weights), args.repeat)
    params = sum(p.numel() for p in ckpt.model.parameters())

    # publish the same files to the loopback Hub, download once, then load from the warm cache offline
    reg = Registry(user=tmp / "cards")
    pub_name, repo = f"bench-{name}", f"bench/{name}"
    zoo.publish(res.folder, name=pub_name, repo_id=repo, cards_dir=tmp / "cards", registry=reg)
    _, t_download = _timed(lambda: zoo.download(pub_name, registry=reg))
    os.environ["HF_HUB_OFFLINE"] = "1"
    before = len(hub.requests)
    hres = zoo.resolve(pub_name, registry=reg)
    _, t_hub_first = _timed(lambda: zoo.load(pub_name, registry=reg))
    t_hub = _median_time(lambda: zoo.load(pub_name, registry=reg), args.repeat)
    t_hub_peer = _median_time(lambda: load_checkpoint(hres.folder), args.repeat)
    calls = len(hub.requests) - before
    hub.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    def goal(t: float) -> str:
        return "met" if t <= 1.0 else "NOT met"

    print(f"model {name}: {params:,} parameters, model.safetensors {size / 1e6:.2f} MB")
    print(f"import torch + model code             {t_import:8.3f} s (once per process)")
    print(f"bundled   ({res.folder})")
    print(f"  zoo.load first call                 {t_first:8.3f} s")
    print(f"  zoo.load warm (median of {args.repeat:2d})        {t_zoo:8.3f} s   goal <= 1 s: {goal(t_zoo)}")
    print(f"  peer load_checkpoint(folder)        {t_peer:8.3f} s   zoo / peer = {t_zoo / t_peer:.2f}x")
    print(f"Hub cache ({hres.repo_id}@{hres.revision[:12]} in {hres.folder.parents[2]})")
    print(f"  download into an empty cache        {t_download:8.3f} s (loopback Hub, real client)")
    print(f"  zoo.load first call, offline        {t_hub_first:8.3f} s")
    print(f"  zoo.load warm (median of {args.repeat:2d})        {t_hub:8.3f} s   goal <= 1 s: {goal(t_hub)}")
    print(f"  peer load_checkpoint(folder)        {t_hub_peer:8.3f} s   zoo / peer = {t_hub / t_hub_peer:.2f}x")
    print(f"  requests to the Hub while offline   {calls:8d}")
    print(f"sha256 of the weights                 {t_sha:8.3f} s   ({size / max(t_sha, 1e-9) / 1e6:.0f} MB/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
