"""mer_models: the optimiser, the guided-diffusion model, its training, retargeting, output files,
the model zoo and the ``mer`` command. Imports :mod:`mer_data`; never the reverse.

Bottom up: :mod:`.config` and :mod:`.batch` (padded mixed-robot batches); :mod:`.solver` (the
energy and the optimiser); :mod:`.export` (CSV / npz / MCAP / PNG / video); :mod:`.hub` (models
as files: names, cards, the Hub, the checkpoint folder, ``from_pretrained``); :mod:`.diffusion`
(the network and its samplers); :mod:`.zoo` (load by name); :mod:`.retarget` (a motion, a dataset,
metrics, ``mer evaluate``); :mod:`.training` (``mer train``, the teacher, ``mer finetune``);
:mod:`.cli` (the ``mer`` command).

``from mer_models import RetargetModel`` gives the model class, with ``from_pretrained``,
``save_pretrained`` and ``push_to_hub`` (:mod:`mer_models.hub.pretrained`); imported on first use, so
``import mer_models`` stays light.
"""

from typing import Any

from mer_models._version import __version__

__all__ = ["RetargetModel", "__version__"]


def __getattr__(name: str) -> Any:
    if name == "RetargetModel":
        from mer_models.diffusion.model import RetargetModel

        return RetargetModel
    raise AttributeError(f"module 'mer_models' has no attribute {name!r}")
