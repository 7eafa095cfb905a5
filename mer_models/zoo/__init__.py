"""The model zoo: pretrained and robot-fine-tuned checkpoints, loadable by name.

>>> from mer_models import zoo
>>> [e.name for e in zoo.list_models()]            # the catalogue (and the user's published models)
>>> folder = zoo.download("mer-base")              # verified config.json + model.safetensors
>>> ckpt = zoo.load("mer-base")                    # the model, built and loaded strictly

The zoo as users call it; the files behind it (names, cards, the Hub, checksums, the checkpoint
folder) are :mod:`mer_models.hub`, and :mod:`.checkpoint` builds the network from them.
A name resolves through its card (``cards/models/<name>.md``) to a Hub repository at a pinned
commit, with every file's sha256 and size; see docs/zoo.md.
"""

from mer_models.hub.card import FileRecord, ModelCard, parse_card, read_card
from mer_models.hub.publish import PublishResult, publish
from mer_models.hub.registry import ModelEntry, Registry
from mer_models.hub.render import render_card
from mer_models.hub.resolve import DEFAULT_MODEL, REQUIRED_FILES, Resolved, download, list_models, model_info, resolve, where

from .checkpoint import Checkpoint, load

__all__ = [
    "Checkpoint",
    "DEFAULT_MODEL",
    "REQUIRED_FILES",
    "FileRecord",
    "ModelCard",
    "ModelEntry",
    "PublishResult",
    "Registry",
    "Resolved",
    "download",
    "list_models",
    "load",
    "model_info",
    "parse_card",
    "publish",
    "read_card",
    "render_card",
    "resolve",
    "where",
]
