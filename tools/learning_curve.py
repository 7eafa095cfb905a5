"""Learning curve: train in chunks and evaluate the held-out error after each, against CPU time.

    PYTHONPATH=$PWD python tools/learning_curve.py --config base --shards SHARDS --out runs/base \\
        --eval-input ../shared/data/lafan1 --chunk-steps 200 --max-minutes 60 [--bf16]

Training is the ordinary trainer (:func:`mer_models.training.train.train`), resumed exactly after every
chunk, so the weights equal those of one uninterrupted run; killed, the same command continues.
After every chunk the checkpoint is evaluated with ``mer evaluate``'s library function, the model
alone, on ``--eval-windows`` windows of the ``--eval-source`` robot's clips (the shipped weights
never see LAFAN1, so every LAFAN1 clip is held out), and one JSON line is appended to
``OUT.learning_curve.jsonl`` (beside the checkpoint folder, which every save replaces): step, wall and CPU minutes of training so far (``process_time``:
all threads of this process), the training loss, and g-mpbpe per target.

``--configs A B C --minutes-each M`` compares configurations for the same CPU budget each (the
issue's "which configuration learns fastest per CPU-minute"), one folder per configuration.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))  # overfit_probe: ffn_width, widen_ffn

log = logging.getLogger("learning_curve")


def _curve(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()] if path.is_file() else []


def held_out(ckpt_dir: Path, eval_input: str, source: str, targets: list[str], windows: int, steps: int | None,
             trained: bool = False) -> dict:
    """Mean g-mpbpe [m] (and limit violations) per target of the model alone on held-out windows.

    ``trained``: for a checkpoint with a moving average (``TrainConfig.ema``), score the trained
    weights instead of the average its weights file holds."""
    from mer_models.retarget.evaluate import EvalOptions, evaluate
    from mer_models.zoo.checkpoint import load_checkpoint

    opts = EvalOptions(split="all", max_windows=windows, methods=("model",), steps=steps, batch_size=16)
    ckpt = load_checkpoint(ckpt_dir)
    if trained:
        from safetensors.torch import load_file

        from mer_models.hub.checkpoint_files import OPTIMIZER, TRAINED_PREFIX

        own = {k[len(TRAINED_PREFIX):]: v for k, v in load_file(str(ckpt_dir / OPTIMIZER)).items() if k.startswith(TRAINED_PREFIX)}
        ckpt.model.load_state_dict(own, strict=True)
    rep = evaluate(eval_input, source, targets, checkpoint=ckpt, opts=opts)
    out = {}
    for r in rep["rows"]:
        m = r["metrics"]
        out[r["robot"]] = {"g_mpbpe": m["g_mpbpe"]["mean"], "limit_violation": m["limit_violation"]["mean"],
                           "jerk_frame": m["jerk_frame"]["mean"]}  # fmt: skip
    return out


def widened_init(init: Path, ffn: int, dest: Path) -> Path:
    """``init``'s weights with every feed-forward widened to ``ffn`` (the same function;
    ``overfit_probe.widen_ffn``), written to ``dest``; ``init`` itself when already that wide."""
    from overfit_probe import ffn_width, widen_ffn
    from safetensors.torch import load_file, save

    from mer_data.base.atomic import atomic_write

    if ffn_width(init) == ffn:
        return init
    dest.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(dest, save(widen_ffn(load_file(str(init)), ffn)))
    log.info("%s widened to a feed-forward of %d: %s", init, ffn, dest)
    return dest


def run_curve(cfg_name: str, args, out: Path, minutes: float) -> list[dict]:
    import torch

    from mer_data.shards import ShardDataset
    from mer_models.config import preset
    from mer_models.training.train import train

    run = preset(cfg_name)
    if args.batch_size:
        run = run.replace(train=dataclasses.replace(run.train, batch_size=args.batch_size))
    if args.lr is not None:  # 0 or a negative rate reaches TrainConfig and is refused there, not dropped
        run = run.replace(train=dataclasses.replace(run.train, lr=args.lr))
    if args.lr_decay_steps:
        run = run.replace(train=dataclasses.replace(run.train, lr_decay_steps=args.lr_decay_steps))
    if args.lr_min_ratio is not None:
        run = run.replace(train=dataclasses.replace(run.train, lr_min_ratio=args.lr_min_ratio))
    if args.warmup is not None:
        run = run.replace(train=dataclasses.replace(run.train, warmup=args.warmup))
    if args.start_frac is not None:
        run = run.replace(train=dataclasses.replace(run.train, start_frac=args.start_frac))
    if args.feedback_frac is not None:
        run = run.replace(train=dataclasses.replace(run.train, feedback_frac=args.feedback_frac))
    if args.sampler:
        run = run.replace(sampler=dataclasses.replace(run.sampler, method=args.sampler[0], steps=int(args.sampler[1])))
    if args.feedback_sigma is not None:
        run = run.replace(sampler=dataclasses.replace(run.sampler, feedback_sigma=args.feedback_sigma))
    if args.norm_first:
        run = run.replace(model=dataclasses.replace(run.model, norm_first=True))
    from overfit_probe import ffn_width

    ffn = args.ffn if args.ffn is not None else (ffn_width(Path(args.init) / "model.safetensors") if args.init else None)
    if ffn is not None and ffn != run.model.ffn:  # --ffn, or --init's own width (the bundled mer-base: 768)
        run = run.replace(model=dataclasses.replace(run.model, ffn=ffn))
    if args.init:  # the network must be the one the weights were trained as: the fixes' flags come from --init
        from mer_models.hub.checkpoint_files import read_run

        _, init_run = read_run(Path(args.init))
        flags = {k: getattr(init_run.model, k) for k in ("split_encoding", "goal_frame_rotation")}
        run = run.replace(model=dataclasses.replace(run.model, **flags))
    if args.ref_group:
        run = run.replace(train=dataclasses.replace(run.train, ref_group=args.ref_group))
    if args.ema is not None:
        run = run.replace(train=dataclasses.replace(run.train, ema=args.ema))
    run = run.replace(train=dataclasses.replace(run.train, save_every=args.chunk_steps, log_every=min(10, args.chunk_steps)))
    ds = ShardDataset(args.shards, teacher=True)
    curve_path = out.parent / f"{out.name}.learning_curve.jsonl"  # beside the folder: a checkpoint save replaces the folder
    curve = _curve(curve_path)
    cpu = curve[-1]["cpu_min"] if curve else 0.0
    wall = curve[-1]["wall_min"] if curve else 0.0
    step = curve[-1]["step"] if curve else 0
    info = {"shards": [str(p) for p in ds.paths], "samples": len(ds), "teacher": True}
    init = Path(args.init) / "model.safetensors" if args.init else None
    if init is not None and args.ffn is not None and not (out / "config.json").is_file():
        init = widened_init(init, args.ffn, out.parent / f"{out.name}.widened.safetensors")
    while (wall if args.clock == "wall" else cpu) < minutes or step == 0:
        c0, w0 = time.process_time(), time.time()
        resume = (out / "config.json").is_file()
        res = train(run, ds, out, steps=step + args.chunk_steps, resume=resume, bf16=args.bf16, data_info=info, device=args.device,
                    init=None if resume else init)  # fmt: skip
        cpu += (time.process_time() - c0) / 60
        wall += (time.time() - w0) / 60
        step = res.step
        rec = {"config": cfg_name, "step": step, "cpu_min": round(cpu, 2), "wall_min": round(wall, 2),
               "threads": torch.get_num_threads(), "loss": res.last.get("loss"), "edm": res.last.get("edm"),
               "f_kp": res.last.get("f_kp")}  # fmt: skip
        if args.eval_input:
            rec["held_out"] = held_out(out, args.eval_input, args.eval_source, args.eval_targets, args.eval_windows, args.eval_steps)
            rec["g_mpbpe_mean"] = sum(v["g_mpbpe"] for v in rec["held_out"].values()) / len(rec["held_out"])
            if run.train.ema > 0:  # the curve scores the average; the trained weights beside it
                rec["held_out_trained"] = held_out(out, args.eval_input, args.eval_source, args.eval_targets, args.eval_windows,
                                                   args.eval_steps, trained=True)  # fmt: skip
                rec["g_mpbpe_mean_trained"] = sum(v["g_mpbpe"] for v in rec["held_out_trained"].values()) / len(rec["held_out_trained"])
        with open(curve_path, "a") as fh:
            fh.write(json.dumps(rec) + "\n")
        print(json.dumps(rec), flush=True)
    return _curve(curve_path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="base", help="preset to train (default base)")
    ap.add_argument("--configs", nargs="+", help="compare these presets, --minutes-each CPU minutes each (OUT/<preset>)")
    ap.add_argument("--shards", nargs="+", required=True, help="shards with teacher files (mer shards solve)")
    ap.add_argument("--out", required=True, help="checkpoint folder (with --configs: parent folder)")
    ap.add_argument("--chunk-steps", type=int, default=200, help="steps between evaluations (default 200)")
    ap.add_argument("--max-minutes", type=float, default=60.0, help="CPU minutes of training in all (default 60)")
    ap.add_argument("--minutes-each", type=float, default=10.0, help="with --configs: CPU minutes per configuration")
    ap.add_argument("--batch-size", type=int, help="override the preset's batch size")
    ap.add_argument("--lr", type=float, help="override the preset's peak learning rate (e.g. a lower one to continue from --init)")
    ap.add_argument("--lr-decay-steps", type=int, help="cosine learning-rate decay over this many steps after the warm-up")
    ap.add_argument("--lr-min-ratio", type=float, help="where the cosine decay ends, as a share of --lr (TrainConfig.lr_min_ratio)")
    ap.add_argument("--warmup", type=int, help="linear warm-up steps (TrainConfig.warmup)")
    ap.add_argument("--start-frac", type=float, help="share of every batch trained at the sampler's starting point (TrainConfig.start_frac)")
    ap.add_argument("--feedback-frac", type=float, help="share of every batch trained on the network's own estimates (TrainConfig.feedback_frac)")
    ap.add_argument("--feedback-sigma", type=float, help="noise level of the feedback evaluations (SamplerConfig.feedback_sigma)")
    ap.add_argument("--sampler", nargs=2, metavar=("METHOD", "STEPS"), help="the checkpoint's sampler (what the curve evaluates), "
                    "e.g. feedback 2; default: the preset's")
    ap.add_argument("--init", metavar="DIR", help="start from this checkpoint's weights (fresh optimiser), e.g. the bundled "
                    "mer-base, to continue training in a session that lacks the run folder")
    ap.add_argument("--ffn", type=int, help="feed-forward width instead of the preset's; with --init, the checkpoint "
                    "widened to it function-preservingly (tools/overfit_probe.py widen_ffn); default with --init: its width")
    ap.add_argument("--norm-first", action="store_true", help="pre-norm layers (ModelConfig.norm_first) instead of the preset's post-norm")
    ap.add_argument("--ref-group", type=int, help="samples per reference window in a batch (TrainConfig.ref_group)")
    ap.add_argument("--ema", type=float, metavar="DECAY", help="moving average of the weights (TrainConfig.ema, e.g. 0.999): "
                    "the checkpoint and the curve hold the average, the curve also scores the trained weights")
    ap.add_argument("--bf16", action="store_true", help="bfloat16 autocast (GPUs; CPUs with AMX or AVX512-BF16 only)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--clock", choices=["cpu", "wall"], default="cpu",
                    help="what --max-minutes/--minutes-each count: CPU time of this process (default) or wall time (accelerators)")
    ap.add_argument("--eval-input", help="LAFAN1-layout folder (e.g. ../shared/data/lafan1); omitted: no evaluation")
    ap.add_argument("--eval-source", default="g1")
    ap.add_argument("--eval-targets", nargs="+", default=["g1", "h1", "atlas"])
    ap.add_argument("--eval-windows", type=int, default=16)
    ap.add_argument("--eval-steps", type=int, default=None, help="sampler steps (default: the model's)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.configs:
        for name in args.configs:
            run_curve(name, args, Path(args.out) / name, args.minutes_each)
    else:
        run_curve(args.config, args, Path(args.out), args.max_minutes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
