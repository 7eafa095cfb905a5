"""How far a rounding-level change of the input moves the retargeted motion, per method.

Each LAFAN1 window is retargeted (the optimiser's path, :func:`mer_models.retarget.clip.retarget_features`)
twice per method: as read, and with the source's base path moved by ``--eps`` metres of noise per
frame (a change at the level of float32 rounding and of two runs batched differently). Printed per
method: the mean and largest displacement of the target's bodies between the two results [mm]. A
well-posed solve moves them by about ``--eps``; centimetres mean the result hangs on a thresholded
decision (an active set, a round's stop) that the change flipped.

    python tools/bench_sensitivity.py --input ../shared/data/lafan1 --targets h1 talos --methods optimize physics constraints
    python tools/bench_sensitivity.py --input ../shared/data/lafan1 --methods constraints --set al_iters=8

``--set FIELD=VALUE``: :class:`~mer_models.solver.physics.PhysicsConfig` fields of both physical methods.

Reads LAFAN1 data: never commit its output. docs/decisions.md §Physics as constraints, session 7.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.retarget.clip import retarget_features, source_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

sys.path.insert(0, str(REPO / "tools"))
from bench_artifacts import set_fields  # noqa: E402

FPS = 30.0
METHODS = {"optimize": None, "physics": "penalty", "constraints": "constraints"}  # name -> PhysicsConfig.method
WINDOWS = ("walk1_subject1:600:750", "dance1_subject1:600:750", "fallAndGetUp1_subject1:600:750")


def bodies(res) -> np.ndarray:
    """(F, J, 3) [m] every node of the result."""
    return res.motion.forward_kinematics()[0]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/, ...)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=["h1", "talos"])
    p.add_argument("--windows", nargs="+", default=list(WINDOWS), help="clip:first:last (0-based, last excluded)")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    p.add_argument("--eps", type=float, default=1e-6, help="noise on the source's base position [m] (default 1e-6)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE", help="PhysicsConfig fields (e.g. al_iters=8)")
    args = p.parse_args(argv)
    fields = set_fields(PhysicsConfig, args.set)
    if not args.eps > 0:
        raise SystemExit(f"--eps {args.eps}: expected a positive distance in metres")
    torch.set_num_threads(args.threads)
    src = load_robot(args.source)
    rng = np.random.default_rng(0)
    print(f"{args.source} source; each window again with {args.eps:g} m of noise on the source's base path; "
          "body displacement between the two results [mm]: mean / largest")  # fmt: skip
    for t in args.targets:
        robot = load_robot(t)
        for w in args.windows:
            clip, a, b = w.split(":")
            m = read_lafan1_csv(Path(args.input) / args.source / f"{clip}.csv", src)
            f = source_features(m.base_pos, m.base_quat, m.node_angles(src.skeleton), src.skeleton, FPS)[int(a) : int(b)]
            g = f.copy()
            g[:, 0, 3:6] += args.eps * rng.standard_normal((len(f), 3))
            cells = []
            for name in args.methods:
                phys = None if METHODS[name] is None else PhysicsConfig(**{**fields, "method": METHODS[name]})
                kw = {"method": "optimize", "fps": FPS, "physics": phys}
                d = np.linalg.norm(bodies(retarget_features(f, src.skeleton, robot.skeleton, **kw))
                                   - bodies(retarget_features(g, src.skeleton, robot.skeleton, **kw)), axis=-1)  # fmt: skip
                cells.append(f"{name} {1000 * d.mean():6.2f} / {1000 * d.max():6.1f}")
            print(f"{t:9s} {w:28s} " + "   ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
