"""What each requirement of the constraint method costs: g-mpbpe, jerk and frames/s against the plain optimiser.

Retargets LAFAN1 windows of one source robot to each target with the plain optimiser and with
``PhysicsConfig(method="constraints")`` variants, back to back, and prints per variant g-mpbpe
(and its ratio to the plain solution's, per window), jerk and frames/s as ratios of the same run,
hovering, self-penetration deeper than 1 cm, any body below -1 cm and the median stance skate
(:mod:`mer_models.retarget.artifacts`). A variant is a name, then ``:field=value`` overrides of
:class:`~mer_models.solver.physics.PhysicsConfig`:

    plain               no physical term (the baseline; first)
    full                the constraint method's defaults
    floor               the floor constraint alone (no self pairs, no hovering, no no-slip term)
    floor+self          ... and the self-penetration constraint
    floor+self+hover    ... and the no-hovering constraint (all but the no-slip term)
    full:xy_weight=0.2:self_margin=0.0   overrides

    python tools/ablate_constraints.py --input ../shared/data/lafan1 --targets talos g1 \\
        --windows walk1_subject1:600:900 dance1_subject1:600:900 fallAndGetUp1_subject1:600:900 \\
        --variants plain full floor floor+self floor+self+hover

``--ground``: every variant (the plain one too) tracks goals lifted, frame by frame, by how deep the
plain solution's lowest body is in the floor (a running maximum over 7 frames, then a Gaussian of
2 frames): what a reference grounded to the target's geometry would do to the ratios. g-mpbpe is
then against the lifted goals, with the unedited goals' figure after it ("raw").

Reads LAFAN1 data: never commit its output. docs/decisions.md §Physics as constraints, session 3.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import mer_models.retarget.clip as clip_module  # noqa: E402
from mer_data.kinematics.collision import shape_points  # noqa: E402
from mer_data.motion.lafan1 import read_lafan1_csv  # noqa: E402
from mer_data.robots.collision import collision_model  # noqa: E402
from mer_data.robots.registry import load_robot  # noqa: E402
from mer_models.retarget.clip import retarget_features, sequence_metrics, source_features  # noqa: E402
from mer_models.solver.physics import PhysicsConfig  # noqa: E402

FPS = 30.0
_C = PhysicsConfig(method="constraints")
BASES = {
    "full": _C,
    "floor": dataclasses.replace(_C, w_self=0.0, hover=1e3, stance_xy=False),
    "floor+self": dataclasses.replace(_C, hover=1e3, stance_xy=False),
    "floor+self+hover": dataclasses.replace(_C, stance_xy=False),
}


def variant(text: str) -> PhysicsConfig | None:
    """``name[:field=value...]`` -> the configuration (None: the plain optimiser)."""
    name, *over = text.split(":")
    if name == "plain":
        return None
    if name not in BASES:
        raise SystemExit(f"variant {text!r}: expected plain or one of {', '.join(BASES)}, then :field=value")
    kw = {}
    for part in over:
        key, _, val = part.partition("=")
        if not hasattr(_C, key):
            raise SystemExit(f"variant {text!r}: PhysicsConfig has no field {key!r}")
        kind = type(getattr(_C, key))
        kw[key] = val.lower() in ("1", "true") if kind is bool else kind(val)
    return dataclasses.replace(BASES[name], **kw)


def lift_of(res, geom) -> np.ndarray:
    """(F,) [m]: how far to raise each frame of ``res`` so its lowest body is on the floor, smoothed."""
    from scipy.ndimage import gaussian_filter1d, maximum_filter1d

    pos, rot = res.motion.forward_kinematics()
    low = shape_points(geom, torch.from_numpy(pos), torch.from_numpy(rot), "vertices")[..., 2].min(-1).values.min(-1).values
    return gaussian_filter1d(maximum_filter1d(np.clip(-low.numpy(), 0.0, None), 7), 2.0)


class lifted_goals:
    """Within the block, :func:`prepare_reference` (as the retargeting calls it) raises the goals by ``dz`` (F,) [m]."""

    def __init__(self, dz: np.ndarray | None):
        self.dz, self.orig = dz, clip_module.prepare_reference

    def __enter__(self):
        if self.dz is not None:
            def lifted(ref, source, target, dz=self.dz, orig=self.orig):
                feats, scaled, shift, rot = orig(ref, source, target)
                scaled = scaled.copy()
                scaled[..., 2] += dz[:, None]
                return feats, scaled, shift, rot

            clip_module.prepare_reference = lifted
        return self

    def __exit__(self, *exc):
        clip_module.prepare_reference = self.orig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--input", required=True, help="LAFAN1 robot CSV folder (g1/, h1/, ...)")
    p.add_argument("--source", default="g1")
    p.add_argument("--targets", nargs="+", default=["talos", "g1"])
    p.add_argument("--windows", nargs="+", default=["walk1_subject1:600:900", "dance1_subject1:600:900", "fallAndGetUp1_subject1:600:900"],
                   help="clip:first:last (0-based, last excluded)")  # fmt: skip
    p.add_argument("--variants", nargs="+", default=["plain", "full", "floor", "floor+self", "floor+self+hover"])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--ground", action="store_true", help="goals lifted by the plain solution's depth in the floor (docstring)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    configs = [(v, variant(v)) for v in args.variants]
    src = load_robot(args.source)
    feats = {}
    for w in args.windows:
        clip, a, b = w.split(":")
        m = read_lafan1_csv(Path(args.input) / args.source / f"{clip}.csv", src)
        feats[w] = source_features(m.base_pos, m.base_quat, m.node_angles(src.skeleton), src.skeleton, FPS)[int(a) : int(b)]
    print(f"{args.source} source, windows {' '.join(args.windows)}; g-mpbpe x the first variant per window in brackets")
    for t in args.targets:
        robot = load_robot(t)
        geom = collision_model(robot)
        base, lifts = None, {}
        for name, cfg in configs:
            g, raw, jerk, hover, self_pen, floor, skate, sec, frames = [], [], [], [], [], [], [], 0.0, 0
            for w, f in feats.items():
                if args.ground and w not in lifts:
                    lifts[w] = lift_of(retarget_features(f, src.skeleton, robot.skeleton, method="optimize", fps=FPS), geom)
                t0 = time.perf_counter()
                with lifted_goals(lifts.get(w)):
                    res = retarget_features(f, src.skeleton, robot.skeleton, method="optimize", fps=FPS, physics=cfg)
                sec += time.perf_counter() - t0
                frames += len(f)
                met = sequence_metrics(f, src.skeleton, res.motion, prepared=res.prepared, geometry=geom)
                if args.ground:
                    raw.append(sequence_metrics(f, src.skeleton, res.motion)["g_mpbpe"])
                g.append(met["g_mpbpe"])
                jerk.append(met["jerk_frame"])
                hover.append(met["hover_frames"])
                self_pen.append(met["selfpen_1cm_frames"])
                floor.append(met["body_floor_frames"])
                skate.append(met["skate_median"])
            row = {"g": np.array(g), "jerk": float(np.mean(jerk)), "fps": frames / sec}
            base = base or row
            per = " ".join(f"{x / y:.2f}" for x, y in zip(row["g"], base["g"]))
            if raw:
                per += f"; raw {1000 * np.mean(raw):.1f} mm"
            print(f"{t:9s} {name:42s} g-mpbpe {1000 * row['g'].mean():5.1f} mm x{row['g'].mean() / base['g'].mean():.2f} [{per}] "
                  f"jerk x{row['jerk'] / base['jerk']:.2f} hovering {np.mean(hover):.3f} self>1cm {np.mean(self_pen):.3f} "
                  f"body<-1cm {np.mean(floor):.3f} skate {100 * np.nanmean(np.array(skate, float)):.1f} cm/s frames/s {row['fps']:.0f} x{row['fps'] / base['fps']:.2f}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
