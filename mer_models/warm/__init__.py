"""The warm-start model: a cheap per-frame network whose output a few optimiser iterations finish.

* :mod:`.features`: what the network reads per target node and frame, in the goals' own frame (no parameters);
* :mod:`.network`: :class:`~.network.WarmNet`, spatial attention with relation codes and a short temporal convolution;
* :mod:`.model`: :class:`~.model.WarmModel`, the network with its output parametrisation, loss and checkpoint loading.
"""

from .model import WarmModel

__all__ = ["WarmModel"]
