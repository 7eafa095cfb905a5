"""Training shards: LAFAN1 robot CSVs -> origin-normalized 30 Hz windows with (augmented) target
skeletons and joint maps, in HDF5 or MCAP (docs/shards.md).

* :func:`build_shards` (``mer shards build``) and :class:`BuildConfig`;
* :class:`ShardDataset`: samples (:class:`mer_data.motion.samples.TrainingSample`) from either format;
* :func:`open_shard`, :func:`inspect_shards` (``mer shards inspect``), :func:`write_card`;
* :func:`push_shards` (``mer shards push``), ``hf://datasets/...`` in :class:`ShardDataset`, and
  :func:`read_sidecar` (``mer_meta.json``, the metadata ``datasets.load_dataset`` does not read).
"""

from .builder import BuildReport, build_shards
from .card import render_card, write_card
from .config import PAPER_TARGETS, BuildConfig
from .dataset import ShardDataset, WindowRef
from .hub import push_shards
from .inspect import format_inspection, inspect_shards
from .reader import find_shards, open_shard
from .schema import FORMAT_VERSION, ShardMeta
from .sidecar import META_FILE, Sidecar, read_sidecar, write_sidecar

__all__ = [
    "BuildConfig",
    "BuildReport",
    "FORMAT_VERSION",
    "META_FILE",
    "PAPER_TARGETS",
    "ShardDataset",
    "ShardMeta",
    "Sidecar",
    "WindowRef",
    "build_shards",
    "find_shards",
    "format_inspection",
    "inspect_shards",
    "open_shard",
    "push_shards",
    "read_sidecar",
    "render_card",
    "write_card",
    "write_sidecar",
]
