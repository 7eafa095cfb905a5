"""Maintainer script: train, evaluate and bundle mer's default model (``mer-tiny-synthetic``).

    PYTHONPATH=$PWD python tools/train_bundled.py            # all steps (about 10-25 min on 2 CPU cores)
    PYTHONPATH=$PWD python tools/train_bundled.py --skip-train   # re-evaluate and re-bundle runs/<name>

Steps:

1. **train** with the ordinary trainer, on synthetic motion generated in code only (never LAFAN1:
   the bundled weights must be free of its non-commercial terms)::

       python -m mer_models train TRAIN_ARGS  (below)

   An interrupted run is continued with ``--resume`` (exact: the data order, noise and optimiser
   state are restored, so the weights equal those of one uninterrupted run).
2. **evaluate** with ``mer evaluate``'s library function on held-out synthetic motion of G1:
   *in-domain* = clips of the training generator (:func:`mer_models.synthetic.synthetic_motion`)
   with seeds the training never draws from (>= 10**6), *out-of-domain* = walking clips of another
   generator (:func:`mer_data.synthetic.walking_motion`) the model never saw; the model and the
   optimisation baseline on the same windows.
3. **bundle**: ``config.json`` (with the evaluation added to its ``metrics``) and
   ``model.safetensors`` go to ``mer_models/bundled/<name>/``; the optimiser state stays behind.
4. **card**: ``cards/models/<name>.md`` (and its packaged copy) rendered by
   :func:`mer_models.zoo.fromckpt.card_from_checkpoint` from the bundled checkpoint's own metadata,
   with status ``bundled``: files and sha256, robots, data, metrics, licence (Apache-2.0: no
   third-party motion), and the commands above.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

NAME = "mer-tiny-synthetic"
TARGETS = ("g1", "h1", "h1_2", "atlas", "oli", "tron1", "talos", "valkyrie")
SOURCE = "g1"
STEPS = 1300
SEED = 0
SYNTHETIC = 4096
TRAIN_ARGS = [
    "--config", "tiny", "--synthetic", str(SYNTHETIC), "--source", SOURCE, "--targets", *TARGETS,
    "--steps", str(STEPS), "--seed", str(SEED), "--save-every", "40", "--log-every", "10",
]  # fmt: skip
EVAL_SEEDS = tuple(range(1_000_000, 1_000_004))  # in-domain clips: 4 x 120 frames = 8 windows
EVAL_WALKS = ((0.1, 0.0), (-0.2, 1.0))  # out-of-domain clips: (turn rate, gait phase), 8 s = 4 windows each
EVAL_OPTS = {"split": "split.txt", "max_windows": 8, "batch_size": 8, "seed": 0}
METRIC_COLS = (("g_mpbpe", "E_g-mpbpe [m]"), ("mpboe", "E_mpboe [rad]"), ("mpbve", "E_mpbve [m/s]"),
               ("jerk", "E_smooth [rad/s^3]"), ("limit_violation", "limit violation"))  # fmt: skip


def train_command(out: Path) -> list[str]:
    return [sys.executable, "-m", "mer_models", "train", *TRAIN_ARGS, "--out", str(out)]


def train_step(out: Path) -> None:
    cmd = train_command(out)
    if (out / "config.json").is_file():
        step = json.loads((out / "config.json").read_text())["step"]
        if step >= STEPS:
            print(f"train: {out} is at step {step}, done")
            return
        cmd.append("--resume")
    print("train:", " ".join(cmd[1:]), flush=True)
    t = time.time()
    subprocess.run(cmd, cwd=REPO, check=True, env={**__import__("os").environ, "PYTHONPATH": str(REPO)})
    print(f"train: {time.time() - t:.0f} s wall")


def write_eval_data(folder: Path) -> Path:
    """The held-out evaluation clips of G1 (LAFAN1 layout) and the split file naming the in-domain ones."""
    import torch

    from mer_data.motion_io import write_lafan1_csv
    from mer_data.registry import get_skeleton
    from mer_data.rotations import quat_to_matrix
    from mer_data.synthetic import walking_motion
    from mer_models.synthetic import synthetic_motion
    from mer_models.writers import TargetMotion, write_csv

    if folder.exists():
        shutil.rmtree(folder)
    skel = get_skeleton(SOURCE)
    names = []
    for seed in EVAL_SEEDS:
        m = synthetic_motion(skel, 120, seed=seed)
        rot = quat_to_matrix(torch.from_numpy(m["base_quat"])).numpy()
        write_csv(folder / SOURCE / f"random_s{seed}.csv", TargetMotion(skel, 30.0, m["q"], m["base_pos"], rot))
        names.append(f"random_s{seed}")
    for i, (turn, phase) in enumerate(EVAL_WALKS, start=1):
        write_lafan1_csv(folder / SOURCE / f"walk{i}.csv", walking_motion(SOURCE, 8.0, turn_rate=turn, phase=phase))
    split = folder / EVAL_OPTS["split"]
    split.write_text("# in-domain: the training generator, held-out seeds; every other clip is out-of-domain\n"
                     + "".join(f"{SOURCE}/{n}\n" for n in names))
    return folder


def evaluate_step(model_dir: Path, data: Path) -> dict:
    from mer_models.checkpoint import load_checkpoint
    from mer_models.evaluate import EvalOptions, evaluate, format_table

    opts = EvalOptions(split=str(data / EVAL_OPTS["split"]), max_windows=EVAL_OPTS["max_windows"],
                       batch_size=EVAL_OPTS["batch_size"], seed=EVAL_OPTS["seed"], methods=("model", "optimize"))  # fmt: skip
    t = time.time()
    report = evaluate(data, SOURCE, TARGETS, checkpoint=load_checkpoint(model_dir), opts=opts,
                      progress=lambda s: print("evaluate:", s, flush=True))  # fmt: skip
    print(format_table(report))
    print(f"evaluate: {time.time() - t:.0f} s wall")
    return report


def card_metrics(report: dict) -> dict:
    """The report as the card's tables: '<method>, <domain>' -> robot -> column -> 'mean ± std'."""
    out: dict = {
        "data": "held-out synthetic G1 motion generated in code (tools/train_bundled.py)",
        "in-domain": "the training generator with seeds never drawn in training",
        "out-of-domain": "walking clips of another generator (mer_data.synthetic), never trained on",
        "windows per robot and domain": max(r["windows"] for r in report["rows"]),
    }
    for r in report["rows"]:
        table = out.setdefault(f"{'model' if r['method'] == 'model' else 'optimisation baseline'}, {r['domain']}", {})
        row = {}
        for key, col in METRIC_COLS:
            v = r["metrics"].get(key)
            row[col] = "-" if not v or v["mean"] != v["mean"] else (
                f"{v['mean']:.3f}" if key == "limit_violation" else f"{v['mean']:.3g} ± {v['std']:.2g}")
        table[r["robot"]] = row
    return out


def bundle_step(run_dir: Path, report: dict) -> Path:
    from mer_models.zoo.registry import bundled_dir

    dest = bundled_dir() / NAME
    tmp = dest.parent / f".tmp-{NAME}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    meta = json.loads((run_dir / "config.json").read_text())
    meta["metrics"] = {"train": meta.get("metrics", {}).get("train", {}), "evaluation (mer evaluate)": card_metrics(report)}
    (tmp / "config.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    shutil.copy2(run_dir / "model.safetensors", tmp / "model.safetensors")
    for f in tmp.iterdir():
        f.chmod(0o644)  # package data: readable by every user of an installation
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    print(f"bundle: {dest} ({sum(p.stat().st_size for p in dest.iterdir()) / 1e6:.2f} MB)")
    return dest


def reproduce_text() -> str:
    return "\n".join([
        "# the whole pipeline (train, evaluate, bundle, card):",
        "python tools/train_bundled.py",
        "# its training step:",
        "mer train " + " ".join(TRAIN_ARGS) + f" --out runs/{NAME}",
        "# its evaluation (held-out synthetic G1 clips written by the script into runs/" + NAME + "-eval):",
        f"mer evaluate --model runs/{NAME} --input runs/{NAME}-eval --source {SOURCE} --targets {' '.join(TARGETS)} "
        f"--split runs/{NAME}-eval/{EVAL_OPTS['split']} --max-windows {EVAL_OPTS['max_windows']} --batch-size {EVAL_OPTS['batch_size']}",
    ])


def card_step(folder: Path) -> Path:
    from mer_models.zoo.fromckpt import DATASETS, card_from_checkpoint
    from mer_models.zoo.registry import source_cards_dir, write_card

    step = json.loads((folder / "config.json").read_text())["step"]
    summary = (f"A tiny model (the `tiny` preset) trained for {step} steps on 2 CPU cores, on synthetic motion generated in "
               "code: it ships inside the package so that `mer retarget`, `mer demo` and the tests run offline right "
               "after install. It is for demos and tests, not for real use: its motion is not human-like, and it was "
               "never trained on real motion data (use `mer-base` or a fine-tune of it for that).")
    note = DATASETS["synthetic"].note + " Not for real use: a demonstration model (see the summary and the metrics)."
    card = card_from_checkpoint(folder, name=NAME, status="bundled", summary=summary, license_note=note, reproduce=reproduce_text())
    cards = source_cards_dir()
    if cards is None:
        raise SystemExit("run this from a source checkout (cards/models is missing)")
    path = write_card(card, cards)
    print(f"card: {path} (and its packaged copy)")
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default=str(REPO / "runs"), help="where the run and the evaluation data go (default runs/)")
    ap.add_argument("--skip-train", action="store_true", help="use the run in WORK/<name> as it is")
    args = ap.parse_args()
    work = Path(args.work)
    run_dir = work / NAME
    if not args.skip_train:
        train_step(run_dir)
    data = write_eval_data(work / f"{NAME}-eval")
    report = evaluate_step(run_dir, data)
    (work / f"{NAME}-metrics.json").write_text(json.dumps(report, indent=2) + "\n")
    folder = bundle_step(run_dir, report)
    card_step(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
