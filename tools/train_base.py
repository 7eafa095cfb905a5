"""Maintainer script: build, teach, train, evaluate and bundle ``mer-base`` (synthetic motion only).

    PYTHONPATH=$PWD python tools/train_base.py --minutes 80           # all steps; resumes where it stopped
    PYTHONPATH=$PWD python tools/train_base.py --skip-train           # evaluate and bundle runs/mer-base

Steps (every one resumable; the same command continues a killed run; ``--from-bundled`` starts a
new run from the committed weights when the run folder, with its optimiser state, is gone):

1. **shards**: ``mer shards build --synthetic 8 --synthetic-seconds 20`` for the 8 built-in robots,
   each both source and target, one augmented skeleton per window and target (the paper's link
   scaling and dropped correspondences). Synthetic motion generated in code: the weights carry no
   LAFAN1 licence (Apache-2.0).
2. **teacher**: ``mer shards solve`` (the optimiser's solution of every sample).
3. **train**: ``tools/learning_curve.py --config base`` for ``--minutes`` CPU minutes, bf16 autocast,
   evaluated on held-out LAFAN1 windows after every chunk when ``--lafan1`` is given (the learning
   curve of docs/model.md).
4. **evaluate**: ``mer evaluate`` on LAFAN1 (G1 and H1 as sources, 8 targets, 32 windows each, the
   model, the model + 5 optimiser iterations, and the optimiser on the same windows) when
   ``--lafan1`` is given; the tables go into the card.
5. **bundle**: ``config.json`` (with the evaluation) and ``model.safetensors`` into
   ``mer_models/bundled/mer-base/``; **card**: ``cards/models/mer-base.md`` from the checkpoint.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

NAME = "mer-base"
ROBOTS = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")
SOURCES = ("g1", "h1")
BUILD = ["--synthetic", "8", "--synthetic-seconds", "20", "--robots", *ROBOTS, "--targets", *ROBOTS, "--augment", "1"]
EVAL = {"split": "all", "max_windows": 32, "refine": 5}


def mer(*args: str) -> None:
    cmd = [sys.executable, "-m", "mer_models", *args]
    print("+", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, cwd=REPO, check=True, env={**os.environ, "PYTHONPATH": str(REPO)})


def shards_step(work: Path) -> Path:
    out = work / f"{NAME}-shards"
    mer("shards", "build", *BUILD, "--out", str(out), "--quiet")  # up-to-date files are kept
    mer("shards", "solve", str(out), "--quiet")  # resumes a partial solve
    return out


def train_step(work: Path, shards: Path, minutes: float, lafan1: str | None, clock: str, init: str | None = None) -> Path:
    out = work / NAME
    cmd = [sys.executable, str(REPO / "tools" / "learning_curve.py"), "--config", "base", "--shards", str(shards), "--out", str(out),
           "--bf16", "--max-minutes", str(minutes), "--clock", clock, "--chunk-steps", "150"]  # fmt: skip
    if init:
        cmd += ["--init", init]
    if lafan1:
        cmd += ["--eval-input", lafan1, "--eval-targets", "g1", "h1", "atlas", "--eval-windows", "16"]
    print("+", " ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, cwd=REPO, check=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    return out


def evaluate_step(run_dir: Path, lafan1: str) -> dict:
    from mer_models.checkpoint import load_checkpoint
    from mer_models.evaluate import EvalOptions, evaluate, format_table

    opts = EvalOptions(split=EVAL["split"], max_windows=EVAL["max_windows"], refine=EVAL["refine"], methods=("model", "refine", "optimize"))
    reports = {}
    for src in SOURCES:
        t = time.time()
        rep = evaluate(lafan1, src, ROBOTS, checkpoint=load_checkpoint(run_dir), opts=opts, progress=lambda s: print("evaluate:", s, flush=True))
        print(format_table(rep), f"\nevaluate: {time.time() - t:.0f} s wall", flush=True)
        reports[src] = rep
    return reports


_COLS = (("g_mpbpe", "E_g-mpbpe [m]"), ("mpboe", "E_mpboe [rad]"), ("jerk_frame", "E_smooth [rad/frame^3]"), ("limit_violation", "limit violation"))
_METHOD = {"model": "model alone (4 Euler steps, 4 evaluations)", "refine": f"model + {EVAL['refine']} optimiser iterations",
           "optimize": "optimiser (the teacher)"}  # fmt: skip


def card_metrics(reports: dict) -> dict:
    """source -> '<method>' -> robot -> column -> value, plus frames/s."""
    out: dict = {"data": "LAFAN1 robot CSVs (G1, H1), every clip: never seen in training (synthetic motion only)",
                 "windows per robot": EVAL["max_windows"]}  # fmt: skip
    for src, rep in reports.items():
        for r in rep["rows"]:
            table = out.setdefault(f"source {src}, {_METHOD[r['method']]}", {})
            row = {"frames/s": round(r.get("frames_per_s", 0))}
            for key, col in _COLS:
                v = r["metrics"].get(key)
                row[col] = "-" if not v or v["mean"] != v["mean"] else (f"{v['mean']:.3f}" if key == "limit_violation" else f"{v['mean']:.3g}")
            table[r["robot"]] = row
    return out


def bundle_step(run_dir: Path, metrics: dict | None) -> Path:
    from mer_models.zoo.registry import bundled_dir

    dest = bundled_dir() / NAME
    tmp = dest.parent / f".tmp-{NAME}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    meta = json.loads((run_dir / "config.json").read_text())
    meta["metrics"] = {"train": meta.get("metrics", {}).get("train", {})}
    if metrics:
        meta["metrics"]["evaluation (mer evaluate)"] = metrics
    meta["data"] = {k: v for k, v in meta.get("data", {}).items() if k != "shards"} | {"shards": f"tools/train_base.py: mer shards build {' '.join(BUILD)}"}
    (tmp / "config.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    shutil.copy2(run_dir / "model.safetensors", tmp / "model.safetensors")
    for f in tmp.iterdir():
        f.chmod(0o644)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    print(f"bundle: {dest} ({sum(p.stat().st_size for p in dest.iterdir()) / 1e6:.2f} MB)")
    return dest


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default=str(REPO / "runs"), help="where shards and the run go (default runs/)")
    ap.add_argument("--minutes", type=float, default=80.0, help="minutes of training in all (default 80)")
    ap.add_argument("--clock", choices=["cpu", "wall"], default="cpu", help="what --minutes counts (default: CPU time)")
    ap.add_argument("--lafan1", help="LAFAN1-layout folder for the evaluations (e.g. ../shared/data/lafan1)")
    ap.add_argument("--skip-train", action="store_true", help="evaluate and bundle WORK/mer-base as it is")
    ap.add_argument("--from-bundled", action="store_true",
                    help="a new run (no WORK/mer-base yet) starts from the bundled mer-base weights, with a fresh optimiser: "
                    "how training continues in a session without the earlier run folder (exact resume needs that folder)")
    ap.add_argument("--no-bundle", action="store_true")
    args = ap.parse_args()
    work = Path(args.work)
    if not args.skip_train:
        shards = shards_step(work)
        train_step(work, shards, args.minutes, args.lafan1, args.clock,
                   str(REPO / 'mer_models' / 'bundled' / NAME) if args.from_bundled else None)
    run_dir = work / NAME
    metrics = None
    if args.lafan1:
        reports = evaluate_step(run_dir, args.lafan1)
        (work / f"{NAME}-evaluation.json").write_text(json.dumps(reports, indent=2) + "\n")
        metrics = card_metrics(reports)
    if not args.no_bundle:
        bundle_step(run_dir, metrics)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
