"""Profile: dataset retargeting (``mer retarget --input DIR``) per robot, where the time goes, and a
whole LAFAN1 folder in worker processes next to ``tools/bench_retarget.py``'s G1 -> H1 figure.

Three parts, in one run on one machine (the load average is printed with each: other processes on
a shared machine slow every figure, unequally):

1. **Per robot** (``--robots``, default the 8 built-ins and romeo, unitree_a1, unitree_h1_hands,
   icub from ``--wild``): ``retarget_dataset`` of the first ``--profile-clips`` clips of the source,
   each cut to ``--profile-frames`` frames, in this process on one torch thread (what each worker
   process does), with the physical terms (the default) and without (``--no-physics``). Printed:
   frames/s, and where the time goes: reading and goals, the optimiser (of which the physical
   terms' rows, contact search and repair detection: ``physics.py``), the feasibility pass, the
   metrics (of which the artifact metrics), writing. Robots of ``--wild`` are registered into a
   private ``MER_HOME`` (a temporary folder; ``--mer-home`` to keep one).
2. **Whole folder** (``--whole``, default romeo and unitree_a1): every clip of
   ``DATA/<source>/`` (``--whole-clips N``: the first N) to each robot, one ``retarget_dataset`` call
   per robot with ``--workers`` processes, physical terms on (``mer retarget``'s default;
   ``--whole-no-physics`` adds runs without); frames/s per robot = that robot's frames / wall time.
3. **bench_retarget**: ``tools/bench_retarget.py --targets h1 --dataset-clips 0`` in a subprocess
   (its own 2 threads, key points only, best of 2 on 1800 frames of one clip), and each whole-folder
   figure as a ratio of its G1 -> H1 frames/s.

Outputs go to a temporary folder (LAFAN1-derived: never into the repository) and are deleted.

    nice -n 5 .venv/bin/python tools/profile_dataset.py [--robots ...] [--profile-clips 2] \\
        [--profile-frames 2048] [--whole romeo unitree_a1] [--whole-clips 0] [--workers 2] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BUILTIN = ("g1", "h1", "h1_2", "atlas", "oli", "talos", "tron1", "valkyrie")
WILD = ("romeo", "unitree_a1", "unitree_h1_hands", "icub")
STAGES = ("read", "solve", "physics", "feasible", "metrics", "artifacts", "write")


def _parser() -> argparse.ArgumentParser:
    shared = Path(os.environ.get("MER_SHARED", REPO.parent / "shared"))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=shared / "data" / "lafan1", help="LAFAN1 folder (DATA/<source>/*.csv)")
    ap.add_argument("--wild", type=Path, default=shared / "robots-wild", help="folder of <name>/<name>.urdf to register")
    ap.add_argument("--source", default="g1")
    ap.add_argument("--robots", nargs="*", default=[*BUILTIN, *WILD], help="robots of part 1 (none: skip it)")
    ap.add_argument("--profile-clips", type=int, default=2)
    ap.add_argument("--profile-frames", type=int, default=2048, help="frames of each clip in part 1 (0: all)")
    ap.add_argument("--whole", nargs="*", default=["romeo", "unitree_a1"], help="robots of part 2 (none: skip it)")
    ap.add_argument("--whole-clips", type=int, default=0, help="the first N clips in part 2 (0: the whole folder)")
    ap.add_argument("--whole-no-physics", action="store_true", help="also run part 2 with --no-physics")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-bench", action="store_true", help="skip part 3")
    ap.add_argument("--mer-home", type=Path, help="MER_HOME to register the wild robots in (default: a temporary one)")
    ap.add_argument("--json", type=Path, help="also write every figure to this JSON file")
    return ap


class Stages:
    """Wall time per stage of a dataset run in this process (wrapped entry points, exclusive where nested)."""

    def __init__(self) -> None:
        self.t = dict.fromkeys(STAGES, 0.0)
        self._undo: list = []

    def wrap(self, owner, name: str, stage: str) -> None:
        fn = getattr(owner, name)

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.t[stage] += time.perf_counter() - t0

        setattr(owner, name, timed)
        self._undo.append((owner, name, fn))

    def __enter__(self) -> "Stages":
        import mer_models.retarget.artifacts as artifacts
        import mer_models.retarget.clip as clip
        import mer_models.retarget.dataset as dataset
        from mer_models.solver import physics

        self.wrap(dataset, "_read", "read")
        self.wrap(dataset, "_lock_stance", "read")
        self.wrap(dataset, "optimize_motion", "solve")
        for name in ("linearise", "cost", "freeze", "speed_terms", "speed_cost"):
            self.wrap(physics.Physics, name, "physics")
        self.wrap(physics.PhysicsInputs, "repair", "physics")
        self.wrap(clip, "feasible_motion", "feasible")
        self.wrap(dataset, "sequence_metrics", "metrics")
        self.wrap(artifacts, "motion_artifacts", "artifacts")
        for name in ("write_csv", "write_npz", "atomic_write"):
            self.wrap(dataset, name, "write")
        return self

    def __exit__(self, *exc) -> None:
        for owner, name, fn in reversed(self._undo):
            setattr(owner, name, fn)


def register_wild(wild: Path, names) -> None:
    from mer_data.robots.register import register_robot
    from mer_data.robots.registry import as_robot

    for name in names:
        try:
            as_robot(name)
            continue
        except Exception:  # not registered yet  # noqa: BLE001
            pass
        urdf = wild / name / f"{name}.urdf"
        if not urdf.is_file():
            raise SystemExit(f"{urdf} not found (--wild)")
        register_robot(name, urdf)


def subset(data_dir: Path, source: str, out: Path, clips: int, frames: int) -> Path:
    """The first ``clips`` clips of the source, each cut to its first ``frames`` lines, under ``out/<source>/``."""
    files = sorted((data_dir / source).glob("*.csv"))[: clips or None]
    (out / source).mkdir(parents=True, exist_ok=True)
    for f in files:
        lines = f.read_bytes().splitlines(keepends=True)
        (out / source / f.name).write_bytes(b"".join(lines[:frames] if frames else lines))
    return out


def load() -> float:
    return os.getloadavg()[0]


def part_robots(args, tmp: Path) -> list[dict]:
    from mer_models.retarget.dataset import retarget_dataset
    from mer_models.retarget.workers import one_thread
    from mer_models.solver.physics import PhysicsConfig

    inp = subset(args.data_dir, args.source, tmp / "profile-in", args.profile_clips, args.profile_frames)
    with one_thread():
        retarget_dataset(
            str(inp), args.source, [args.robots[0]], tmp / "warm", physics=PhysicsConfig(), workers=1
        )  # imports, caches
    rows = []
    print(f"\n1. per robot: {args.profile_clips} clips of {args.source} x {args.profile_frames or 'all'} frames, one process, "
          "one torch thread [s per 1000 frames by stage; physics and artifacts are parts of solve and metrics]")  # fmt: skip
    head = f"{'robot':17s} {'physics':7s} {'nodes':>5s} {'dof':>4s} {'frames/s':>9s} " + " ".join(f"{s:>9s}" for s in STAGES)
    print(head + f" {'other':>7s} {'load':>5s}\n" + "-" * (len(head) + 14))
    from mer_data.robots.registry import as_robot

    for robot in args.robots:
        skel = as_robot(robot).skeleton
        for phys in (True, False):
            out = tmp / f"profile-{robot}-{phys}"
            with one_thread(), Stages() as st:
                t0 = time.perf_counter()
                s = retarget_dataset(str(inp), args.source, [robot], out, physics=PhysicsConfig() if phys else None, workers=1)
                dt = time.perf_counter() - t0
            k = 1000.0 / s["frames"]
            exclusive = st.t["read"] + st.t["solve"] + st.t["feasible"] + st.t["metrics"] + st.t["write"]
            row = {"robot": robot, "physics": phys, "nodes": skel.num_nodes, "dof": skel.num_dof, "frames": s["frames"], "seconds": dt,
                   "fps": s["frames"] / dt, **{f"{k_}_s": v for k_, v in st.t.items()}, "other_s": dt - exclusive, "load": load()}  # fmt: skip
            rows.append(row)
            print(f"{robot:17s} {'on' if phys else 'off':7s} {skel.num_nodes:5d} {skel.num_dof:4d} {row['fps']:9.0f} "
                  + " ".join(f"{st.t[x] * k:9.2f}" for x in STAGES) + f" {(dt - exclusive) * k:7.2f} {row['load']:5.2f}", flush=True)  # fmt: skip
    return rows


def part_whole(args, tmp: Path) -> list[dict]:
    from mer_models.retarget.dataset import retarget_dataset
    from mer_models.solver.physics import PhysicsConfig

    inp = subset(args.data_dir, args.source, tmp / "whole-in", args.whole_clips, 0)
    n = len(list((inp / args.source).glob("*.csv")))
    rows = []
    print(f"\n2. whole folder: {n} clips of {args.source} ({'all' if not args.whole_clips else 'the first ' + str(n)}), "
          f"--workers {args.workers}, one call per robot")  # fmt: skip
    for phys in (True, False) if args.whole_no_physics else (True,):
        for robot in args.whole:
            l0, t0 = load(), time.perf_counter()
            s = retarget_dataset(str(inp), args.source, [robot], tmp / f"whole-{robot}-{phys}", physics=PhysicsConfig() if phys else None,
                                 workers=args.workers)  # fmt: skip
            dt = time.perf_counter() - t0
            row = {"robot": robot, "physics": phys, "clips": n, "frames": s["frames"], "seconds": dt, "fps": s["frames"] / dt,
                   "workers": s["workers"], "load": (l0, load())}  # fmt: skip
            rows.append(row)
            print(f"{args.source} -> {robot:12s} physics {'on ' if phys else 'off'}: {s['frames']} frames in {dt:.1f} s = "
                  f"{row['fps']:.0f} frames/s ({s['workers']} processes; load {l0:.2f} -> {row['load'][1]:.2f})", flush=True)  # fmt: skip
    return rows


def part_bench(tmp: Path) -> dict | None:
    out = tmp / "bench.json"
    cmd = [
        sys.executable,
        str(REPO / "tools" / "bench_retarget.py"),
        "--targets",
        "h1",
        "--dataset-clips",
        "0",
        "--json",
        str(out),
    ]
    l0 = load()
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        print(f"bench_retarget failed:\n{res.stderr[-2000:]}")
        return None
    rows = json.loads(out.read_text())["rows"]
    mer = next(r for r in rows if r["target"] == "h1" and r["method"] == "mer optimize")
    print(f"\n3. tools/bench_retarget.py G1 -> H1 (mer optimize, {mer['frames']} frames, 2 threads, key points only): "
          f"{mer['fps']:.0f} frames/s (load {l0:.2f} -> {load():.2f})")  # fmt: skip
    return {"fps": mer["fps"], "frames": mer["frames"], "seconds": mer["seconds"], "load": (l0, load())}


def main() -> None:
    args = _parser().parse_args()
    home = None
    if args.mer_home is None:
        home = tempfile.TemporaryDirectory(prefix="mer-home-")
        args.mer_home = Path(home.name)
    os.environ["MER_HOME"] = str(args.mer_home)
    sys.path.insert(0, str(REPO))
    import torch

    register_wild(args.wild, [r for r in dict.fromkeys([*args.robots, *args.whole]) if r in WILD])
    print(
        f"{os.cpu_count()} cores, {len(os.sched_getaffinity(0))} available, torch {torch.__version__}, load average {load():.2f}"
    )
    result: dict = {}
    with tempfile.TemporaryDirectory(prefix="mer-profile-") as tmp:
        if args.robots:
            result["robots"] = part_robots(args, Path(tmp))
        if args.whole:
            result["whole"] = part_whole(args, Path(tmp))
        if not args.no_bench:
            result["bench_h1"] = part_bench(Path(tmp))
    bench = result.get("bench_h1")
    if bench and result.get("whole"):
        print("\nwhole folder vs bench_retarget G1 -> H1 and the 1,000 frames/s bar:")
        for r in result["whole"]:
            print(f"  {r['robot']:12s} physics {'on ' if r['physics'] else 'off'} {r['fps']:7.0f} frames/s = {r['fps'] / bench['fps']:.2f}x "
                  f"G1 -> H1's {bench['fps']:.0f}, {r['fps'] / 1000:.2f}x the bar")  # fmt: skip
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1))
    if home is not None:
        home.cleanup()


if __name__ == "__main__":
    main()
