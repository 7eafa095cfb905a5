"""Training shards: LAFAN1 robot CSVs or human motion (BVH, SMPL, joint positions; one reference per
body: ``humans.py``) -> origin-normalized 30 Hz windows with (augmented) target skeletons and joint
maps, in HDF5 or MCAP (docs/shards.md).

* :func:`build_shards` (``mer shards build``) and :class:`BuildConfig`;
* :class:`ShardDataset`: samples (:class:`mer_data.motion.samples.TrainingSample`) from either format;
* :func:`open_shard`, :func:`inspect_shards` (``mer shards inspect``), :func:`write_card`;
* :func:`push_shards` (``mer shards push``), ``hf://datasets/...`` in :class:`ShardDataset`, and
  :func:`read_sidecar` (``mer_meta.json``, the metadata ``datasets.load_dataset`` does not read).
"""

from importlib import import_module
from typing import Any

#: name -> the submodule defining it; imported on first use, so that ``import mer_data.shards.config``
#: (the command line's defaults) does not import torch.
_EXPORTS = {
    "BuildReport": "builder", "build_shards": "builder", "render_card": "card", "write_card": "card",
    "PAPER_TARGETS": "config", "BuildConfig": "config", "ShardDataset": "dataset", "WindowRef": "dataset",
    "push_shards": "hub", "format_inspection": "inspect", "inspect_shards": "inspect", "find_shards": "reader",
    "open_shard": "reader", "FORMAT_VERSION": "schema", "ShardMeta": "schema", "META_FILE": "sidecar",
    "Sidecar": "sidecar", "read_sidecar": "sidecar", "write_sidecar": "sidecar",
}  # fmt: skip


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
