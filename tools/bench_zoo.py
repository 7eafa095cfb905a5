"""Benchmark: ``zoo.load(default)`` from a warm cache (goal <= 1 s), against its peer in the same run.

    PYTHONPATH=$PWD python tools/bench_zoo.py [--name mer-tiny] [--repeat 10]

Figures printed:

* ``import``: importing torch and the model code once (paid by any caller, not by the zoo);
* ``zoo.load``: name -> card -> verified files (size + sha256 of every file) -> model built from
  ``config.json`` -> weights loaded strictly; first call and median of the following calls;
* peer ``load_checkpoint(folder)``: the model package's strict loader on the same folder, with no
  name resolution and no checksum: the zoo's overhead is the ratio of the two;
* ``sha256``: the checksum throughput on this machine, which bounds the overhead for big models.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _median_time(fn, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--name", default=None, help="zoo name (default: the bundled default model)")
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()

    t = time.perf_counter()
    import torch  # noqa: F401

    from mer_models import zoo
    from mer_models.checkpoint import load_checkpoint
    from mer_models.zoo.integrity import sha256_file

    t_import = time.perf_counter() - t
    name = args.name or zoo.DEFAULT_MODEL

    t = time.perf_counter()
    ckpt = zoo.load(name)
    t_first = time.perf_counter() - t
    t_zoo = _median_time(lambda: zoo.load(name), args.repeat)
    folder = zoo.download(name)
    t_peer = _median_time(lambda: load_checkpoint(folder), args.repeat)
    weights = folder / "model.safetensors"
    size = weights.stat().st_size
    t_sha = _median_time(lambda: sha256_file(weights), args.repeat)
    params = sum(p.numel() for p in ckpt.model.parameters())

    print(f"model {name}: {params:,} parameters, model.safetensors {size / 1e6:.2f} MB, from {folder}")
    print(f"import torch + model code           {t_import:8.3f} s (once per process)")
    print(f"zoo.load first call                 {t_first:8.3f} s")
    print(f"zoo.load warm (median of {args.repeat:2d})        {t_zoo:8.3f} s   goal <= 1 s: {'met' if t_zoo <= 1.0 else 'NOT met'}")
    print(f"peer load_checkpoint(folder)        {t_peer:8.3f} s   zoo / peer = {t_zoo / t_peer:.2f}x")
    print(f"sha256 of the weights               {t_sha:8.3f} s   ({size / max(t_sha, 1e-9) / 1e6:.0f} MB/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
