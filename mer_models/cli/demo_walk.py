"""The second half of ``mer demo``: register a robot, load the default model by name, retarget.

:func:`register_example_robot` writes the example humanoid URDF (generated in code,
:mod:`mer_data.robots.example`) and registers it in ``$MER_HOME`` exactly as
``mer robots register NAME --urdf FILE`` does. :func:`retarget_to_all` retargets one source
motion with one model to every robot given, writes a CSV per robot (plus an MCAP, a PNG and a
GIF for one of them) and measures each result with the paper's metrics (:func:`mer_models.retarget.clip.sequence_metrics`).
A robot the model never saw is retargeted zero-shot (the ``--allow-unseen`` path) and marked so.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from mer_data.robots.register import RegistrationReport, register_robot
from mer_data.robots.registry import get_skeleton
from mer_models.export.writers import write_csv, write_mcap
from mer_models.retarget.clip import MODEL_FPS, retarget_features, sequence_metrics, source_features
from mer_models.retarget.columns import METRIC_COLUMNS, metric_legend
from mer_models.zoo.checkpoint import Checkpoint

log = logging.getLogger(__name__)

__all__ = ["register_example_robot", "RobotResult", "retarget_to_all", "format_results"]

#: Frame rate of the demo's GIF [Hz]: every other frame of the 30 Hz motion (half the rendering time).
DEMO_VIDEO_FPS = 15.0

# the paper's metrics, named and drawn as every retarget's metrics row names them (mer_models.retarget.columns)
COLUMNS = tuple(c for c in METRIC_COLUMNS if c.key in ("g_mpbpe", "mpboe", "mpbve", "jerk_frame", "limit_violation"))


def register_example_robot(folder: str | Path, name: str | None = None) -> RegistrationReport:
    """Write the example humanoid's URDF into ``folder`` and register it (replacing an earlier demo copy)."""
    from mer_data.robots.example import EXAMPLE_ROBOT, write_example_urdf

    name = name or EXAMPLE_ROBOT
    urdf = write_example_urdf(Path(folder) / f"{name}.urdf", name)
    return register_robot(name, urdf, force=True)


@dataclass
class RobotResult:
    """One target of the walk: whether the model saw it, its metrics and its files."""

    robot: str
    seen: bool
    frames: int
    seconds: float
    metrics: dict[str, float]
    outputs: dict[str, Path] = field(default_factory=dict)


def retarget_to_all(
    source_csv: str | Path,
    source: str,
    targets: Sequence[str],
    checkpoint: Checkpoint,
    out: str | Path,
    *,
    show: str | None = None,
    steps: int | None = None,
    seed: int = 0,
) -> list[RobotResult]:
    """Retarget ``source_csv`` (``source``'s LAFAN1 layout, 30 Hz) to every robot of ``targets``.

    Writes ``out/<robot>.csv`` for each, and ``out/<show>.mcap`` + ``.png`` + ``.gif`` (the scaled
    reference and the result side by side, :mod:`mer_models.export.video`, at ``DEMO_VIDEO_FPS``) for ``show``.
    """
    from mer_data.motion.lafan1 import read_lafan1_csv
    from mer_models.export.plot import plot_motion
    from mer_models.export.video import write_video

    out = Path(out)
    motion = read_lafan1_csv(source_csv, source)
    skel = get_skeleton(source)
    feats = source_features(motion.base_pos, motion.base_quat, motion.node_angles(skel), skel, MODEL_FPS)
    seen_targets = set(checkpoint.robots.get("targets", {}))
    results = []
    for robot in targets:
        tgt = get_skeleton(robot)
        seen = robot in seen_targets
        t = time.perf_counter()
        res = retarget_features(feats, skel, tgt, checkpoint=checkpoint, steps=steps, seed=seed, fps=MODEL_FPS,
                                allow_unseen=not seen)  # fmt: skip
        dt = time.perf_counter() - t
        outputs = {"csv": write_csv(out / f"{robot}.csv", res.motion)}
        if robot == show:
            outputs["mcap"] = write_mcap(out / f"{robot}.mcap", res.motion, reference_points=res.reference_points)
            outputs["png"] = plot_motion(out / f"{robot}.png", res.motion, reference_points=res.reference_points)
            outputs["gif"] = write_video(out / f"{robot}.gif", res.motion, res.reference_points, reference_nodes=res.reference_nodes,
                                         reference_skeleton=res.reference_skeleton, fps=DEMO_VIDEO_FPS)  # fmt: skip
        results.append(RobotResult(robot, seen, res.motion.num_frames, dt, sequence_metrics(feats, skel, res.motion), outputs))
        log.info("%s -> %s: %.1f s", source, robot, dt)
    return results


def format_results(results: Sequence[RobotResult]) -> str:
    """A table: robot, whether the model saw it, the metrics, the seconds it took."""
    head = f"{'robot':18s} {'model saw it':13s} " + " ".join(f"{c.header:>{c.width}s}" for c in COLUMNS) + f" {'seconds':>8s}"
    lines = [head]
    for r in results:
        cells = " ".join(f"{v:>{c.width}{c.fmt}}" if math.isfinite(v := r.metrics.get(c.key, math.nan)) else f"{'-':>{c.width}s}"
                         for c in COLUMNS)  # fmt: skip
        lines.append(f"{r.robot:18s} {'yes' if r.seen else 'no: zero-shot':13s} {cells} {r.seconds:8.1f}")
    return "\n".join([*lines, metric_legend(COLUMNS)])
