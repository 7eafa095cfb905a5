"""Maintainer script: build, teach, train, evaluate and bundle ``mer-base``, mer's default model
(synthetic motion only; bundled in the package).

    PYTHONPATH=$PWD python tools/train_base.py --minutes 80           # all steps; resumes where it stopped
    PYTHONPATH=$PWD python tools/train_base.py --skip-train --lafan1 DIR   # evaluate, bundle and card runs/mer-base
    PYTHONPATH=$PWD python tools/train_base.py --bundle-only --run DIR     # bundle and card a checkpoint as it is

Steps (every one resumable; the same command continues a killed run; ``--from-bundled`` starts a
new run from the committed weights when the run folder, with its optimiser state, is gone):

1. **shards**: ``mer shards build --synthetic 8 --synthetic-seconds 20`` for the 8 built-in robots,
   each both source and target, one augmented skeleton per window and target (the paper's link
   scaling and dropped correspondences). Synthetic motion generated in code: the weights carry no
   LAFAN1 licence (Apache-2.0).
2. **teacher**: ``mer shards solve`` (the optimiser's solution of every sample).
3. **train**: ``tools/learning_curve.py --config base`` for ``--minutes`` CPU minutes, bf16 autocast
   where the CPU runs it natively (AMX or AVX512-BF16; float32 elsewhere),
   evaluated on held-out LAFAN1 windows after every chunk when ``--lafan1`` is given (the learning
   curve of docs/model.md).
4. **evaluate**: ``mer evaluate`` on LAFAN1 (G1 and H1 as sources, 8 targets, 32 windows each, the
   model, the model + 5 optimiser iterations, and the optimiser on the same windows) when
   ``--lafan1`` is given; the tables go into the card.
5. **bundle**: ``config.json`` (with the evaluation) and ``model.safetensors`` into
   ``mer_models/bundled/mer-base/``; **card**: ``cards/models/mer-base.md`` and its packaged copy
   ``mer_models/cards/mer-base.md``, rendered by :func:`mer_models.hub.fromckpt.card_from_checkpoint`
   from the bundled checkpoint's own metadata (status ``bundled``, licence Apache-2.0).

``--bundle-only`` skips steps 1-4: it bundles the checkpoint in ``--run`` (default WORK/mer-base)
with the evaluation of ``WORK/mer-base-evaluation.json`` when that file exists (the reports step 4
wrote), and renders the card. Replacing the bundled model with a newer checkpoint is that command.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

NAME = "mer-base"
ROBOTS = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")
SOURCES = ("g1", "h1")
BUILD = ["--synthetic", "8", "--synthetic-seconds", "20", "--robots", *ROBOTS, "--targets", *ROBOTS, "--augment", "1"]
EVAL = {"split": "all", "max_windows": 32, "refine": 5}
EVALUATION_FILE = f"{NAME}-evaluation.json"  # in WORK: the reports of the evaluate step (source -> report)


def mer(*args: str) -> None:
    cmd = [sys.executable, "-m", "mer_models", *args]
    print("+", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, cwd=REPO, check=True, env={**os.environ, "PYTHONPATH": str(REPO)})


def shards_step(work: Path) -> Path:
    out = work / f"{NAME}-shards"
    mer("shards", "build", *BUILD, "--out", str(out), "--quiet")  # up-to-date files are kept
    mer("shards", "solve", str(out), "--quiet")  # resumes a partial solve
    return out


def train_step(work: Path, shards: Path, minutes: float, lafan1: str | None, clock: str, init: str | None = None,
               lr_decay_steps: int = 0) -> Path:
    out = work / NAME
    cmd = [sys.executable, str(REPO / "tools" / "learning_curve.py"), "--config", "base", "--shards", str(shards), "--out", str(out),
           "--max-minutes", str(minutes), "--clock", clock, "--chunk-steps", "150"]  # fmt: skip
    from mer_models.training.train import native_bf16

    if native_bf16("cpu"):  # AMX / AVX512-BF16; elsewhere bf16 is emulated and slower than float32
        cmd.append("--bf16")
    if lr_decay_steps:
        cmd += ["--lr-decay-steps", str(lr_decay_steps)]
    if init:
        cmd += ["--init", init]
    if lafan1:
        cmd += ["--eval-input", lafan1, "--eval-targets", "g1", "h1", "atlas", "--eval-windows", "16"]
    print("+", " ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, cwd=REPO, check=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    return out


def sampler_step(run_dir: Path) -> dict[str, Any]:
    """Give the run the ``base`` preset's sampler (sampling settings are not training state: a resumed
    run takes the preset's too) before it is evaluated and bundled; returns it."""
    from mer_data.base.atomic import atomic_write
    from mer_models.config import preset

    path = run_dir / "config.json"
    meta = json.loads(path.read_text())
    sampler = dataclasses.asdict(preset("base").sampler)
    if meta["run"]["sampler"] != sampler:
        print(f"sampler: {meta['run']['sampler']} -> {sampler}")
        meta["run"]["sampler"] = sampler
        atomic_write(path, (json.dumps(meta, indent=2, sort_keys=True) + "\n").encode())
    return sampler


def evaluate_step(run_dir: Path, lafan1: str) -> dict:
    from mer_models.retarget.evaluate import EvalOptions, evaluate, format_table
    from mer_models.zoo.checkpoint import load_checkpoint

    opts = EvalOptions(split=EVAL["split"], max_windows=EVAL["max_windows"], refine=EVAL["refine"], methods=("model", "refine", "optimize"))
    reports = {}
    for src in SOURCES:
        t = time.time()
        rep = evaluate(lafan1, src, ROBOTS, checkpoint=load_checkpoint(run_dir), opts=opts, progress=lambda s: print("evaluate:", s, flush=True))
        print(format_table(rep), f"\nevaluate: {time.time() - t:.0f} s wall", flush=True)
        reports[src] = rep
    return reports


_COLS = (("g_mpbpe", "E_g-mpbpe [m]"), ("mpboe", "E_mpboe [rad]"), ("jerk_frame", "E_smooth [rad/frame^3]"), ("limit_violation", "limit violation"))
_METHOD = {"model": "model alone", "refine": f"model + {EVAL['refine']} optimiser iterations",
           "optimize": "optimiser (the teacher)"}  # fmt: skip


def card_metrics(reports: dict, sampler: dict[str, Any] | None = None) -> dict:
    """source -> '<method>' -> robot -> column -> value, plus frames/s (and the sampler the model ran with)."""
    out: dict = {"data": "LAFAN1 robot CSVs (G1, H1), every clip: never seen in training (synthetic motion only)",
                 "windows per robot": EVAL["max_windows"]}  # fmt: skip
    if sampler is not None:
        out["model sampler"] = sampler_text(sampler)
    for src, rep in reports.items():
        for r in rep["rows"]:
            table = out.setdefault(f"source {src}, {_METHOD[r['method']]}", {})
            row = {"frames/s": round(r.get("frames_per_s", 0))}
            for key, col in _COLS:
                v = r["metrics"].get(key)
                row[col] = "-" if not v or v["mean"] != v["mean"] else (f"{v['mean']:.3f}" if key == "limit_violation" else f"{v['mean']:.3g}")
            table[r["robot"]] = row
    return out


def _require_synthetic(meta: dict, run_dir: Path) -> None:
    """Refuse a run whose training shards are not all synthetic (weights trained on LAFAN1 carry its
    CC BY-NC-ND terms and must never ship), or whose shards can no longer be read to check."""
    from mer_data.base.errors import PublishError
    from mer_data.shards import open_shard

    shards = (meta.get("data") or {}).get("shards")
    if not isinstance(shards, list) or not shards:
        raise PublishError(f"{run_dir} does not record the shard files it was trained on", path=run_dir / "config.json",
                           element="data.shards", fix="bundle a run trained by tools/train_base.py (it records them)")  # fmt: skip
    for p in shards:
        try:
            f = open_shard(p)
        except Exception as exc:  # noqa: BLE001 - any unreadable shard: cannot prove the data is synthetic
            raise PublishError(f"cannot check the training data: shard {p} is not readable ({exc})", path=run_dir / "config.json",
                               element="data.shards", fix="bundle on the machine that holds the run's shards") from None  # fmt: skip
        source = f.meta.config.get("input")
        f.close()
        if source != "synthetic":
            raise PublishError(f"{run_dir} was trained on {p}, built from {source!r}, not synthetic motion: its weights must not ship",
                               path=run_dir / "config.json", element="data.shards",
                               fix="keep LAFAN1-trained weights outside the repository; bundle a run on synthetic shards")  # fmt: skip


def require_every_robot(meta: dict, run_dir: Path, name: str) -> None:
    """Refuse a run that lacks a built-in robot as target or reference, or that trained on other
    skeletons of them than this checkout's (fingerprints differ)."""
    from mer_data.base.errors import PublishError
    from mer_data.robots.registry import get_skeleton

    robots = meta.get("robots") or {}
    have = {k: sorted(robots.get(k, {})) for k in ("targets", "references")}
    if have != {"targets": sorted(ROBOTS), "references": sorted(ROBOTS)}:
        raise PublishError(f"{run_dir} is not a {name} checkpoint: its robots are {have}, {name} needs every built-in "
                           f"robot ({' '.join(ROBOTS)}) as target and as reference", path=run_dir / "config.json", element="robots")
    stale = sorted({r for k in ("targets", "references") for r, fp in robots[k].items() if fp != get_skeleton(r).fingerprint})
    if stale:
        raise PublishError(f"{run_dir} was trained on other skeletons of {', '.join(stale)} than the built-in ones of this "
                           "checkout (skeleton fingerprints differ)", path=run_dir / "config.json", element="robots",
                           fix="train on shards built from this checkout's robots")  # fmt: skip


def bundle_step(run_dir: Path, metrics: dict | None, history: str | None = None) -> Path:
    """Copy ``config.json`` (training metrics + ``metrics`` as its evaluation) and the weights of
    ``run_dir`` into ``mer_models/bundled/mer-base/``, replacing what is there atomically."""
    from mer_models.hub.fromckpt import read_checkpoint_meta

    read_checkpoint_meta(run_dir)  # a mer checkpoint with config.json and model.safetensors, or a clear error
    meta = json.loads((run_dir / "config.json").read_text())
    require_every_robot(meta, run_dir, NAME)
    _require_synthetic(meta, run_dir)
    meta["metrics"] = {"train": meta.get("metrics", {}).get("train", {})}
    if metrics:
        meta["metrics"]["evaluation (mer evaluate)"] = metrics
    meta["data"] = {k: v for k, v in meta.get("data", {}).items() if k != "shards"} | {
        "shards": f"tools/train_base.py: mer shards build {' '.join(BUILD)}",
        "motion": "synthetic motion generated in code (mer_data.synthesis), no third-party motion data",
    }
    if history:
        meta["data"]["history"] = history
    return install_bundle(NAME, meta, run_dir / "model.safetensors")


def install_bundle(name: str, meta: dict, weights: Path) -> Path:
    """``meta`` as ``config.json`` and ``weights`` into ``mer_models/bundled/<name>/``, replacing what is
    there in one rename (``tools/train_base.py`` and ``tools/train_warm.py``)."""
    from mer_models.hub.registry import bundled_dir

    dest = bundled_dir() / name
    tmp = dest.parent / f".tmp-{name}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    (tmp / "config.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    shutil.copy2(weights, tmp / "model.safetensors")
    for f in tmp.iterdir():
        f.chmod(0o644)
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    print(f"bundle: {dest} ({sum(p.stat().st_size for p in dest.iterdir()) / 1e6:.2f} MB)")
    return dest


def reproduce_text(step: int) -> str:
    robots = " ".join(ROBOTS)
    return "\n".join([
        "# the whole pipeline (shards, teacher, train, evaluate, bundle, card); the same command resumes a killed run:",
        "python tools/train_base.py --minutes MINUTES --lafan1 LAFAN1_DIR",
        f"# training stops at a chunk boundary once MINUTES are spent (this checkpoint: step {step}); its steps:",
        f"mer shards build {' '.join(BUILD)} --out runs/{NAME}-shards",
        f"mer shards solve runs/{NAME}-shards",
        f"python tools/learning_curve.py --config base --shards runs/{NAME}-shards --out runs/{NAME} --bf16 --max-minutes MINUTES --chunk-steps 150 --lr-decay-steps 2400",
        *(f"mer evaluate --model runs/{NAME} --input LAFAN1_DIR --source {src} --targets {robots} --split {EVAL['split']} "
          f"--max-windows {EVAL['max_windows']} --refine {EVAL['refine']} --methods model refine optimize" for src in SOURCES),
        "# bundle and card a checkpoint (no training, no evaluation; reuses runs/" + EVALUATION_FILE + " if present):",
        f"python tools/train_base.py --work runs --bundle-only --run runs/{NAME}",
    ])  # fmt: skip


def sampler_text(sampler: dict[str, Any]) -> str:
    """'4 Euler steps = 4 network evaluations' for a checkpoint's ``run.sampler`` (no ``method``: Heun, as the loader reads it)."""
    method, steps = sampler.get("method", "heun"), int(sampler["steps"])
    evals = 2 * steps - 1 if method == "heun" else steps  # Heun: the last step is an Euler step; euler/ancestral: one per step
    text = f"{steps} {method.capitalize()} step{'s' if steps > 1 else ''} = {evals} network evaluation{'s' if evals > 1 else ''}"
    noise = float(sampler.get("init_noise", 1.0))
    return text + (", deterministic (no initial noise)" if noise == 0 else "" if noise == 1 else f", initial noise x{noise:g}")


def _range(metrics: dict[str, Any], method: str) -> tuple[float, float]:
    vals = [float(row["E_g-mpbpe [m]"]) for key, table in metrics.items() if isinstance(table, dict) and _METHOD[method] in key
            for row in table.values() if row.get("E_g-mpbpe [m]", "-") != "-"]  # fmt: skip
    return min(vals), max(vals)


def _verdict(metrics: dict[str, Any]) -> str:
    """One plain sentence on what the figures mean for a user (computed from them, not written by hand)."""
    m, r, o = _range(metrics, "model"), _range(metrics, "refine"), _range(metrics, "optimize")
    return (f"Measured: the model alone is {m[0]:.2f}-{m[1]:.2f} m from the scaled reference (E_g-mpbpe), the model + "
            f"{EVAL['refine']} optimiser iterations {r[0]:.3f}-{r[1]:.3f} m, the optimiser alone {o[0]:.3f}-{o[1]:.3f} m: "
            "for real use take `--refine 5` or `--method optimize`; the model alone is not yet accurate (issue 11).")


def architecture_text(run: dict[str, Any]) -> str:
    """'the `base` preset (H = 96, 2 layers per decoder, feed-forward 256, 1 Euler step = ...)' for a checkpoint's
    ``run`` section, saying where its network differs from the preset's."""
    from mer_data.base.errors import ConfigError
    from mer_models.config import preset

    model, name = run["model"], run["name"]
    try:
        ref = dataclasses.asdict(preset(name).model)
    except ConfigError:
        ref = model
    size = f"H = {model['hidden']}, {model['layers']} layers per decoder, feed-forward {model['ffn']}"
    labels = {"hidden": "H", "layers": "layers", "ffn": "feed-forward", "heads": "heads"}
    changed = [f"{labels[k]} {ref[k]}" for k in labels if model.get(k) != ref.get(k)]
    return (f"the `{name}` preset ({size}{' (the preset: ' + ', '.join(changed) + ')' if changed else ''}, "
            f"{sampler_text(run['sampler'])})")


def card_step(folder: Path, metrics: dict[str, Any] | None) -> Path:
    """Render ``cards/models/mer-base.md`` and its packaged copy from the bundled checkpoint ``folder``."""
    from mer_models.hub.fromckpt import DATASETS, card_from_checkpoint
    from mer_models.hub.registry import source_cards_dir, write_card

    meta = json.loads((folder / "config.json").read_text())
    step = int(meta["step"])
    evaluated = ("Its accuracy on LAFAN1 motion (G1 and H1 as sources; never seen in training) is in this card's metrics "
                 "(`evaluation (mer evaluate)`): the model alone, the model + "
                 f"{EVAL['refine']} optimiser iterations, and the optimiser on the same windows. {_verdict(metrics)}"
                 if metrics else "It has not been evaluated on LAFAN1 yet: its metrics hold the training losses only.")
    summary = ("mer's bundled model: `mer demo` and `mer retarget --method diffusion` without `--model` use it, "
               "offline (`mer retarget`'s default path is the optimiser, not a model). Trained only on synthetic motion "
               "generated in code (no third-party motion data), with every "
               f"built-in robot ({', '.join(ROBOTS)}) as source (reference) and as target; {architecture_text(meta['run'])}, "
               f"trained for {step} steps{' (' + meta['data']['history'] + ')' if meta.get('data', {}).get('history') else ''}; the teacher is "
               f"the optimiser (`mer shards solve`). {evaluated}")
    note = DATASETS["synthetic"].note
    card = card_from_checkpoint(folder, name=NAME, status="bundled", summary=summary, license_note=note, reproduce=reproduce_text(step))
    if card.license != DATASETS["synthetic"].license or card.training.get("dataset") != "synthetic":
        raise SystemExit(f"the checkpoint in {folder} does not describe synthetic training data: {card.training}")
    cards = source_cards_dir()
    if cards is None:
        raise SystemExit("run this from a source checkout (cards/models is missing)")
    path = write_card(card, cards)
    print(f"card: {path} (and its packaged copy)")
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default=str(REPO / "runs"), help="where shards and the run go (default runs/)")
    ap.add_argument("--minutes", type=float, default=80.0, help="minutes of training in all (default 80)")
    ap.add_argument("--clock", choices=["cpu", "wall"], default="cpu", help="what --minutes counts (default: CPU time)")
    ap.add_argument("--lr-decay-steps", type=int, default=2400,
                    help="cosine learning-rate decay over this many steps after the warm-up (default 2400; 0: constant)")
    ap.add_argument("--lafan1", help="LAFAN1-layout folder for the evaluations (e.g. ../shared/data/lafan1)")
    ap.add_argument("--skip-train", action="store_true", help="evaluate and bundle the run as it is")
    ap.add_argument("--bundle-only", action="store_true",
                    help=f"no shards, training or evaluation: bundle and card the run, with WORK/{EVALUATION_FILE} as its "
                    "evaluation when that file exists")  # fmt: skip
    ap.add_argument("--run", help=f"the checkpoint folder to evaluate and bundle (default WORK/{NAME}; training always writes WORK/{NAME})")
    ap.add_argument("--from-bundled", action="store_true",
                    help="a new run (no WORK/mer-base yet) starts from the bundled mer-base weights, with a fresh optimiser: "
                    "how training continues in a session without the earlier run folder (exact resume needs that folder)")
    ap.add_argument("--no-bundle", action="store_true")
    ap.add_argument("--history", help="how the run's starting weights were trained, when it started from other weights "
                    "(--init): recorded in the bundle and said in the card")
    args = ap.parse_args()
    if args.bundle_only and args.no_bundle:
        ap.error("--bundle-only and --no-bundle contradict each other")
    if args.run and not (args.skip_train or args.bundle_only):
        ap.error(f"--run names a checkpoint to bundle as it is: use it with --skip-train or --bundle-only (training writes WORK/{NAME})")
    work = Path(args.work)
    run_dir = Path(args.run) if args.run else work / NAME
    if not (args.skip_train or args.bundle_only):
        shards = shards_step(work)
        run_dir = train_step(work, shards, args.minutes, args.lafan1, args.clock,
                             str(REPO / "mer_models" / "bundled" / NAME) if args.from_bundled else None, args.lr_decay_steps)
    metrics = None
    evaluation = work / EVALUATION_FILE
    sampler = sampler_step(run_dir) if (run_dir / "config.json").is_file() else None  # (a missing run: bundle_step says so)
    if args.bundle_only:
        if evaluation.is_file():
            reports = json.loads(evaluation.read_text())
            evaluated = {str(Path(r["model"]).resolve()) for r in reports.values() if r.get("model")}
            if evaluated != {str(run_dir.resolve())}:
                raise SystemExit(f"{evaluation} evaluates {', '.join(sorted(evaluated)) or 'no model'}, not {run_dir}: "
                                 f"bundle that run (--run), evaluate this one (--skip-train --lafan1 DIR), or move the file away")
            if sampler is not None and any(r.get("sampler") != sampler for r in reports.values()):
                raise SystemExit(f"{evaluation} was measured with another sampler than the one that ships ({sampler}): "
                                 "evaluate again (--skip-train --lafan1 DIR)")
            metrics = card_metrics(reports, sampler)
            print(f"evaluation: {evaluation}")
        else:
            print(f"evaluation: none ({evaluation} does not exist); the card holds the training metrics only")
    elif args.lafan1:
        from mer_data.base.atomic import atomic_write

        work.mkdir(parents=True, exist_ok=True)  # before the minutes of evaluation, not after
        reports = evaluate_step(run_dir, args.lafan1)
        for r in reports.values():
            r["sampler"] = sampler
        atomic_write(evaluation, json.dumps(reports, indent=2) + "\n")
        metrics = card_metrics(reports, sampler)
    if not args.no_bundle:
        card_step(bundle_step(run_dir, metrics, args.history), metrics)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
