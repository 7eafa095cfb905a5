"""Benchmark: a training step with batches grouped by reference window (``TrainConfig.ref_group``)
against ungrouped batches, the same trainer, shards and configuration, in one run.

    PYTHONPATH=$PWD python tools/bench_train_step.py --shards SHARDS [--config base] [--groups 1 4 8] \\
        [--steps 6] [--rounds 2] [--threads 1] [--bf16] [--init mer_models/bundled/mer-base]

Each round trains every grouping for ``--steps`` steps from the same weights (the real trainer,
:func:`mer_models.training.train.train`, logging every step); a step's time is the gap between two log
records (load + collate + conditions + teacher + forward + energy + backward + AdamW). The first
step of each run is left out (allocation, caches). Rounds alternate the groupings so that a busy
neighbour on a shared machine slows them alike; the median over all rounds is reported with its
ratio to ``ref_group`` 1 (docs/model.md, Training: batches grouped by reference window).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def step_times(run, ds, steps: int, init: Path | None, bf16: bool = False) -> list[float]:
    from mer_models.training.train import train

    stamps: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        train(run, ds, Path(tmp) / "c", steps=steps, init=init, bf16=bf16, progress=lambda rec: stamps.append(time.perf_counter()))
    return [b - a for a, b in zip(stamps, stamps[1:])]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shards", nargs="+", required=True, help="shards with teacher files (mer shards solve)")
    ap.add_argument("--config", default="base")
    ap.add_argument("--groups", type=int, nargs="+", default=[1, 4, 8], help="ref_group values (1 is the peer)")
    ap.add_argument("--steps", type=int, default=6, help="steps per run (the first is left out)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--bf16", action="store_true", help="bfloat16 autocast, as `mer train --bf16`")
    ap.add_argument("--init", help="checkpoint folder to start every run from (default: fresh weights)")
    args = ap.parse_args()

    import torch

    from mer_data.shards import ShardDataset
    from mer_models.config import preset

    torch.set_num_threads(args.threads)
    ds = ShardDataset(args.shards, teacher=True)
    base = preset(args.config)
    init = Path(args.init) / "model.safetensors" if args.init else None
    if init is not None:  # the checkpoint's feed-forward width (the bundled mer-base: 768, not the preset's 256)
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from overfit_probe import ffn_width

        base = base.replace(model=dataclasses.replace(base.model, ffn=ffn_width(init) or base.model.ffn))
    times: dict[int, list[float]] = {k: [] for k in args.groups}
    groups = [1] + [k for k in args.groups if k != 1]
    for r in range(args.rounds):
        for k in groups if r % 2 == 0 else groups[::-1]:
            run = base.replace(train=dataclasses.replace(base.train, ref_group=k, log_every=1, save_every=10**6))
            times[k] += step_times(run, ds, args.steps, init, args.bf16)
    peer = statistics.median(times[1])
    batch = base.train.batch_size
    print(f"{args.config}, batch {batch}, {'bf16' if args.bf16 else 'float32'}, {torch.get_num_threads()} thread(s), {len(ds)} samples, "
          f"{args.rounds} rounds x {args.steps - 1} timed steps per grouping")  # fmt: skip
    print(f"{'ref_group':>9} {'windows/batch':>13} {'s/step (median)':>16} {'min':>6} {'max':>6} {'speed-up':>9}")
    rows = []
    for k in groups:
        t = times[k]
        med = statistics.median(t)
        rows.append({"ref_group": k, "windows_per_batch": batch // k, "median_s": med, "min_s": min(t), "max_s": max(t),
                     "speedup_vs_1": peer / med, "steps": len(t)})  # fmt: skip
        print(f"{k:>9} {batch // k:>13} {med:>16.2f} {min(t):>6.2f} {max(t):>6.2f} {peer / med:>8.2f}x")
    print(json.dumps({"config": args.config, "bf16": args.bf16, "threads": torch.get_num_threads(), "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
