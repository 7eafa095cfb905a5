"""mer_models: the guided-diffusion retargeting model, its training, sampling and the model zoo.

Imports :mod:`mer_data` (skeletons, FK, shards); never the reverse.
"""

__version__ = "0.1.0"
