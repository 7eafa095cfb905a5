"""Maintainer script: the warm start fine-tuned for a robot no built-in model saw, its gain, and its
catalogue entry ``mer-warm-<robot>`` (synthetic motion only, Apache-2.0).

    PYTHONPATH=$PWD python tools/finetune_warm.py --home /tmp/ft/home --work /tmp/ft/romeo            # 1-3
    PYTHONPATH=$PWD python tools/finetune_warm.py --home /tmp/ft/home --work /tmp/ft/romeo --publish  # 1-4
    PYTHONPATH=$PWD python tools/finetune_warm.py --home /tmp/ft/home --publish-only                  # 4 again

Steps (each resumable: the same command continues or skips what is done):

1. **register** ``--robot`` (default ``romeo``, ``../shared/robots-wild/romeo/romeo.urdf``) into the
   MER_HOME ``--home`` (``mer robots register``), unless it is there already;
2. **fine-tune** ``--base`` (a zoo name or a checkpoint folder; default ``mer-warm``) for it:
   ``mer finetune --synthetic N`` (motion generated in code; every target of the base replayed beside
   the new robot, whose samples the trainer solves on the fly) into ``WORK/finetune``;
3. **evaluate** on LAFAN1 G1 windows (``--split all``, ``--max-windows``) retargeted to the robot and to
   the ``--keep`` targets of the base (is anything forgotten?): the base (zero-shot on the new robot:
   ``mer evaluate`` refuses a target the model never saw, so this runs the same library function with
   the robot allowed, as ``mer retarget --allow-unseen`` does), the fine-tuned model (exactly ``mer
   evaluate --model WORK/finetune --methods model refine optimize --refine 2``), each alone and + 2 LM
   iterations, and the optimiser as the reference; ``WORK/evaluation.json``; prints the gain;
4. **publish**: ``config.json`` (the evaluation in its ``metrics``, the commands in ``command``, no local
   paths) and ``model.safetensors`` into ``cards/weights/mer-warm-<robot>/`` (committed: small,
   synthetic-only), published with ``mer zoo publish`` to a loopback Hub (``tests/hub_server.py``; the
   commit it pins is the one every fresh loopback Hub gives the same upload, which
   ``tests/models/hub/test_warm_zoo.py`` replays before loading the model by name), or to the Hub
   at ``--hub-url`` (``HF_TOKEN`` from the environment); the card goes into ``cards/models`` and its
   packaged copy. ``--publish-only`` re-publishes the committed weights (e.g. after the loopback Hub
   changed) without fine-tuning again.

Nothing of LAFAN1 is written into the repository: the evaluation reads it and keeps only metrics.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared"

REFINE = 2  # LM iterations after the network: the warm start's default (WarmConfig.refine)
_COLS = (("g_mpbpe", "E_g-mpbpe [m]"), ("mpboe", "E_mpboe [rad]"), ("jerk_frame", "E_smooth [rad/frame^3]"),
         ("limit_violation", "limit violation"))  # fmt: skip


def weights_dir(name: str) -> Path:
    """Where the catalogue's small synthetic-only weights of ``name`` live in the repository."""
    return REPO / "cards" / "weights" / name


def mer(args: list[str], home: Path, threads: int, env: dict[str, str] | None = None) -> None:
    """``python -m mer_models ARGS`` with MER_HOME ``home`` and ``threads`` CPU threads; stops on failure."""
    e = {**os.environ, "MER_HOME": str(home), "OMP_NUM_THREADS": str(threads), "PYTHONPATH": str(REPO), **(env or {})}
    print("+ mer " + shlex.join(args), flush=True)
    r = subprocess.run([sys.executable, "-m", "mer_models", *args], env=e, cwd=REPO)
    if r.returncode:
        raise SystemExit(f"mer {args[0]} failed (exit {r.returncode})")


def register(robot: str, urdf: Path, home: Path) -> None:
    if (home / "robots" / robot / "robot.yaml").is_file():
        print(f"register: {robot} is registered in {home}")
        return
    if not urdf.is_file():
        raise SystemExit(f"no URDF at {urdf}: pass --urdf")
    mer(["robots", "register", robot, "--urdf", str(urdf)], home, 1)


def finetune(args: argparse.Namespace, out: Path) -> None:
    from mer_models.hub.checkpoint_files import read_meta
    from mer_models.hub.integrity import sha256_file
    from mer_models.zoo import download

    done = 0
    if (out / "config.json").is_file():
        meta = read_meta(out)
        if meta["data"].get("base_sha256") != sha256_file(download(args.base) / "model.safetensors"):
            raise SystemExit(f"{out} was fine-tuned from another base than {args.base}: choose another --work")
        done = int(meta["step"])
    if done >= args.steps:
        print(f"fine-tune: {out} is at step {done}")
        return
    data = ["--shards", *map(str, args.shards)] if args.shards else ["--synthetic", str(args.synthetic)]
    extra = [x for k, v in (("--batch-size", args.batch_size), ("--lr", args.lr)) if v is not None for x in (k, str(v))]
    mer(["finetune", "--base", args.base, "--robot", args.robot, *data, "--steps", str(args.steps), "--out", str(out),
         "--log-every", "10", *extra, *(["--resume"] if done else [])], args.home, args.threads)  # fmt: skip


def _row(r: dict) -> dict[str, Any]:
    out: dict[str, Any] = {"frames/s": round(r.get("frames_per_s", 0))}
    for key, col in _COLS:
        v = r["metrics"].get(key)
        out[col] = (
            "-" if not v or v["mean"] != v["mean"] else (f"{v['mean']:.3f}" if key == "limit_violation" else f"{v['mean']:.3g}")
        )
    return out


def evaluate(args: argparse.Namespace, tuned: Path) -> dict:
    """Base (zero-shot on the new robot) and fine-tuned, alone and + REFINE iterations, and the optimiser."""
    import torch

    from mer_data.robots.registry import get_skeleton
    from mer_models.hub.integrity import sha256_file
    from mer_models.retarget.evaluate import EvalOptions
    from mer_models.retarget.evaluate import evaluate as run_evaluation
    from mer_models.solver.physics import PhysicsConfig
    from mer_models.zoo import download, load

    os.environ["MER_HOME"] = str(args.home)
    torch.set_num_threads(args.threads)
    targets = [args.robot, *[t for t in args.keep if t != args.robot]]
    key = {"tuned": sha256_file(tuned / "model.safetensors"), "base": sha256_file(download(args.base) / "model.safetensors"),
           "targets": targets, "windows": args.max_windows, "lafan1": str(args.lafan1.resolve()), "refine": REFINE}  # fmt: skip
    cache = args.work / "evaluation.json"
    saved = json.loads(cache.read_text()) if cache.is_file() else {}
    if saved.get("key") == key:
        print(f"evaluation: {cache} (the same models and windows)")
        reports = saved["reports"]
    else:
        base = load(args.base)
        base.robots.setdefault("targets", {})[args.robot] = get_skeleton(args.robot).fingerprint  # zero-shot, in memory only
        opts = dict(split="all", max_windows=args.max_windows, refine=REFINE, physics=PhysicsConfig())
        reports = {
            "base": run_evaluation(args.lafan1, "g1", targets, checkpoint=base, opts=EvalOptions(methods=("model", "refine"), **opts)),
            "fine-tuned": run_evaluation(args.lafan1, "g1", targets, checkpoint=load(str(tuned)),
                                         opts=EvalOptions(methods=("model", "refine", "optimize"), **opts)),
        }  # fmt: skip
        cache.write_text(json.dumps({"key": key, "reports": reports}, indent=2) + "\n")
    table: dict[str, dict[str, dict]] = {}
    for who, rep in reports.items():
        for r in rep["rows"]:
            method = {"model": f"{who} alone", "refine": f"{who} + {REFINE} LM iterations", "optimize": "optimiser"}[r["method"]]
            table.setdefault(r["robot"], {})[method] = r
    return {"targets": targets, "windows": args.max_windows, "rows": table, "reports": reports}


def gain_lines(ev: dict, robot: str) -> list[str]:
    rows = ev["rows"]
    g = {t: {m: r["metrics"]["g_mpbpe"]["mean"] for m, r in rows[t].items()} for t in rows}
    opt = g[robot]["optimiser"]
    out = [f"LAFAN1 G1 windows ({ev['windows']} per robot, --split all) -> {robot}: E_g-mpbpe [m] (x the optimiser's)"]
    for m, v in g[robot].items():
        out.append(f"  {m:32s} {v:.4f}  ({v / opt:.2f}x)")
    for k in ("alone", f"+ {REFINE} LM iterations"):
        b, f = g[robot][f"base {k}"], g[robot][f"fine-tuned {k}"]
        out.append(f"gain of the fine-tune on {robot}, model {k}: {b / f:.2f}x lower E_g-mpbpe ({b:.4f} -> {f:.4f} m)")
    for t in ev["targets"][1:]:
        b, f = g[t][f"base + {REFINE} LM iterations"], g[t][f"fine-tuned + {REFINE} LM iterations"]
        out.append(
            f"kept target {t}: base + {REFINE} {b:.4f} m, fine-tuned + {REFINE} {f:.4f} m ({f / b:.2f}x), optimiser {g[t]['optimiser']:.4f} m"
        )
    return out


def card_metrics(ev: dict, robot: str) -> dict:
    """The card's ``evaluation (mer evaluate)``: per method, robot (the new one, then the kept ones) -> columns."""
    out: dict[str, Any] = {"data": f"LAFAN1 robot CSVs (G1 source, every clip, {ev['windows']} windows per robot, --split all): never seen in "
                                   f"training (synthetic motion only); the base on {robot} is zero-shot"}  # fmt: skip
    for t in ev["targets"]:
        for method, r in ev["rows"][t].items():
            out.setdefault(f"source g1, {method}", {})[t] = _row(r)
    return out


def _without_paths(data: dict, base: str) -> dict:
    """The data record with this machine's paths replaced by what they were (a published card names no local file)."""
    out = dict(data)
    if "base_checkpoint" in out:
        out["base_checkpoint"] = f"a local checkpoint folder ({Path(str(out['base_checkpoint'])).name}), not a zoo model"
    inner = dict(out.get("base_data") or {})
    if isinstance(inner.get("shards"), list):
        inner["shards"] = f"{len(inner['shards'])} synthetic shard files" + (f" ({inner['build']})" if inner.get("build") else "")
    out["base_data"] = inner
    out["base_spec"] = base
    return out


def base_label(args: argparse.Namespace) -> str:
    """How the card and command name the base: its zoo name, or ``--base-label`` for a local folder."""
    return args.base_label or (args.base if not Path(args.base).is_dir() else "a local warm-start checkpoint")


def stage_weights(tuned: Path, dest: Path, metrics: dict, command: str, base: str) -> Path:  # base: base_label()
    """config.json (evaluation, command, no local paths) + model.safetensors of ``tuned`` into ``dest``, atomically."""
    meta = json.loads((tuned / "config.json").read_text())
    meta["metrics"] = {"train": meta.get("metrics", {}).get("train", {}), "evaluation (mer evaluate)": metrics}
    meta["data"] = _without_paths(meta.get("data") or {}, base)
    meta["command"] = command
    if "lafan" in json.dumps(meta["data"]).lower():
        raise SystemExit(f"{tuned} records LAFAN1 among its training data: its weights must not be committed")
    tmp = dest.parent / f".tmp-{dest.name}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    (tmp / "config.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    shutil.copyfile(tuned / "model.safetensors", tmp / "model.safetensors")
    shutil.rmtree(dest, ignore_errors=True)
    tmp.rename(dest)
    size = sum(p.stat().st_size for p in dest.iterdir())
    print(f"weights: {dest} ({size / 1e3:.0f} kB)")
    return dest


def summary_text(args: argparse.Namespace, meta: dict, hub_url: str | None) -> str:
    data = meta["data"]
    ev = meta["metrics"].get("evaluation (mer evaluate)", {})
    g = {
        k.split(", ", 1)[1]: float(v[args.robot]["E_g-mpbpe [m]"])
        for k, v in ev.items()
        if k.startswith("source g1, ") and args.robot in v
    }
    base = f"`{data['base_model']}`" if data.get("base_model") else data.get("base_spec") or "the warm start"
    size = sum(p.stat().st_size for p in weights_dir(args.name).iterdir())
    where = (f"published at {hub_url}" if hub_url else
             "The pinned commit is the one the loopback Hub of mer's tests (tests/hub_server.py) gives this upload, "
             "which every fresh loopback Hub reproduces: the repository is not on huggingface.co until a maintainer runs "
             "`tools/finetune_warm.py --publish-only --hub-url URL`")  # fmt: skip
    text = (f"{base[0].upper()}{base[1:]} (the warm start) fine-tuned for {args.robot}, a robot no built-in model saw, with `mer finetune` on "
            f"synthetic motion only ({data.get('synthetic') or data.get('samples')} windows, {meta['step']} steps; every target "
            f"of the base replayed beside it). ")  # fmt: skip
    if g:
        r, b, o = g.get(f"fine-tuned + {REFINE} LM iterations"), g.get(f"base + {REFINE} LM iterations"), g.get("optimiser")
        text += (f"On LAFAN1 G1 windows retargeted to {args.robot} (never trained on) its output + {REFINE} LM iterations is "
                 f"{r:.3g} m E_g-mpbpe, the base's (zero-shot) {b:.3g} m ({b / r:.2f}x the fine-tune's), the optimiser "
                 f"{o:.3g} m; alone {g['fine-tuned alone']:.3g} m vs {g['base alone']:.3g} m. ")  # fmt: skip
    return text + (f"Weights ({size / 1e3:.0f} kB) also in the source repository at cards/weights/{args.name}/ "
                   f"(`--model cards/weights/{args.name}`). {where}.")  # fmt: skip


# publish() as `mer zoo publish` runs it for a catalogue name, into a copy of the catalogue: in a fresh process, so
# huggingface_hub reads HF_ENDPOINT when it is imported
_PUBLISH = """
import json, sys
from mer_models.hub.publish import publish
from mer_models.hub.registry import Registry
a = json.loads(sys.argv[1])
r = publish(a["folder"], name=a["name"], repo_id=a["repo_id"], base=a["base"], summary=a["summary"],
            cards_dir=a["catalogue"], registry=Registry(builtin=a["catalogue"]))
print(json.dumps({"commit": r.commit, "card": str(r.card_path)}))
"""


def publish_copy(folder: Path, name: str, repo_id: str, summary: str, base: str | None, env: dict[str, str], tmp: Path) -> Path:
    """Publish ``folder`` as the catalogue model ``name`` into a copy of the catalogue without its old card (so no
    earlier revision is carried into ``history``); returns the card written there."""
    from mer_models.hub.registry import source_cards_dir

    cards = source_cards_dir()
    if cards is None:
        raise SystemExit("run this from a source checkout (cards/models is missing)")
    catalogue = tmp / "catalogue"
    shutil.copytree(cards, catalogue)
    (catalogue / f"{name}.md").unlink(missing_ok=True)
    a = {"folder": str(folder), "name": name, "repo_id": repo_id, "base": base, "summary": summary, "catalogue": str(catalogue)}
    e = {**os.environ, "PYTHONPATH": str(REPO), "HF_HOME": str(tmp / "hf"), "HF_HUB_CACHE": str(tmp / "hub"), **env}
    print(f"+ publish {folder} as {name} ({repo_id}) to {env.get('HF_ENDPOINT', 'the Hub')}", flush=True)
    r = subprocess.run([sys.executable, "-c", _PUBLISH, json.dumps(a)], env=e, cwd=REPO, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"publishing failed:\n{r.stderr[-3000:]}")
    return catalogue / f"{name}.md"


def publish(args: argparse.Namespace) -> Path:
    """Publish the committed weights; their card into the catalogue (and its packaged copy)."""
    from mer_models.hub.card import read_card
    from mer_models.hub.registry import source_cards_dir, write_card

    folder = weights_dir(args.name)
    if not (folder / "model.safetensors").is_file():
        raise SystemExit(f"no weights in {folder}: run the fine-tune and evaluation first (without --publish-only)")
    meta = json.loads((folder / "config.json").read_text())
    summary = summary_text(args, meta, args.hub_url)
    env = {"MER_HOME": str(args.home)}
    with tempfile.TemporaryDirectory(prefix="mer-warm-publish-") as tmp:
        if args.hub_url:
            card = read_card(publish_copy(folder, args.name, args.repo_id, summary, meta["data"].get("base_model"),
                                          {**env, "HF_ENDPOINT": args.hub_url}, Path(tmp)))  # fmt: skip
        else:
            sys.path.insert(1, str(REPO / "tests"))
            from hub_server import HubServer
            from zoo_helpers import TOKEN

            with HubServer(token=TOKEN) as hub:
                env |= {"HF_ENDPOINT": hub.url, "HF_HUB_DISABLE_XET": "1", "HF_TOKEN": TOKEN}
                card = read_card(
                    publish_copy(folder, args.name, args.repo_id, summary, meta["data"].get("base_model"), env, Path(tmp))
                )
    path = write_card(card, source_cards_dir())
    print(f"card: {path} (and its packaged copy), {args.repo_id}@{card.revision}")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--home", type=Path, required=True, help="the MER_HOME the robot is registered in")
    ap.add_argument("--work", type=Path, help="folder of the fine-tune and its evaluation (not needed with --publish-only)")
    ap.add_argument(
        "--base", default="mer-warm", help="the warm-start model: a zoo name or a checkpoint folder (default mer-warm)"
    )
    ap.add_argument("--base-label", help="how the card names a --base folder (default: a local warm-start checkpoint)")
    ap.add_argument("--robot", default="romeo", help="the robot to fine-tune for (default romeo)")
    ap.add_argument("--urdf", type=Path, help="its URDF (default ../shared/robots-wild/ROBOT/ROBOT.urdf)")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--synthetic", type=int, default=4096, help="synthetic windows of G1 motion (default 4096)")
    src.add_argument("--shards", type=Path, nargs="+", help="synthetic shards instead (their teacher files are used)")
    ap.add_argument("--steps", type=int, default=300, help="fine-tune steps (default 300)")
    ap.add_argument("--batch-size", type=int, help="override the base's batch size")
    ap.add_argument("--lr", type=float, help="override the base's learning rate")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads (default 1)")
    ap.add_argument("--lafan1", type=Path, default=SHARED / "data" / "lafan1", help="LAFAN1 robot CSVs (read only)")
    ap.add_argument("--max-windows", type=int, default=32, help="LAFAN1 windows per robot (default 32)")
    ap.add_argument("--keep", nargs="*", default=["h1"], help="targets of the base checked for forgetting (default h1)")
    ap.add_argument("--publish", action="store_true", help="publish the result (step 4)")
    ap.add_argument("--publish-only", action="store_true", help="re-publish the committed weights (step 4 alone)")
    ap.add_argument("--hub-url", help="publish to this Hub (HF_ENDPOINT) instead of a loopback Hub")
    ap.add_argument("--name", help="zoo name (default mer-warm-ROBOT)")
    ap.add_argument("--repo-id", help="Hub repository (default mer-robotics/NAME)")
    args = ap.parse_args()
    args.name = args.name or f"mer-warm-{args.robot}"
    args.repo_id = args.repo_id or f"mer-robotics/{args.name}"
    args.home = args.home.resolve()
    if args.shards:
        args.synthetic = None
    if args.publish_only:
        publish(args)
        return
    if args.work is None:
        raise SystemExit("--work is needed (where the fine-tune and its evaluation go)")
    args.work.mkdir(parents=True, exist_ok=True)
    register(args.robot, args.urdf or SHARED / "robots-wild" / args.robot / f"{args.robot}.urdf", args.home)
    tuned = args.work / "finetune"
    finetune(args, tuned)
    ev = evaluate(args, tuned)
    print("\n".join(gain_lines(ev, args.robot)))
    if args.publish:
        base = args.base if not Path(args.base).is_dir() else "BASE"
        command = " ".join(["python tools/finetune_warm.py --home MER_HOME --work WORK", f"--base {base}",
                            f"--robot {args.robot}",
                            *([f"--synthetic {args.synthetic}"] if args.synthetic else ["--shards SHARDS"]),
                            f"--steps {args.steps}", f"--max-windows {args.max_windows}",
                            *([f"--batch-size {args.batch_size}"] if args.batch_size else []),
                            *([f"--lr {args.lr}"] if args.lr else []), "--publish"])  # fmt: skip
        stage_weights(tuned, weights_dir(args.name), card_metrics(ev, args.robot), command, base_label(args))
        publish(args)


if __name__ == "__main__":
    main()
