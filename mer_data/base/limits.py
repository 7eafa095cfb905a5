"""Limits on untrusted input: one place, one table (documented in docs/robots.md and docs/shards.md).

Every limit has a default far above any real file (the figures of the real data are in the docs)
and can be raised with an environment variable of the same name, e.g. ``MER_MAX_URDF_BYTES=200000000``.
Past a limit the reader raises the package's own error, with the number found, the limit, and the
variable that raises it. Values are read when checked, so a test or a caller can change them.

Plausibility bounds on values (:data:`MAX_LENGTH_M`, :data:`MAX_NUMBER`) are not limits on size:
they keep every computed output finite, and are not configurable.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

__all__ = ["Limit", "LIMITS", "limit", "too_big", "check_motion_size", "check_upsampling", "MAX_LENGTH_M", "MAX_NUMBER",
           "LINK_SCALE_RANGE"]

#: Largest length accepted in a URDF origin, collision shape or key-point offset [m].
MAX_LENGTH_M = 1e3
#: Largest magnitude of any other number read from a URDF (angles, limits, axes, mimic factors).
MAX_NUMBER = 1e6
#: Plausible link scale factors stored in a shard (augmentation draws 0.5-2).
LINK_SCALE_RANGE = (1e-2, 1e2)


@dataclass(frozen=True)
class Limit:
    """A named limit: the environment variable that sets it, its default and what it counts."""

    name: str
    default: int
    unit: str
    what: str

    @property
    def value(self) -> int:
        raw = os.environ.get(self.name)
        if raw is None:
            return self.default
        try:
            v = int(float(raw))
        except ValueError:
            return self.default
        return v if v > 0 else self.default


LIMITS: dict[str, Limit] = {
    lim.name: lim
    for lim in (
        Limit("MER_MAX_URDF_BYTES", 32 * 2**20, "bytes", "size of a URDF file"),
        Limit("MER_MAX_URDF_ELEMENTS", 10_000, "elements", "number of <link> (or of <joint>) elements in a URDF"),
        Limit("MER_MAX_XML_DEPTH", 64, "levels", "nesting depth of XML elements in a URDF"),
        Limit("MER_MAX_URDF_LINE_BYTES", 2**20, "bytes", "length of one line of a URDF"),
        Limit("MER_MAX_MJCF_ELEMENTS", 5_000, "elements", "elements of an MJCF with <replicate>, <flexcomp> and sub-models expanded"),
        Limit("MER_MAX_MESH_BYTES", 32 * 2**20, "bytes", "size of one mesh file (STL, OBJ, ...) of a robot"),
        Limit("MER_MAX_CARD_BYTES", 2**20, "bytes", "size of a robot card or key-point file"),
        Limit("MER_MAX_MOTION_BYTES", 64 * 2**20, "bytes", "size of a motion CSV (after gunzip)"),
        Limit("MER_MAX_CSV_LINE_BYTES", 64 * 2**10, "bytes", "length of one line of a motion CSV"),
        Limit("MER_MAX_CONFIG_BYTES", 2**20, "bytes", "size of a checkpoint's config.json"),
        Limit("MER_MAX_MODEL_PARAMETERS", 500_000_000, "parameters", "parameters of a model built from a config"),
        Limit("MER_MAX_BVH_BYTES", 32 * 2**20, "bytes", "size of a BVH motion capture file"),
        Limit("MER_MAX_BVH_LINE_BYTES", 2**20, "bytes", "length of one line of a BVH file"),
        Limit("MER_MAX_BVH_JOINTS", 1_000, "joints", "number of joints (and End Sites) in a BVH hierarchy"),
        Limit("MER_MAX_BVH_FRAMES", 2_000_000, "frames", "number of frames of a BVH motion"),
        Limit("MER_MAX_MOTION_VALUES", 16_000_000, "numbers", "numbers of a motion a reader produces (frames x values per frame, after resampling)"),
        Limit("MER_MAX_UPSAMPLING", 8, "times", "how many times more frames resampling makes than a motion has (output rate / its rate)"),
        Limit("MER_MAX_ARRAY_BYTES", 2 * 2**30, "bytes", "size of the arrays of an .npz/.npy motion or body model"),
        Limit("MER_MAX_ARRAY_FRAMES", 2_000_000, "frames", "number of frames of an SMPL or joint-position motion"),
        Limit("MER_MAX_SHARD_ROWS", 10_000_000, "rows", "declared number of rows (windows) of a shard or teacher file"),
        Limit("MER_MAX_HDF5_ATTR_BYTES", 16 * 2**20, "bytes", "size of one HDF5 attribute (shard metadata)"),
        Limit("MER_MAX_HDF5_CHUNK_BYTES", 16 * 2**20, "bytes", "decompressed size of one HDF5 chunk"),
        Limit("MER_MAX_HDF5_READ_BYTES", 512 * 2**20, "bytes", "decompressed bytes of one read from an HDF5 dataset"),
        Limit("MER_MAX_HDF5_READ_CHUNKS", 200_000, "chunks", "HDF5 chunks one read touches (a whole small column)"),
        Limit("MER_MAX_HDF5_DATASET_BYTES", 2**40, "bytes", "declared size of an HDF5 dataset (the product of its shape)"),
        Limit("MER_MAX_MCAP_CHUNK_BYTES", 64 * 2**20, "bytes", "decompressed size of one MCAP chunk"),
        Limit("MER_MAX_MCAP_BYTES", 2 * 2**30, "bytes", "decompressed size of all the chunks of an MCAP shard"),
        Limit("MER_MAX_MCAP_RECORDS", 10_000_000, "records", "number of records (messages included) of an MCAP shard"),
        Limit("MER_MAX_SIDECAR_BYTES", 64 * 2**20, "bytes", "size of a shard folder's mer_meta.json"),
        Limit("MER_MAX_DATASET_CARD_BYTES", 16 * 2**20, "bytes", "size of a dataset card (README.md) downloaded with shards"),
        Limit("MER_MAX_HUB_FILE_BYTES", 64 * 2**30, "bytes", "size of one file downloaded from the Hub (shards)"),
        Limit("MER_MAX_HUB_DOWNLOAD_BYTES", 1024 * 2**30, "bytes", "size of all the files of one Hub download"),
        Limit("MER_MAX_HUB_FILES", 1_000_000, "entries", "entries of a Hub repository's file listing"),
        Limit("MER_MAX_HUB_JSON_BYTES", 64 * 2**20, "bytes", "size of one JSON answer of a Hub server (a listing)"),
    )
}


def limit(name: str) -> int:
    """The current value of the limit ``name`` (its environment variable, else the default)."""
    return LIMITS[name].value


def too_big(name: str, found: int | str) -> tuple[str, str]:
    """(message, fix) for an input past the limit ``name``: the number, the limit, how to raise it."""
    lim = LIMITS[name]
    shown = f"{found:,}" if isinstance(found, int) else found
    message = f"{lim.what} is {shown} {lim.unit}, over mer's limit of {lim.value:,} {lim.unit}"
    fix = f"if the input is genuine, raise the limit: set {lim.name}=N in the environment (default {lim.default:,})"
    return message, fix


def check_motion_size(frames: int, per_frame: int, *, what: str, error: type | None = None, path=None,
                      line: int | None = None) -> None:  # fmt: skip
    """Refuse, before it is allocated, a motion array of ``frames`` x ``per_frame`` numbers over
    ``MER_MAX_MOTION_VALUES`` (a limit on what a reader PRODUCES: a resampled motion, a BVH's
    kinematics of every joint, a table of channels), whatever the file declared.

    Every reader of motion (CSV, BVH, resampling, new formats) calls it with the size it is about to
    make. ``error``: the :class:`~mer_data.base.errors.MerError` subclass to raise (default MerError).
    """
    from .errors import MerError

    n = int(frames) * int(per_frame)
    if n > limit("MER_MAX_MOTION_VALUES"):
        msg, fix = too_big("MER_MAX_MOTION_VALUES", n)
        raise (error or MerError)(f"{what}: {int(frames):,} frames x {int(per_frame):,} numbers; {msg}", path=path,
                                  line=line, fix=f"split the motion into shorter clips, or {fix}")  # fmt: skip


def check_upsampling(fps_in: float, fps_out: float, *, error: type | None = None, path=None, line: int | None = None) -> None:
    """Refuse resampling a motion at ``fps_in`` [Hz] to ``fps_out`` [Hz] when it makes more than
    ``MER_MAX_UPSAMPLING`` times its frames (a ``Frame Time: 10`` BVH, ``--fps 0.001`` on a CSV)."""
    from .errors import MerError

    if not (fps_in > 0 and fps_out > 0) or fps_out / fps_in > limit("MER_MAX_UPSAMPLING"):
        msg, fix = too_big("MER_MAX_UPSAMPLING", f"{fps_out / fps_in:,.4g}" if fps_in > 0 else "infinite")
        raise (error or MerError)(f"the motion's frame rate {fps_in:g} Hz resampled to {fps_out:g} Hz: {msg}", path=path,
                                  line=line, fix=f"check the frame rate (--fps, a BVH's Frame Time in seconds), or {fix}")  # fmt: skip
