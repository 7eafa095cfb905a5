"""mer_models: the guided-diffusion retargeting model, its training, sampling and the model zoo.

Imports :mod:`mer_data` (skeletons, FK, shards); never the reverse.

``from mer_models import RetargetModel`` gives the model class, with ``from_pretrained``,
``save_pretrained`` and ``push_to_hub`` (:mod:`mer_models.hub.pretrained`); imported on first use, so
``import mer_models`` stays light.
"""

from typing import Any

__version__ = "0.1.0"

__all__ = ["RetargetModel", "__version__"]


def __getattr__(name: str) -> Any:
    if name == "RetargetModel":
        from mer_models.diffusion.model import RetargetModel

        return RetargetModel
    raise AttributeError(f"module 'mer_models' has no attribute {name!r}")
