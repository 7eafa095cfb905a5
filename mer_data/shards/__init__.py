"""Training shards: LAFAN1 robot CSVs -> origin-normalized 30 Hz windows with (augmented) target
skeletons and joint maps, in HDF5 or MCAP (docs/shards.md).

* :func:`build_shards` (``mer shards build``) and :class:`BuildConfig`;
* :class:`ShardDataset`: samples (:class:`mer_data.samples.TrainingSample`) from either format;
* :func:`open_shard`, :func:`inspect_shards` (``mer shards inspect``), :func:`write_card`.
"""

from .builder import BuildReport, build_shards
from .card import render_card, write_card
from .config import PAPER_TARGETS, BuildConfig
from .dataset import ShardDataset, WindowRef
from .inspect import format_inspection, inspect_shards
from .reader import find_shards, open_shard
from .schema import FORMAT_VERSION, ShardMeta

__all__ = [
    "BuildConfig",
    "BuildReport",
    "FORMAT_VERSION",
    "PAPER_TARGETS",
    "ShardDataset",
    "ShardMeta",
    "WindowRef",
    "build_shards",
    "find_shards",
    "format_inspection",
    "inspect_shards",
    "open_shard",
    "render_card",
    "write_card",
]
