"""``python -m mer_models.cli``: the same as ``mer``."""

import sys

from . import main

sys.exit(main())
