"""The model zoo: pretrained and robot-fine-tuned checkpoints, loadable by name.

>>> from mer_models import zoo
>>> [e.name for e in zoo.list_models()]            # the catalogue (and the user's published models)
>>> folder = zoo.download("mer-base")              # verified config.json + model.safetensors
>>> ckpt = zoo.load("mer-base")                    # the model, built and loaded strictly

A name resolves through its card (``cards/models/<name>.md``) to a Hub repository at a pinned
commit, with every file's sha256 and size; see docs/zoo.md.
"""

from .api import DEFAULT_MODEL, REQUIRED_FILES, Resolved, download, list_models, load, model_info, resolve, where
from .card import FileRecord, ModelCard, parse_card, read_card
from .publish import PublishResult, publish
from .registry import ModelEntry, Registry
from .render import render_card

__all__ = [
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
