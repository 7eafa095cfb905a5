"""Maintainer script: build, teach, train and bundle ``mer-warm``, the warm-start model (synthetic motion only).

    PYTHONPATH=$PWD python tools/train_warm.py --work /tmp/mer-warm --steps 1500        # every step; resumes
    PYTHONPATH=$PWD python tools/train_warm.py --work /tmp/mer-warm --bundle-only      # bundle WORK/run as it is

Steps (each resumable: the same command continues a killed run):

1. **shards**: ``mer shards build --synthetic 8 --synthetic-seconds 20`` for the 8 built-in robots, each
   both source and target, one augmented skeleton per window and target (as ``tools/train_base.py``).
   Synthetic motion generated in code: the weights carry no LAFAN1 licence (Apache-2.0).
2. **teacher**: ``mer shards solve --physics-method METHOD`` (the optimiser's solution of every sample, with
   its physical terms: ``penalty``, the default, is what the bundled weights were taught with; ``constraints``,
   the least change to the plain solution that keeps every body above the floor, bodies apart and stance
   feet planted, issue 50: measured in docs/model.md §The warm start, not bundled).
3. **train**: the ``warm`` preset (:data:`mer_models.config.PRESETS`) for ``--steps`` steps, the cosine
   decay spanning them, in chunks of ``--chunk`` steps; each chunk trains on the shards whose teacher
   file is complete by then (so training can start while the teacher still solves the last shards).
4. **bundle**: ``config.json`` + ``model.safetensors`` into ``mer_models/bundled/mer-warm/`` (refused
   unless every shard the run trained on is synthetic), the card rendered from the checkpoint.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

from train_base import BUILD, ROBOTS, _require_synthetic, install_bundle, mer, require_every_robot  # noqa: E402 (mer-base's data and checks)

NAME = "mer-warm"


def taught(shards: Path) -> list[Path]:
    """The shard files of ``shards`` whose teacher file is complete."""
    return sorted(p for p in shards.glob("*.h5") if (shards / "teacher" / p.name).is_file())


def train_step(work: Path, shards: Path, steps: int, chunk: int, init: Path | None = None, lr: float | None = None) -> Path:

    from mer_data.shards import ShardDataset
    from mer_models.config import preset
    from mer_models.hub.checkpoint_files import read_meta
    from mer_models.training.train import train

    out = work / "run"
    run = preset("warm")
    run = run.replace(train=dataclasses.replace(run.train, lr_decay_steps=max(1, steps - run.train.warmup), log_every=20,
                                                lr=lr or run.train.lr))  # fmt: skip
    done = int(read_meta(out)["step"]) if (out / "config.json").is_file() else 0
    while done < steps:
        files = taught(shards)
        if not files:
            raise SystemExit(f"no shard in {shards} has a complete teacher file yet: run `mer shards solve {shards}`")
        data = ShardDataset(files, teacher=True)
        info = {"shards": [str(p) for p in data.paths], "samples": len(data), "teacher": True, "split": "all",
                "motion": "synthetic motion generated in code (mer_data.synthesis), no third-party motion data",
                "build": f"mer shards build {' '.join(BUILD)}"}  # fmt: skip
        if init is not None:
            first = read_meta(init.parent)
            info["history"] = (f"a second cosine cycle, started from the weights of a first run of the same preset on the same shards "
                               f"({int(first['step'])} steps, peak lr {first['run']['train']['lr']:g})")  # fmt: skip
        target = min(steps, done + chunk)
        print(f"training {done} -> {target} on {len(files)} shard(s), {len(data)} samples", flush=True)
        res = train(run, data, out, steps=target, resume=done > 0, data_info=info, init=init if done == 0 else None,
                    progress=lambda r: print(json.dumps({k: round(v, 6) for k, v in r.items()}), flush=True))  # fmt: skip
        done = res.step
    return out


def bundle_step(run_dir: Path, summary: str | None = None, metrics: dict | None = None) -> Path:
    """``config.json`` + weights of ``run_dir`` into ``mer_models/bundled/mer-warm/`` (refused unless every
    built-in robot is a target and a reference and every training shard is synthetic), then its card
    ``cards/models/mer-warm.md`` and the packaged copy."""
    from mer_models.hub.fromckpt import DATASETS, card_from_checkpoint, read_checkpoint_meta
    from mer_models.hub.registry import source_cards_dir, write_card

    read_checkpoint_meta(run_dir)
    meta = json.loads((run_dir / "config.json").read_text())
    require_every_robot(meta, run_dir, NAME)
    _require_synthetic(meta, run_dir)
    meta["metrics"] = {"train": meta.get("metrics", {}).get("train", {}), **({"evaluation (tools/bench_warm.py)": metrics} if metrics else {})}
    meta["data"] = {k: v for k, v in meta.get("data", {}).items() if k != "shards"} | {
        "shards": f"tools/train_warm.py: mer shards build {' '.join(BUILD)}"}
    dest = install_bundle(NAME, meta, run_dir / "model.safetensors")
    w = meta["run"]["warm"]
    text = summary or (
        "The warm-start model: a cheap per-frame network (no reference encoder) whose output "
        f"{w['refine']} whole-window optimiser iterations finish (`mer retarget --model {NAME}`). Trained only on synthetic "
        f"motion generated in code, every built-in robot ({', '.join(ROBOTS)}) as source and target; H = {w['hidden']}, "
        f"{w['layers']} layers, stride {w['stride']}; {int(meta['step'])} steps"
        f"{' (' + meta['data']['history'] + ')' if meta['data'].get('history') else ''} on 2 CPU cores. docs/model.md, The warm start."
        + (_verdict(metrics) if metrics else ""))
    card = card_from_checkpoint(dest, name=NAME, status="bundled", summary=text, license_note=DATASETS["synthetic"].note,
                                reproduce=f"python tools/train_warm.py --work WORK --steps {int(meta['step'])}")  # fmt: skip
    if card.license != DATASETS["synthetic"].license:
        raise SystemExit(f"the checkpoint in {dest} does not describe synthetic training data: {card.training}")
    cards = source_cards_dir()
    if cards is None:
        raise SystemExit("run this from a source checkout (cards/models is missing)")
    print(f"card: {write_card(card, cards)} (and its packaged copy)")
    return dest


def _verdict(metrics: dict) -> str:
    """One sentence of the card from tools/bench_warm.py's figures (metrics.py-shaped: source -> target -> row)."""
    rows = [r for k, t in metrics.items() if isinstance(t, dict) for r in t.values()]
    g = [float(r["vs optimiser"]) for r in rows]
    tc = [float(r["time vs capped optimiser"]) for r in rows]
    return (f" Measured on LAFAN1 (G1 and H1 sources, 8 targets, never seen in training; tools/bench_warm.py): + 2 iterations "
            f"{sum(g) / len(g):.2f}x the optimiser's E_g-mpbpe on average ({min(g):.2f}-{max(g):.2f}x) at {sum(tc) / len(tc):.2f}x "
            "the time of the optimiser capped at 3 coarse iterations, which is as accurate: not mer's default path.")


def main() -> None:
    logging.basicConfig(level=logging.WARNING)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True, help="folder of the shards, teacher and run")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--chunk", type=int, default=200, help="steps between looks for newly taught shards")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--init", type=Path, help="start from these weights (a run's model.safetensors): a second cosine cycle")
    ap.add_argument("--lr", type=float, help="peak learning rate (default: the preset's)")
    ap.add_argument("--physics-method", choices=["penalty", "constraints"], default="penalty",
                    help="the teacher's physical terms (default penalty: the bundled weights' teacher)")
    ap.add_argument("--shards", type=Path, help="use these shards (built and solved elsewhere) instead of steps 1-2")
    ap.add_argument("--bundle-only", action="store_true", help="bundle WORK/run as it is (with --metrics JSON as its evaluation)")
    ap.add_argument("--metrics", type=Path, help="a JSON of evaluation figures to store in the bundled config.json")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    if args.bundle_only:
        bundle_step(args.work / "run", metrics=json.loads(args.metrics.read_text()) if args.metrics else None)
        return
    shards = args.shards or args.work / "shards"
    if args.shards is None:
        mer("shards", "build", *BUILD, "--out", str(shards), "--quiet")
        mer("shards", "solve", str(shards), "--physics-method", args.physics_method, "--quiet")
    run_dir = train_step(args.work, shards, args.steps, args.chunk, args.init, args.lr)
    print(f"trained: {run_dir}")


if __name__ == "__main__":
    main()
