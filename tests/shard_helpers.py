"""Synthetic LAFAN1-layout inputs for shard tests (motion generated in code, never LAFAN1 data)."""

from __future__ import annotations

from pathlib import Path

from mer_data.motion.lafan1 import write_lafan1_csv
from mer_data.synthesis.walking import walking_motion

#: clip name -> (seconds, gait phase, turn rate); names follow the LAFAN1 categories so that the
#: paper split applies (one dance, one fallAndGetUp, one fight for training, the rest held out)
CLIPS = {
    "dance1_subject1": (4.0, 0.0, 0.1),
    "fallAndGetUp1_subject1": (3.0, 1.0, -0.2),
    "fight1_subject2": (2.5, 2.0, 0.3),
    "walk1_subject1": (5.0, 0.5, 0.0),
    "walk2_subject3": (3.5, 1.5, -0.1),
}


def make_input(folder: Path, robots=("g1", "h1"), clips: dict | None = None, *, gz: bool = False) -> Path:
    """Write ``folder/<robot>/<clip>.csv[.gz]`` for every robot and clip; returns ``folder``."""
    for robot in robots:
        for name, (seconds, phase, turn) in (clips or CLIPS).items():
            m = walking_motion(robot, seconds, phase=phase, turn_rate=turn)
            write_lafan1_csv(folder / robot / f"{name}.csv{'.gz' if gz else ''}", m)
    return folder


def build(input_dir: Path, out: Path, **kw):
    """Build with test-friendly defaults (small augmentation, in-process); returns the report."""
    from mer_data.shards import BuildConfig, build_shards

    workers = kw.pop("workers", 1)
    keep_going = kw.pop("keep_going", False)
    shard_index = kw.pop("shard_index", None)
    cfg = BuildConfig(**{"input": str(input_dir), "robots": ("g1", "h1"), "augment": 2, **kw})
    return build_shards(cfg, out, workers=workers, keep_going=keep_going, shard_index=shard_index)


def shard_arrays(path: Path) -> dict:
    """Every column of a shard file, read through the format-independent reader."""
    from mer_data.shards import open_shard

    s = open_shard(path)
    return s.rows(0, s.num_rows)


def assert_same_arrays(a: dict, b: dict) -> None:
    import numpy as np

    assert a.keys() == b.keys()
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.dtype == y.dtype and x.shape == y.shape, k
        if x.dtype == object:
            assert list(x) == list(y), k
        else:
            assert x.tobytes() == y.tobytes(), k
